"""Check's problems and a run's exception as the editor shows them (HTML, never markdown).

Each problem is listed with its line number as a link that moves the code
editor there (``data-wart-line``, handled by viewers/web/assets/editor-src/editor.js),
followed by an excerpt of the code with ``>>`` in front of each problem line.
All text is escaped: a message or a line of code is shown as it is.
"""

from __future__ import annotations

import html
import re
from dataclasses import dataclass

from common.controller.advice import Problem
from viewers.web.adapters import DryRunResult

DEFAULT_NAME = "my_controller.py"
CONTEXT_LINES = 1  # lines shown around each marked line
MAX_MARKED = 8  # problems shown with an excerpt; the rest as a count
# A traceback frame, and the line that ends a traceback (the exception and its message).
_FRAME = re.compile(r'File "(?P<path>[^"]+)", line (?P<line>\d+)')
_EXCEPTION = re.compile(r"^(?:[A-Za-z_][\w.]*\.)?[A-Za-z_]\w*(?:Error|Exception|Exit|Interrupt)\b")


def excerpt(source: str, problems: list[Problem]) -> str:
    """The code around each problem line, the line itself marked ``>>`` (plain text)."""
    lines = source.splitlines()
    marked = sorted({p.line for p in problems if p.line is not None and p.line >= 1})
    if not marked or not lines:
        return ""
    shown: list[int] = []
    for n in marked[:MAX_MARKED]:
        for i in range(max(1, n - CONTEXT_LINES), min(len(lines), n + CONTEXT_LINES) + 1):
            if i not in shown:
                shown.append(i)
    width = len(str(shown[-1])) if shown else 1
    out, previous = [], 0
    for i in shown:
        if previous and i > previous + 1:
            out.append("   ...")
        mark = ">>" if i in marked else "  "
        out.append(f"{mark} {i:>{width}} | {lines[i - 1]}")
        previous = i
    return "\n".join(out)


def problem_item(problem: Problem) -> str:
    """One problem as HTML: its line a link that moves the editor there, the rest escaped."""
    if problem.line is None:
        return f"<li>{html.escape(problem.message)}</li>"
    n = problem.line
    link = f'<a href="#" data-wart-line="{n}" title="Go to line {n}">line {n}</a>'
    return f"<li>{link}: {html.escape(problem.message)}</li>"


def format_problems(source: str, problems: list[Problem], heading: str) -> str:
    """Problems as HTML (text escaped, never interpreted): a list, then the marked excerpt."""
    items = "".join(problem_item(p) for p in problems)
    shown = excerpt(source, problems)
    code = f'<pre class="wart-output">{html.escape(shown)}</pre>' if shown else ""
    return (
        f'<div class="wart-output"><b>{html.escape(heading)}</b>'
        f'<ul style="margin:4px 0;padding-left:18px">{items}</ul>{code}</div>'
    )


def format_dry_run(source: str, result: DryRunResult, heading: str) -> str:
    """A dry run's verdict (HTML): an exception's line marked as Check marks it."""
    details = "\n".join(result.details)
    if result.line is None:
        body = f'<div class="wart-output"><b>{html.escape(heading)}</b></div>'
    else:
        # The verdict says "will NOT run: line 12: ZeroDivisionError: ..."; the item says it once.
        message = result.verdict.removeprefix("will NOT run: ")
        message = message.removeprefix(f"line {result.line}: ")
        body = format_problems(source, [Problem(result.line, message)], heading)
    return body + (f'<pre class="wart-output">{html.escape(details)}</pre>' if details else "")


@dataclass
class TracebackReader:
    """Finds ``line N: Exception: message`` for the student's file in relayed output lines."""

    filename: str = DEFAULT_NAME
    _line: int | None = None

    def feed(self, text: str) -> Problem | None:
        frame = _FRAME.search(text)
        if frame is not None:
            path = frame.group("path").replace("\\", "/")
            name = path.rsplit("/", 1)[-1]
            # The sandbox stores the upload as controller.py; the API is lib/common/controller/.
            if name in (self.filename, "controller.py") and "/common/" not in path:
                self._line = int(frame.group("line"))
            return None
        stripped = text.strip()
        if self._line is not None and _EXCEPTION.match(stripped):
            found = Problem(self._line, stripped)
            self._line = None
            return found
        return None
