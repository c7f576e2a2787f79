"""Start a router, a registry and chat rooms as real processes for the benchmarks."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from common import keys
from common.auth import RegistryIdentity, create_identity_key
from common.keys import AliveKind
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.lab.supervisor import AliveWatch
from services.registry.accounts_db import RegistryDB

REPO = Path(__file__).resolve().parent.parent


class BenchLab:
    def __init__(self, users: list[str], password: str) -> None:
        self.tmp = Path(tempfile.mkdtemp(prefix="wart-bench-"))
        self.realm = "bench"
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.identity, _ = RegistryIdentity.load_or_create(self.tmp / "registry.key")
        db = RegistryDB(self.tmp / "registry.db")
        db.ensure_admin()
        for user in users:
            db.add_user(user, ["student"], password=password)
        db.close()
        self.procs: list[subprocess.Popen[bytes]] = []
        self.options = NetworkOptions(realm=self.realm, connect=(f"tcp/127.0.0.1:{self.port}",))

    def net(self) -> list[str]:
        return [*self.options.as_args(), "--registry-key", self.identity.verify_key.hex()]

    def spawn(self, args: list[str], alive: tuple[AliveKind, str]) -> None:
        log = open(self.tmp / f"{alive[1]}.log", "wb")  # noqa: SIM115 - the child owns it
        self.procs.append(
            subprocess.Popen(
                [sys.executable, "-m", "services.cli", *args],
                cwd=REPO,
                stdout=log,
                stderr=subprocess.STDOUT,
                env={
                    "PYTHONPATH": str(REPO),
                    "PATH": "/usr/bin:/bin",
                    "WART_LOG_LEVEL": os.environ.get("WART_BENCH_LOG_LEVEL", "WARNING"),
                },
            )
        )
        session = open_session(self.options, wait=20.0)
        try:
            key = keys.alive(self.realm, *alive)
            watch = AliveWatch(session, key)
            if not watch.wait(key, 30.0):
                raise RuntimeError(f"{alive[1]} did not start; see {self.tmp}")
            watch.close()
        finally:
            close_session(session)

    def start(self, room_args: list[str] | None = None) -> None:
        listen = f"tcp/127.0.0.1:{self.port}"
        self.spawn(
            ["router", "--realm", self.realm, "--name", "r", "--listen", listen],
            (AliveKind.ROUTER, "r"),
        )
        self.spawn(
            [
                "registry",
                "--db",
                str(self.tmp / "registry.db"),
                "--key-file",
                str(self.tmp / "registry.key"),
                *self.net(),
            ],
            (AliveKind.REGISTRY, "registry"),
        )
        if room_args is not None:
            key = create_identity_key(self.tmp / "room.key")
            db = RegistryDB(self.tmp / "registry.db")
            db.add_user("chat-room", ["service"], public_key=bytes(key.verify_key))
            db.close()
            self.spawn(
                [
                    "context",
                    "chat",
                    "--name",
                    "room",
                    "--user",
                    "chat-room",
                    "--identity",
                    str(self.tmp / "room.key"),
                    *room_args,
                    *self.net(),
                ],
                (AliveKind.CONTEXT, "room"),
            )

    def stop(self) -> None:
        for proc in reversed(self.procs):
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
