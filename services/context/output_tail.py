"""Each run's output so far, as the agent context passed it on: its last lines, numbered.

The context numbers the lines a run prints as they come in (``OutputLines.first`` in its
events), and keeps each run's last OUTPUT_KEPT_LINES here, for whoever comes to the run
late: a second tab, a page reloaded, a web viewer restarted while the run went on. Their
copy then picks up by number from the events, missing nothing and showing nothing twice.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

from common.messages import OUTPUT_KEPT_LINES, OutputSoFar

RUNS_KEPT = 128  # the newest runs that printed: the running ones and those that ended lately


@dataclass
class _RunOutput:
    agent: str
    user: str
    printed: int = 0  # lines numbered so far
    last: collections.deque[str] = field(
        default_factory=lambda: collections.deque(maxlen=OUTPUT_KEPT_LINES)
    )


class OutputTails:
    """The last lines of the RUNS_KEPT runs that printed most lately; thread-safe (the
    output comes in on Zenoh's threads, the questions on the context's)."""

    def __init__(self, runs: int = RUNS_KEPT) -> None:
        self._runs: collections.OrderedDict[str, _RunOutput] = collections.OrderedDict()
        self._limit = runs
        self._lock = threading.Lock()

    def add(self, request_id: str, agent: str, user: str, lines: Sequence[str]) -> int:
        """Keep ``lines`` printed by ``request_id``'s run; returns the number of its first."""
        with self._lock:
            run = self._runs.get(request_id)
            if run is None:
                run = self._runs[request_id] = _RunOutput(agent, user)
                while len(self._runs) > self._limit:
                    self._runs.popitem(last=False)
            else:
                self._runs.move_to_end(request_id)
            first = run.printed
            run.printed += len(lines)
            run.last.extend(lines)
            return first

    def so_far(self, request_id: str) -> OutputSoFar | None:
        """The run's kept lines; None if it printed nothing that is still kept."""
        with self._lock:
            run = self._runs.get(request_id)
            if run is None:
                return None
            lines = list(run.last)
            return OutputSoFar(
                request_id=request_id,
                agent=run.agent,
                user=run.user,
                first=run.printed - len(lines),
                lines=lines,
            )
