"""The arena tab's editor: write a controller, Check it, run it, stop it, reset the robot.

A student starts from an example (examples/*.py) or one of their own files,
which the agent context keeps per user (:meth:`LabConnection.save_file`; the
page keeps nothing of its own), edits it in a multiline text input, and:

- **Check**: :func:`common.controller.advice.check_source` (the pre-run check plus
  syntax, a Controller with do_work, calls Khepera does not have, imports the
  sandbox refuses), each problem as ``line N: what is wrong``;
- **Run in simulation**: saves the file, then queues it on the robot chosen in
  the robot panel, exactly as an upload does;
- **Queue on the real robot**: the same on a robot of a real arena (a Khepera
  bridge) the student has joined;
- **Dry run**: the editor's text run a few simulated seconds in a private copy
  of the arena on the chosen robot (:meth:`LabConnection.dry_run`, as the robot
  panel's "Dry run (.py)" upload does); the verdict ("will run" / "will NOT run:
  ...") is shown under the code, an exception's line marked as Check marks it;
- **Stop**: cancels the student's own request on the robot (running or waiting);
- **Reset**: the robot back at its start pose (the world allows it only to
  whoever holds the robot now, or a map editor).

The code is written in a CodeMirror editor (viewers/web/code_editor.py) laid
over the viser text area ``code``, which stays what this class reads and
writes. Problems are marked in the editor's gutter (message on hover) and
listed under it, each line number a link that moves the editor there, with an
excerpt of the code (``>>`` in front of each problem line), all as escaped
HTML, never markdown. A run's exception (the runner relays the traceback as
output lines) is parsed for the innermost line of the student's file and shown
the same way.
"""

from __future__ import annotations

import logging
import re
import threading
from dataclasses import dataclass
from pathlib import Path

import viser

from common.controller.advice import Problem, check_source
from common.messages.agent import FILE_NAME_PATTERN
from viewers.web.adapters import (
    AgentStatus,
    LabConnection,
    LabError,
    OutputEvent,
    RequestEvent,
)
from viewers.web.code_editor import CodeEditor, show_text
from viewers.web.followed_run import RESUMED_NOTE, FollowedRun
from viewers.web.inputs import on_click, set_value
from viewers.web.live_agents import check_upload
from viewers.web.marks import (
    DEFAULT_NAME,
    MAX_MARKED,
    format_dry_run,
    format_problems,
)
from viewers.web.robot_panel import RobotPanel
from viewers.web.run_on import RunOn
from viewers.web.run_output import RunOutput
from viewers.web.text import escape_md

log = logging.getLogger("wart.viewer.workbench")

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
EXAMPLE_PREFIX = "example: "
MINE_PREFIX = "mine: "
_FILE_NAME = re.compile(FILE_NAME_PATTERN)


def examples() -> dict[str, bytes]:
    """The example controllers, by file name."""
    return {p.name: p.read_bytes() for p in sorted(EXAMPLES.glob("*.py"))}


@dataclass(frozen=True)
class BenchMemory:
    """What a student had in the editor when the page went away (a reload): put back."""

    file_name: str
    code: str
    target: str
    running_on: tuple[str, str] | None
    status: str
    errors: tuple[Problem, ...]  # the run's exceptions so far
    shown: tuple[tuple[Problem, ...], str]  # the problems under the editor, and their heading
    printed: tuple[str, ...]  # the run's output under the editor (HTML, escaped)
    # The robot whose run printed ``printed``, when that run is not followed from here but
    # found again (a restarted viewer's): following it then keeps these lines.
    output_of: str | None = None
    # The followed run and, in the context's count, its next line the page did not get:
    # what it printed while the page was away comes from the context (a reload).
    run_request: str | None = None
    next_line: int | None = None

    @classmethod
    def of_text(
        cls,
        file_name: str,
        code: str,
        target: str,
        printed: tuple[str, ...] = (),
        output_of: str | None = None,
    ) -> BenchMemory:
        """The editor and its output (a viewer restarted): the run, if any, is found again."""
        return cls(file_name, code, target, None, "", (), ((), ""), printed, output_of)


