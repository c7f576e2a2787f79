"""The arena tab's Recordings folder: my recorded runs, and what I can do with each.

Every slot an agent context runs is recorded (services/context/recorder.py);
the context lists and serves a student's own. Here, newest first (robot,
when, how it ended, duration), and for the chosen one:

- **Download**: the MCAP file, through viser's file download (a link in a
  notification);
- **Summary**: :func:`common.recording.summarize`'s numbers as text (the
  same lines ``wart report`` prints);
- **Plots**: the trajectory over the map and IR and wheel speeds over time,
  drawn by common/recording/plots.py (matplotlib) and shown as images;
- **Calibrate the robot (twin)**: the run's robot fitted from it, with the gap of the
  datasheet model and the twin, open-loop and sensor by sensor; the arena's owner (no
  one else sees it) then has **Keep as k1's twin**: the registry keeps it as the
  robot's twin in force, and its answer shows under the button;
- **Replay**: the run in the world view with a timeline (viewers/web/replay.py);
  "Back to live" returns to the arena;
- **Promote to real**: the run's controller file queued on a robot of a real
  arena the student has joined (``AgentClient.promote``).

A recording is downloaded once into a per-panel temporary directory and read
there; a file that is not a readable recording is said in words.
"""

from __future__ import annotations

import logging
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import viser

from common.recording import Recording, RecordingError, plots, read_recording, report, summarize
from common.twin import gap
from common.twin.fit import TwinError, calibrate, run_data
from common.twin.motion import Drive
from common.twin.twinfile import parse_twin
from viewers.web.adapters import LabConnection, LabError, RecordingEntry
from viewers.web.inputs import on_click, set_value
from viewers.web.replay import ReplayControls, ReplayFeed, ReplaySpot
from viewers.web.text import escape_md
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.recordings")

NONE = "(no recordings yet)"
NO_REAL = "(join a real arena first)"
MAX_LISTED = 20  # rows in the table (the context keeps 20 per user by default)
DOWNLOAD_NOTICE_CSS = (
    ".mantine-Notification-root a[download] .mantine-Button-root "
    "{ height: auto; padding-top: 4px; padding-bottom: 4px; } "
    ".mantine-Notification-root a[download] .mantine-Button-inner, "
    ".mantine-Notification-root a[download] .mantine-Button-label "
    "{ white-space: normal; overflow-wrap: anywhere; overflow: visible; height: auto; }"
)


def describe(entry: RecordingEntry) -> str:
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(entry.start))
    return f"{entry.agent} {when}"


def format_recordings(entries: list[RecordingEntry]) -> str:
    if not entries:
        return "_No recordings of yours here yet: every slot you run is recorded._"
    lines = ["| robot | when | how it ended | duration |", "| --- | --- | --- | --- |"]
    for e in entries[:MAX_LISTED]:
        when = time.strftime("%m-%d %H:%M:%S", time.localtime(e.start))
        ended = escape_md(e.status or "?") + (f": {escape_md(e.reason)}" if e.reason else "")
        took = "-" if e.duration_s is None else f"{e.duration_s:.1f} s"
        lines.append(f"| {escape_md(e.agent)} | {when} | {ended} | {took} |")
    return "\n".join(lines)


def summary_text(rec: Recording) -> str:
    return "```\n" + "\n".join(report.describe(summarize(rec))).replace("```", "'''") + "\n```"


