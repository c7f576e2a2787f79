"""Where a camera's frames come from: a V4L2 device, a video file, a network stream, or a
synthetic camera over an emulated arena.

Every source opens, gives one BGR frame at a time and says in words why it
cannot (unplugged, the file ended, the stream is unreachable): the service
turns that into "camera offline: ..." on the page and tries again.
"""

from __future__ import annotations

import dataclasses
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Protocol

import cv2
import numpy as np

from common.tracking.markers import default_layout
from common.tracking.synthetic import CameraModel, SyntheticCamera
from common.tracking.truth import TruthError, read_truth

SYNTHETIC = "synthetic:"
Rectangle = tuple[float, float, float, float]  # x0, y0, x1, y1 in arena mm
_DEVICE = re.compile(r"^(/dev/video\d+|\d+)$")
_URL = re.compile(r"^(rtsp|rtsps|http|https|tcp|udp)://", re.IGNORECASE)


class SourceError(Exception):
    """A source that cannot give a frame now; the message is for the page and the log."""


class SourceEnded(SourceError):
    """A recording that has ended: it will give no more frames, so it is not tried again."""


class FrameSource(Protocol):
    @property
    def description(self) -> str: ...

    # The camera's intrinsics when the source knows them (the synthetic camera).
    @property
    def camera_matrix(self) -> np.ndarray | None: ...

    @property
    def dist_coeffs(self) -> np.ndarray | None: ...

    # When the last frame read was true (wall clock, s): a recording's own timeline;
    # None for a live source (the service stamps it on arrival).
    @property
    def captured_at(self) -> float | None: ...

    # A recording plays at its own rate; a live source is read at the service's.
    @property
    def paces_itself(self) -> bool: ...

    # How many times a looping recording has started again.
    @property
    def loops(self) -> int: ...

    def open(self) -> None: ...

    def read(self) -> np.ndarray: ...

    def notes(self) -> list[str]:
        """What happened since the last call that the log should say (corrupt frames)."""
        ...

    def close(self) -> None: ...


def describe_spec(spec: str) -> str:
    if spec.startswith(SYNTHETIC):
        return f"synthetic camera over {spec[len(SYNTHETIC) :]}"
    if _DEVICE.match(spec):
        return f"video device {spec}"
    if _URL.match(spec):
        return f"stream {re.sub(r'//[^@/]*@', '//***@', spec)}"  # no password in logs
    return f"video file {spec}"


def check_spec(spec: str) -> str:
    """The spec if it names a source this service can open; ValueError in words if not."""
    if not spec or len(spec) > 1024 or any(c in spec for c in "\0\n\r"):
        raise ValueError(
            "--source must be a device (/dev/video0 or 0), a file, a URL or synthetic:FILE"
        )
    if spec.startswith(SYNTHETIC) and not spec[len(SYNTHETIC) :]:
        raise ValueError(
            "synthetic: needs the emulator's truth file, e.g. synthetic:/tmp/arena.json"
        )
    return spec


def open_source(
    spec: str,
    *,
    loop: bool = False,
    seed: int = 0,
    sample_fps: float | None = None,
    grid: tuple[int, int] = (2, 2),
    over: Rectangle | None = None,
) -> FrameSource:
    """The source ``spec`` names. ``loop`` and ``sample_fps`` are for a video file: play it
    again at its end, and take frames at that rate from its timeline (default: all);
    ``grid`` and ``over`` for a synthetic camera: the reference markers it renders, and
    the part of the arena it hangs over."""
    check_spec(spec)
    if spec.startswith(SYNTHETIC):
        return SyntheticSource(Path(spec[len(SYNTHETIC) :]), seed=seed, grid=grid, over=over)
    if _DEVICE.match(spec) or _URL.match(spec):
        return OpenCvSource(spec)
    return Recording(Path(spec), loop=loop, sample_fps=sample_fps)


def _bgr(frame: np.ndarray) -> np.ndarray:
    if frame.ndim == 2:
        frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    return np.asarray(frame)


