"""The dataflow table (common/dataflow.py) as docs/ARCHITECTURE.md prints it.

``python -m common.dataflow_doc`` prints the key table and the messages per key;
tests/unit/common/test_dataflow.py holds the architecture's copy equal to it.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Iterable

from common.dataflow import CONTEXTS, FLOWS, PEOPLE, SERVICES, WORLDS, Flow, Pattern
from common.messages import Message


def _names(types: Iterable[type[Message] | None]) -> str:
    return ", ".join("(none)" if t is None else f"`{t.__name__}`" for t in types)


def _exchange_text(flow: Flow) -> str:
    """Requests with the same replies grouped: ``A``, ``B`` → ``m.OkReply``."""
    groups: dict[tuple[type[Message], ...], list[type[Message] | None]] = {}
    for ex in flow.exchanges:
        groups.setdefault(ex.replies, []).append(ex.message)
    parts = []
    for replies, messages in groups.items():
        text = _names(messages)
        if replies:
            text += " → " + " / ".join(f"`{r.__name__}`" for r in replies)
        parts.append(text)
    return "; ".join(parts) or "-"


def _roles_text(roles: tuple[str, ...]) -> str:
    """Roles as the docs say them: a whole group by its name ("people", "services")."""
    names = list(roles)
    for group, members in (
        ("services", SERVICES),
        ("contexts", CONTEXTS),
        ("worlds", WORLDS),
        ("people", PEOPLE),
    ):
        if set(members) <= set(names):
            at = names.index(members[0])
            names = [n for n in names if n not in members]
            names.insert(min(at, len(names)), group)
    return ", ".join(names) or "-"


def markdown_table() -> str:
    """The key table of docs/ARCHITECTURE.md, as the table says it.

    Groups of roles go by their names: services (every service that logs in:
    chat, agent, engine, bridge, runner, grader, lti, host), contexts (chat,
    agent), worlds (engine, bridge), people (student, admin, viewer).
    """
    lines = [
        "| key (under `wart/<realm>/`) | pattern | produced by | consumed by | urgency | sealed |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for flow in FLOWS:
        sealed = "yes" if flow.sealed else "-"
        urgency = flow.urgency if flow.pattern is Pattern.PUT else "-"
        lines.append(
            f"| `{flow.pattern_key()}` | {flow.pattern} | {_roles_text(flow.producers)} "
            f"| {_roles_text(flow.consumers)} | {urgency} | {sealed} |"
        )
    return "\n".join(lines)


def markdown_messages() -> str:
    """What travels on each key, one line a flow (docs/ARCHITECTURE.md)."""
    lines = []
    for flow in FLOWS:
        if not flow.exchanges and not flow.note:
            continue
        note = f" ({flow.note})" if flow.note else ""
        text = f"- `{flow.pattern_key()}` {flow.pattern}: {_exchange_text(flow)}{note}"
        lines += textwrap.wrap(text, 100, subsequent_indent="  ", break_on_hyphens=False)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the key table and the messages per key, as docs/ARCHITECTURE.md carries them."""
    args = sys.argv[1:] if argv is None else argv
    if args and args[0] in ("-h", "--help"):
        print("python -m common.dataflow_doc: print the lab's key table and messages per key")
        return 0
    print(markdown_table())
    print()
    print(markdown_messages())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
