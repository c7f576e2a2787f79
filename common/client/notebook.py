"""The lab from a Jupyter notebook: log in, choose a robot, run a controller class defined
in a cell, read its sensors, and watch its IR and wheels plotted live.

The same client as ``wart control`` (LabClient, AgentClient: the controller runs in
the notebook's kernel and drives the robot over Zenoh during its slot)::

    from common.client.notebook import Lab

    lab = Lab.login("alice", context="arena")  # the password is asked, hidden
    lab.robots()                                # ['k0', 'k1', 'k2']
    k1 = lab.robot("k1")
    k1.sensors().proximity                      # one reading, no slot needed
    run = k1.run(Braitenberg)                   # waits for the slot, drives, plots
    run.proximity                               # every IR reading of the run (numpy)
    lab.recording(run.result.request_id)        # the run as the lab recorded it

Where the lab is: ``connect``, ``realm`` and ``registry_key``, else the variables
every ``wart`` command reads (WART_CONNECT, WART_REALM, WART_REGISTRY_KEY); the
password: ``password``, else WART_PASSWORD, else a hidden prompt (getpass). Live
plots need the ``notebook`` extra (ipywidgets and matplotlib:
``pip install 'wart-lab[notebook]'``); without it a run prints its progress.
"""

from __future__ import annotations

import getpass
import os
import threading
import time
from argparse import Namespace
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zenoh

from common import keys
from common.client.agent_client import AgentClient, DriveResult
from common.client.lab_client import LabClient
from common.client.notebook_plots import LivePlot, plots_available
from common.controller import Controller
from common.lab_errors import LabError, NotFound, RegistryUnreachable
from common.messages import MessageError, RecordingInfo, RequestStatus, SensorSample, decode
from common.recording import Recording, read_recording
from common.service import close_session, open_session
from common.zconfig import ConfigError, NetworkOptions, options_from_args

NOTEBOOK_INSTALL = "pip install 'wart-lab[notebook]'"
PLOT_EVERY_S = 0.5  # how often a live plot is drawn again


@dataclass
class Run:
    """One slot of a controller on a robot: how it ended, and every sample it sensed.

    ``times`` (s since the first sample), ``proximity`` and ``ambient`` (one row a
    sample, one column a sensor), ``speeds`` and ``counters`` (left, right): numpy
    arrays in the robot type's units, for plotting or analysis in the next cell.
    """

    agent: str
    result: DriveResult
    samples: list[SensorSample] = field(default_factory=list)

    @property
    def status(self) -> str:
        return self.result.status

    @property
    def times(self) -> np.ndarray:
        if not self.samples:
            return np.zeros(0)
        return np.array([s.sim_time for s in self.samples]) - self.samples[0].sim_time

    @property
    def proximity(self) -> np.ndarray:
        return _rows([s.proximity for s in self.samples])

    @property
    def ambient(self) -> np.ndarray:
        return _rows([s.ambient for s in self.samples])

    @property
    def speeds(self) -> np.ndarray:
        return _rows([list(s.speeds) for s in self.samples])

    @property
    def counters(self) -> np.ndarray:
        return _rows([list(s.counters) for s in self.samples])

    def __repr__(self) -> str:
        r = self.result
        ended = f"{r.status}: {r.reason}" if r.reason else r.status
        return (
            f"<Run of {self.agent}, {r.request_id}: {ended}; {r.iterations} steps, "
            f"{len(self.samples)} samples>"
        )


def _rows(values: list[list[int]]) -> np.ndarray:
    width = max((len(v) for v in values), default=0)
    out = np.zeros((len(values), width), dtype=float)
    for i, row in enumerate(values):
        out[i, : len(row)] = row
    return out


