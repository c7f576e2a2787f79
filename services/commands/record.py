"""``wart record list|get``: your recordings in an agent context, and downloading one.

Every slot an agent context runs is recorded (an MCAP file: the robot's
poses and everything in the world, what it sensed, the commands it obeyed,
what the controller printed, how the slot ended). The context keeps each
user's latest few (the host sets how many); you see and fetch your own, the
context's managers anyone's::

    wart record list --context arena --user alice
    wart record get  --context arena --user alice k1-3-9f2a1c   # -> k1-3-9f2a1c.mcap
    wart report k1-3-9f2a1c.mcap                                 # the run's summary

Open the file in Foxglove (or any MCAP tool) to see poses and plot sensors.
For ROS 2 tools (``ros2 bag``, rviz2, PlotJuggler), get it as a ROS 2 bag (a
directory; the ``ros`` extra: ``pip install 'wart-lab[ros]'``, docs/ROS2.md)::

    wart record get --context arena --user alice k1-3-9f2a1c --format rosbag2
    wart record export k1-3-9f2a1c.mcap                 # a file you have: -> k1-3-9f2a1c/
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from common import cli, keys
from common.client.agent_client import AgentClient
from common.messages import RecordingList
from common.recording import Recording, RecordingError, read_recording, ros2bag
from common.zconfig import NetworkOptions
from services.commands.control import session_for
from services.commands.terminal import say


def _parser(prog: str) -> argparse.ArgumentParser:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument(
        "action",
        choices=("list", "get", "export"),
        help="list your recordings, get one, or export a recording file as a ROS 2 bag",
    )
    p.add_argument(
        "name", nargs="?", help="get: the recording's name (as listed); export: its .mcap file"
    )
    p.add_argument("--context", help="list, get: the agent context, e.g. arena")
    p.add_argument("--user", help="list, get: your account")
    p.add_argument("--password-file", help="read the password from this file")
    p.add_argument("--of", metavar="USER", help="list: another user's (the manage right)")
    p.add_argument("--all", action="store_true", help="list: every user's (the manage right)")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        help="get, export: where to write (default NAME.mcap; a ROS 2 bag's directory: NAME)",
    )
    p.add_argument("--summary", action="store_true", help="get: the run's summary (JSON) instead")
    p.add_argument(
        "--format",
        choices=("mcap", "rosbag2"),
        default="mcap",
        help="get: the lab's recording (mcap) or a ROS 2 bag (rosbag2: ROS 2 messages, MCAP); "
        "export writes rosbag2",
    )
    return p


def _size(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e6 else f"{n / 1e3:.0f} kB"


def show_list(listing: RecordingList) -> None:
    if not listing.recordings:
        say(f"no recordings in {listing.ctx} (it keeps the latest {listing.keep} per user)")
        return
    say(f"{len(listing.recordings)} recording(s) in {listing.ctx}, latest {listing.keep} per user:")
    for r in listing.recordings:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(r.start))
        dist = f"{r.distance_mm / 1000:.2f} m" if r.distance_mm is not None else "-"
        say(
            f"  {r.name:<24} {r.user:<12} {r.agent:<6} {when}  {_size(r.size):>8}  "
            f"{dist:>7}  {r.status or '?'}: {r.reason}"
        )


def _progress() -> Callable[[int, int], None]:
    last = [0.0]

    def show(done: int, total: int) -> None:
        now = time.monotonic()
        if total > 2_000_000 and (now - last[0] > 0.5 or done >= total):
            last[0] = now
            say(f"  {_size(done)} of {_size(total)}")

    return show


def main(argv: Sequence[str] | None = None, prog: str = "wart record") -> int:
    args, options = cli.parse_networked(_parser(prog), argv)
    if args.action == "export":
        return _export(args.name, args.output)
    if not args.context or not args.user:
        return cli.fail(f"{args.action} needs --context and --user")
    try:
        keys.check_ident("context", args.context)
        keys.check_ident("user", args.user)
        for name in (args.name, args.of):
            if name:
                keys.check_ident("name", name)
    except ValueError as exc:
        return cli.fail(str(exc))
    if args.action == "get" and not args.name:
        return cli.fail("get needs the recording's name (see: wart record list)")
    if args.format == "rosbag2":
        if args.summary:
            return cli.fail("--summary is JSON: it has no rosbag2 format")
        if not ros2bag.available():  # said before logging in, not after the download
            return cli.fail(f"--format rosbag2 needs the rosbags library: {ros2bag.ROS_INSTALL}")
        bag = args.output or Path(args.name)
        if bag.exists():
            return cli.fail(f"{bag} exists: a bag is written to a new directory (-o DIR)")
    return _with_context(args, options)


def _with_context(args: argparse.Namespace, options: NetworkOptions) -> int:
    def body(agents: AgentClient) -> int:
        if args.action == "list":
            show_list(agents.recordings(args.of, all_users=args.all))
            return 0
        if args.format == "rosbag2":
            return _get_rosbag2(agents, args.name, args.output or Path(args.name))
        suffix = ".summary.json" if args.summary else ".mcap"
        dest = args.output or Path(f"{args.name}{suffix}")
        try:
            agents.download(args.name, dest, summary=args.summary, progress=_progress())
        except OSError as exc:
            return cli.fail(f"cannot write: {exc}", 1)
        say(f"wrote {dest} ({_size(dest.stat().st_size)})")
        return 0

    return session_for(args, options, body)


def _export(file: str | None, output: Path | None) -> int:
    """A recording file on this machine as a ROS 2 bag (no lab needed)."""
    if not file:
        return cli.fail("export needs the recording's file (wart record export RUN.mcap)")
    if not ros2bag.available():
        return cli.fail(f"export needs the rosbags library: {ros2bag.ROS_INSTALL}")
    source = Path(file)
    bag = output or source.with_suffix("")
    if bag.exists():
        return cli.fail(f"{bag} exists: a bag is written to a new directory (-o DIR)")
    return _write_bag(source, bag)


def _write_bag(source: Path, bag: Path) -> int:
    """The recording file ``source`` written as a ROS 2 bag in ``bag``, and said."""
    try:
        recording = read_recording(source)
        export = ros2bag.write_bag(recording, bag)
    except (OSError, RecordingError, ros2bag.RosbagsMissing) as exc:
        return cli.fail(f"cannot write the bag: {exc}", 1)
    _said_bag(export, recording)
    return 0


def _said_bag(export: ros2bag.Export, recording: Recording) -> None:
    topics = ", ".join(f"{topic} {n}" for topic, n in sorted(export.counts.items()))
    say(f"wrote {export.path}/ (ROS 2 bag, MCAP storage): {topics}")
    for note in export.notes:
        say(f"  note: {note}")
    if recording.truncated:
        say(f"  note: the recording {recording.truncated}: the bag holds what it had")


def _get_rosbag2(agents: AgentClient, name: str, bag: Path) -> int:
    """Download the recording (to a temporary file) and write it as a ROS 2 bag in ``bag``."""
    with tempfile.TemporaryDirectory(prefix="wart-record-") as tmp:
        try:
            path = agents.download(name, Path(tmp) / f"{name}.mcap", progress=_progress())
        except (OSError, RecordingError, ros2bag.RosbagsMissing) as exc:
            return cli.fail(f"cannot write the bag: {exc}", 1)
        return _write_bag(path, bag)


if __name__ == "__main__":
    sys.exit(main())
