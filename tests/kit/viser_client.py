"""A headless viewer client: speaks viser 1.1.1's websocket protocol like the page does.

Used by the viewer's session tests and bench/bench_viewer_sessions.py to stand
for many browsers without rendering: it connects with viser's subprotocol,
reports a camera (viser counts a client as connected from its first camera
message), keeps the GUI the server builds (elements by uuid, with their
labels), types into text inputs and clicks buttons with the same
``GuiUpdateMessage`` the page sends, and reads scene updates.

Wire format, server to client (viser/infra/_infra.py ``_message_producer``):
8 bytes decompressed size, 8 bytes compressed size (little-endian), the
zstd-compressed msgpack ``{"messages": [...], "binaryBufferLengths": [...]}``,
then the binary buffers, each 8-byte aligned; a message field holding an
array is a placeholder ``{"__binary_index": i, "dtype": "<f4"}``. Client to
server: one plain msgpack map per message, its class name in ``type``.

Every input from the server is checked as far as this client relies on it:
a frame shorter than its header says, or not a map of messages, raises
:class:`ProtocolError`.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time
from collections.abc import Callable, Coroutine, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import msgspec
import numpy as np
import numpy.typing as npt
import viser
import websockets
import websockets.asyncio.client
import zstandard

from tests.kit.procs import free_port
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoConnector, DemoLab

T = TypeVar("T")
ROBOTS_NODE = "/world/robots"
MAX_MSGPACK = 64 * 1024 * 1024  # far above any GUI or scene message the viewer sends


class ProtocolError(Exception):
    """The server sent something that is not viser's wire format."""


@dataclass
class GuiElement:
    uuid: str
    kind: str  # the message type: GuiTextMessage, GuiButtonMessage ...
    label: str
    value: Any
    container: str
    props: dict[str, Any]


@dataclass
class RobotFrame:
    """One robots-mesh update as received: positions (viser metres), and when."""

    positions: npt.NDArray[np.float32]
    received_at: float
    index: int  # this client's count of frames received, from 1


