"""``wart twin``: the real robots' twins the lab keeps (its database), versioned.

- ``wart twin --db DB list``: each robot with a twin, its versions, the one in force;
- ``wart twin --db DB show ROBOT``: every version of ROBOT's twin (who fitted it, when,
  from which runs, who saved it) and the drive of the one in force; ``--robot-file
  FILE`` writes its simulated copy as a robot file (the Khepera with the fitted drive:
  ``wart engine --robots-dir``, a map's ``robot_types``);
- ``wart twin --db DB save FILE``: keep a twin file (``wart calibrate --out``) as its
  robot's newest version, after checking every field (a file refused is named with
  each problem; nothing is kept).

``wart calibrate ROBOT --recordings ... --save --db DB`` fits and saves in one go. A
runner given the database (``--twins-db``) simulates a real arena's robot by its
newest twin in dry runs ("Run in simulation"), and says so. docs/CALIBRATION.md.
"""

from __future__ import annotations

import getpass
import sys
from collections.abc import Sequence
from pathlib import Path

from common import cli
from common.twin.twinfile import MAX_BYTES, TwinFileError, parse_twin
from services.lab.database import DbError
from services.lab.twins_db import TwinStore


def main(argv: Sequence[str] | None = None, prog: str = "wart twin") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument("--db", type=Path, required=True, help="the lab's database (registry.db)")
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    sub.add_parser("list", help="each robot with a twin, its versions")
    show = sub.add_parser("show", help="every version of a robot's twin, the newest in force")
    show.add_argument("robot")
    show.add_argument(
        "--robot-file", type=Path, metavar="FILE",
        help="write the simulated copy of the robot as a robot file (TOML)",
    )  # fmt: skip
    save = sub.add_parser("save", help="keep a twin file as its robot's newest version")
    save.add_argument("file", type=Path, help="a twin file (wart calibrate --out)")
    args, _ = cli.parse(p, argv)
    try:
        store = TwinStore.open(args.db)
    except DbError as exc:
        return cli.fail(exc.message, 1)
    try:
        if args.action == "list":
            return _list(store)
        if args.action == "show":
            return _show(store, args.robot, args.robot_file)
        return _save(store, args.file)
    except DbError as exc:
        return cli.fail(exc.message, 1)
    finally:
        store.close()


def _list(store: TwinStore) -> int:
    robots = store.robots()
    if not robots:
        print("no twin is kept: wart calibrate ROBOT --recordings RUN.mcap --save --db DB")
    for robot, count in robots:
        current = store.current(robot)
        assert current is not None  # it has versions
        print(f"{robot}: {count} version(s); in force {current.line()}")
    return 0


def _show(store: TwinStore, robot: str, robot_file: Path | None) -> int:
    versions = store.versions(robot)
    if not versions:
        return cli.fail(f"no twin of {robot} is kept (wart twin --db DB list)", 1)
    print(f"{robot}'s twin, {len(versions)} version(s), the newest in force:")
    for stored in versions:
        print(f"  {stored.line()}")
    twin = versions[-1].twin
    d = twin.drive
    fitted = ", ".join(twin.fitted) or "none (the datasheet's drive)"
    print(f"in force (v{versions[-1].version}): scale_left {d.scale_left:.4g}, scale_right "
          f"{d.scale_right:.4g}, wheel_base_mm {d.wheel_base_mm:.4g}, latency_s "
          f"{d.latency_s:.3g} (fitted: {fitted})")  # fmt: skip
    if robot_file is not None:
        try:
            robot_file.write_text(twin.robot_file())
        except OSError as exc:
            return cli.fail(f"cannot write {robot_file}: {exc.strerror or exc}", 1)
        print(f"wrote {robot_file} (robot type {twin.type_name})")
    return 0


def _save(store: TwinStore, path: Path) -> int:
    try:
        if path.stat().st_size > MAX_BYTES:  # refused unread
            return cli.fail(f"{path} is over {MAX_BYTES} bytes: not a twin file", 1)
        data = path.read_bytes()
    except OSError as exc:
        return cli.fail(f"cannot read {path}: {exc.strerror or exc}", 1)
    try:
        twin = parse_twin(data, str(path))
    except TwinFileError as exc:
        return cli.fail(f"refused, nothing kept:\n{exc}", 1)
    version = store.save(twin, getpass.getuser())
    print(f"kept {twin.model()} as {twin.robot}'s twin v{version} (in force)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