class RecordingsPanel:
    def __init__(
        self,
        client: viser.ClientHandle,
        connection: LabConnection,
        ctx: str,
        *,
        view: Callable[[], WorldView | None],
        show: Callable[[ReplayFeed], None],
        back_to_live: Callable[[], None],
        owner: bool = False,
    ) -> None:
        self.client = client
        self.connection = connection
        self.ctx = ctx
        self.owner = owner  # this user owns the arena: may keep a fitted twin in the lab
        self.fitted: tuple[str, str] | None = None  # (robot, twin file) of the last fit
        self._entries: list[RecordingEntry] = []
        self._files: dict[str, Path] = {}
        self._tmp = tempfile.TemporaryDirectory(prefix="wart-recordings-")
        self._lock = threading.Lock()
        # One listing at a time: viser runs each click in its pool, and a slow listing begun
        # before a run was written, landing after a newer one, drew the older list.
        self._listing = threading.Lock()
        self._images: list[viser.GuiImageHandle] = []
        gui = client.gui
        with gui.add_folder("Recordings", expand_by_default=False) as self.folder:
            self.table = gui.add_markdown("_Press Refresh to list your recordings._")
            self.refresh_button = gui.add_button("Refresh", icon=viser.Icon.REFRESH)
            self.chosen = gui.add_dropdown("Recording", (NONE,))
            self.download = gui.add_button("Download", icon=viser.Icon.DOWNLOAD)
            # viser's download notice is a one-line button that cut a run's long file
            # name off: let its label wrap (a style rule; takes no room in the panel).
            gui.add_html(f"<style>{DOWNLOAD_NOTICE_CSS}</style>")
            self.summary = gui.add_button("Summary", icon=viser.Icon.LIST_NUMBERS)
            self.twin = gui.add_button(
                "Calibrate the robot (twin)",
                icon=viser.Icon.ADJUSTMENTS,
                hint="A real robot's run under the arena camera: fit its wheels' slip, wheel "
                "base, latency and IR gains (wart calibrate; docs/CALIBRATION.md)",
            )
            self.keep = gui.add_button(
                "Keep as the robot's twin",
                icon=viser.Icon.DEVICE_FLOPPY,
                visible=False,
                hint="The registry keeps it as the robot's twin in force: dry runs on the "
                "robot simulate it (the arena's owner only)",
            )
            self.keep_answer = gui.add_markdown("", visible=False)
            self.plots = gui.add_button("Plots", icon=viser.Icon.CHART_LINE)
            self.replay_button = gui.add_button(
                "Replay", color="grape", icon=viser.Icon.PLAYER_PLAY
            )
            self.real = gui.add_dropdown("Real robot", (NO_REAL,))
            self.promote = gui.add_button("Promote to real", icon=viser.Icon.ROBOT)
            self.status = gui.add_markdown("")
            self.details = gui.add_markdown("")
            self.pictures = gui.add_folder("Plots of the run", visible=False)
            self.spot = ReplaySpot(
                client, view=view, show=show, back_to_live=self._back_to_live(back_to_live)
            )
        on_click(self.refresh_button, self.refresh)
        self.download.on_click(lambda _: self._download())
        self.summary.on_click(lambda _: self._summary())
        self.twin.on_click(lambda _: self._calibrate())
        self.keep.on_click(lambda _: self._keep())
        self.plots.on_click(lambda _: self._plots())
        self.replay_button.on_click(lambda _: self._replay())
        self.promote.on_click(lambda _: self._promote())

    def say(self, text: str, *, bad: bool = False) -> None:
        self.status.content = ("**Not done:** " if bad else "") + escape_md(text)

    # -- the list

    def refresh(self) -> list[RecordingEntry]:
        with self._listing:
            return self._refresh()

    def _refresh(self) -> list[RecordingEntry]:
        try:
            entries = self.connection.recordings(self.ctx)
        except LabError as exc:
            self.say(f"Could not list your recordings: {exc}", bad=True)
            return self._entries
        self._entries = entries
        self.table.content = format_recordings(entries)
        options = tuple(describe(e) for e in entries[:MAX_LISTED]) or (NONE,)
        if tuple(self.chosen.options) != options:
            keep = self.chosen.value
            self.chosen.options = options
            set_value(self.chosen, keep if keep in options else options[0])
        robots = self.connection.real_robots()
        real = tuple(f"{c}/{a}" for c, a in robots) or (NO_REAL,)
        if tuple(self.real.options) != real:
            self.real.options = real
        self.say(f"{len(entries)} recording{'s' if len(entries) != 1 else ''}.")
        return entries

    def _entry(self) -> RecordingEntry | None:
        label = self.chosen.value
        entry = next((e for e in self._entries if describe(e) == label), None)
        if entry is None:
            self.say("Choose a recording first (press Refresh if the list is empty).", bad=True)
        return entry

    def _file(self, entry: RecordingEntry) -> Path | None:
        """The recording's file here, downloaded once."""
        with self._lock:
            path = self._files.get(entry.name)
            if path is not None and path.exists():
                return path
            dest = Path(self._tmp.name) / f"{entry.name}.mcap"
            try:
                self.connection.fetch_recording(self.ctx, entry.name, dest)
            except (LabError, OSError) as exc:
                self.say(f"Could not fetch {entry.name}: {exc}", bad=True)
                return None
            self._files[entry.name] = dest
            return dest

    def _read(self, entry: RecordingEntry) -> Recording | None:
        path = self._file(entry)
        if path is None:
            return None
        try:
            return read_recording(path)
        except RecordingError as exc:
            self.say(f"{entry.name} cannot be read: {exc}", bad=True)
            return None

    # -- the actions

    def _download(self) -> None:
        entry = self._entry()
        path = self._file(entry) if entry is not None else None
        if entry is None or path is None:
            return
        self.client.send_file_download(f"{entry.name}.mcap", path.read_bytes())
        self.say(f"{entry.name}.mcap is on its way: the link is in the notification.")

    def _summary(self) -> None:
        entry = self._entry()
        rec = self._read(entry) if entry is not None else None
        if rec is None:
            return
        self.details.content = summary_text(rec)
        self.say(f"Summary of {entry.name}." if entry else "")

    def _calibrate(self) -> None:
        """The run's robot calibrated from this run, with the gap of the datasheet model and
        the twin on it (shown here; ``wart calibrate --save`` keeps a twin in the lab)."""
        entry = self._entry()
        rec = self._read(entry) if entry is not None else None
        if entry is not None and rec is not None:
            self.show_calibration(entry.name, entry.agent, rec)

    def show_calibration(self, name: str, agent: str, rec: Recording) -> None:
        """``agent`` fitted from the run ``name`` (``rec``): the values, the open-loop gap
        and each sensor's error of the datasheet model and the twin, under the buttons."""
        self._offer(None)
        try:
            twin = calibrate(agent, [(name, rec)])
            runs = [run_data(rec, name)]
        except TwinError as exc:
            self.say(f"{name} cannot calibrate {agent}: {exc}", bad=True)
            return
        gaps = [gap.gap(model, drive, runs).line() for model, drive in
                (("datasheet", Drive()), ("twin", twin.fitted_drive()))]  # fmt: skip
        lines = "\n".join(f"- {escape_md(line)}" for line in twin.lines())
        lines += f"\n\n{escape_md(gap.heading())}:\n\n"
        lines += "\n".join(f"- {escape_md(line)}" for line in gaps)
        document = twin.to_json(self.connection.user, time.time())
        sensors = gap.sensor_lines(runs[0], parse_twin(document, f"{agent}'s twin"), name)
        lines += f"\n\n{escape_md(sensors[0])}\n\n"
        lines += "\n".join(f"- {escape_md(line.strip())}" for line in sensors[1:])
        self.details.content = f"**{escape_md(agent)}'s twin from {name}**\n\n{lines}"
        self.say(f"{agent} calibrated from {name}: below.")
        self._offer((agent, document))

    def _offer(self, fitted: tuple[str, str] | None) -> None:
        """Offer the arena's owner to keep a fitted twin (robot, twin file); None: nothing."""
        self.fitted = fitted
        self.keep_answer.visible = False
        if fitted is not None and self.owner:
            self.keep.label = f"Keep as {fitted[0]}'s twin"
        self.keep.visible = fitted is not None and self.owner

    def _keep(self) -> None:
        """The last fit kept by the registry as its robot's twin; its answer under the button."""
        if self.fitted is None or not self.owner:
            return
        robot, document = self.fitted
        try:
            said = self.connection.save_twin(self.ctx, robot, document)
        except LabError as exc:
            said = f"**Not kept:** {escape_md(str(exc))}"
        else:
            said = escape_md(said)
        self.keep_answer.content = said
        self.keep_answer.visible = True

    def _plots(self) -> None:
        entry = self._entry()
        rec = self._read(entry) if entry is not None else None
        if entry is None or rec is None:
            return
        if not plots.available():
            self.say("Plots need matplotlib on the viewer's machine (pip install matplotlib).")
            return
        import matplotlib.image  # optional: plots only (plots.available() said yes)

        out = Path(self._tmp.name) / "plots"
        try:
            written = plots.write_plots(rec, out, entry.name)
        except (ValueError, OSError) as exc:  # a recording too damaged to draw
            self.say(f"Could not draw {entry.name}: {exc}", bad=True)
            return
        for old in self._images:
            old.remove()
        self._images = []
        with self.pictures:
            for path in written:
                pixels = (matplotlib.image.imread(str(path))[:, :, :3] * 255).astype(np.uint8)
                label = "trajectory over the map" if "trajectory" in path.name else "IR and wheels"
                self._images.append(self.client.gui.add_image(pixels, label=label))
        self.pictures.visible = True
        self.say(f"Plots of {entry.name}: below.")

    @property
    def replay(self) -> ReplayControls | None:
        return self.spot.replay

    def _back_to_live(self, back: Callable[[], None]) -> Callable[[], None]:
        def left() -> None:
            self.say("Back to the live arena.")
            back()

        return left

    def _replay(self) -> None:
        entry = self._entry()
        rec = self._read(entry) if entry is not None else None
        if entry is None or rec is None:
            return
        problem = self.spot.start(rec)
        if problem:
            self.say(f"{entry.name}: {problem}", bad=True)
            return
        self.say(f"Replaying {entry.name} in the view: scrub the timeline, or press Play.")

    def _promote(self) -> None:
        entry = self._entry()
        if entry is None:
            return
        robots = self.connection.real_robots()
        if not robots:
            self.say(
                "Promote to real needs a real arena (a Khepera bridge's context): join one from "
                "the lobby, then promote the run here.",
                bad=True,
            )
            return
        chosen = next((r for r in robots if f"{r[0]}/{r[1]}" == self.real.value), robots[0])
        path = self._file(entry)
        if path is None:
            return
        try:
            queued = self.connection.promote(chosen[0], chosen[1], path)
        except LabError as exc:
            self.say(f"Not promoted: {exc}", bad=True)
            return
        self.say(
            f"{entry.name}'s controller is queued on the real robot {chosen[1]} in {chosen[0]}"
            f" (#{queued.position} in its queue)."
        )

    def close(self) -> None:
        self.spot.close()
        self._tmp.cleanup()
