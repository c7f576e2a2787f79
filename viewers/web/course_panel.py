"""The Course folder of an arena's panel: my assignments, submit the editor's code, my scores,
the leaderboard (the grader, docs/COURSES.md), and the competitions of my courses, all live.

A student picks an assignment of their courses, hands in the file open in the
workbench's editor, and reads their submissions (status, mean, each episode's
score and how it ended: their code's fault with the line, or the lab's, re-run
free) and the leaderboard. Both update by themselves: the grader says when a
submission changes (``GradingChanged``: no score, no name), and the panel asks
again for what its user may see: "my scores" when the change is one of mine,
the leaderboard when a submission of the chosen assignment was graded (a board
hidden until the deadline stays hidden: the grader answers a student with no
entries). The buttons still read both at once. A competition's standings
come as the grader publishes them (each heat's start and end): whoever has the
folder open sees the ranking change when a heat ends, with the heat in progress.

Each graded episode of a recent submission can be replayed in the world view
(the grader keeps its recording: services/grader/episode_recordings.py), with
the same timeline as a recorded run.
"""

from __future__ import annotations

import re
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import viser

from common.messages import AssignmentInfo, GradingChanged, Leaderboard, Standings, SubmissionInfo
from common.recording import RecordingError, read_recording
from viewers.web.adapters import LabConnection, LabError
from viewers.web.inputs import on_click, set_value
from viewers.web.replay import ReplayFeed, ReplaySpot
from viewers.web.text import code_md, escape_md
from viewers.web.world_view import WorldView

NONE = "(no assignment)"
NO_REPLAY = "(no graded episode kept)"
MAX_SHOWN = 10  # the latest submissions in the table
MAX_COMPETITIONS = 3  # the latest competitions shown
COALESCE_S = 0.1  # changes that come together are read once
SUBMITTED = re.compile(r"submitted (\S+):")  # the id in submitted_words' text


def _when(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(t))


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


def format_assignment(a: AssignmentInfo) -> str:
    better = "higher" if a.order == "higher" else "lower"
    unit = f" {escape_md(a.unit)}" if a.unit else ""
    return (
        f"**{escape_md(a.title)}** ({escape_md(a.course)}): {a.episodes} episodes of "
        f"{a.time_limit:g} simulated s; due {_when(a.deadline)}; {a.quota} graded runs a day. "
        f"Score: {escape_md(a.score_name)}{unit}, {better} is better: {code_md(a.rule)}"
    )


def format_submissions(subs: list[SubmissionInfo]) -> str:
    if not subs:
        return "_No submission of yours yet._"
    lines = ["| submitted | status | mean | episodes |", "| --- | --- | --- | --- |"]
    for s in subs[-MAX_SHOWN:][::-1]:
        episodes = "; ".join(
            f"{'real' if e.real else e.episode}: {_num(e.score)} ({escape_md(e.cause)}"
            + (f", line {e.error_line}" if e.error_line else "")
            + (f", lab re-run {e.lab_reruns}x free" if e.lab_reruns else "")
            + ")"
            for e in s.episodes
        )
        whose = "the teacher's grader" if s.message.startswith("the teacher's") else "the lab's"
        status = s.status if s.status != "failed" else f"failed ({whose}; not counted)"
        when = time.strftime("%H:%M:%S", time.localtime(s.submitted_at))
        lines.append(f"| {when} | {status} | {_num(s.mean)} | {episodes or '-'} |")
    return "\n".join(lines)


def format_episodes(sub: SubmissionInfo) -> str:
    """One submission episode by episode: its score term by term, how it ended, what it said."""
    when = time.strftime("%H:%M:%S", time.localtime(sub.submitted_at))
    lines = [f"**Submission of {when}, episode by episode** ({sub.status})"]
    for e in sub.episodes:
        name = "real robot" if e.real else f"episode {e.episode} (seed {e.seed})"
        if e.cause == "hidden":
            lines.append(f"- {name}: {escape_md(e.detail)}")
            continue
        score = f"**{_num(e.score)}**"
        if e.terms:
            score += " = " + " ".join(f"{code_md(text)} → {value:g}" for text, value in e.terms)
        lines.append(f"- {name}: {score}; ended: {escape_md(e.cause)}")
        if e.detail:
            lines.append(f"  - {escape_md(e.detail)}")
        if e.output:
            shown = "  \n".join(escape_md(line) for line in e.output[-8:])
            lines.append(f"  - printed (last lines):  \n{shown}")
    if not sub.episodes:
        lines.append("_No episode has run yet._")
    return "\n".join(lines)


def replayable(subs: list[SubmissionInfo]) -> dict[str, tuple[str, int]]:
    """The episodes of my recent submissions that can be replayed, newest first, by label."""
    found: dict[str, tuple[str, int]] = {}
    for sub in subs[-MAX_SHOWN:][::-1]:
        when = time.strftime("%H:%M:%S", time.localtime(sub.submitted_at))
        for e in sub.episodes:
            if e.replay:
                ended = "" if e.score is None else f", score {e.score:g}"
                label = f"{when} · episode {e.episode} ({e.cause}{ended})"
                found[label] = (sub.submission, e.episode)
    return found


