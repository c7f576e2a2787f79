"""``wart context KIND ...``: run a context process (``chat``; agent contexts add theirs)."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

KINDS: dict[str, tuple[str, str]] = {
    "chat": ("services.chat_context", "a chat room"),
    "agent": ("services.agent_context", "an agent context: chat + per-robot queues and leases"),
}


def main(argv: Sequence[str] | None = None, prog: str = "wart context") -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(f"usage: {prog} KIND [options]   ({prog} KIND --help for each)\n\nkinds:")
        for name, (_, text) in KINDS.items():
            print(f"  {name:<8} {text}")
        return 0
    if args[0] not in KINDS:
        print(
            f"{prog}: unknown context kind {args[0]!r}: one of {', '.join(KINDS)}", file=sys.stderr
        )
        return 2
    module = importlib.import_module(KINDS[args[0]][0])
    return int(module.main(args[1:], prog=f"{prog} {args[0]}") or 0)
