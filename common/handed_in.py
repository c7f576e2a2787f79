"""Files people hand in (robot files, assignments) read as TOML, nesting bounded first.

``tomllib`` recurses once per level of nested arrays or inline tables: a file of a
few thousand brackets exhausts the interpreter's recursion limit, and CPython 3.11
is left unable to parse Python source afterwards (``ast`` then fails with "recursion
depth mismatch"). So the depth is counted by a plain scan before ``tomllib`` sees
the text, and a file nested deeper than any real one is refused in words.
"""

from __future__ import annotations

import tomllib
from typing import Any

MAX_DEPTH = 64


def nesting_depth(text: str) -> int:
    """The deepest nesting of ``[`` and ``{`` outside strings and comments."""
    depth = deepest = 0
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c == "#":
            end = text.find("\n", i)
            i = n if end < 0 else end
        elif c in "\"'":
            quote = c * 3 if text.startswith(c * 3, i) else c
            i += len(quote)
            while i < n and not text.startswith(quote, i):
                if text[i] == "\\" and c == '"':
                    i += 1
                elif text[i] == "\n" and len(quote) == 1:
                    break  # an unclosed one-line string: tomllib will say so
                i += 1
            i += len(quote)
            continue
        elif c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth = max(0, depth - 1)
        i += 1
    return deepest


def load_toml(text: str, max_depth: int = MAX_DEPTH) -> dict[str, Any]:
    """``tomllib.loads``, refusing first a text nested deeper than ``max_depth``."""
    if nesting_depth(text) > max_depth:
        raise tomllib.TOMLDecodeError(f"arrays or tables nested more than {max_depth} deep")
    return tomllib.loads(text)
