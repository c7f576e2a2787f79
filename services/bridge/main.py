"""``wart bridge``: real Khepera robots on serial ports as the agents of a real world.

    wart bridge --world real1 --port /dev/ttyUSB0=k1 [--port PATH[=ID] ...]
                [--autodetect [--scan GLOB ...] [--no-system-ports]]
                [--baud 9600|19200|38400] [--arena-mm W H] [--poll-ms 50] [--watchdog-ms 300]

Each robot becomes agent ID (default: the port's file name) of world WORLD,
on the same keys and messages as a simulated world: sensor samples at the
polling rate, frames with every robot's odometry pose, a snapshot with the
arena and each robot's online state, commands obeyed from the current lease
holder only. A robot that is unplugged is reported offline and picked up
again when its port returns (use a stable path: /dev/serial/by-id/...).
--autodetect probes serial ports for robots (ask B) at start and every
--scan-interval seconds. Motors stop when commands stop for --watchdog-ms,
when the lease ends, and when the bridge stops.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence

import zenoh

from common import cli
from common.client.service_login import add_world_args, world_login
from common.keys import is_ident
from common.service import run_service
from services.bridge.link import BAUD_RATES
from services.bridge.odometry import Pose
from services.bridge.robot import RobotOptions
from services.bridge.service import BridgeService, BridgeSettings, RobotSpec, agent_id_for


def parse_port(text: str, taken: Sequence[str]) -> RobotSpec:
    """``PATH``, ``PATH=ID`` or ``PATH=ID@X,Y,HEADING_DEG`` (mm, mm, degrees)."""
    path, sep, rest = text.partition("=")
    if not path:
        raise ValueError(f"--port {text!r}: no port path")
    agent, _, where = rest.partition("@")
    if not sep or not agent:
        agent = agent_id_for(path, taken)
    if not is_ident(agent):
        raise ValueError(f"--port {text!r}: agent id {agent!r} is not valid (letters, digits, _-.)")
    if agent in taken:
        raise ValueError(f"--port {text!r}: agent id {agent} is used twice")
    pose = None
    if where:
        try:
            x, y, deg = (float(v) for v in where.split(","))
        except ValueError:
            raise ValueError(f"--port {text!r}: the pose is X,Y,HEADING_DEG (numbers)") from None
        if not all(math.isfinite(v) for v in (x, y, deg)):
            raise ValueError(f"--port {text!r}: the pose must be finite numbers")
        pose = Pose(x, y, math.radians(deg))
    return RobotSpec(port=path, agent=agent, pose=pose)


def main(argv: Sequence[str] | None = None, prog: str = "wart bridge") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("--world", required=True, help="this real world's name (e.g. real1)")
    p.add_argument(
        "--port",
        action="append",
        default=[],
        metavar="PATH[=ID[@X,Y,DEG]]",
        help="a robot's serial port, its agent id and start pose in the arena (repeatable)",
    )
    p.add_argument("--autodetect", action="store_true", help="probe serial ports for robots")
    p.add_argument(
        "--scan",
        action="append",
        default=[],
        metavar="GLOB",
        help="with --autodetect: also probe these paths or globs (repeatable)",
    )
    p.add_argument(
        "--no-system-ports",
        action="store_true",
        help="with --autodetect: probe only the --scan paths, not every port pyserial lists",
    )
    p.add_argument(
        "--scan-interval",
        type=float,
        default=5.0,
        help="with --autodetect: seconds between probes for new robots (0: only at start)",
    )
    p.add_argument(
        "--baud",
        type=int,
        choices=BAUD_RATES,
        help="the robots' baud rate (default 38400; --autodetect without it tries all three)",
    )
    p.add_argument(
        "--arena-mm",
        nargs=2,
        type=float,
        default=(1000.0, 1000.0),
        metavar=("W", "H"),
        help="the real arena's size in mm (default 1000 1000)",
    )
    p.add_argument(
        "--poll-ms", type=float, default=50.0, help="ms between sensor rounds (default 50)"
    )
    add_world_args(p)
    args, options = cli.parse_networked(p, argv)
    if args.user and (args.identity is None or not options.registry_key):
        p.error("--user needs --identity and --registry-key")
    if not is_ident(args.world):
        p.error(f"--world {args.world!r} is not a valid name (letters, digits, _ - .)")
    if not args.port and not args.autodetect:
        p.error("give at least one --port, or --autodetect")
    if (args.scan or args.no_system_ports) and not args.autodetect:
        p.error("--scan and --no-system-ports need --autodetect")
    w, h = args.arena_mm
    if not (0 < w <= 1e6 and 0 < h <= 1e6):
        p.error("--arena-mm: width and height must be between 0 and 1000000 mm")
    if not 0 <= args.poll_ms <= 10_000:
        p.error("--poll-ms must be between 0 and 10000")
    if not 10 <= args.watchdog_ms <= 60_000:
        p.error("--watchdog-ms must be between 10 and 60000")
    if not 0 <= args.scan_interval <= 3600:
        p.error("--scan-interval must be between 0 and 3600 s")
    robots: list[RobotSpec] = []
    for text in args.port:
        try:
            robots.append(parse_port(text, [r.agent for r in robots]))
        except ValueError as exc:
            p.error(str(exc))
    registry_key = cli.registry_key(p, options)
    baud = args.baud or 38400
    settings = BridgeSettings(
        robots=tuple(robots),
        autodetect=args.autodetect,
        scan=tuple(args.scan),
        system_ports=not args.no_system_ports,
        scan_interval=args.scan_interval,
        bauds=(args.baud,) if args.baud else (38400, 19200, 9600),
        arena=(w, h),
        robot=RobotOptions(
            baud=baud, poll_interval=args.poll_ms / 1000.0, watchdog=args.watchdog_ms / 1000.0
        ),
        frame_interval=max(0.02, args.poll_ms / 1000.0),
        registry_key=registry_key,
    )

    def build(session: zenoh.Session) -> BridgeService:
        login = world_login(session, options.realm, registry_key, args.user, args.identity)
        identity = (lambda: login.session) if login is not None else None
        return BridgeService(session, options.realm, args.world, settings, identity=identity)

    return run_service(f"bridge {args.world}", options, build)


if __name__ == "__main__":
    sys.exit(main())