class OpenCvSource:
    """A device or stream through OpenCV's VideoCapture (V4L2 or FFmpeg): live frames,
    stamped by the service when they arrive."""

    camera_matrix: np.ndarray | None = None
    dist_coeffs: np.ndarray | None = None
    captured_at: float | None = None  # live: the service stamps the frame on arrival
    paces_itself = False
    loops = 0

    def __init__(self, spec: str) -> None:
        self.spec = spec
        self.description = describe_spec(spec)
        self._capture: cv2.VideoCapture | None = None

    def open(self) -> None:
        if _DEVICE.match(self.spec):
            index = self.spec if not self.spec.isdigit() else int(self.spec)
            capture = cv2.VideoCapture(index, cv2.CAP_V4L2)
        else:
            capture = cv2.VideoCapture(self.spec, cv2.CAP_FFMPEG)
        if not capture.isOpened():
            capture.release()
            raise SourceError(f"cannot open the {self.description} (unplugged, or in use?)")
        # A live camera keeps one frame in its buffer: the newest, not a backlog.
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        self._capture = capture

    def read(self) -> np.ndarray:
        if self._capture is None:
            raise SourceError("not open")
        ok, frame = self._capture.read()
        if not ok or frame is None:
            raise SourceError(f"the {self.description}: it stopped giving frames")
        return _bgr(frame)

    def notes(self) -> list[str]:
        return []

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


@dataclass
class SyntheticSource:
    """Frames rendered from the emulator's truth file (see common/tracking/synthetic.py)."""

    truth: Path
    seed: int = 0
    model: CameraModel = field(default_factory=CameraModel)
    blur_sigma_px: float = 0.6
    noise_sigma: float = 2.0
    grid: tuple[int, int] = (2, 2)  # the reference markers on its floor
    over: Rectangle | None = None  # the part of the arena it sees; None: all of it

    def __post_init__(self) -> None:
        self.description = describe_spec(SYNTHETIC + str(self.truth))
        self._camera: SyntheticCamera | None = None
        self._arena: tuple[float, float] | None = None
        self._agents: tuple[str, ...] = ()

    @property
    def camera_matrix(self) -> np.ndarray | None:
        return None if self._camera is None else self._camera.camera_matrix

    @property
    def dist_coeffs(self) -> np.ndarray | None:
        return None if self._camera is None else self._camera.dist_coeffs

    captured_at: float | None = None
    paces_itself = False
    loops = 0

    def notes(self) -> list[str]:
        return []

    def open(self) -> None:
        self.read()

    def read(self) -> np.ndarray:
        try:
            truth = read_truth(self.truth)
        except TruthError as exc:
            raise SourceError(str(exc)) from None
        if time.time() - truth.at > 2.0:
            raise SourceError(
                f"the emulator stopped writing {self.truth} "
                f"(last {time.time() - truth.at:.0f} s ago)"
            )
        agents = tuple(sorted(truth.robots))
        arena = (truth.width_mm, truth.height_mm)
        if self._camera is None or arena != self._arena or agents != self._agents:
            layout = default_layout(arena[0], arena[1], agents, grid=self.grid)
            self._camera = SyntheticCamera(
                arena[0],
                arena[1],
                layout,
                self._placed(arena),
                blur_sigma_px=self.blur_sigma_px,
                noise_sigma=self.noise_sigma,
                seed=self.seed,
            )
            self._arena, self._agents = arena, agents
        # The frame shows the robots where they were when the emulator wrote them, not
        # when it is rendered: a loaded host reads a truth file 0.1 to 1.5 s old.
        self.captured_at = truth.at
        return self._camera.render(truth.robots)

    def _placed(self, arena: tuple[float, float]) -> CameraModel:
        """The model hung straight down over the centre of ``over``, its view fitting
        that rectangle as the whole camera's fits the whole arena."""
        m = self.model
        if self.over is None:
            return m
        x0, y0, x1, y1 = self.over
        whole = max(arena[0] / m.width, arena[1] / m.height)
        part = max((x1 - x0) / m.width, (y1 - y0) / m.height)
        return dataclasses.replace(
            m, x_mm=(x0 + x1) / 2.0, y_mm=(y0 + y1) / 2.0, margin=m.margin * part / whole
        )

    def close(self) -> None:
        self._camera = None


