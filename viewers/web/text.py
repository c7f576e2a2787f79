"""Turning people's text into safe markdown, and checking what they type."""

from __future__ import annotations

import re
import time

MAX_LINE = 1000  # one chat line
_MD_SPECIAL = re.compile(r"([\\`*_{}\[\]()#+\-.!|~>])")


def escape_md(text: str) -> str:
    """Text shown literally in viser markdown: no links, no HTML, no formatting."""
    text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return _MD_SPECIAL.sub(r"\\\1", text)


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
