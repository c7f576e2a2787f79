"""The paced loop that carries the newest world frame to every watching browser.

One thread for the whole viewer. Each tick (default 25 Hz) it takes each
watched world's newest frame (``WorldFeed.latest()``, which never blocks),
converts it once (:class:`PreparedFrame`), and lets every view of that world
apply it. Pacing matters: an unpaced loop holds the GIL and starves viser's
sender thread. A browser that is slow costs nothing here: viser keeps only
the newest value of each scene property, so the browser skips frames instead
of the server queueing them.
"""

from __future__ import annotations

import logging
import threading
import time

from common.worker import Worker
from viewers.web.prepared_frame import PreparedFrame
from viewers.web.viser_fast import HeldBuffers
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.pump")

DEFAULT_RATE = 25.0
SLOW_EVERY = 5  # slow hooks (plots, agent lists) run every 5th tick: 5 Hz at 25 Hz


class FramePump:
    def __init__(self, rate: float = DEFAULT_RATE) -> None:
        if not 0 < rate <= 60:
            raise ValueError(f"frame rate {rate} must be between 0 and 60 per second")
        self.rate = rate
        self.period = 1.0 / rate
        self._views: dict[int, WorldView] = {}
        self._lock = threading.Lock()
        self._worker = Worker(self._run, "frame-pump")
        self.ticks = 0
        self.busy_s = 0.0  # time spent working, for the benchmark and the log

    def attach(self, view: WorldView) -> None:
        with self._lock:
            self._views[id(view)] = view

    def detach(self, view: WorldView) -> None:
        with self._lock:
            self._views.pop(id(view), None)

    def start(self) -> FramePump:
        self._worker.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._worker.stop(timeout)

    def _run(self) -> None:
        next_at = time.monotonic()
        while not self._worker.stopping.is_set():
            started = time.monotonic()
            self.tick()
            self.busy_s += time.monotonic() - started
            next_at += self.period
            delay = next_at - time.monotonic()
            if delay < -self.period:  # overloaded: drop the backlog, never burst
                next_at = time.monotonic()
                delay = 0.0
            self._worker.wait(max(0.001, delay))  # always yield the GIL a little

    def tick(self) -> None:
        self.ticks += 1
        with self._lock:
            views = list(self._views.values())
        prepared: dict[int, PreparedFrame | None] = {}
        held = HeldBuffers()  # one event-loop wake-up for every browser, not one each
        try:
            self._tick_views(views, prepared, held)
        finally:
            held.release()

    def _tick_views(
        self, views: list[WorldView], prepared: dict[int, PreparedFrame | None], held: HeldBuffers
    ) -> None:
        for view in views:
            feed = view.feed
            if feed is None:
                continue
            try:
                # Per-user feeds over one shared world (viewers/web/live.py) say so with
                # ``source``: its frame is converted once for all of them.
                key = id(getattr(feed, "source", feed))
                if key not in prepared:
                    frame = feed.latest()
                    prepared[key] = None if frame is None else PreparedFrame.of(frame)
                snap = feed.snapshot()
                if view.snapshot is not None and snap.version != view.snapshot.version:
                    view.redraw(snap)  # an edit: everyone watching sees it
                ready = prepared[key]
                held.hold(view.client)
                # A swarm too big for a browser's byte budget is drawn every k-th tick
                # (prepared_frame.ROBOT_BYTES_PER_S); every view of it on the same ticks.
                if ready is not None and self.ticks % ready.every(self.rate) == 0:
                    view.apply(ready)
                for hook in view.tick_hooks:  # every tick: a real arena's video
                    hook()
                if self.ticks % SLOW_EVERY == 0:
                    view.slow_tick()
                held.done(view.client)
            except Exception:
                # One broken view (a browser gone mid-frame) must not stop the others.
                log.exception("could not update a world view; it stays attached")
