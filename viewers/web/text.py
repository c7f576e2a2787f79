"""Turning people's text into safe markdown or HTML, and checking what they type."""

from __future__ import annotations

import html
import re
import time
from collections.abc import Iterable

MAX_LINE = 1000  # one chat line
_MD_SPECIAL = re.compile(r"([\\`*_{}\[\]()#+\-.!|~>])")


def escape_md(text: str) -> str:
    """Text shown literally in viser markdown: no links, no HTML, no formatting."""
    text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return _MD_SPECIAL.sub(r"\\\1", text)


def code_md(text: str) -> str:
    """Text as an inline code span: shown as written (a rule, a file's line), no escapes."""
    text = " ".join(text.splitlines())
    longest = max((len(run) for run in re.findall(r"`+", text)), default=0)
    fence = "`" * (longest + 1)
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


# Inline (not a class): output is shown in panels that may not have the editor's styles.
OUTPUT_STYLE = (
    "font-family: ui-monospace, Menlo, Consolas, monospace; font-size: 12px; margin: 0; "
    "white-space: pre-wrap; overflow-wrap: anywhere"
)


def output_html(lines: Iterable[str], empty: str = "") -> str:
    """Program output exactly as printed: each line escaped, monospace, never markdown.

    ``lines`` are HTML already (see :func:`printed`); ``empty`` is plain text.
    """
    body = "\n".join(lines)
    if not body:
        return f"<i>{html.escape(empty)}</i>" if empty else ""
    return f'<pre class="wart-output" style="{OUTPUT_STYLE}">{body}</pre>'


def printed(text: str) -> str:
    """One printed line as HTML: what was printed, escaped (markup and markdown shown as is)."""
    return html.escape(text, quote=False)


def check_line(text: str) -> str | None:
    """What is wrong with a chat line (None: it can be sent)."""
    if not text.strip():
        return "Type something first."
    if len(text) > MAX_LINE:
        return f"A message is at most {MAX_LINE} characters."
    if any(ord(ch) < 32 and ch not in "\t" for ch in text):
        return "A message is one line of text."
    return None


def clock(at: float) -> str:
    return time.strftime("%H:%M", time.localtime(at))
