"""Finding Khepera robots on serial ports (thesis 7.4.3) and the Fleet of a bridge's robots.

``candidate_ports`` lists pyserial's ports plus given paths and globs;
``detect`` probes them in parallel with ``B``; ``Fleet`` adds robots by hand
or by auto-detection.
"""

from __future__ import annotations

import glob
import logging
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

from serial.tools import list_ports

from services.bridge import protocol as P
from services.bridge.link import LinkOffline, LinkOptions, SerialKheperaLink
from services.bridge.robot import KheperaRobot, RobotOptions

log = logging.getLogger("wart.bridge.robot")


@dataclass(frozen=True)
class DetectedRobot:
    port: str
    baud: int
    version: P.Version


def candidate_ports(patterns: Iterable[str] = (), *, system: bool = True) -> list[str]:
    """The serial ports pyserial lists, plus the paths and globs given; no duplicates."""
    found: list[str] = []
    if system:
        found += [p.device for p in list_ports.comports()]
    for pattern in patterns:
        matches = sorted(glob.glob(pattern)) if any(c in pattern for c in "*?[") else [pattern]
        found += matches
    return list(dict.fromkeys(found))


def probe(port: str, baud: int = 38400, timeout: float = 0.3, tries: int = 2) -> P.Version | None:
    """Ask B on ``port``; the version if a Khepera answers ``b,...``, else None (quickly)."""
    try:
        link = SerialKheperaLink.open(port, baud, LinkOptions(reply_timeout=timeout, tries=tries))
    except LinkOffline as exc:
        log.debug("probe %s: %s", port, exc)
        return None
    except ValueError as exc:
        log.debug("probe %s: %s", port, exc)
        return None
    try:
        return link.request(P.read_version())
    except P.ProtocolError as exc:
        log.debug("probe %s at %d baud: not a Khepera: %s", port, baud, exc)
        return None
    finally:
        link.close()


def detect(
    ports: Sequence[str], bauds: Sequence[int] = (38400,), timeout: float = 0.3
) -> list[DetectedRobot]:
    """Probe every port in parallel (each at each baud until one answers); robots in port order."""

    def one(port: str) -> DetectedRobot | None:
        for baud in bauds:
            version = probe(port, baud, timeout)
            if version is not None:
                return DetectedRobot(port, baud, version)
        return None

    if not ports:
        return []
    with ThreadPoolExecutor(
        max_workers=min(16, len(ports)), thread_name_prefix="khepera-probe"
    ) as pool:
        results = list(pool.map(one, ports))
    return [r for r in results if r is not None]


class Fleet:
    """The robots of one bridge: added by port name or found by auto-detection."""

    def __init__(self, options: RobotOptions | None = None) -> None:
        self.options = options or RobotOptions()
        self.robots: dict[str, KheperaRobot] = {}

    def add(self, port: str, options: RobotOptions | None = None) -> KheperaRobot:
        """Manual add (thesis 7.4.3): the robot is polled from now on, online when it answers."""
        if port in self.robots:
            return self.robots[port]
        robot = KheperaRobot(port, options or self.options).start()
        self.robots[port] = robot
        return robot

    def autodetect(
        self,
        patterns: Iterable[str] = (),
        *,
        system: bool = True,
        bauds: Sequence[int] = (38400,),
        timeout: float = 0.3,
    ) -> list[KheperaRobot]:
        """Probe the candidate ports not already in use and add every robot that answers."""
        ports = [p for p in candidate_ports(patterns, system=system) if p not in self.robots]
        added = []
        for found in detect(ports, bauds, timeout):
            added.append(self.add(found.port, replace(self.options, baud=found.baud)))
        return added

    def remove(self, port: str) -> None:
        robot = self.robots.pop(port, None)
        if robot is not None:
            robot.stop()

    def stop(self) -> None:
        for port in list(self.robots):
            self.remove(port)
