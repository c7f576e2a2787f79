"""``wart runner``: runs uploaded controllers for agent contexts, each in a sandbox.

An agent context (a principal with ``lease``) asks on ``runner/<name>/run``
(:class:`RunRequest`) to run a controller on an agent until a wall-clock
end. The runner pre-checks the source again (never trusting the context's
check), starts a :class:`~services.runner.sandbox.Sandbox`, and replies with a
claim sealed by its own session: the context's lease names that session.
Then, per run:

- a relay thread hands the agent's newest sensor sample to the sandbox (the
  Zenoh callback only keeps the newest one: a stalled sandbox stalls nothing);
- the sandbox's validated commands become ``AgentCommand`` sealed with the
  runner's session (``common.world.remote_robot.ZenohRobotLink``, whose keep-alive
  feeds the world's watchdog while the sandbox lives);
- all runs on one world share a ``WorldChannel``: the world's samples of
  every leased agent arrive in one ``SampleBundle`` per tick and the runs'
  commands leave in ``CommandBundle``s, not one message per robot each way;
- output lines (prints, tracebacks) go to the context as
  :class:`ControllerOutput` on ``ctx/<ctx>/output``, batched every 100 ms;
- at the end (slot over, :class:`RunStop`, the controller ended or crashed)
  the robot is told to stop and the context gets ``done`` with the reason.

Dry runs (:class:`DryRun`, on ``runner/<name>/dryrun``, sealed, ``lease``):
a few simulated seconds of a controller in a private copy of the world,
built from its public snapshot (services/runner/dryrun.py), in the same
sandbox. They are served on threads of their own (at most
``DRY_RUN_WORKERS`` at once), so a dry run never delays a slot's start or stop.

Graded episodes (:class:`Episode`, on ``runner/<name>/episode``, sealed,
``lease``: the grader's service account): one seeded episode of a submission
on a World built from the assignment's map (services/runner/episode.py), on
workers of their own likewise; a sandbox that cannot start is answered as the
lab's fault (``cause="lab"``), never the student's.

Uploaded code never sees Zenoh, keys or the lease: only pipes to this process.
Token: ``alive/runner/<name>``.
"""

from __future__ import annotations

import json
import logging
import threading
import time

import zenoh

from common import keys, qos
from common.ask import QueryFailed, ask
from common.auth import Verifier
from common.client.service_login import ServiceLogin
from common.controller.upload_gate import PrecheckError, precheck
from common.keys import AliveKind
from common.lab_errors import LabError
from common.messages import (
    MAX_OUTPUT_LINE,
    ControllerOutput,
    DryRun,
    Episode,
    EpisodeReport,
    GradeData,
    GradeResult,
    Heat,
    HeatReport,
    Message,
    OkReply,
    RunAccepted,
    RunCheck,
    RunCheckReply,
    RunClaim,
    RunRequest,
    RunStop,
    WorldSnapshot,
)
from common.service import RequestError, Service
from common.sim2d.maps import MapError
from common.world.remote_robot import WorldChannel, ZenohRobotLink
from services.runner.dryrun import dry_run
from services.runner.episode import run_episode
from services.runner.grader_run import run_grader
from services.runner.heat import run_heat
from services.runner.sandbox import Sandbox, SandboxLimits, cpu_share, release_cpu_share
from services.runner.twins import TwinChoice, TwinLookup

log = logging.getLogger("wart.runner")

MAX_RUNS = 32
# One user's stalled or hostile uploads must not take every place.
MAX_RUNS_PER_USER = 4
MAX_SLOT_S = 3600.0
OUTPUT_FLUSH_S = 0.1
# A robot's readings arrive 50 to 100 times a second: this long without one, the
# student is told (Run._say_silent), once, and again when they come back.
READINGS_SILENT_S = 5.0
DRY_RUN_WORKERS = 2  # dry runs at once (each a sandbox at full speed for a few seconds)
EPISODE_WORKERS = 2  # graded episodes at once (the grader sends no more than it has workers)
EPISODE_WAITING = 8
DRY_RUN_WAITING = 4  # more wait for a worker; the next is told the runner is busy


