"""``wart context race``: a race over one world's frames (the plugin's context type).

Watches ``world/<w>/frame`` (the lab's keys, common/keys.py), counts each
robot's laps across the start line (race.py) and, when one finishes, writes
the standings as JSON to ``--result`` and logs them.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from common import cli, keys
from common.messages import WorldFrame, WorldSnapshot, decode
from common.service import close_session, open_session
from wart_race.race import Race

log = logging.getLogger("wart.race")


def _line(text: str) -> tuple[float, float, float, float]:
    values = [float(v) for v in text.split(",")]
    if len(values) != 4:
        raise ValueError("--start must be X0,Y0,X1,Y1 in mm")
    return values[0], values[1], values[2], values[3]


def main(argv: Sequence[str] | None = None, prog: str = "wart context race") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("--world", required=True, help="the world whose robots race")
    p.add_argument("--start", required=True, help="the start line X0,Y0,X1,Y1 (mm)")
    p.add_argument("--laps", type=int, default=3, help="laps to finish (default 3)")
    p.add_argument("--result", type=Path, required=True, help="where to write the standings")
    p.add_argument("--seconds", type=float, default=600.0, help="give up after this long")
    args, options = cli.parse(p, argv)
    assert options is not None
    try:
        keys.check_ident("world", args.world)
        race = Race(_line(args.start), args.laps)
    except ValueError as exc:
        return cli.fail(str(exc))
    if not 1 <= args.laps <= 1000:
        return cli.fail("--laps must be 1..1000")
    session = open_session(options, wait=30.0)
    done = threading.Event()
    rows: list[str] = []
    try:
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
        done.wait(args.seconds)
        sub.undeclare()
    finally:
        close_session(session)
    result = {"world": args.world, "laps": args.laps, "winner": race.winner,
              "standings": race.standings(), "at": time.time()}  # fmt: skip
    args.result.write_text(json.dumps(result, indent=1))
    log.info("race on %s: winner %s", args.world, race.winner)
    return 0 if race.finished else 1


class _RaceType:
    """The context type the entry point names: ``wart context race``."""

    kind = "race"
    doc = "a race: a start line, laps, a finish, over one world's frames"

    @staticmethod
    def main(argv: Sequence[str] | None = None, prog: str = "wart context race") -> int:
        return main(argv, prog)


RACE = _RaceType()

if __name__ == "__main__":
    sys.exit(main())
