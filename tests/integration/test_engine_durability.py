"""No acknowledged write is lost: live map edits survive a kill -9 of the engine."""

from __future__ import annotations

from pathlib import Path

from common import keys
from common.auth import issue_session
from common.messages import (
    EditResult,
    ErrorReply,
    MapRequest,
    MoveItem,
    WorldEdit,
    WorldSnapshot,
    decode,
)
from tests.conftest import Procs, Router
from tests.kit.agentkit import WORLD, start_engine
from tests.kit.lab import make_lab


def _ask(z, key: str, payload: bytes | None = None):  # type: ignore[no-untyped-def]
    for reply in z.get(key, payload=payload, timeout=10.0):
        assert reply.ok is not None, reply.err
        return decode(reply.ok.payload, (WorldSnapshot, EditResult, ErrorReply))
    raise AssertionError(f"no reply on {key}")


def _rock(snapshot: WorldSnapshot) -> tuple[float, float]:
    rock = next(i for i in snapshot.items if i.id == "rock1")
    return rock.x, rock.y


def test_every_acknowledged_edit_survives_an_engine_kill(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    engine = start_engine(lab)
    realm = router.realm
    editor = issue_session(lab.identity, realm, "teacher", ["edit_map"])
    edit_key = keys.world_edit(realm, WORLD)
    snap_key = keys.world_snapshot(realm, WORLD)
    with lab.zsession() as z:
        acknowledged = []
        for i in range(24):
            where = (600.0 + 10 * i, 900.0)
            done = _ask(
                z,
                edit_key,
                editor.seal(edit_key, WorldEdit(op=MoveItem(id="rock1", x=where[0], y=where[1]))),
            )
            assert isinstance(done, EditResult), done
            acknowledged.append(where)
        map_key = keys.world_map(realm, WORLD)
        saved = _ask(z, map_key, editor.seal(map_key, MapRequest(action="save", name="kept")))
        assert isinstance(saved, EditResult), saved
        engine.kill9()  # no save, no goodbye
        start_engine(lab)
        after = _ask(z, snap_key)
        assert isinstance(after, WorldSnapshot)
        assert _rock(after) == acknowledged[-1]
    assert "replayed 24 live edits" in procs.started[-1].output()
