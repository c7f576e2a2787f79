"""Replay a recorded run in a world view: a timeline slider, Play/Pause, speed.

:class:`ReplayFeed` is a :class:`~viewers.web.adapters.WorldFeed` whose
"latest" frame is the recording's frame at the player's cursor, so the
:class:`~viewers.web.pump.FramePump` draws a replay into the same
:class:`~viewers.web.world_view.WorldView` exactly as it draws a live world
(no second renderer): the map from the recording's ``/world/snapshot``, the
robots from ``/world/frame``. :class:`ReplayControls` is the GUI: the arena
tab's Recordings folder opens it (leaving is "Back to live"), and ``wart
replay FILE`` serves it alone, without a lab (:func:`main`).
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import viser
import viser.uplot

from common.messages import RobotTypeReply, WorldSnapshot
from common.recording import RecordingError, read_recording
from common.recording.reader import Recording
from common.recording.replay import SPEEDS, Player, Timeline
from common.service import stop_on_signals
from viewers.web.adapters import LabError
from viewers.web.arena_video import ArenaVideo, RecordedCamera
from viewers.web.inputs import set_value
from viewers.web.live_world import convert_snapshot
from viewers.web.pump import FramePump
from viewers.web.text import escape_md, output_html, printed
from viewers.web.world_feed import MapEdit, RobotReadings, SceneFrame, SceneLayout
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.replay")

OUTPUT_LINES = 12  # the controller's lines shown up to the cursor
PLOT_WINDOW_S = 10.0  # the IR plot shows the 10 s that end at the cursor
SLIDER_STEP = 0.05  # s
NOT_EDITABLE = "this is a replay of a recorded run: the live arena is edited, not its recording"


@dataclass(frozen=True)
class _Layout:
    view: SceneLayout
    object_rows: tuple[str, ...]


class ReplayFeed:
    """A recording as a world the view watches: the frame at the cursor is the newest."""

    def __init__(self, player: Player) -> None:
        self.player = player
        self.timeline = player.timeline
        info = self.timeline.recording.info
        assert info is not None  # Timeline refuses a recording without one
        self._world = info.world
        self._layouts: dict[int, _Layout] = {}  # id(WorldSnapshot) -> converted
        self._frames: dict[int, SceneFrame] = {}  # frame index -> converted (at most one)
        self._camera: RecordedCamera | bool | None = None  # False: the run has no video

    @property
    def world(self) -> str:
        return self._world

    def _layout(self, snap: WorldSnapshot) -> _Layout:
        found = self._layouts.get(id(snap))
        if found is None:
            view, rows = convert_snapshot(snap)
            found = self._layouts[id(snap)] = _Layout(view, rows)
        return found

    def snapshot(self) -> SceneLayout:
        return self._layout(self.player.moment().snapshot).view

    def latest(self) -> SceneFrame | None:
        moment = self.player.moment()
        cached = self._frames.get(moment.index)
        if cached is not None:
            return cached
        layout = self._layout(moment.snapshot)
        frame = moment.frame
        where = {name: i for i, name in enumerate(frame.rows)}
        robots = layout.view.robots
        poses = np.zeros((len(robots), 3), np.float32)
        gripper = np.zeros(len(robots), np.uint8)
        for k, name in enumerate(robots):
            i = where.get(name)
            if i is None or i >= len(frame.x):
                continue  # not in this frame (added by an edit later): left at the origin
            poses[k] = (frame.x[i], frame.y[i], frame.heading[i])
            if i < len(frame.fingers):
                gripper[k] = min(max(frame.fingers[i], 0), 2)
        balls = np.zeros((len(layout.view.balls), 2), np.float32)
        for k, ball in enumerate(layout.view.balls):
            i = where.get(ball.ident)
            balls[k] = (
                (frame.x[i], frame.y[i])
                if i is not None and i < len(frame.x)
                else (
                    ball.x,
                    ball.y,
                )
            )
        scene = SceneFrame(
            seq=moment.index,  # a new frame exactly when the cursor crosses one, either way
            t=moment.t,
            poses=poses,
            gripper=gripper,
            ball_xy=balls,
            lights_on=np.array([lt.on for lt in layout.view.lights], np.bool_),
        )
        self._frames = {moment.index: scene}
        return scene

    def camera(self) -> RecordedCamera | None:
        """A real run's floor video at the cursor; None when it recorded none."""
        if self._camera is None:
            images = [
                (stamped.t, stamped.record.data)
                for stamped in self.timeline.recording.images
                if stamped.record.frame_id.endswith("/floor")
            ]
            self._camera = RecordedCamera(images, self._wall_cursor) if images else False
        return self._camera if isinstance(self._camera, RecordedCamera) else None

    def _wall_cursor(self) -> float:
        """The cursor on the recording's own clock (its records' log times)."""
        return self.player.cursor + self.timeline.start

    def sensors(self, agent: str) -> RobotReadings | None:
        sample = self.player.moment().sample
        if sample is None or sample.agent != agent:
            return None  # only the run's robot was sensed
        ir = np.zeros(8, np.float32)
        ambient = np.zeros(8, np.float32)
        ir[: min(8, len(sample.proximity))] = sample.proximity[:8]
        ambient[: min(8, len(sample.ambient))] = sample.ambient[:8]
        return RobotReadings(agent, self.player.cursor, ir, ambient)

    def edit(self, edit: MapEdit) -> None:
        raise LabError(NOT_EDITABLE)

    def maps(self) -> list[str]:
        raise LabError(NOT_EDITABLE)

    def save_map(self, name: str) -> str:
        raise LabError(NOT_EDITABLE)

    def load_map(self, name: str) -> str:
        raise LabError(NOT_EDITABLE)

    def robot_types(self) -> RobotTypeReply:
        raise LabError(NOT_EDITABLE)

    def robot_file(self, name: str) -> str:
        raise LabError(NOT_EDITABLE)

    def save_robot_type(self, text: str) -> tuple[str, str]:
        raise LabError(NOT_EDITABLE)


