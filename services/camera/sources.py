"""Where a camera's frames come from: a V4L2 device, a video file, a network stream, or a
synthetic camera over an emulated arena.

Every source opens, gives one BGR frame at a time and says in words why it
cannot (unplugged, the file ended, the stream is unreachable): the service
turns that into "camera offline: ..." on the page and tries again.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from common.tracking.markers import default_layout
from common.tracking.synthetic import CameraModel, SyntheticCamera
from common.tracking.truth import TruthError, read_truth

SYNTHETIC = "synthetic:"
_DEVICE = re.compile(r"^(/dev/video\d+|\d+)$")
_URL = re.compile(r"^(rtsp|rtsps|http|https|tcp|udp)://", re.IGNORECASE)


class SourceError(Exception):
    """A source that cannot give a frame now; the message is for the page and the log."""


class FrameSource(Protocol):
    @property
    def description(self) -> str: ...

    # The camera's intrinsics when the source knows them (the synthetic camera).
    @property
    def camera_matrix(self) -> np.ndarray | None: ...

    @property
    def dist_coeffs(self) -> np.ndarray | None: ...

    def open(self) -> None: ...

    def read(self) -> np.ndarray: ...

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


def open_source(spec: str, *, loop: bool = False, seed: int = 0) -> FrameSource:
    check_spec(spec)
    if spec.startswith(SYNTHETIC):
        return SyntheticSource(Path(spec[len(SYNTHETIC) :]), seed=seed)
    return OpenCvSource(spec, loop=loop)


class OpenCvSource:
    """A device, file or stream through OpenCV's VideoCapture (V4L2 or FFmpeg)."""

    camera_matrix: np.ndarray | None = None
    dist_coeffs: np.ndarray | None = None

    def __init__(self, spec: str, *, loop: bool = False) -> None:
        self.spec = spec
        self.description = describe_spec(spec)
        self.loop = loop
        self.is_file = not (_DEVICE.match(spec) or _URL.match(spec))
        self._capture: cv2.VideoCapture | None = None
        self._period = 0.0
        self._next = 0.0

    def open(self) -> None:
        if self.is_file and not Path(self.spec).is_file():
            raise SourceError(f"no video file at {self.spec}")
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
        fps = capture.get(cv2.CAP_PROP_FPS) if self.is_file else 0.0
        self._period = 1.0 / fps if 0 < fps <= 240 else 0.0
        self._next = time.monotonic()
        self._capture = capture

    def read(self) -> np.ndarray:
        if self._capture is None:
            raise SourceError("not open")
        if self._period:  # a file plays at its own rate, not as fast as it decodes
            delay = self._next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self._next = max(self._next + self._period, time.monotonic() - self._period)
        ok, frame = self._capture.read()
        if not ok and self.is_file and self.loop:
            self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, frame = self._capture.read()
        if not ok or frame is None:
            what = "the video file ended" if self.is_file else "it stopped giving frames"
            raise SourceError(f"the {self.description}: {what}")
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        return np.asarray(frame)

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
            layout = default_layout(arena[0], arena[1], agents)
            self._camera = SyntheticCamera(
                arena[0],
                arena[1],
                layout,
                self.model,
                blur_sigma_px=self.blur_sigma_px,
                noise_sigma=self.noise_sigma,
                seed=self.seed,
            )
            self._arena, self._agents = arena, agents
        return self._camera.render(truth.robots)

    def close(self) -> None:
        self._camera = None
