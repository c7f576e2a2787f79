"""``wart context race``: a race over one world's frames (the plugin's context type).

Watches ``world/<w>/frame`` (the lab's keys, common/keys.py), counts each
robot's laps across the start line (race.py) and, when one finishes, writes
the standings as JSON to ``--result`` (default ``DATA_DIR/result.json``) and
logs them. It holds ``alive/context/<name>`` while it runs and runs until it
is stopped (a host's supervisor restarts what exits), or, with
``--exit-when-done``, until the race is over or ``--seconds`` have passed.

Hosted on request (``wart room new RACE --kind race --param world=arena
--param start=X0,Y0,X1,Y1 --param laps=2``), its params are checked by the
host against :data:`PARAMS`.
"""

from __future__ import annotations

import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from common import cli, keys
from common.keys import AliveKind
from common.messages import WorldFrame, WorldSnapshot, decode
from common.robots.schema import Param
from common.service import close_session, open_session
from wart_race.race import Race

log = logging.getLogger("wart.race")


def _line(text: str) -> tuple[float, float, float, float]:
    values = [float(v) for v in text.split(",")]
    if len(values) != 4:
        raise ValueError("--start must be X0,Y0,X1,Y1 in mm")
    return values[0], values[1], values[2], values[3]


# What a host checks a request's params against (common/robots/registry.py,
# context_arguments): the params a user may give when the race is hosted on request.
PARAMS = (
    Param("world", "text", "the world whose robots race"),
    Param("start", "text", "the start line X0,Y0,X1,Y1 in mm (laps count leftwards across it)"),
    Param("laps", "integer", "laps to finish", "", 3, lo=1, hi=1000),
)


def main(argv: Sequence[str] | None = None, prog: str = "wart context race") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("--world", required=True, help="the world whose robots race")
    p.add_argument("--start", required=True, help="the start line X0,Y0,X1,Y1 (mm)")
    p.add_argument("--laps", type=int, default=3, help="laps to finish (default 3)")
    p.add_argument("--name", default="race", help="this race's context name (default race)")
    p.add_argument("--data-dir", type=Path, help="where its result goes (result.json)")
    p.add_argument("--result", type=Path, help="where to write the standings")
    p.add_argument("--exit-when-done", action="store_true", help="exit when the race is over")
    p.add_argument("--seconds", type=float, default=600.0, help="with --exit-when-done: give up")
    args, options = cli.parse_networked(p, argv)
    try:
        keys.check_ident("world", args.world)
        keys.check_ident("name", args.name)
        race = Race(_line(args.start), args.laps)
    except ValueError as exc:
        return cli.fail(str(exc))
    if not 1 <= args.laps <= 1000:
        return cli.fail("--laps must be 1..1000")
    if args.result is None:
        if args.data_dir is None:
            return cli.fail("give --result or --data-dir")
        args.data_dir.mkdir(parents=True, exist_ok=True)
        args.result = args.data_dir / "result.json"
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    session = open_session(options, wait=30.0)
    done = threading.Event()
    rows: list[str] = []
    try:
        token = session.liveliness().declare_token(
            keys.alive(options.realm, AliveKind.CONTEXT, args.name)
        )
        reply = session.get(keys.world_snapshot(options.realm, args.world), timeout=10.0)
        for r in reply:
            if r.ok is not None:
                rows = decode(r.ok.payload.to_bytes(), WorldSnapshot).rows
        log.info("race on %s: %d robots, %d laps", args.world, len(rows), args.laps)

        def on_frame(sample: object) -> None:
            frame = decode(sample.payload.to_bytes(), WorldFrame)  # type: ignore[attr-defined]
            poses = np.asarray(frame.poses.to_numpy())
            race.update(
                frame.sim_time,
                {a: (float(poses[i, 0]), float(poses[i, 1])) for i, a in enumerate(rows)},
            )
            if race.finished:
                done.set()

        sub = session.declare_subscriber(keys.world_frame(options.realm, args.world), on_frame)
        if args.exit_when_done:
            done.wait(args.seconds)
        else:
            while not stop.wait(0.2):
                if done.is_set() and not args.result.exists():
                    _write(args, race)
        sub.undeclare()
        token.undeclare()
    finally:
        close_session(session)
    _write(args, race)
    return 0 if race.finished else 1


def _write(args: object, race: Race) -> None:
    world, laps, result = args.world, args.laps, args.result  # type: ignore[attr-defined]
    standings = {"world": world, "laps": laps, "winner": race.winner,
                 "standings": race.standings(), "at": time.time()}  # fmt: skip
    result.write_text(json.dumps(standings, indent=1))
    log.info("race on %s: winner %s", world, race.winner)


class _RaceType:
    """The context type the entry point names: ``wart context race``."""

    kind = "race"
    doc = "a race: a start line, laps, a finish, over one world's frames"
    params = PARAMS

    @staticmethod
    def main(argv: Sequence[str] | None = None, prog: str = "wart context race") -> int:
        return main(argv, prog)


RACE = _RaceType()

if __name__ == "__main__":
    sys.exit(main())
