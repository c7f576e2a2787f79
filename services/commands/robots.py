"""``wart robots``: the robot types and component types this lab has, from their schemas.

- ``wart robots list``: every robot type (its components), every component
  type (built-in or from which plugin), engine and context types from
  plugins, and what was refused and why;
- ``wart robots describe NAME``: a robot type (each component with the
  parameters its file sets, units, defaults, and the controller calls it
  gives) or a component type (its parameters: kind, unit, default, range);
- ``wart robots check FILE``: validate a robot file as the lab would load it,
  printing every problem with its line and field (exit 1 if refused).

Robot types come from the shipped files, installed plugins (entry points
``wart.agents``) and ``--robots-dir`` (or ``WART_ROBOTS_DIR``): a lab's saved
robot files, data only, never executed.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from common import cli
from common.robots import describe, registry
from common.robots.robotfile import MAX_BYTES, RobotFileError, parse, too_big


def main(argv: Sequence[str] | None = None, prog: str = "wart robots") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument(
        "--robots-dir",
        type=Path,
        metavar="DIR",
        help="a directory of robot files (*.toml) to load too (default: WART_ROBOTS_DIR)",
    )
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    sub.add_parser("list", help="robot types, component types, plugins and what was refused")
    d = sub.add_parser("describe", help="a robot type or component type, from its schema")
    d.add_argument("name", help="a robot type (khepera) or a component type (range_finder)")
    c = sub.add_parser("check", help="validate a robot file (every problem, line and field)")
    c.add_argument("file", type=Path)
    args, _ = cli.parse(p, argv)
    reg = registry.build(robots_dir=args.robots_dir)
    if args.action == "list":
        print(describe.list_text(reg))
        return 0
    if args.action == "describe":
        if args.name in reg.robots:
            print(describe.robot_text(reg.robots[args.name], reg))
            return 0
        if args.name in reg.components:
            origin = reg.describe_origin("wart.components", args.name)
            print(describe.component_text(reg.components[args.name], origin))
            return 0
        known = ", ".join(sorted(reg.robots) + sorted(reg.components))
        return cli.fail(f"no robot or component type {args.name!r} (known: {known})", 1)
    path: Path = args.file
    try:
        size = path.stat().st_size
        data = path.read_bytes() if size <= MAX_BYTES else b""  # too big: never read
    except OSError as exc:
        return cli.fail(f"cannot read {path}: {exc.strerror or exc}", 1)
    try:
        if size > MAX_BYTES:
            raise too_big(path.name, size)
        spec = parse(data, path.name, reg.components)
    except RobotFileError as exc:
        print(str(exc), file=sys.stderr)
        print(f"{path.name}: refused ({len(exc.problems)} problem(s))", file=sys.stderr)
        return 1
    parts = ", ".join(f"{c.name}:{c.type}" for c in spec.components)
    print(f"{path.name}: robot type {spec.name} is valid: {parts}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
