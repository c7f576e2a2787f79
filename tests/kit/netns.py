"""Test hosts in Linux network namespaces, joined through a bridge (root only).

Each host is a namespace with one veth link into a bridge that lives in its
own "switch" namespace, addressed 169.254.77.N/24 (link-local: these hosts
exist only inside this machine's sandbox). ``HostNet.down()/up()`` cut and
restore a host's link. Where namespaces cannot be made, ``available()``
returns the reason and the tests skip with it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from tests.kit.procs import REPO, wart_env

SUBNET = "169.254.77"


def _ip(*args: str, netns: str | None = None, check: bool = True) -> subprocess.CompletedProcess:
    cmd = ["ip", *(["-n", netns] if netns else []), *args]
    return subprocess.run(cmd, capture_output=True, text=True, check=check)


def available() -> str | None:
    """None if namespaces can be made here, else why not."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "the 'ip' command (Debian package iproute2) is not installed"
    probe = f"wprobe{uuid.uuid4().hex[:6]}"
    made = _ip("netns", "add", probe, check=False)
    if made.returncode != 0:
        return f"cannot create a network namespace: {made.stderr.strip()}"
    _ip("netns", "del", probe, check=False)
    return None


@dataclass
class HostNet:
    name: str  # the namespace
    address: str
    veth: str  # the switch-side end of its link
    switch: str

    def down(self) -> None:
        _ip("link", "set", self.veth, "down", netns=self.switch)

    def up(self) -> None:
        _ip("link", "set", self.veth, "up", netns=self.switch)

    def popen(
        self, args: list[str], log_path: Path, env: dict[str, str] | None = None
    ) -> subprocess.Popen[bytes]:
        """Run ``python ARGS`` inside this host's namespace."""
        out = open(log_path, "wb")  # noqa: SIM115 - handed to the child
        try:
            return subprocess.Popen(
                ["ip", "netns", "exec", self.name, sys.executable, *args],
                cwd=REPO,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=wart_env(env),
                start_new_session=True,
            )
        finally:
            out.close()


@dataclass
class Network:
    """N hosts on one bridge. Use as a context manager; everything is removed at exit."""

    count: int
    tag: str = field(default_factory=lambda: uuid.uuid4().hex[:5])
    hosts: list[HostNet] = field(default_factory=list)

    @property
    def switch(self) -> str:
        return f"wsw{self.tag}"

    def __enter__(self) -> Network:
        try:
            _ip("netns", "add", self.switch)
            _ip("link", "add", "br0", "type", "bridge", netns=self.switch)
            _ip("link", "set", "br0", "up", netns=self.switch)
            for i in range(self.count):
                name = f"wh{self.tag}{i}"
                _ip("netns", "add", name)
                outer, inner = f"wv{self.tag}{i}", f"wi{self.tag}{i}"
                _ip("link", "add", outer, "type", "veth", "peer", "name", inner)
                _ip("link", "set", outer, "netns", self.switch)
                _ip("link", "set", inner, "netns", name)
                _ip("link", "set", inner, "name", "eth0", netns=name)
                address = f"{SUBNET}.{i + 1}"
                _ip("addr", "add", f"{address}/24", "dev", "eth0", netns=name)
                _ip("link", "set", "eth0", "up", netns=name)
                _ip("link", "set", "lo", "up", netns=name)
                _ip("link", "set", outer, "master", "br0", netns=self.switch)
                _ip("link", "set", outer, "up", netns=self.switch)
                self.hosts.append(HostNet(name, address, outer, self.switch))
        except subprocess.CalledProcessError as exc:
            self.__exit__()
            raise RuntimeError(f"could not build the test network: {exc.stderr}") from exc
        return self

    def __exit__(self, *exc: object) -> None:
        for host in self.hosts:
            _ip("netns", "del", host.name, check=False)
        _ip("netns", "del", self.switch, check=False)
