"""``wart``: one console command, a subcommand per process or tool.

Each subcommand lives in its own module with a ``main(argv, prog)``; this file
only maps names to modules, imported on demand so ``wart --help`` stays fast.
"""

from __future__ import annotations

import ctypes
import importlib
import importlib.util
import os
import signal
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import NoReturn

# name: (module, one-line description). Kept in the order of the help text.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "up": ("services.commands.up", "start a whole lab on this machine under supervision"),
    "router": ("services.router.main", "run a Zenoh router (one per host)"),
    "registry": (
        "services.registry.main",
        "the server: accounts, login, ACL, presence, directory",
    ),
    "users": (
        "services.registry.users",
        "add, change and remove accounts and grants (registry DB)",
    ),
    "course": (
        "services.grader.course_cli",
        "a course's assignments: add or check an assignment file (registry DB)",
    ),
    "grader": ("services.grader.main", "grade submissions to assignments in simulation"),
    "lti": (
        "services.lti.main",
        "an LTI 1.3 tool: launches from Moodle or Canvas, grades passed back",
    ),
    "submit": (
        "services.commands.submit",
        "hand a controller in to an assignment; see your scores",
    ),
    "leaderboard": ("services.commands.leaderboard", "an assignment's best score per student"),
    "ban": (
        "services.commands.ban",
        "keep an account out for a while or for good, with a reason (admins)",
    ),
    "throttles": (
        "services.commands.throttles",
        "the registry's login throttles: list them, unlock an account, clear a source (admins)",
    ),
    "audit": (
        "services.commands.audit",
        "who did what, when, from where: the audit trail, filtered, CSV/JSON (admins)",
    ),
    "context": ("services.context.main", "run a context: wart context chat --name ROOM"),
    "chat": ("services.commands.chat", "chat in a room from a terminal"),
    "khepera-emulator": (
        "services.bridge.emulator",
        "an emulated Khepera robot on a pseudo-terminal (no hardware needed)",
    ),
    "engine": ("services.engine.main", "run a simulated world (the Sim2D engine)"),
    "viewer": ("viewers.web.app", "serve the web viewer (browser WARTApp on viser)"),
    "runner": ("services.runner.main", "run uploaded controllers in sandboxes"),
    "control": (
        "services.commands.control",
        "drive a robot with your controller from this machine",
    ),
    "deploy": ("services.commands.deploy", "upload a controller to run on a robot in the lab"),
    "record": ("services.commands.record", "list and download your recorded runs (MCAP)"),
    "report": ("services.commands.report", "the summary (and plots) of a recorded run"),
    "calibrate": (
        "services.commands.calibrate",
        "a real robot's twin (slip, wheel base, latency, IR gains) fitted from its recordings",
    ),
    "twin": (
        "services.commands.twin",
        "real robots' twins kept in the lab's database: list, show, save (versioned)",
    ),
    "replay": (
        "viewers.web.replay",
        "replay a recorded run in a web viewer: timeline, play, speed (no lab needed)",
    ),
    "bridge": ("services.bridge.main", "real Khepera robots on serial ports as a real world"),
    "camera": (
        "services.camera.main",
        "a camera over a real arena: its video and the robots it tracks (and `calibrate`)",
    ),
    "host": ("services.host.main", "run this machine's share of a multi-host lab (lab file)"),
    "arena": (
        "services.commands.arena",
        "start, list and stop simulated arenas on the lab's hosts",
    ),
    "room": ("services.commands.room", "start and stop chat rooms on request (host permission)"),
    "certs": (
        "services.commands.certs",
        "the lab's CA and TLS certificates (routers, services, clients)",
    ),
    "robots": (
        "services.commands.robots",
        "robot types and component types from their schemas: list, describe, check a file",
    ),
    "doctor": (
        "services.commands.doctor",
        "check a lab's hosts, routers, links and services; say what is wrong",
    ),
    "probe": (
        "services.commands.probe",
        "is a service's liveliness token in the lab? (Kubernetes' probes)",
    ),
    "kube": (
        "services.commands.kube",
        "a lab file's host as Kubernetes manifests (or pods podman can play)",
    ),
}


# Two-word commands whose second word is a tool of its own (the first word's module is
# another process's: `wart course` edits the lab's database, `wart course competition`
# asks the grader over the network).
SUBCOMMAND_TOOLS: dict[tuple[str, str], str] = {
    ("course", "competition"): "services.commands.competition",
}