def describe_run(recording: Recording) -> str:
    """One markdown line: whose run, which robot, how it ended."""
    info = recording.info
    assert info is not None
    end = recording.end
    how = f"{end.status}" + (f" ({end.reason})" if end.reason else "") if end else "cut short"
    file = f", {info.filename}" if info.filename else ""
    return escape_md(f"{info.user} on {info.agent} in {info.ctx} ({info.mode}{file}): {how}")


def readings_text(feed: ReplayFeed) -> str:
    """The run's robot at the cursor: IR, ambient, wheel speeds, the command in force."""
    moment = feed.player.moment()
    lines = [f"**t = {moment.t:.2f} s** of {feed.timeline.duration:.1f} s"]
    sample = moment.sample
    if sample is None:
        lines.append("_no sensor sample yet_")
    else:
        lines.append(f"IR: `{' '.join(str(v) for v in sample.proximity[:8])}`")
        lines.append(f"ambient: `{' '.join(str(v) for v in sample.ambient[:8])}`")
        lines.append(f"wheels (measured): `{sample.speeds[0]} {sample.speeds[1]}`")
    command = moment.command
    if command is not None and command.speeds is not None:
        lines.append(
            f"commanded: `{command.speeds[0]} {command.speeds[1]}` by {escape_md(command.sender)}"
        )
    return "  \n".join(lines)


def output_text(feed: ReplayFeed) -> str:
    """The output up to the cursor (HTML): each line as printed, after its time."""
    lines = feed.timeline.output_until(feed.player.cursor, OUTPUT_LINES)
    return output_html(
        (f"{t:6.2f}  {printed(text)}" for t, text in lines), "Nothing printed by then."
    )


