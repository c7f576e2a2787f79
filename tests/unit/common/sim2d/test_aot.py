"""The kernels compiled ahead of time (common/sim2d/aot.py): the same run, without numba.

What a user relies on: an engine on the ahead-of-time module runs the very
trajectories and readings numba's kernels give, bit for bit, tick after tick
(the bench's full scenario at 10, 100 and 1,000 robots), and imports no numba
doing it; a module built from other sources is never loaded. The comparison
runs each path in its own process, as an engine would (``WART_KERNELS``).
It skips, saying so, only where the module is not built: ``./dev test``
builds it first.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from common.sim2d import aot, packs

REPO = Path(__file__).resolve().parents[4]

try:
    aot.load()
    NOT_BUILT = ""
except aot.Unavailable as exc:
    NOT_BUILT = f"the ahead-of-time module is {exc}"

needs_module = pytest.mark.skipif(bool(NOT_BUILT), reason=NOT_BUILT)

# One process per path: the bench's full scenario (gripper turrets, the lamp, a
# ball for every two robots) driven by the compiled Braitenberg rule, hashed
# after every tick; prints the path, whether numba was imported, and the hashes.
_RUN = """
import hashlib, json, sys
import numpy as np
import services.engine.main  # what an engine imports, zenoh and all
from tests.kit.worlds import CRUISE, WEIGHTS, scenario_world
from common.sim2d import compiled

n, ticks = int(sys.argv[1]), int(sys.argv[2])
world = scenario_world(n, "discs", full=True)
hashes = []
for _ in range(ticks):
    compiled.braitenberg_speeds(
        world.proximity, WEIGHTS, CRUISE, world.tables.max_speed, world.cmd
    )
    world.step()
    digest = hashlib.sha256()
    for a in (world.agent_pose, world.agent_vel, world.counters, world.proximity,
              world.ambient, world.presence, world.object_pose):
        digest.update(np.ascontiguousarray(a).tobytes())
    hashes.append(digest.hexdigest()[:16])
numba = sorted(m for m in sys.modules if m.split(".")[0] in ("numba", "llvmlite"))
print(json.dumps({"path": compiled.PATH, "numba": numba[:3], "hashes": hashes}))
"""


def _run(mode: str, robots: int, ticks: int) -> dict[str, object]:
    env = {**os.environ, "WART_KERNELS": mode}
    done = subprocess.run(
        [sys.executable, "-c", _RUN, str(robots), str(ticks)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    result: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


@needs_module
@pytest.mark.parametrize(("robots", "ticks"), [(10, 300), (100, 150), (1000, 40)])
def test_the_ahead_of_time_kernels_run_numbas_run_bit_for_bit(robots: int, ticks: int) -> None:
    jit = _run("jit", robots, ticks)
    ahead = _run("aot", robots, ticks)
    assert jit["path"] == "jit" and ahead["path"] == "aot"
    assert ahead["numba"] == [], "the ahead-of-time path imported numba"
    jit_hashes, aot_hashes = jit["hashes"], ahead["hashes"]
    assert isinstance(jit_hashes, list) and isinstance(aot_hashes, list)
    assert len(aot_hashes) == len(jit_hashes) == ticks
    pairs = enumerate(zip(jit_hashes, aot_hashes, strict=True))
    first = next((t for t, (a, b) in pairs if a != b), None)
    assert first is None, f"the paths part at tick {first} of {ticks}"


@needs_module
def test_a_state_of_other_types_goes_to_numba_rather_than_read_wrongly(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from common.sim2d import compiled, fused

    if compiled.PATH != "aot":
        pytest.skip(f"this process runs {compiled.WHY}")
    given = list(aot.state_sample())
    state, _ = compiled.new_tick(tuple(given))
    assert isinstance(state, int)  # the module's state: its address
    # numba's kernels stand in (compiling them for a new type takes a minute).
    monkeypatch.setattr(fused, "new_state", lambda given: ("numba's", given[0]))
    monkeypatch.setattr(fused, "entry", lambda state: None)
    given[0] = np.full((1, 6), 50.0)[:, ::2]  # a pose that is a strided view
    state, _ = compiled.new_tick(tuple(given))
    assert state == ("numba's", given[0])


def test_a_module_built_from_other_sources_is_never_loaded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    stale = tmp_path / (aot.PREFIX + "0123456789abcdef" + ".so")
    stale.write_bytes(b"")
    monkeypatch.setattr(aot, "HERE", tmp_path)
    monkeypatch.setattr(aot, "stamp", lambda: "fedcba9876543210")
    with pytest.raises(aot.Unavailable, match="stale"):
        aot.load()
    stale.unlink()
    with pytest.raises(aot.Unavailable, match="not built"):
        aot.load()


def test_a_module_that_does_not_load_leaves_numbas_kernels(monkeypatch: pytest.MonkeyPatch) -> None:
    """A broken build (a file cut short, say) is refused: compiled.py then runs numba's."""
    monkeypatch.setattr(aot, "stamp", lambda: "0000000000000000")
    broken = aot.module_path()
    broken.write_bytes(b"not an extension")
    try:
        with pytest.raises(aot.Unavailable, match="does not load"):
            aot.load()
    finally:
        broken.unlink()


def test_the_stamp_covers_every_file_with_kernels() -> None:
    """An edit to any kernel's file makes a new module name: the old module is not loaded."""
    here = REPO / "common" / "sim2d"
    compiled_code = {
        p.name
        for p in here.glob("*.py")
        if any(w in p.read_text() for w in ("@njit", "@intrinsic", "structref"))
    }
    assert compiled_code <= set(aot.SOURCES)
    assert all((here / name).exists() for name in aot.SOURCES)


def test_the_thread_count_is_numbas() -> None:
    import numba

    assert numba.config.NUMBA_NUM_THREADS == packs.MAX_THREADS  # type: ignore[attr-defined]


def test_an_unknown_kernels_mode_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WART_KERNELS", "fast")
    with pytest.raises(ValueError, match="WART_KERNELS"):
        aot.mode()