# The commands a client install runs (`pip install wart-lab`: a student's laptop). Every
# other command is one of the lab's services or its operators' tools and needs the `lab`
# extra; tests/unit/services/test_cli_client.py checks that these import none of it.
CLIENT_COMMANDS = frozenset(
    {
        "chat",
        "control",
        "deploy",
        "submit",
        "leaderboard",
        "record",
        "report",
        "robots",
        "course competition",
    }
)

# The `lab` extra's packages (pyproject.toml) by their top-level module, in its order;
# setuptools (the ahead-of-time build only) and matplotlib (plots, optional) are not needed
# to start a service.
LAB_MODULES = {
    "pymunk": "pymunk",
    "serial": "pyserial",
    "viser": "viser",
    "numba": "numba",
    "psutil": "psutil",
    "cryptography": "cryptography",
    "cv2": "opencv-python-headless",
    "jwt": "PyJWT",
    "scipy": "scipy",
}

LAB_INSTALL = "pip install 'wart-lab[lab]'"


def missing_lab_packages() -> list[str]:
    """The lab extra's packages this install lacks (looked up, not imported: no cost)."""
    return [
        package
        for module, package in LAB_MODULES.items()
        if importlib.util.find_spec(module) is None
    ]


def needs_the_lab(command: str, missing: Sequence[str]) -> str:
    return (
        f"wart {command}: this command needs the lab's services: {LAB_INSTALL}\n"
        f"  (this is a client install, without {', '.join(missing)}; a client runs "
        f"{', '.join(sorted(CLIENT_COMMANDS))})"
    )


def _import_command(command: str, module_name: str) -> ModuleType | None:
    """The command's module, or None (said on stderr) on a client install of a lab command."""
    if command not in CLIENT_COMMANDS and (missing := missing_lab_packages()):
        print(needs_the_lab(command, missing), file=sys.stderr)
        return None
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        top = (error.name or "").partition(".")[0]
        if top not in LAB_MODULES:
            raise
        print(needs_the_lab(command, [LAB_MODULES[top]]), file=sys.stderr)
        return None


def usage() -> str:
    width = max(len(name) for name in SUBCOMMANDS)
    lines = [
        "usage: wart <command> [options]   (wart <command> --help for each)",
        "",
        "A distributed lab for designing, testing and deploying robot controllers.",
        "",
        "commands:",
    ]
    client = bool(missing_lab_packages())
    for name, (_, text) in SUBCOMMANDS.items():
        mark = "*" if client and name not in CLIENT_COMMANDS else " "
        lines.append(f" {mark}{name:<{width}}  {text}")
    if client:
        lines += ["", f"* needs the lab's services, not in this client install: {LAB_INSTALL}"]
    return "\n".join(lines)


def _die_with_supervisor() -> None:
    """Under a supervisor (WART_PARENT_PID), ask the kernel for SIGTERM when it dies."""
    parent = os.environ.get("WART_PARENT_PID")
    if not parent or not sys.platform.startswith("linux"):
        return
    pr_set_pdeathsig = 1
    try:
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGTERM))
    except (OSError, AttributeError):
        return
    if str(os.getppid()) != parent:  # it died before prctl took effect
        sys.exit(1)


def main(argv: Sequence[str] | None = None) -> int:
    _die_with_supervisor()
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name, rest = args[0], args[1:]
    if name not in SUBCOMMANDS:
        print(f"wart: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    tool = SUBCOMMAND_TOOLS.get((name, rest[0])) if rest else None
    if tool is not None:
        name, rest = f"{name} {rest[0]}", rest[1:]
    module = _import_command(name, tool or SUBCOMMANDS[name][0])
    if module is None:
        return 2
    try:
        return int(module.main(rest, prog=f"wart {name}") or 0)
    except KeyboardInterrupt:  # a second Ctrl-C: quit at once, as the tool said, no traceback
        print(f"wart {name}: interrupted", file=sys.stderr)
        return 130


def run() -> NoReturn:
    """The ``wart`` command: :func:`main` in a process of its own, ended by its exit code."""
    code = main()
    # Here, after the command: a command that never opened a session (--help, the
    # pods' probe) loads no Zenoh for it.
    from common.service import exit_process

    exit_process(code)


if __name__ == "__main__":
    run()
