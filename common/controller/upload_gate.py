"""The upload gate: the pre-run check every service runs on a controller file before it queues.

Shared by the CLI tools, the agent context and the runner (and the page, first).

A file that cannot run (too big, not UTF-8, a syntax error, no Controller
subclass) is refused with a message for the student before it queues; the
runner checks again before it runs anything (never trust the client's check).
"""

from __future__ import annotations

import ast

# The wire's upload cap (common.messages.agent.MAX_UPLOAD_BYTES), written again here
# because this package is copied into the sandbox and imports nothing of the project;
# tests/unit/test_import_contracts.py holds the two equal.
MAX_SOURCE_BYTES = 64 * 1024


class PrecheckError(ValueError):
    """An uploaded controller cannot run; the message says why, for the student."""


def precheck(source: bytes, filename: str = "controller.py") -> str:
    """Check an upload before it queues; returns the controller class name.

    Refuses oversized files, non-UTF-8 text, syntax errors (with the line) and
    files without a Controller subclass.
    """
    if len(source) > MAX_SOURCE_BYTES:
        raise PrecheckError(
            f"{filename} is {len(source)} bytes; controllers are limited to {MAX_SOURCE_BYTES}"
        )
    try:
        text = source.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PrecheckError(f"{filename} is not UTF-8 text (byte {exc.start})") from None
    try:
        tree = ast.parse(text, filename=filename)
    except SyntaxError as exc:
        raise PrecheckError(f"{filename}, line {exc.lineno}: syntax error: {exc.msg}") from None
    classes = controller_classes(tree)
    if not classes:
        raise PrecheckError(
            f"{filename} defines no controller: write a class deriving from "
            "common.controller.Controller with a do_work(self, robot) method"
        )
    return classes[0].name


def controller_classes(tree: ast.Module) -> list[ast.ClassDef]:
    """The file's classes with a base whose name ends in ``Controller``, in walk order."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            for base in node.bases:
                name = base.attr if isinstance(base, ast.Attribute) else getattr(base, "id", "")
                if name.endswith("Controller"):
                    found.append(node)
    return found