class Run:
    """One controller running for one request: sandbox, robot link, relays."""

    def __init__(self, runner: RunnerService, request: RunRequest, limits: SandboxLimits) -> None:
        self.runner = runner
        self.request = request
        self.ended = threading.Event()  # the sandbox is gone: relaying stops
        self.finished = threading.Event()  # its last output sent and the run forgotten
        self._lines: list[str] = []
        self._lines_lock = threading.Lock()
        self.link = ZenohRobotLink(
            runner.session,
            runner.realm,
            request.world,
            request.agent,
            lambda: runner.login.session,
            verifier=runner.verifier,  # accepts a MAC lease: commands cost µs to check
            channel=runner.channel(request.world),  # one message per tick for all its runs
        )
        self.sandbox = Sandbox(
            request.source,
            filename=request.filename,
            limits=limits,
            on_command=self.link.send,
            on_output=self._on_output,
            on_exit=self._on_exit,
        )
        self._output_key = keys.ctx_output(runner.realm, request.ctx)

    def start(self) -> None:
        self.sandbox.start(max(0.1, self.request.end - time.time()))
        threading.Thread(
            target=self._relay, name=f"relay-{self.request.agent}", daemon=True
        ).start()
        threading.Thread(target=self._flush_loop, name="run-output", daemon=True).start()

    def _relay(self) -> None:
        seen = 0
        last = time.monotonic()  # the run's start, then the newest reading's arrival
        silent = False  # the student was told the readings stopped
        while not self.ended.is_set():
            newest = self.link.wait_sample(seen, 0.2)
            now = time.monotonic()
            if newest == seen:
                if not silent and now - last >= READINGS_SILENT_S:
                    silent = True
                    self._say_silent(first=seen == 0)
                continue
            if seen == 0:
                log.info(
                    "%s on %s: first readings %.1f s after the run's start",
                    self.request.request_id,
                    self.request.agent,
                    now - last,
                )
            if silent:
                silent = False
                back = "again" if seen else "at last"  # a gap, or the slot's first ones
                self._say(f"readings from {self.request.agent} {back} after {now - last:.0f} s")
            last, seen = now, newest
            if not self.sandbox.send_state(self.link.latest()):
                return

    def _say_silent(self, *, first: bool) -> None:
        """Tell the student (and the runner's log) that their robot's readings stopped coming.

        A controller that "runs" while its robot neither reads nor moves is the
        worst thing a student can be shown without a word: a world that is down
        or frozen, a robot offline, a lease that never reached the world (the
        world sends a robot's readings only under a lease in force).
        """
        request = self.request
        when = "in the first" if first else "for"
        self._say(
            f"no readings from {request.agent} {when} {READINGS_SILENT_S:.0f} s: world "
            f"{request.world} sends none (down, frozen, its robot offline, or your slot's "
            "lease has not reached it), so your commands may not move it either. If it "
            "lasts, tell the lab's staff."
        )
        log.warning(
            "%s on %s for %s: no readings from world %s %s %.0f s",
            request.request_id,
            request.agent,
            request.user,
            request.world,
            when,
            READINGS_SILENT_S,
        )

    def _say(self, text: str) -> None:
        self._on_output(f"[runner] {text}")

    def _on_output(self, line: str) -> None:
        with self._lines_lock:
            if len(self._lines) < 200:  # the sandbox already caps lines per second
                self._lines.append(line[:MAX_OUTPUT_LINE])

    def _flush(self, *, done: bool = False, reason: str = "") -> None:
        with self._lines_lock:
            lines, self._lines = self._lines, []
        while lines or done:
            batch, lines = lines[:100], lines[100:]
            last = done and not lines
            if batch or last:
                self.runner.report(
                    self._output_key,
                    ControllerOutput(
                        request_id=self.request.request_id,
                        lines=batch,
                        done=last,
                        reason=reason[:256] if last else "",
                    ),
                )
            if last or not lines:
                break

    def _flush_loop(self) -> None:
        while not self.ended.wait(OUTPUT_FLUSH_S):
            self._flush()

    def _on_exit(self, reason: str) -> None:
        self.link.close(stop=True)  # the robot stops now, not 300 ms later
        self.ended.set()
        self._flush(done=True, reason=reason)
        log.info(
            "%s on %s for %s ended: %s",
            self.request.request_id,
            self.request.agent,
            self.request.user,
            reason,
        )
        self.runner.forget(self.request.request_id)
        self.finished.set()

    def stop(self, reason: str) -> None:
        threading.Thread(
            target=self.sandbox.stop, kwargs={"grace": 0.5, "reason": reason}, daemon=True
        ).start()


def _precheck(source: bytes, filename: str, whose: str = "") -> None:
    """An upload the sandbox would refuse is a bad request, said before any sandbox starts."""
    try:
        precheck(source, filename)
    except PrecheckError as exc:
        raise RequestError("bad_request", f"{whose}{exc}") from None