def run_in_thread(coro: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(coro)`` on a thread of its own: callable where a loop already runs
    (Playwright's sync API keeps one in the main thread of a browser test session)."""
    box: dict[str, Any] = {}

    def body() -> None:
        try:
            box["value"] = asyncio.run(coro)
        except BaseException as exc:  # handed to the caller below
            box["error"] = exc

    thread = threading.Thread(target=body, name="viser-clients")
    thread.start()
    thread.join()
    if "error" in box:
        raise box["error"]
    value: T = box["value"]
    return value


def _align(offset: int) -> int:
    return (offset + 7) // 8 * 8


def decode_window(data: bytes) -> list[dict[str, Any]]:
    """One websocket message from viser's server -> its messages, arrays as numpy views."""
    if len(data) < 16:
        raise ProtocolError(f"frame of {len(data)} bytes is shorter than its header")
    raw_size = int.from_bytes(data[0:8], "little")
    packed_size = int.from_bytes(data[8:16], "little")
    if raw_size > MAX_MSGPACK or 16 + packed_size > len(data):
        raise ProtocolError("frame sizes do not match its length")
    inner = zstandard.ZstdDecompressor().decompress(data[16 : 16 + packed_size], raw_size)
    body = msgspec.msgpack.decode(inner)
    if not isinstance(body, dict) or not isinstance(body.get("messages"), list):
        raise ProtocolError("frame body is not a map with a list of messages")
    lengths = body.get("binaryBufferLengths") or []
    buffers: list[memoryview] = []
    offset = 16 + packed_size
    view = memoryview(data)
    for length in lengths:
        if not isinstance(length, int) or length < 0:
            raise ProtocolError("bad binary buffer length")
        offset = _align(offset)
        if offset + length > len(data):
            raise ProtocolError("binary buffer runs past the frame")
        buffers.append(view[offset : offset + length])
        offset += length

    def resolve(value: Any) -> Any:
        if isinstance(value, dict):
            if "__binary_index" in value and "dtype" in value:
                index = value["__binary_index"]
                if not isinstance(index, int) or not 0 <= index < len(buffers):
                    raise ProtocolError("binary placeholder points nowhere")
                return np.frombuffer(buffers[index], dtype=np.dtype(value["dtype"]))
            return {k: resolve(v) for k, v in value.items()}
        if isinstance(value, list):
            return [resolve(v) for v in value]
        return value

    messages = []
    for message in body["messages"]:
        if not isinstance(message, dict) or not isinstance(message.get("type"), str):
            raise ProtocolError("a message without a type")
        messages.append(resolve(message))
    return messages


@dataclass
class ViserClient:
    """One headless browser session on a viser server (asyncio; one task reads)."""

    url: str  # ws://host:port
    name: str = "client"
    gui: dict[str, GuiElement] = field(default_factory=dict)
    notifications: list[str] = field(default_factory=list)
    frames: int = 0  # robots-mesh position updates received
    messages: int = 0  # websocket messages received
    bytes: int = 0
    latest: RobotFrame | None = None
    on_frame: Callable[[RobotFrame], None] | None = None
    _ws: websockets.asyncio.client.ClientConnection | None = None
    _reader: asyncio.Task[None] | None = None
    _changed: asyncio.Event = field(default_factory=asyncio.Event)
    _reading: asyncio.Event = field(default_factory=asyncio.Event)
    error: BaseException | None = None

    async def connect(self, *, max_queue: int = 16, rcvbuf: int | None = None) -> None:
        """Open the socket and report a camera (the server's connect callbacks run then).

        ``max_queue``: websocket messages the library buffers before it stops
        reading the socket; a small one makes a stalled client push back at once.
        ``rcvbuf``: this end's kernel receive buffer (SO_RCVBUF), for a client
        whose link, not its own kernel, is where the bytes wait.
        """
        sock = None
        if rcvbuf is not None:
            host, _, port = self.url.removeprefix("ws://").partition(":")
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            sock.setblocking(False)
            await asyncio.get_running_loop().sock_connect(sock, (host, int(port.split("/")[0])))
        self._ws = await websockets.asyncio.client.connect(
            self.url,
            sock=sock,
            subprotocols=[websockets.Subprotocol(f"viser-v{viser.__version__}")],
            max_size=64 * 1024 * 1024,
            max_queue=max_queue,
            open_timeout=60,
            compression=None,
        )
        self._reading.set()
        self._reader = asyncio.get_running_loop().create_task(self._read_loop())
        await self.send(
            {
                "type": "ViewerCameraMessage",
                "wxyz": [1.0, 0.0, 0.0, 0.0],
                "position": [0.0, 0.0, 5.0],
                "fov": 0.35,
                "near": 0.01,
                "far": 1000.0,
                "image_height": 600,
                "image_width": 960,
                "look_at": [0.0, 0.0, 0.0],
                "up_direction": [0.0, 1.0, 0.0],
            }
        )

    async def close(self) -> None:
        if self._reader is not None:
            self._reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reader
        if self._ws is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._ws.close(), 5)

    def stall(self) -> None:
        """Stop reading the socket (a frozen tab, a saturated link)."""
        self._reading.clear()

    def resume(self) -> None:
        self._reading.set()

    async def send(self, message: dict[str, Any]) -> None:
        assert self._ws is not None, "connect first"
        await self._ws.send(msgspec.msgpack.encode(message))

    async def _read_loop(self) -> None:
        assert self._ws is not None
        try:
            while True:
                await self._reading.wait()
                data = await self._ws.recv()
                if not isinstance(data, bytes):
                    raise ProtocolError("a text frame; viser sends binary only")
                self.messages += 1
                self.bytes += len(data)
                for message in decode_window(data):
                    self._handle(message)
                self._changed.set()
        except websockets.exceptions.ConnectionClosed as exc:
            self.error = exc
        except ProtocolError as exc:
            self.error = exc
        finally:
            self._changed.set()

    def _handle(self, message: dict[str, Any]) -> None:
        kind = message["type"]
        if kind == "SceneNodeUpdateMessage" and message.get("name") == ROBOTS_NODE:
            updates = message.get("updates") or {}
            positions = updates.get("batched_positions", updates.get("points"))
            if isinstance(positions, np.ndarray):
                self.frames += 1
                frame = RobotFrame(positions.reshape(-1, 3), time.monotonic(), self.frames)
                self.latest = frame
                if self.on_frame is not None:
                    self.on_frame(frame)
        elif kind == "GuiUpdateMessage":
            element = self.gui.get(str(message.get("uuid")))
            updates = message.get("updates") or {}
            if element is not None and isinstance(updates, dict):
                if "value" in updates:
                    element.value = updates["value"]
                if "label" in updates:
                    element.label = str(updates["label"])
                element.props.update(updates)
        elif kind == "GuiRemoveMessage":
            self.gui.pop(str(message.get("uuid")), None)
        elif kind == "NotificationShowMessage":
            props = message.get("props") or {}
            self.notifications.append(f"{props.get('title', '')}: {props.get('body', '')}")
        elif (
            kind.startswith("Gui") and "uuid" in message and isinstance(message.get("props"), dict)
        ):
            props = message["props"]
            self.gui[str(message["uuid"])] = GuiElement(
                uuid=str(message["uuid"]),
                kind=kind,
                label=str(props.get("label", "")),
                value=message.get("value"),
                container=str(message.get("container_uuid", "")),
                props=dict(props),
            )

    # -- waiting on what the page would show

    async def wait_for(self, check: Callable[[], Any], timeout: float = 60.0) -> Any:
        """Wait until ``check()`` is truthy (re-checked on every message); return its value."""
        deadline = time.monotonic() + timeout
        while True:
            self._changed.clear()
            value = check()
            if value:
                return value
            if self.error is not None:
                raise ConnectionError(f"{self.name}: connection ended: {self.error}")
            left = deadline - time.monotonic()
            if left <= 0:
                labels = sorted({e.label for e in self.gui.values()})
                raise TimeoutError(f"{self.name}: condition not met; GUI labels: {labels}")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), min(left, 1.0))

    def find(self, label: str, kind: str | None = None) -> GuiElement | None:
        """The newest GUI element with this label (and message type)."""
        found = [
            e for e in self.gui.values() if e.label == label and (kind is None or e.kind == kind)
        ]
        return found[-1] if found else None

    def markdown_containing(self, text: str) -> GuiElement | None:
        for element in self.gui.values():
            if element.kind == "GuiMarkdownMessage" and text in str(
                element.props.get("_markdown", "")
            ):
                return element
        return None

    async def element(self, label: str, kind: str, timeout: float = 60.0) -> GuiElement:
        found: GuiElement = await self.wait_for(lambda: self.find(label, kind), timeout)
        return found

    async def type_into(self, label: str, text: str, timeout: float = 60.0) -> None:
        element = await self.element(label, "GuiTextMessage", timeout)
        element.value = text
        await self.send(
            {"type": "GuiUpdateMessage", "uuid": element.uuid, "updates": {"value": text}}
        )

    async def click(self, label: str, timeout: float = 60.0) -> None:
        element = await self.element(label, "GuiButtonMessage", timeout)
        await self.send(
            {"type": "GuiUpdateMessage", "uuid": element.uuid, "updates": {"value": True}}
        )

    async def click_until(
        self, label: str, check: Callable[[], Any], timeout: float = 60.0, every: float = 2.0
    ) -> Any:
        """Click, then click again every ``every`` s until ``check()`` holds.

        A page's first click can race the server: viser sends a button before
        the code that made it has registered its handler, and a click handled
        in between is lost. A person clicks again; so does this.
        """
        deadline = time.monotonic() + timeout
        while True:
            await self.click(label, max(0.1, deadline - time.monotonic()))
            try:
                return await self.wait_for(check, min(every, max(0.1, deadline - time.monotonic())))
            except TimeoutError:
                if time.monotonic() >= deadline:
                    raise

    # -- what a student does

    def logged_in(self) -> bool:
        """What a person sees once in: the "Logged in to" notice, or the lobby's Log out."""
        return any(n.startswith("Logged in to") for n in self.notifications) or (
            self.find("Log out") is not None
        )

    async def log_in(self, user: str, password: str, timeout: float = 120.0) -> None:
        """Connect to the address bar's lab (the viewer's own), as the page's login form does."""
        await self.click_until("Connect", lambda: self.find("User", "GuiTextMessage"), timeout)
        await self.type_into("User", user, timeout)
        await self.type_into("Password", password, timeout)
        # A retry: the last answer is still on the form; wait for this attempt's own.
        # (The viewer sends the new answer even when its words are the same: the form
        # shows "Logging in..." in between.)
        for element in self.gui.values():
            if "Could not" in str(element.props.get("_markdown", "")):
                element.props["_markdown"] = ""
        await self.click("Log in", timeout)
        await self.wait_for(
            lambda: self.logged_in() or self.markdown_containing("Could not"), timeout
        )
        problem = self.markdown_containing("Could not")
        if problem is not None and problem.props.get("visible", True):
            raise ConnectionError(f"{self.name}: {problem.props.get('_markdown')}")

    async def join_room(self, context: str, timeout: float = 120.0) -> None:
        """Press "Join CONTEXT" in the lobby, then wait for its chat input."""
        before = {e.uuid for e in self.gui.values() if e.label == "Message"}
        await self.click_until(
            f"Join {context}",
            lambda: any(e.label == "Message" and e.uuid not in before for e in self.gui.values()),
            timeout,
            every=5.0,
        )

    async def say(self, text: str, timeout: float = 60.0) -> None:
        """Type into the newest chat panel's Message input and press Send."""
        await self.type_into("Message", text, timeout)
        await self.click("Send", timeout)

    async def join(self, context: str, timeout: float = 120.0) -> None:
        """Press "Join CONTEXT" in the lobby, then wait for the first robots frame."""
        await self.click_until(f"Join {context}", lambda: self.frames > 0, timeout, every=5.0)


@contextlib.contextmanager
def demo_lab_viewer(lab: DemoLab, data_dir: Path) -> Iterator[WebViewer]:
    """A real WebViewer (its data in ``data_dir``) serving the in-memory ``lab``; both
    stopped after."""
    viewer = WebViewer(DemoConnector(("lab", lab)), port=free_port(), data_dir=data_dir)
    try:
        yield viewer
    finally:
        viewer.stop()
        lab.close()