class Recording:
    """A video file played as the recording it is: at its own frame rate, each frame
    stamped with the file's own timeline (from when it started playing), corrupt
    stretches skipped and said with their frame numbers, and an end that is final
    (``SourceEnded``) unless it loops; a loop carries the timeline on, never back."""

    camera_matrix: np.ndarray | None = None
    dist_coeffs: np.ndarray | None = None
    paces_itself: ClassVar[bool] = True

    def __init__(self, path: Path, *, loop: bool = False, sample_fps: float | None = None) -> None:
        self.path = path
        self.description = describe_spec(str(path))
        self.loop = loop
        self.sample_fps = sample_fps
        self.captured_at: float | None = None
        self.loops = 0
        self.frames = 0  # the file's frames (from its header)
        self.fps = 0.0
        self._capture: cv2.VideoCapture | None = None
        self._notes: list[str] = []
        self._index = -1  # the last frame read, in the file's numbering
        self._offset_s = 0.0  # the timeline's length before this pass (loops)
        self._start_wall = 0.0
        self._start_mono = 0.0
        self._next_sample = 0.0
        self._ended = False

    def open(self) -> None:
        if self._ended:
            raise SourceEnded(f"the {self.description} ended; give --loop to play it again")
        if not self.path.is_file():
            raise SourceError(f"no video file at {self.path}")
        capture = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not capture.isOpened():
            capture.release()
            raise SourceError(f"cannot open the {self.description} (not a video OpenCV reads?)")
        fps = capture.get(cv2.CAP_PROP_FPS)
        self.fps = fps if 0 < fps <= 240 else 10.0
        self.frames = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        self._capture = capture
        self._index = -1
        self._start_wall, self._start_mono = time.time(), time.monotonic()
        self._next_sample = 0.0

    def read(self) -> np.ndarray:
        if self._capture is None:
            raise SourceError("not open")
        while True:
            index, position_s = self._grab()
            if index is None:
                if not self.loop:
                    self._ended = True
                    raise SourceEnded(
                        f"the {self.description} ended after {self._index + 1} frames "
                        f"({(self._index + 1) / self.fps:.1f} s); give --loop to play it again"
                    )
                self._offset_s += (self._index + 1) / self.fps
                self.loops += 1
                self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
                self._index = -1
                continue
            timeline = self._offset_s + position_s
            if self.sample_fps is not None and timeline + 1e-6 < self._next_sample:
                continue  # between the samples asked for: decoded, not used
            self._next_sample = timeline + 1.0 / self.sample_fps if self.sample_fps else 0.0
            ok, frame = self._capture.retrieve()
            if not ok or frame is None:
                self._corrupt(index, index)
                continue
            delay = self._start_mono + timeline - time.monotonic()
            if delay > 0:  # a file plays at its own rate, not as fast as it decodes
                time.sleep(delay)
            self.captured_at = self._start_wall + timeline
            return _bgr(frame)

    def _grab(self) -> tuple[int | None, float]:
        """The next frame that decodes: its number and time in the file; (None, 0) at the
        end. Frames that do not decode before it are said as corrupt."""
        assert self._capture is not None
        expected = self._index + 1
        # A corrupt frame fails one grab each; past the file's end every grab fails.
        for _ in range(max(self.frames - expected, 0) + 2):
            if self._capture.grab():
                position_s = max(self._capture.get(cv2.CAP_PROP_POS_MSEC), 0.0) / 1000.0
                index = max(round(position_s * self.fps), expected)
                if index > expected:
                    self._corrupt(expected, index - 1)
                self._index = index
                return index, index / self.fps
        if expected < self.frames:
            self._corrupt(expected, self.frames - 1)
        return None, 0.0

    def _corrupt(self, first: int, last: int) -> None:
        frames = f"frame {first}" if first == last else f"frames {first} to {last}"
        verb = "is" if first == last else "are"
        self._notes.append(
            f"{frames} of the {self.description} {verb} corrupt (do not decode): skipped"
        )

    def notes(self) -> list[str]:
        said, self._notes = self._notes, []
        return said

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None