class ReplayControls:
    """A replay's GUI in one client's panel: slider, Play/Pause, speed, readings, output.

    Made inside whatever GUI container is current (the arena tab's Recordings
    folder, or the root of ``wart replay``'s page). ``on_leave`` (None: no
    button) is "Back to live". When something else takes the view (the arena's
    "Show this arena"), the controls notice at the next slow tick and close.
    """

    def __init__(
        self,
        client: viser.ClientHandle,
        view: WorldView,
        recording: Recording,
        *,
        on_leave: Callable[[ReplayControls], None] | None = None,
        show: Callable[[ReplayFeed], None] | None = None,
    ) -> None:
        self.client = client
        self.view = view
        self.player = Player(Timeline(recording))  # RecordingError: nothing to replay
        self.feed = ReplayFeed(self.player)
        self.closed = False
        self._on_leave = on_leave
        self._shown = -1
        self._was_playing = False  # the last refresh saw it playing: the end must reach the slider
        duration = max(self.player.timeline.duration, SLIDER_STEP)
        gui = client.gui
        # With its handlers, as a chat panel is (chat_panel.py says why).
        with client.atomic():
            with gui.add_folder("Replay") as self.folder:
                gui.add_markdown(f"**Replay:** {describe_run(recording)}")
                self.slider = gui.add_slider(
                    "Time (s)", min=0.0, max=round(duration, 2), step=SLIDER_STEP, initial_value=0.0
                )
                self.play = gui.add_button("Play", color="green", icon=viser.Icon.PLAYER_PLAY)
                self.pause = gui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE)
                self.speed = gui.add_dropdown(
                    "Speed", tuple(f"{s:g}x" for s in SPEEDS), initial_value="1x"
                )
                self.back = (
                    gui.add_button("Back to live", color="teal", icon=viser.Icon.ARROW_BACK_UP)
                    if on_leave is not None
                    else None
                )
                self.readings = gui.add_markdown("")
                series = (
                    viser.uplot.Series(label="t"),
                    *[
                        viser.uplot.Series(label=f"IR{i}", stroke=_colour(i), width=1)
                        for i in range(8)
                    ],
                )
                empty = (np.zeros(0), *[np.zeros(0)] * 8)
                self.ir_plot = gui.add_uplot(empty, series, title="IR up to the cursor", aspect=2.0)
                with gui.add_folder("Output up to the cursor"):
                    self.output = gui.add_html("")
            self.slider.on_update(self._scrubbed)
            self.play.on_click(lambda _: self._play())
            self.pause.on_click(lambda _: self._pause())
            self.speed.on_update(lambda _: self._speed())
            if self.back is not None:
                self.back.on_click(lambda _: self.leave())
        if show is not None:
            show(self.feed)
        else:
            view.show(self.feed)
        names = view.robot_names
        if self.player.timeline.agent in names:  # the run's robot: ring, trail, its readings
            view.select(names.index(self.player.timeline.agent))
        view.slow_hooks.append(self.tick)
        self.refresh()

    # -- the student's hands

    def _scrubbed(self, event: viser.GuiEvent) -> None:
        if event.client is None:
            return  # our own assignment while playing (viser calls back for those too)
        self.player.seek(float(self.slider.value))
        self.refresh()

    def _play(self) -> None:
        self.player.play()
        self.refresh()

    def _pause(self) -> None:
        self.player.pause()
        self._was_playing = True  # the slider goes to where the cursor stopped
        self.refresh()

    def _speed(self) -> None:
        try:
            speed = float(self.speed.value.rstrip("x"))
        except ValueError:
            return
        if speed in SPEEDS:
            self.player.set_speed(speed)

    def seek(self, t: float) -> None:
        """Move the cursor as the slider does (tests, and a page that jumps to an event)."""
        self.player.seek(t)
        self.refresh()

    # -- following the cursor

    def tick(self) -> None:
        """The pump's slow tick (5 Hz): the slider follows a playing cursor; readings follow."""
        if self.closed:
            return
        if self.view.feed is not self.feed:  # the view went live (or to another replay)
            self.close()
            return
        self.refresh()

    def refresh(self) -> None:
        cursor = self.player.cursor
        value = round(cursor, 2)
        # Only a playing cursor moves the slider (and Play/Pause/the end): when paused the
        # slider is the student's, and writing back a cursor a step behind their drag would
        # pull the thumb back under their hand.
        if (self.player.playing or self._was_playing) and abs(
            float(self.slider.value) - value
        ) >= SLIDER_STEP / 2:
            set_value(self.slider, value)
        self._was_playing = self.player.playing
        self.play.disabled = self.player.playing
        self.pause.disabled = not self.player.playing
        moment = self.player.moment()
        if moment.index == self._shown and not self.player.playing:
            return
        self._shown = moment.index
        self.readings.content = readings_text(self.feed)
        self.output.content = output_text(self.feed)
        window = self.player.timeline.samples_between(cursor - PLOT_WINDOW_S, cursor)
        if window:
            t = np.array([w[0] for w in window], np.float64)
            ir = np.zeros((8, len(window)), np.float64)
            for j, (_, sample) in enumerate(window):
                values = sample.proximity[:8]
                ir[: len(values), j] = values
            self.ir_plot.data = (t, *ir)

    # -- leaving

    def leave(self) -> None:
        """Back to live: close the controls, then let the owner show the live arena."""
        self.close()
        if self._on_leave is not None:
            self._on_leave(self)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.player.pause()
        if self.tick in self.view.slow_hooks:
            self.view.slow_hooks.remove(self.tick)
        self.folder.remove()


