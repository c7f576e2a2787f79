"""The page's driving of a taken-over robot: wheel speeds held until changed.

A world stops a robot 300 ms after its last command (its watchdog), so a
button press ("Forward") is a speed this thread sends again every 100 ms with
the browser user's own session (the take-over's lease holder), until "Stop",
another direction, the hand-back, or the take-over ending.
"""

from __future__ import annotations

import logging
import threading

from common.client.agent_client import AgentClient
from common.controller import Khepera
from common.world.remote_robot import ZenohRobotLink

log = logging.getLogger("wart.viewer.drive")

RESEND_S = 0.1
MAX_SPEED = 20  # of the Khepera's units: the page drives gently


class KeyDriver:
    """One browser user's drive of the robot they took over (at most one at a time)."""

    def __init__(self, agents: AgentClient) -> None:
        self.agents = agents
        self._lock = threading.Lock()
        self._link: ZenohRobotLink | None = None
        self._agent = ""
        self._speeds = (0, 0)
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None

    def set(self, world: str, agent: str, left: int, right: int) -> None:
        left = max(-MAX_SPEED, min(MAX_SPEED, int(left)))
        right = max(-MAX_SPEED, min(MAX_SPEED, int(right)))
        with self._lock:
            if self._link is None or self._agent != agent:
                self._close()
                self._link = self.agents.robot_link(world, agent)
                self._agent = agent
                self._halt = threading.Event()
                self._thread = threading.Thread(
                    target=self._run, args=(self._link, self._halt), name="page-drive", daemon=True
                )
                self._thread.start()
            self._speeds = (left, right)
            Khepera(self._link).set_speeds(left, right)

    def _run(self, link: ZenohRobotLink, halt: threading.Event) -> None:
        robot = Khepera(link)
        me = self.agents.client.user
        while not halt.wait(RESEND_S):
            if not self.agents.is_taken_by(self._agent, me):
                break  # handed back (perhaps by another teacher), or the run ended
            with self._lock:
                speeds = self._speeds
            if speeds != (0, 0):
                try:
                    robot.set_speeds(*speeds)
                except Exception as exc:  # the session closing
                    log.debug("drive %s: %s", self._agent, exc)
                    break

    def stop(self) -> None:
        with self._lock:
            self._close()

    def _close(self) -> None:
        self._halt.set()
        if self._link is not None:
            self._link.close(stop=True)
        self._link = None
        self._speeds = (0, 0)
