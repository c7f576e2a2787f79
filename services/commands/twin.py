"""``wart twin``: the real robots' twins the lab keeps (the registry serves them), versioned.

- ``wart twin --user U list``: each arena's robot with a twin, its versions, the one
  in force;
- ``wart twin --user U show ROBOT [--arena CTX]``: every version of the twin in force
  for the arena's ROBOT (who fitted it, when, from which runs, who saved it) and its
  drive; ``--robot-file FILE`` writes its simulated copy as a robot file (the Khepera
  with the fitted drive and IR gains: ``wart engine --robots-dir``, a map's
  ``robot_types``);
- ``wart twin --user U save FILE [--arena CTX]``: keep a twin file (``wart calibrate
  --out``) as the newest version of the arena's robot's twin, after checking every
  field here and in the registry (a file refused is named with each problem; nothing
  is kept).

Twins are kept by arena (the real arena's agent context) and robot: two arenas' k1
are two robots. A twin kept for no arena (a lab admin's save without ``--arena``, or
one kept before twins were per arena) is in force for a robot of that name in an
arena without its own.

The registry keeps the twins in the lab's database and says who may read them (the
runners, teachers, lab admins, arena owners) and who may save one (the owner of the
arena named with ``--arena``, or a lab admin). ``wart calibrate ROBOT --recordings ...
--save`` fits and saves in one go. A runner, wherever it runs, asks the registry for
a real arena's robot's twin in dry runs ("Run in simulation"), and says so.
The password comes from --password-file, WART_PASSWORD or a prompt.
docs/CALIBRATION.md.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from common import cli, keys
from common.client.lab_client import LabClient
from common.twin.twinfile import MAX_BYTES, Twin, TwinFileError, parse_twin
from common.zconfig import NetworkOptions
from services.commands.arena import add_lab_arguments, lab_login, run_lab_command


def add_login_arguments(p: argparse.ArgumentParser, *, required: bool = True) -> None:
    """The lab and the account a twin command asks the registry as."""
    add_lab_arguments(p)
    p.add_argument("--user", required=required, help="your account (a teacher, an arena's owner)")
    p.add_argument("--password-file", help="read the password from this file")


def main(argv: Sequence[str] | None = None, prog: str = "wart twin") -> int:
    p = cli.parser(prog, __doc__ or "")
    add_login_arguments(p)
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    sub.add_parser("list", help="each robot with a twin, its versions")
    show = sub.add_parser("show", help="every version of a robot's twin, the newest in force")
    show.add_argument("robot")
    show.add_argument("--arena", help="the robot's arena (none: the twin kept for no arena)")
    show.add_argument(
        "--robot-file", type=Path, metavar="FILE",
        help="write the simulated copy of the robot as a robot file (TOML)",
    )  # fmt: skip
    save = sub.add_parser("save", help="keep a twin file as its robot's newest version")
    save.add_argument("file", type=Path, help="a twin file (wart calibrate --out)")
    save.add_argument("--arena", help="the arena you own the robot's twin for (admins: none)")
    return run_lab_command(p, argv, _run)


def _run(args: argparse.Namespace, options: NetworkOptions) -> int:
    arena = getattr(args, "arena", None)  # show and save name one
    if arena is not None:
        keys.check_ident("--arena", arena)
    if args.action == "save":  # checked before any network: a bad file costs no login
        try:
            twin = read_twin_file(args.file)
        except ValueError as exc:
            return cli.fail(str(exc), 1)
    with lab_login(args, options) as client:
        if args.action == "list":
            return _list(client)
        if args.action == "show":
            return _show(client, args.robot, args.arena, args.robot_file)
        return save_twin(client, twin, args.arena)


def read_twin_file(path: Path) -> Twin:
    """A twin file, checked field by field; ValueError naming each problem."""
    try:
        if path.stat().st_size > MAX_BYTES:  # refused unread
            raise ValueError(f"{path} is over {MAX_BYTES} bytes: not a twin file")
        data = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        return parse_twin(data, str(path))
    except TwinFileError as exc:
        raise ValueError(f"refused, nothing kept:\n{exc}") from None


def save_twin(client: LabClient, twin: Twin, arena: str | None) -> int:
    saved = client.twins.save(twin.text, twin.robot, arena)
    where = f" in {saved.arena}" if saved.arena else " (for no arena in particular)"
    print(f"kept {saved.model} as {saved.robot}'s twin{where} v{saved.version} (in force)")
    return 0


def _list(client: LabClient) -> int:
    robots = client.twins.robots()
    if not robots:
        print("no twin is kept: wart calibrate ROBOT --recordings RUN.mcap --save --user U")
    for listed in robots:
        name = f"{listed.arena}/{listed.robot}" if listed.arena else f"{listed.robot} (no arena)"
        print(f"{name}: {listed.versions} version(s); in force {listed.current}")
    return 0


def _show(client: LabClient, robot: str, arena: str | None, robot_file: Path | None) -> int:
    reply = client.twins.of(robot, arena, history=True)
    where = f" in {arena}" if arena else ""
    if reply.current is None:
        return cli.fail(f"no twin of {robot}{where} is kept (wart twin list)", 1)
    try:
        twin = parse_twin(reply.current.document, f"{robot}'s twin from the registry")
    except TwinFileError as exc:
        return cli.fail(str(exc), 1)
    whose = "" if reply.arena else ": the one kept for no arena"
    print(f"{robot}'s twin{where}{whose}, {reply.versions} version(s), the newest in force:")
    for line in reply.history:
        print(f"  {line}")
    d = twin.drive
    fitted = ", ".join(twin.fitted) or "none (the datasheet's drive)"
    print(f"in force (v{reply.current.version}): scale_left {d.scale_left:.4g}, scale_right "
          f"{d.scale_right:.4g}, wheel_base_mm {d.wheel_base_mm:.4g}, latency_s "
          f"{d.latency_s:.3g} (fitted: {fitted})")  # fmt: skip
    if robot_file is not None:
        try:
            robot_file.write_text(twin.robot_file())
        except OSError as exc:
            return cli.fail(f"cannot write {robot_file}: {exc.strerror or exc}", 1)
        print(f"wrote {robot_file} (robot type {twin.type_name})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