class SampleWatch:
    """The robot's sensor samples as the world publishes them (no lease needed: the
    samples are the lab's to see), kept while ``keep`` is set."""

    def __init__(self, z: zenoh.Session, realm: str, world: str, agent: str) -> None:
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)
        self.latest: SensorSample | None = None
        self.kept: list[SensorSample] = []
        self.keep = False
        self._sub = z.declare_subscriber(keys.agent_sensors(realm, world, agent), self._on)
        # A world of many robots publishes a robot's samples once it is watched.
        self._watch = z.liveliness().declare_token(keys.agent_watch(realm, world, agent))

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            reading = decode(bytes(sample.payload.to_bytes()), SensorSample)
        except MessageError:
            return
        with self._arrived:
            self.latest = reading
            if self.keep:
                self.kept.append(reading)
            self._arrived.notify_all()

    def start_keeping(self) -> None:
        with self._lock:
            self.kept = []
            self.keep = True

    def stop_keeping(self) -> None:
        with self._lock:
            self.keep = False

    def kept_now(self) -> list[SensorSample]:
        with self._lock:
            return list(self.kept)

    def next(self, timeout: float) -> SensorSample | None:
        """A sample newer than the one held now; None if none came in ``timeout`` s."""
        with self._arrived:
            before = self.latest
            self._arrived.wait_for(lambda: self.latest is not before, timeout)
            return self.latest if self.latest is not before else None

    def close(self) -> None:
        self._sub.undeclare()
        self._watch.undeclare()


class Robot:
    """One robot of the lab's agent context, as a notebook drives it."""

    def __init__(self, lab: Lab, agent: str, world: str) -> None:
        self.lab = lab
        self.agent = agent
        self.world = world
        self._watch = SampleWatch(lab.client.z, lab.client.realm, world, agent)

    def __repr__(self) -> str:
        return f"<Robot {self.agent} of {self.lab.context} ({self.world})>"

    def sensors(self, timeout: float = 5.0) -> SensorSample:
        """Its newest reading (proximity, ambient, speeds, counters, ...)."""
        reading = self._watch.next(timeout) or self._watch.latest
        if reading is None:
            raise LabError(f"{self.agent} sent no reading in {timeout:.0f} s: is its world up?")
        return reading

    def run(
        self,
        controller: Controller | type[Controller],
        *,
        plot: bool | None = None,
        say: Callable[[str], None] = print,
    ) -> Run:
        """Queue for the robot, wait for the slot, run ``controller`` (a class or an
        instance) here for the slot, and return the run with everything it sensed.

        ``plot``: draw IR and wheels live (None: when the notebook extra is installed).
        Interrupting the cell (the kernel's stop button) cancels the request.
        """
        instance = controller() if isinstance(controller, type) else controller
        live = _live_plot(self.agent, plot, say)
        stop = threading.Event()
        done: list[DriveResult] = []
        failed: list[BaseException] = []

        def on_wait(position: int, eta: float | None) -> None:
            when = f"; your slot starts in about {max(0.0, eta - time.time()):.0f} s" if eta else ""
            where = "you are next" if position <= 1 else f"position {position} in the queue"
            say(f"{self.agent}: {where}{when}")

        def on_start(status: RequestStatus) -> None:
            slot = f" for {status.end - time.time():.0f} s" if status.end else ""
            say(f"{self.agent}: your slot started{slot}")
            self._watch.start_keeping()

        def drive() -> None:
            try:
                done.append(
                    self.lab.agents.drive(
                        self.agent, instance, stop=stop, on_wait=on_wait, on_start=on_start
                    )
                )
            except BaseException as exc:  # said in the cell, where the student looks
                failed.append(exc)

        worker = threading.Thread(target=drive, name=f"drive-{self.agent}", daemon=True)
        worker.start()
        try:
            while worker.is_alive():
                worker.join(PLOT_EVERY_S)
                if live is not None:
                    live.draw(self._watch.kept_now())
        except KeyboardInterrupt:
            stop.set()
            worker.join(10)
        finally:
            self._watch.stop_keeping()
        if failed:
            raise failed[0]
        run = Run(self.agent, done[0] if done else DriveResult("", "interrupted", "stopped"))
        run.samples = self._watch.kept_now()
        if live is not None:
            live.draw(run.samples)
        say(f"{self.agent}: {run.status} ({run.result.reason}), {len(run.samples)} samples")
        if run.result.error:
            say(run.result.error)
        return run

    def close(self) -> None:
        self._watch.close()