class RunnerService(Service):
    kind = AliveKind.RUNNER

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        name: str,
        *,
        registry_key: bytes,
        login: ServiceLogin,
        limits: SandboxLimits | None = None,
    ) -> None:
        super().__init__(session, realm, name)
        # Real robots' twins for dry runs, asked of the registry with this runner's session.
        self.twins = TwinLookup(session, realm, lambda key, m: login.session.seal(key, m))
        self.verifier = Verifier(registry_key, realm)
        self.login = login
        self.limits = limits or SandboxLimits()
        self._runs: dict[str, Run] = {}
        self._channels: dict[str, WorldChannel] = {}
        self._channels_lock = threading.Lock()  # not _lock: runs are made while it is held
        self._lock = threading.Lock()
        self._key = keys.runner_run(realm, name)

    def on_start(self) -> None:
        self.log.info("sandbox CPU share: %s", cpu_share(self.limits.cpu_share).mode)
        self.serve(self._key, self._on_run)
        self.serve(
            keys.runner_dryrun(self.realm, self.ident),
            self._on_dry_run,
            workers=DRY_RUN_WORKERS,
            max_waiting=DRY_RUN_WAITING,
        )
        self.serve(
            keys.runner_episode(self.realm, self.ident),
            self._on_episode,
            workers=EPISODE_WORKERS,
            max_waiting=EPISODE_WAITING,
        )
        self.serve(keys.runner_grade(self.realm, self.ident), self._on_grade, workers=1)
        self.serve(keys.runner_heat(self.realm, self.ident), self._on_heat, workers=1)

    def on_stop(self, timeout: float) -> None:
        with self._lock:
            runs = list(self._runs.values())
        # All at once, against one deadline: one by one, each stop's kill and
        # wait came after the one before, and on a busy machine the last run
        # was still listed when the runner closed its channels.
        for run in runs:
            threading.Thread(
                target=run.sandbox.stop,
                kwargs={"grace": 0.2, "reason": "the runner stopped"},
                name=f"stop-{run.request.agent}",
                daemon=True,
            ).start()
        deadline = time.monotonic() + timeout
        for run in runs:
            run.finished.wait(max(0.0, deadline - time.monotonic()))
        left = [run.request.request_id for run in runs if not run.finished.is_set()]
        if left:
            self.log.warning(
                "%d run(s) had not ended %.0f s after the stop: %s",
                len(left),
                timeout,
                ", ".join(left),
            )
        with self._channels_lock:
            channels, self._channels = list(self._channels.values()), {}
        for channel in channels:
            channel.close()
        release_cpu_share(self.limits.cpu_share)

    def channel(self, world: str) -> WorldChannel:
        """The runs' shared channel to ``world``: its samples in, their commands out."""
        with self._channels_lock:
            channel = self._channels.get(world)
            if channel is None:
                channel = WorldChannel(self.session, self.realm, world)
                self._channels[world] = channel
            return channel

    def runs(self) -> list[str]:
        with self._lock:
            return sorted(self._runs)

    def forget(self, request_id: str) -> None:
        with self._lock:
            self._runs.pop(request_id, None)

    def report(self, key: str, message: ControllerOutput) -> None:
        try:
            self.session.put(key, self.login.session.seal(key, message), **qos.of(keys.ctx_output))
        except Exception as exc:  # the session closing at shutdown
            self.log.debug("could not report on %s: %s", key, exc)

    def _on_run(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(
            str(query.key_expr), query.payload, (RunRequest, RunStop, RunCheck)
        )
        principal.require("lease", "ask a runner to run controllers")
        if isinstance(request, RunCheck):
            with self._lock:
                running = [r for r in request.request_ids if r in self._runs]
            return RunCheckReply(running=running)
        if isinstance(request, RunStop):
            with self._lock:
                run = self._runs.get(request.request_id)
            if run is None:
                return OkReply(detail=f"{request.request_id} is not running")
            run.stop(request.reason or f"stopped by {principal.user}")
            return OkReply(detail=f"stopping {request.request_id}")
        assert isinstance(request, RunRequest)  # the decoder allowed only these three
        return self._start(request)

    def _on_dry_run(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(str(query.key_expr), query.payload, DryRun)
        principal.require("lease", "ask a runner for dry runs")
        _precheck(request.source, request.filename)
        snap = self._snapshot(request.world)
        twin = self._twin(snap, request.ctx, request.agent)
        try:
            report = dry_run(
                snap,
                request.agent,
                request.source,
                filename=request.filename,
                seconds=request.seconds,
                limits=self.limits,
                twin=twin.twin,
                why_not_twin=twin.why_not,
            )
        except (ValueError, MapError) as exc:
            raise RequestError("bad_request", str(exc)) from None
        except (RuntimeError, OSError) as exc:
            raise RequestError("unavailable", f"cannot dry-run here: {exc}") from None
        self.log.info(
            "dry run of %s's %s on %s/%s: %s (%.1f simulated s in %.1f s)",
            request.user,
            request.filename,
            request.world,
            request.agent,
            report.verdict,
            report.sim_seconds,
            report.wall_seconds,
        )
        return report

    def _twin(self, snap: WorldSnapshot, arena: str, agent: str) -> TwinChoice:
        """A real arena's robot's twin in force, as the registry keeps it for the arena (its
        agent context); a simulated arena's robots are the map's: no twin."""
        if snap.kind != "real":
            return TwinChoice(None)
        return self.twins.twin_of(arena, agent)

    def _on_heat(self, query: zenoh.Query) -> Message:
        """A competition's heat: several entries in one world (services/runner/heat.py)."""
        principal, request = self.verifier.open(str(query.key_expr), query.payload, Heat)
        principal.require("lease", "ask a runner for a competition's heat")
        for e in request.entries:
            _precheck(e.source, e.filename, f"{e.submission}: ")
        try:
            report = run_heat(request, limits=self.limits)
        except (ValueError, MapError) as exc:
            raise RequestError("bad_request", str(exc)) from None
        except (RuntimeError, OSError) as exc:
            lab = EpisodeReport(cause="lab", detail=f"the sandbox could not start: {exc}"[:256])
            return HeatReport(entries=[lab] * len(request.entries))
        self.log.info(
            "heat %d of %s: %s",
            request.heat,
            request.competition,
            ", ".join(
                f"{e.submission} {r.cause}"
                for e, r in zip(request.entries, report.entries, strict=True)
            ),
        )
        return report

    def _on_grade(self, query: zenoh.Query) -> Message:
        """A teacher's grader function on a real attempt's data, in the sandbox."""
        principal, request = self.verifier.open(str(query.key_expr), query.payload, GradeData)
        principal.require("lease", "ask a runner to run a grader function")
        try:
            data = json.loads(request.episode)
        except ValueError as exc:
            raise RequestError("bad_request", f"the episode's data is not JSON: {exc}") from None
        try:
            out = run_grader(
                request.grader,
                request.grader_filename,
                data,
                seconds=request.grader_seconds,
                limits=self.limits,
            )
        except (RuntimeError, OSError) as exc:
            raise RequestError("unavailable", f"the sandbox could not start: {exc}") from None
        return GradeResult(metrics=out.metrics, error=out.error[:256], line=out.line)

    def _on_episode(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(str(query.key_expr), query.payload, Episode)
        principal.require("lease", "ask a runner for graded episodes")
        _precheck(request.source, request.filename)
        try:
            report = run_episode(request, limits=self.limits)
        except (ValueError, MapError) as exc:
            raise RequestError("bad_request", str(exc)) from None
        except (RuntimeError, OSError) as exc:
            # The lab's fault, said as such: the grader re-runs it elsewhere, free.
            return EpisodeReport(cause="lab", detail=f"the sandbox could not start: {exc}"[:256])
        self.log.info(
            "episode %d of %s (%s): %s, %.1f simulated s in %.1f s",
            request.episode,
            request.submission,
            request.user,
            report.cause,
            report.sim_seconds,
            report.wall_seconds,
        )
        return report

    def _snapshot(self, world: str) -> WorldSnapshot:
        """The world's public snapshot: the arena a dry run copies."""
        try:
            return ask(
                self.session,
                keys.world_snapshot(self.realm, world),
                None,
                WorldSnapshot,
                what=f"world {world}",
                timeout=3.0,
            )
        except QueryFailed as exc:
            raise RequestError(
                "unavailable", f"world {world} did not answer: {exc.reason}"
            ) from None
        except LabError:  # silent, refused, or not a snapshot
            raise RequestError(
                "unavailable", f"world {world} did not answer with its snapshot"
            ) from None

    def _start(self, request: RunRequest) -> Message:
        now = time.time()
        if not now < request.end <= now + MAX_SLOT_S:
            raise RequestError("bad_request", "the run's end must be within the next hour")
        _precheck(request.source, request.filename)
        with self._lock:
            if request.request_id in self._runs:
                raise RequestError("conflict", f"{request.request_id} already runs")
            if len(self._runs) >= MAX_RUNS:
                raise RequestError("unavailable", f"the runner is full ({MAX_RUNS} controllers)")
            mine = sum(1 for r in self._runs.values() if r.request.user == request.user)
            if mine >= MAX_RUNS_PER_USER:
                raise RequestError(
                    "unavailable",
                    f"{request.user} already runs {mine} controllers here "
                    f"(at most {MAX_RUNS_PER_USER} per user): stop one first",
                )
            try:
                run = Run(self, request, self.limits)
            except (RuntimeError, ValueError) as exc:
                raise RequestError("unavailable", str(exc)) from None
            self._runs[request.request_id] = run
        try:
            run.start()
        except OSError as exc:
            self.forget(request.request_id)
            run.link.close(stop=False)
            raise RequestError("unavailable", f"could not start the sandbox: {exc}") from None
        self.log.info(
            "running %s of %s on %s/%s until %.1f",
            request.request_id,
            request.user,
            request.world,
            request.agent,
            request.end,
        )
        claim = RunClaim(request_id=request.request_id, agent=request.agent)
        return RunAccepted(claim=self.login.session.seal(self._key, claim))