def format_board(board: Leaderboard) -> str:
    if board.hidden and not board.entries:
        if board.hidden_until:
            return f"_Hidden: {escape_md(board.hidden_until)}._"
        return f"_Hidden until the deadline, {_when(board.deadline)}._"
    if not board.entries:
        return "_No graded submission yet._"
    lines = ["| rank | name | score | real |", "| --- | --- | --- | --- |"]
    for e in board.entries[:50]:
        lines.append(f"| {e.rank} | {escape_md(e.name)} | {e.score:g} | {_num(e.real)} |")
    return "\n".join(lines)


def format_standings(st: Standings) -> str:
    better = "higher" if st.order == "higher" else "lower"
    if st.status == "running" and st.heat:
        where = f"heat {st.heat} of {st.heats} running"
    else:
        where = f"{st.status}, {st.heats} heat(s)"
    unit = f" ({escape_md(st.unit)})" if st.unit else ""
    lines = [
        f"**Competition {escape_md(st.competition)}** on {escape_md(st.assignment)}: {where}; "
        f"{escape_md(st.score_name)}{unit}, {better} is better",
        "",
        "| rank | team | score | heat | how it ended |",
        "| --- | --- | --- | --- | --- |",
    ]
    for e in st.entries[:50]:
        if e.cause == "waiting":
            running = st.status == "running" and e.heat == st.heat
            ended = "running" if running else (e.detail or "waiting")
        else:
            ended = f"{e.cause}: {e.detail}"
        rank = str(e.rank) if e.rank else "-"
        lines.append(
            f"| {rank} | {escape_md(e.team)} | {_num(e.score)} | {e.heat} | {escape_md(ended)} |"
        )
    return "\n".join(lines)