def _live_plot(agent: str, plot: bool | None, say: Callable[[str], None]) -> LivePlot | None:
    if plot is False:
        return None
    if not plots_available():
        if plot:
            raise LabError(f"live plots need ipywidgets and matplotlib: {NOTEBOOK_INSTALL}")
        say(f"(no live plots: {NOTEBOOK_INSTALL})")
        return None
    return LivePlot(agent)


class Lab:
    """A logged-in user of one agent context (``context``: e.g. "arena")."""

    def __init__(self, z: zenoh.Session, client: LabClient, agents: AgentClient) -> None:
        self.z = z
        self.client = client
        self.agents = agents
        self._robots: dict[str, Robot] = {}

    @property
    def context(self) -> str:
        return self.agents.ctx

    @classmethod
    def login(
        cls,
        user: str,
        *,
        context: str = "arena",
        password: str | None = None,
        connect: str | None = None,
        realm: str | None = None,
        registry_key: str | None = None,
    ) -> Lab:
        """Connect, log in as ``user`` and join ``context``; LabError says what failed."""
        try:
            keys.check_ident("user", user)
            keys.check_ident("context", context)
            options = _options(connect, realm, registry_key)
        except (ValueError, ConfigError) as exc:
            raise LabError(str(exc)) from None
        if not options.registry_key:
            raise LabError(
                "the lab's registry key is needed: registry_key=... or WART_REGISTRY_KEY "
                "(your teacher gives it with the lab's address)"
            )
        if password is None:
            password = os.environ.get("WART_PASSWORD") or getpass.getpass(f"password for {user}: ")
        try:
            z = open_session(options, wait=10.0)
        except ConnectionError as exc:
            raise RegistryUnreachable(str(exc)) from None
        client = LabClient(z, options.realm, options.registry_key)
        try:
            client.login(user, password)
            agents = AgentClient(client, context).join()
        except BaseException:
            client.close()
            close_session(z)
            raise
        print(f"logged in as {user} to {context} ({options.realm})")
        return cls(z, client, agents)

    def robots(self) -> list[str]:
        """The robots of the context, as it lists them now."""
        return [queue.agent for queue in self.agents.state().agents]

    def robot(self, agent: str) -> Robot:
        """One robot to read and drive (the same object each time for the same name)."""
        if agent not in self._robots:
            state = self.agents.state()
            if agent not in {q.agent for q in state.agents}:
                listed = ", ".join(q.agent for q in state.agents)
                raise NotFound(f"{self.context} has no robot {agent!r} (it has: {listed})")
            self._robots[agent] = Robot(self, agent, state.world)
        return self._robots[agent]

    def recordings(self) -> list[RecordingInfo]:
        """Your recorded runs in the context, as ``wart record list`` lists them."""
        return list(self.agents.recordings().recordings)

    def recording(self, name: str, dest: Path | None = None) -> Recording:
        """Download run ``name`` (to ``dest``, default NAME.mcap here) and read it: its
        poses, samples, commands and output, with their times (common/recording/)."""
        keys.check_ident("name", name)
        path = self.agents.download(name, dest or Path(f"{name}.mcap"))
        return read_recording(path)

    def close(self) -> None:
        """Log out and disconnect (also when the kernel stops)."""
        for robot in self._robots.values():
            robot.close()
        self._robots.clear()
        self.client.close()
        close_session(self.z)

    def __enter__(self) -> Lab:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _options(connect: str | None, realm: str | None, registry_key: str | None) -> NetworkOptions:
    """The network options of the arguments, the environment filling the rest (as for
    every ``wart`` command)."""
    flags = Namespace(
        config=None,
        realm=realm,
        mode=None,
        connect=[c.strip() for c in connect.split(",")] if connect else None,
        listen=None,
        no_multicast=None,
        registry_key=registry_key,
    )
    return options_from_args(flags)