class Workbench:
    def __init__(
        self,
        client: viser.ClientHandle,
        connection: LabConnection,
        ctx: str,
        robots: RobotPanel,
        kept: BenchMemory | None = None,
    ) -> None:
        self.client = client
        self.connection = connection
        self.ctx = ctx
        self.robots = robots
        self._examples = examples()
        # (context, robot) my editor's run is queued on: a real one may be in another arena.
        self._running_on: tuple[str, str] | None = None
        # Whether that run is queued or running still: a run of mine started elsewhere (my
        # other tab, `wart control`) is followed here when this editor's own run is over.
        self._run_live = False
        self._shown: tuple[tuple[Problem, ...], str] = ((), "")
        self._output_of: str | None = None  # BenchMemory.output_of, until the run is found
        # The context's news of my run counts up: a reply that arrives after the news
        # (a run can start, or end, before the query's answer is back) must not hide it.
        self._news = 0
        # The check of the count and the words said after a reply, as one step: news landing
        # between them was overwritten by the older "Stopped: ..." (seen at load 9).
        self._news_lock = threading.Lock()
        gui = client.gui
        with gui.add_folder("Editor") as self.folder:
            self.start_from = gui.add_dropdown(
                "Start from", tuple(EXAMPLE_PREFIX + n for n in self._examples) or ("(none)",)
            )
            self.open = gui.add_button(
                "Open", hint="Load the chosen example or file into the editor"
            )
            self.name = gui.add_text("File name", DEFAULT_NAME)
            first = next(iter(self._examples.values()), b"")
            self.code = gui.add_text("Code", first.decode("utf-8", "replace"), multiline=True)
            # CodeMirror over the text area above; it hides it and writes into it.
            self.editor = CodeEditor(client, self.code)
            # My run's output right under the code: both in view at once on a laptop.
            self.run_output = RunOutput(gui)
            self.followed = FollowedRun(connection, self.run_output, self._news_lock, self._raised)
            # The robot the buttons below act on: this arena's robots and those of the
            # real arenas joined, beside the buttons (the robot panel's list follows it).
            self.run_on = RunOn(gui, connection, ctx, robots)
            self.target = self.run_on.dropdown
            self.check = gui.add_button("Check", icon=viser.Icon.CHECKLIST)
            self.save = gui.add_button("Save", icon=viser.Icon.DEVICE_FLOPPY)
            self.run = gui.add_button(
                "Run in simulation", color="green", icon=viser.Icon.PLAYER_PLAY
            )
            self.dry = gui.add_button(
                "Dry run",
                icon=viser.Icon.FLASK,
                hint="Run the code a few simulated seconds in a private copy of the arena: "
                "will it run? Nothing is queued.",
            )
            self.queue_real = gui.add_button("Queue on the real robot", icon=viser.Icon.ROBOT)
            self.stop = gui.add_button("Stop", color="red", icon=viser.Icon.PLAYER_STOP)
            self.reset = gui.add_button("Reset", icon=viser.Icon.REFRESH)
            self.status = gui.add_markdown("")
            self.problems = gui.add_html("")
        self.open.on_click(lambda _: self._open())
        on_click(self.check, self.check_now)
        on_click(self.save, self._save)
        self.run.on_click(lambda _: self._run_sim())
        self.queue_real.on_click(lambda _: self._run_real())
        self.dry.on_click(lambda _: self._dry_run())
        self.stop.on_click(lambda _: self._stop())
        self.reset.on_click(lambda _: self._reset())
        self.refresh_targets()
        if kept is not None:
            self._put_back(kept)
        # My files come from the lab: read them off the page's thread (a query can take 2 s).
        # After a reload the editor keeps the unsaved buffer put back above, not the newest file.
        threading.Thread(
            target=self._load_mine, args=(kept is None,), name=f"files-{ctx}", daemon=True
        ).start()
        if kept is None or kept.running_on is None:
            threading.Thread(target=self._follow_mine, name=f"mine-{ctx}", daemon=True).start()

    # -- surviving a reload

    def memory(self) -> BenchMemory:
        return BenchMemory(
            file_name=self.name.value,
            code=self.code.value,
            target=self.target.value,
            running_on=self._running_on,
            status=self.status.content,
            errors=tuple(self.run_output.errors),
            shown=self._shown,
            printed=tuple(self.run_output.printed),
            run_request=self.followed.request,
            next_line=self.run_output.next_line,
        )

    def _put_back(self, kept: BenchMemory) -> None:
        set_value(self.name, kept.file_name)
        show_text(self.code, kept.code)
        self._running_on = kept.running_on
        self._run_live = kept.running_on is not None
        self.status.content = kept.status
        if kept.target in self.target.options:
            set_value(self.target, kept.target)
        self.run_output.put_back(kept.printed, kept.errors, kept.next_line)
        self._output_of = kept.output_of
        self.followed.follow(kept.run_request)
        if kept.running_on is not None and kept.run_request is not None:
            self.followed.catch_up(*kept.running_on, kept.run_request, replace=False)
        problems, heading = kept.shown
        if problems:
            self._show(list(problems), heading)

    # -- what the student sees

    def say(self, text: str, *, bad: bool = False) -> None:
        self.status.content = ("**Not done:** " if bad else "") + escape_md(text)

    def _show(self, problems: list[Problem], heading: str) -> None:
        self._shown = (tuple(problems), heading)
        self.problems.content = (
            format_problems(self.code.value, problems, heading) if problems else ""
        )
        self.editor.mark(problems)

    def _clear(self) -> None:
        self._shown = ((), "")
        self.problems.content = ""
        self.editor.mark([])

    # -- files

    def _filename(self) -> str | None:
        name = self.name.value.strip()
        if not name.endswith(".py"):
            name += ".py"
        if not _FILE_NAME.match(name):
            self.say(
                f"{name!r} is not a file name: letters, digits, '_', '-', '.', ending in .py",
                bad=True,
            )
            return None
        self.run_output.traceback.filename = name
        return name

    def _source(self) -> bytes:
        return self.code.value.encode("utf-8")

    def current_file(self) -> tuple[str, bytes] | None:
        """The editor's file name and code (None, and said why, if the name is not one)."""
        name = self._filename()
        return None if name is None else (name, self._source())

    def _load_mine(self, open_newest: bool = True) -> None:
        """Fill the list with my files and open my newest one (the editor's 'last file')."""
        try:
            mine = self.connection.list_files(self.ctx)
        except LabError as exc:
            log.info("files of %s in %s: %s", self.connection.user, self.ctx, exc)
            return
        options = tuple(MINE_PREFIX + f.name for f in mine) + tuple(
            EXAMPLE_PREFIX + n for n in self._examples
        )
        if options:
            self.start_from.options = options
        if mine and open_newest:
            set_value(self.start_from, MINE_PREFIX + mine[0].name)
            self._open(tell=False)  # the status line may say how my run goes: it stays

    def _open(self, tell: bool = True) -> None:
        choice = self.start_from.value
        if choice.startswith(EXAMPLE_PREFIX):
            name = choice[len(EXAMPLE_PREFIX) :]
            source = self._examples.get(name)
            if source is None:
                return
            # an example is a start: saving must not look like it
            set_value(self.name, DEFAULT_NAME)
        elif choice.startswith(MINE_PREFIX):
            name = choice[len(MINE_PREFIX) :]
            try:
                source = self.connection.read_file(self.ctx, name)
            except LabError as exc:
                self.say(f"could not open {name}: {exc}", bad=True)
                return
            set_value(self.name, name)
        else:
            return
        show_text(self.code, source.decode("utf-8", "replace"))
        self._clear()
        if tell:
            self.say(f"Opened {name}.")

    def _save(self) -> str | None:
        name = self._filename()
        if name is None:
            return None
        try:
            detail = self.connection.save_file(self.ctx, name, self._source())
        except LabError as exc:
            self.say(f"{name} is not saved: {exc}", bad=True)
            return None
        option = MINE_PREFIX + name
        rest = tuple(o for o in self.start_from.options if o != option and o != "(none)")
        self.start_from.options = (option, *rest)
        self.say(detail[:1].upper() + detail[1:] + ".")
        return name

    # -- check and run

    def check_now(self) -> list[Problem]:
        name = self._filename() or DEFAULT_NAME
        problems = check_source(self._source(), name, self.run_on.robot_api())
        if problems:
            count = f"{len(problems)} problem{'s' if len(problems) > 1 else ''}"
            self._show(problems, f"Check: {count}")
            self.say(f"Check found {count}: see the marked lines below.")
        else:
            self._clear()
            self.say(
                "Check: no problems found. It will load and run; whether it drives well, "
                "only a run shows."
            )
        return problems

    def _ready(self) -> tuple[str, bytes] | None:
        """Checked and saved: (name, source), or None with the reason shown."""
        if self.check_now():
            self.say("Not queued: fix the problems Check found first.", bad=True)
            return None
        name = self._save()
        if name is None:
            return None
        source = self._source()
        _, problem = check_upload(name, source)
        if problem:
            self.say(f"Not queued: {problem}", bad=True)
            return None
        return name, source

    def _queue(self, ctx: str, agent: str, where: str) -> None:
        ready = self._ready()
        if ready is None:
            return
        name, source = ready
        with self._news_lock:  # the event thread shows lines under it
            self._running_on = (ctx, agent)
            self._run_live = True
            self.run_output.clear(next_line=0)  # a new run: its output only, from its first
            self._output_of = None  # the output put back was of another run
            self.followed.follow(None)
            news = self._news
        try:
            queued = self.connection.request_control(ctx, agent, name, source)
        except LabError as exc:
            self.say(f"Not queued on {agent}: {exc}", bad=True)
            return
        when = (
            "it starts now"
            if queued.position == 0 or (queued.eta_s is not None and queued.eta_s < 1.0)
            else f"you are #{queued.position} in the queue"
        )
        with self._news_lock:
            if self._news == news:
                self.say(f"{name} is queued on {agent} ({where}): {when}.")
            if self._running_on == (ctx, agent) and self.followed.request is None:
                self.followed.follow(queued.request_id)
        self.robots.refresh_agents()

    # -- the robot the buttons act on ("Run on")

    def refresh_targets(self) -> None:
        """The list follows this arena's robots and the real arenas joined (or left)."""
        self.run_on.refresh()

    def _run_sim(self) -> None:
        agent = self._simulated_robot("use 'Queue on the real robot'")
        if agent is None:
            return
        self._queue(self.ctx, agent, "simulation")

    def _simulated_robot(self, if_real: str) -> str | None:
        """The robot chosen to run on, if its arena is simulated; else None, having said
        why (``if_real``: what to do instead on a real arena)."""
        agent = self.run_on.here(self.say)
        if agent is not None and self.run_on.arena_is_real():
            self.say(f"This arena's robots are real: {if_real}.", bad=True)
            return None
        return agent

    def _dry_run(self) -> None:
        """The editor's text, dry-run on the chosen robot; the verdict under the code."""
        agent = self.run_on.here(self.say)
        if agent is None:
            return
        if self.check_now():
            self.say("Not dry-run: fix the problems Check found first.", bad=True)
            return
        name = self._filename() or DEFAULT_NAME
        source = self._source()
        _, problem = check_upload(name, source)
        if problem:
            self.say(f"Not dry-run: {problem}", bad=True)
            return
        self.dry.disabled = True
        self.say(f"Dry run of {name} on {agent}: a few simulated seconds in a private copy...")
        try:
            result = self.connection.dry_run(self.ctx, agent, name, source)
        except LabError as exc:
            self.say(f"Dry run of {name} on {agent}: {exc}", bad=True)
            return
        finally:
            self.dry.disabled = False
        verdict = "will NOT run"
        if result.will_run:
            verdict = "will run, with a warning" if "warning" in result.verdict else "will run"
        self.say(f"Dry run of {name} on {agent} done: it {verdict}, see below.")
        heading = f"Dry run on {agent}: {result.verdict}"
        self.problems.content = format_dry_run(self.code.value, result, heading)
        self.editor.mark([] if result.line is None else [Problem(result.line, result.verdict)])

    def _run_real(self) -> None:
        try:
            robots = self.connection.real_robots()
        except LabError as exc:
            self.say(f"Could not list the real robots: {exc}", bad=True)
            return
        self.refresh_targets()
        if not robots:
            self.say(
                "You have not joined a real arena (a Khepera bridge's context): join one from "
                "the lobby, then queue here.",
                bad=True,
            )
            return
        target = self.run_on.target()
        chosen = target if target in robots else robots[0]
        self._queue(chosen[0], chosen[1], f"real robot in {chosen[0]}")

    def _mine(self) -> list[tuple[str, AgentStatus]]:
        """My requests (running or waiting) in this arena and the real arenas joined."""
        contexts = [self.ctx, *sorted({c for c, _ in self.run_on.targets() if c != self.ctx})]
        found: list[tuple[str, AgentStatus]] = []
        for ctx in contexts:
            try:
                found += [(ctx, r) for r in self.connection.agents(ctx) if r.my_request]
            except LabError as exc:
                log.info("my requests in %s: %s", ctx, exc)
        return found

    def _stop(self) -> None:
        """Stop my run wherever it runs: started here, by Queue or Promote, simulated or real.

        Which: the editor's own run; else the chosen robot's; else whatever of mine
        runs now; else my one waiting request. Several waiting: the student chooses.
        """
        mine = self._mine()
        held = [(ctx, row.agent) for ctx, row in mine]
        target = self.run_on.target()
        if self._running_on in held:
            picks = [self._running_on]
        elif target in held:
            picks = [target]
        else:
            picks = [(ctx, row.agent) for ctx, row in mine if row.my_position == 0]
            if not picks and len(held) == 1:
                picks = held
        if not picks:
            if held:
                self.say(
                    f"You have {len(held)} requests waiting: choose the robot in 'Run on', "
                    "then Stop.",
                    bad=True,
                )
            else:
                self.say("Nothing of yours runs or waits on a robot.", bad=True)
            return
        news = self._news
        said = []
        for ctx, agent in picks:
            try:
                said.append(self.connection.cancel_control(ctx, agent))
            except LabError as exc:
                self.say(f"Nothing stopped on {agent}: {exc}", bad=True)
                return
        with self._news_lock:
            if self._news == news:
                self.say("Stopped: " + "; ".join(said) + ".")
        self.robots.refresh_agents()

    def _reset(self) -> None:
        agent = self._simulated_robot("put the robot back by hand")
        if agent is None:
            return
        try:
            detail = self.connection.reset_robot(self.ctx, agent)
        except LabError as exc:
            self.say(f"{agent} was not reset: {exc}", bad=True)
            return
        self.say(f"Reset: {detail}.")

    # -- the lab's news about my run (the connection's thread)

    def _follow_mine(self) -> None:
        """A run of mine already going in this arena when the tab opened: shown here."""
        try:
            rows = self.connection.agents(self.ctx)
        except LabError as exc:
            log.info("my runs in %s: %s", self.ctx, exc)
            return
        running = [(r.agent, r.my_request) for r in rows if r.my_request and r.my_position == 0]
        if running:
            with self._news_lock:
                self._adopt(self.ctx, running[0][0], "running", running[0][1])

    def _adopt(self, ctx: str, agent: str, status: str, request_id: str | None) -> bool:
        """Follow my run on ``agent`` (started in another tab) if this editor has none going."""
        if (ctx, agent) == self._running_on or (self._run_live and self._running_on):
            return False
        if ctx != self.ctx or status not in ("queued", "running"):
            return False
        self._running_on, self._run_live = (ctx, agent), True
        self.followed.follow(request_id)
        resumed, self._output_of = agent == self._output_of, None
        if resumed:  # the run this output came from, across a viewer's restart
            self.say(f"Your controller runs on {agent}.")
            self.run_output.note(RESUMED_NOTE)
            self.run_output.next_line = None  # a copy's lines carry no count
        else:
            self.run_output.clear()
            self.say(f"Your controller runs on {agent} (started in another tab or tool).")
            self.run_output.note(f"following your run on {agent}, started elsewhere")
        if request_id is not None:  # what it printed before this page came to it
            self.followed.catch_up(ctx, agent, request_id, replace=resumed)
        return True

    def on_request(self, event: RequestEvent) -> None:
        if event.user != self.connection.user:
            return
        with self._news_lock:
            self._adopt(event.ctx, event.agent, event.status, event.request_id)
            if (event.ctx, event.agent) == self._running_on:
                self._on_my_request(event)

    def _on_my_request(self, event: RequestEvent) -> None:
        if event.status != "queued":  # "queued" is what the request's own reply says
            self._news += 1
        if event.status in ("finished", "cancelled", "refused"):
            self._run_live = False
            why = f": {event.reason}" if event.reason else ""
            self.say(f"Your controller on {event.agent} {event.status}{why}.")
            self.run_output.note(f"{event.status}{why}")
            if event.status == "refused":
                self._show([Problem(None, event.reason or "refused")], "The lab refused it")
        elif event.status == "running":
            self.say(f"Your controller runs on {event.agent}.")
            self.run_output.note(f"running on {event.agent}")

    def on_output(self, event: OutputEvent) -> None:
        if event.user != self.connection.user:
            return
        with self._news_lock:
            self._adopt(event.ctx, event.agent, "running", event.request_id)
            if (event.ctx, event.agent) != self._running_on:
                return
            self.followed.show(event)

    def _raised(self) -> None:
        self._show(self.run_output.errors[-MAX_MARKED:], "Your controller raised an exception")