class CoursePanel:
    def __init__(
        self,
        client: viser.ClientHandle,
        connection: LabConnection,
        *,
        source: Callable[[], tuple[str, bytes] | None],
        view: Callable[[], WorldView | None] = lambda: None,
        show: Callable[[ReplayFeed], None] = lambda _feed: None,
        back_to_live: Callable[[], None] = lambda: None,
    ) -> None:
        """``source``: the editor's file name and code (None: the name is not a file name);
        ``view``, ``show``, ``back_to_live``: where a graded episode is replayed."""
        self.connection = connection
        self._source = source
        self._assignments: dict[str, AssignmentInfo] = {}
        self._courses: set[str] = set()  # mine, once the assignments are listed
        self._standings: dict[str, Standings] = {}
        self._lock = threading.Lock()
        self._mine: set[str] = set()  # my submissions' ids (shown or handed in here)
        self._want_scores = self._want_board = False
        self._dirty = threading.Event()
        self._closed = threading.Event()
        self._replayable: dict[str, tuple[str, int]] = {}
        self._tmp = tempfile.TemporaryDirectory(prefix="wart-episodes-")
        gui = client.gui
        with gui.add_folder("Course", expand_by_default=False) as self.folder:
            self.refresh_button = gui.add_button("Refresh assignments", icon=viser.Icon.REFRESH)
            self.chosen = gui.add_dropdown("Assignment", (NONE,))
            self.about = gui.add_markdown("")
            self.submit_button = gui.add_button(
                "Submit the editor's code", color="green", icon=viser.Icon.SEND
            )
            self.status = gui.add_markdown("")
            self.scores_button = gui.add_button("My scores", icon=viser.Icon.LIST_NUMBERS)
            self.scores = gui.add_markdown("")
            self.latest = gui.add_markdown("")  # the newest submission, episode by episode
            self.episode = gui.add_dropdown("Graded episode", (NO_REPLAY,))
            self.replay_button = gui.add_button(
                "Replay the episode", color="grape", icon=viser.Icon.PLAYER_PLAY
            )
            self.replay_said = gui.add_markdown("")
            self.spot = ReplaySpot(client, view=view, show=show, back_to_live=back_to_live)
            self.board_button = gui.add_button("Leaderboard", icon=viser.Icon.TROPHY)
            self.board = gui.add_markdown("")
            self.competitions = gui.add_markdown("")
        on_click(self.refresh_button, self.refresh)
        on_click(self.submit_button, self.submit)
        on_click(self.scores_button, self.show_scores)
        on_click(self.board_button, self.show_board)
        on_click(self.replay_button, self.replay_episode)
        self.chosen.on_update(lambda _: self._describe())
        try:
            self._unwatch = connection.courses.watch_standings(self.on_standings)
        except LabError as exc:
            self._unwatch = lambda: None
            self.competitions.content = f"_Competitions are not shown live: {escape_md(str(exc))}_"
        try:
            self._unwatch_grading = connection.courses.watch_grading(self.on_change)
        except LabError:
            self._unwatch_grading = lambda: None  # the buttons still read them
        self._thread = threading.Thread(target=self._loop, name="course-live", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._closed.set()
        self._dirty.set()
        self._unwatch()
        self._unwatch_grading()
        self.spot.close()
        self._tmp.cleanup()

    def on_change(self, change: GradingChanged) -> None:
        """A submission changed (a Zenoh thread): read again what it changes here, soon."""
        if change.assignment != self.chosen.value:
            return
        with self._lock:
            if change.submission in self._mine:
                self._want_scores = True
            if change.status == "graded":
                self._want_board = True
            wanted = self._want_scores or self._want_board
        if wanted:
            self._dirty.set()

    def _loop(self) -> None:
        """Reads what changed off the Zenoh thread (a query from a callback could block it)."""
        while self._dirty.wait():
            if self._closed.is_set():
                return
            time.sleep(COALESCE_S)
            self._dirty.clear()
            with self._lock:
                scores, board = self._want_scores, self._want_board
                self._want_scores = self._want_board = False
            if scores:
                self.show_scores()
            if board:
                self.show_board()

    def on_standings(self, st: Standings) -> None:
        """A competition's standings from the grader (any thread): shown if of my courses."""
        with self._lock:
            held = self._standings.get(st.competition)
            if held is not None and held.at > st.at:
                return  # an older one, late
            self._standings[st.competition] = st
        self._show_standings()

    def _show_standings(self) -> None:
        with self._lock:
            mine = [s for s in self._standings.values() if s.course in self._courses]
        mine.sort(key=lambda s: s.at, reverse=True)
        self.competitions.content = "\n\n".join(
            format_standings(s) for s in mine[:MAX_COMPETITIONS]
        )

    def say(self, text: str, *, bad: bool = False) -> None:
        self.status.content = ("**Not done:** " if bad else "") + escape_md(text)

    def _assignment(self) -> str | None:
        name = self.chosen.value
        if name not in self._assignments:
            self.say("Pick an assignment first (Refresh assignments lists yours).", bad=True)
            return None
        return name

    def _describe(self) -> None:
        a = self._assignments.get(self.chosen.value)
        self.about.content = format_assignment(a) if a else ""

    def refresh(self) -> list[str]:
        try:
            found = self.connection.courses.assignments()
        except LabError as exc:
            self.say(f"Could not list your assignments: {exc}", bad=True)
            return []
        self._assignments = {a.name: a for a in found}
        with self._lock:
            self._courses = {a.course for a in found}
        self._show_standings()
        options = tuple(self._assignments) or (NONE,)
        keep = self.chosen.value
        self.chosen.options = options
        set_value(self.chosen, keep if keep in options else options[0])
        self._describe()
        self.say(f"{len(found)} assignment(s) in your courses." if found else "No assignment yet.")
        return list(self._assignments)

    def submit(self) -> str | None:
        name = self._assignment()
        file = self._source()
        if name is None or file is None:
            return None
        filename, code = file
        try:
            said = self.connection.courses.submit(name, filename, code)
        except LabError as exc:
            self.say(str(exc), bad=True)
            return None
        found = SUBMITTED.match(said)
        if found:
            with self._lock:
                self._mine.add(found.group(1))
        self.say(said + " (My scores and the leaderboard update as it is graded)")
        self.show_scores()
        return said

    def show_scores(self) -> list[SubmissionInfo]:
        name = self._assignment()
        if name is None:
            return []
        try:
            subs = self.connection.courses.submissions(name)
        except LabError as exc:
            self.say(f"Could not read your scores: {exc}", bad=True)
            return []
        with self._lock:
            self._mine.update(s.submission for s in subs)
        self.scores.content = format_submissions(subs)
        self.latest.content = format_episodes(subs[-1]) if subs else ""
        found = replayable(subs)
        with self._lock:
            self._replayable = found
        keep = self.episode.value
        options = tuple(found) or (NO_REPLAY,)
        self.episode.options = options
        set_value(self.episode, keep if keep in options else options[0])
        return subs

    def replay_episode(self) -> str:
        """Replay the chosen graded episode in the world view; what the student is told."""
        name = self._assignment()
        with self._lock:
            chosen = self._replayable.get(self.episode.value)
        if name is None:
            return ""
        if chosen is None:
            said = "No graded episode to replay yet: press My scores once a submission is graded."
            self.replay_said.content = "**Not done:** " + escape_md(said)
            return said
        sub, n = chosen
        dest = Path(self._tmp.name) / f"{sub}-{n}.mcap"
        try:
            if not dest.exists():
                self.connection.courses.fetch_episode(name, sub, n, dest)
            problem = self.spot.start(read_recording(dest))
        except (LabError, RecordingError, OSError) as exc:
            problem = str(exc)
        if problem:
            said = f"Episode {n} of {sub} is not replayed: {problem}"
            self.replay_said.content = "**Not done:** " + escape_md(said)
            return said
        said = f"Replaying episode {n} of {sub} in the view: scrub the timeline, or press Play."
        self.replay_said.content = escape_md(said)
        return said

    def show_board(self) -> Leaderboard | None:
        name = self._assignment()
        if name is None:
            return None
        try:
            board = self.connection.courses.leaderboard(name)
        except LabError as exc:
            self.say(f"Could not read the leaderboard: {exc}", bad=True)
            return None
        self.board.content = format_board(board)
        return board
