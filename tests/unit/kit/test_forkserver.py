"""The kit's fork server: a process it forks behaves as ``python -m services.cli`` does, and
nothing it forked outlives the test process that asked for it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import psutil

from tests.kit.forkserver import ForkServer
from tests.kit.procs import REPO, free_port, wart_env
from tests.kit.waits import wait_for


def _spawn(server: ForkServer, tmp_path: Path, *args: str, **env: str):  # type: ignore[no-untyped-def]
    out = open(tmp_path / "out.txt", "wb")  # noqa: SIM115 - the child holds its own copy
    with out, open(os.devnull, "rb") as nothing:
        return server.spawn(
            args,
            cwd=tmp_path,
            env=wart_env(env),
            stdin=nothing.fileno(),
            stdout=out.fileno(),
            stderr=out.fileno(),
        )


def test_a_forked_command_has_its_arguments_output_exit_code_and_environment(
    tmp_path: Path,
) -> None:
    server = ForkServer(REPO)
    try:
        help_run = _spawn(server, tmp_path, "router", "--help")
        assert help_run.wait(60) == 0
        assert "usage: wart router" in (tmp_path / "out.txt").read_text()

        wrong = _spawn(server, tmp_path, "router", "--mode", "sideways")
        assert wrong.wait(60) == 2  # argparse's own exit, as from a fresh interpreter
        said = (tmp_path / "out.txt").read_text()
        assert "invalid choice: 'sideways'" in said and "Traceback" not in said

        # Its environment is the request's (a variable read at run time, not the server's).
        bad_realm = _spawn(server, tmp_path, "router", WART_REALM="no spaces allowed")
        assert bad_realm.wait(60) != 0
        assert "no spaces allowed" in (tmp_path / "out.txt").read_text()
    finally:
        server.stop()


def test_a_forked_service_stops_on_sigterm_in_its_own_session(tmp_path: Path) -> None:
    server = ForkServer(REPO)
    try:
        port = str(free_port())
        router = _spawn(
            server,
            tmp_path,
            "router",
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--no-multicast-scouting",
            "--realm",
            "forktest",
        )
        wait_for(
            lambda: (
                "listening" in (tmp_path / "out.txt").read_text().lower()
                or router.poll() is not None
            ),
            60,
            "the router to start",
        )
        assert router.poll() is None, (tmp_path / "out.txt").read_text()
        assert os.getsid(router.pid) == router.pid  # its own session, as start_new_session
        assert psutil.Process(router.pid).cwd() == str(tmp_path)
        router.send_signal(signal.SIGTERM)
        assert router.wait(30) == 0
        assert router.cpu_s > 0
    finally:
        server.stop()


def test_processes_do_not_outlive_the_test_process_that_started_them(tmp_path: Path) -> None:
    # A test process killed outright (SIGKILL: no teardown runs) leaves its fork server
    # without a parent; the server stops what it forked.
    script = tmp_path / "killed_test.py"
    script.write_text(
        textwrap.dedent(f"""
        import os, time
        from tests.kit.forkserver import ForkServer
        from tests.kit.lab import REPO, free_port, wart_env
        server = ForkServer(REPO)
        log = open({str(tmp_path / "router.log")!r}, "wb")
        nothing = open(os.devnull, "rb")
        router = server.spawn(
            ["router", "--listen", "tcp/127.0.0.1:{free_port()}", "--no-multicast-scouting"],
            cwd=REPO, env=wart_env(), stdin=nothing.fileno(), stdout=log.fileno(),
            stderr=log.fileno(),
        )
        print(router.pid, flush=True)
        time.sleep(600)
    """)
    )
    test_process = subprocess.Popen(
        [sys.executable, str(script)], stdout=subprocess.PIPE, text=True, env=wart_env()
    )
    try:
        assert test_process.stdout is not None
        pid = int(test_process.stdout.readline())
        assert psutil.pid_exists(pid)
        test_process.kill()
        test_process.wait(10)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and _running(pid):
            time.sleep(0.1)
        assert not _running(pid), "the router outlived the killed test process"
    finally:
        test_process.kill()


def _running(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False
