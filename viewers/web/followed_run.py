"""The run an editor's output pane follows, and the lines it printed before the pane came.

A pane comes to a run late when the run was started in another tab, when the page was
reloaded, or when the web viewer restarted while the run went on. The run's context keeps
its last lines (OutputSoFarRequest); this part asks for them off the caller's thread, holds
the lines that come meanwhile, then shows both in the context's count
(:meth:`RunOutput.numbered`): nothing missed that the context kept, nothing twice.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from viewers.web.adapters import LabConnection, LabError, OutputEvent
from viewers.web.run_output import RunOutput

log = logging.getLogger("wart.viewer.workbench")

RESUMED_NOTE = "the web viewer restarted here; your run went on"


class FollowedRun:
    """Which run the pane follows (its request id) and its lines on their way in.

    Every method but :meth:`catch_up`'s asking runs with ``lock`` held (the editor's news
    lock), as does ``on_raised``, called when lines shown held an exception.
    """

    def __init__(
        self,
        connection: LabConnection,
        output: RunOutput,
        lock: threading.Lock,
        on_raised: Callable[[], None],
    ) -> None:
        self.connection = connection
        self.output = output
        self.lock = lock
        self.on_raised = on_raised
        self.request: str | None = None  # None: the next run's lines name it
        self._held: list[OutputEvent] | None = None  # None: not asking

    def follow(self, request_id: str | None) -> None:
        """From now on the run ``request_id`` (None: the editor's own, not queued yet)."""
        self.request, self._held = request_id, None

    def show(self, event: OutputEvent) -> None:
        """The followed run's lines of ``event``, held while its output so far is asked."""
        if self._held is not None:
            self._held.append(event)
            return
        if self.request is None:
            self.request = event.request_id
        elif event.request_id != self.request:
            return  # an earlier run's last lines, after the editor started another
        if self.output.numbered(event.first, event.lines):
            self.on_raised()

    def catch_up(self, ctx: str, agent: str, request_id: str, *, replace: bool) -> None:
        """Ask the context for the run's output so far and show what the pane lacks: all of
        it, or (``replace``) instead of a restarted viewer's copy, whose lines carry no count."""
        self._held = []

        def ask() -> None:
            try:
                so_far = self.connection.output_so_far(ctx, request_id)
            except LabError as exc:  # the context restarting: the lines to come still show
                log.info("output so far of %s: %s", request_id, exc)
                so_far = None
            with self.lock:
                if self.request != request_id or self._held is None:
                    return  # the pane follows another run now
                held, self._held = self._held, None
                if so_far is not None and so_far.lines:
                    if replace:
                        self.output.clear()
                        self.output.note(RESUMED_NOTE)
                    if self.output.next_line is None and so_far.first:
                        self.output.note(f"{so_far.first} earlier line(s) not kept")
                    user = self.connection.user
                    self.show(OutputEvent(ctx, request_id, agent, user, so_far.lines, so_far.first))
                for event in held:
                    self.show(event)

        threading.Thread(target=ask, name=f"output-{request_id}", daemon=True).start()