class ReplaySpot:
    """Where a panel's replay sits: one replay at a time, in its own folder of the panel.

    Made inside the panel's current GUI container (the arena tab's Recordings or
    Course folder). ``view`` gives the page's world view (None: not shown yet),
    ``show`` puts a replay's feed in it (the arena's panels follow the cursor) and
    ``back_to_live`` returns the view to the arena when the student leaves.
    """

    def __init__(
        self,
        client: viser.ClientHandle,
        *,
        view: Callable[[], WorldView | None],
        show: Callable[[ReplayFeed], None],
        back_to_live: Callable[[], None],
    ) -> None:
        self.client = client
        self._view = view
        self._show = show
        self._back_to_live = back_to_live
        self.replay: ReplayControls | None = None
        self.folder = client.gui.add_folder("Replay controls", visible=False)

    def start(self, recording: Recording) -> str:
        """Replay ``recording`` in the view; "" or why it cannot be (in the student's words)."""
        view = self._view()
        if view is None:
            return "the page has no world view to replay in: press Show this arena first"
        try:
            Timeline(recording)
        except RecordingError as exc:
            return f"it cannot be replayed: {exc}"
        self.close()
        with self.folder:
            self.replay = ReplayControls(
                self.client, view, recording, on_leave=self._left, show=self._show
            )
        self.folder.visible = True
        return ""

    def _left(self, _controls: ReplayControls) -> None:
        self.replay = None
        self.folder.visible = False
        self._back_to_live()

    def close(self) -> None:
        if self.replay is not None:
            self.replay.close()
            self.replay = None
        self.folder.visible = False


def _colour(i: int) -> str:
    return ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45"][
        i % 8
    ]


# --- `wart replay FILE`: a viewer of one recording, no lab ---------------------------------


class ReplayServer:
    """A viser server showing one recording to every browser that opens it (each its own cursor)."""

    def __init__(self, recording: Recording, *, host: str = "127.0.0.1", port: int = 8090) -> None:
        Timeline(recording)  # refuse a recording with nothing to replay before serving
        self.recording = recording
        self.server = viser.ViserServer(host=host, port=port, label="wart replay")
        self.host = host
        self.pump = FramePump().start()
        self.controls: dict[int, ReplayControls] = {}
        self._lock = threading.Lock()
        self.server.on_client_connect(self._connected)
        self.server.on_client_disconnect(self._gone)

    @property
    def url(self) -> str:
        # viser takes the next port when the asked one is busy: print the one it got.
        return f"http://{self.host}:{self.server.get_port()}"

    def _connected(self, client: viser.ClientHandle) -> None:
        view = WorldView(client)
        ArenaVideo(view)  # a real run's recorded video under its world
        self.pump.attach(view)
        client.gui.add_markdown(f"### {escape_md(self.recording.path.name)}")
        controls = ReplayControls(client, view, self.recording)
        with self._lock:
            self.controls[client.client_id] = controls

    def _gone(self, client: viser.ClientHandle) -> None:
        with self._lock:
            controls = self.controls.pop(client.client_id, None)
        if controls is not None:
            self.pump.detach(controls.view)

    def stop(self) -> None:
        self.pump.stop()
        self.server.stop()


def main(argv: Sequence[str] | None = None, prog: str = "wart replay") -> int:
    parser = argparse.ArgumentParser(
        prog=prog,
        description=(
            "Replay a recorded run (an MCAP file from `wart record get` or the page's Download) "
            "in a web viewer: the arena as recorded, a timeline to scrub, play and pause at "
            "0.5x to 4x, the robot's sensors and the controller's output at the cursor. "
            "No lab is needed."
        ),
    )
    parser.add_argument("file", help="the recording (.mcap)")
    parser.add_argument(
        "--host", default="127.0.0.1", help="address to serve on (default %(default)s)"
    )
    parser.add_argument(
        "--port", type=int, default=8090, help="port (default %(default)s; the next if busy)"
    )
    args = parser.parse_args(argv)
    try:
        recording = read_recording(args.file)
        app = ReplayServer(recording, host=args.host, port=args.port)
    except RecordingError as exc:
        print(f"{prog}: {exc}", file=sys.stderr, flush=True)
        return 2
    if recording.truncated:
        print(f"{prog}: warning: {recording.truncated}; replaying what it holds", file=sys.stderr)
    print(f"replay: {app.url}", flush=True)
    done = stop_on_signals()
    try:
        done.wait()
    finally:
        app.stop()
    return 0
