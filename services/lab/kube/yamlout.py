"""Kubernetes objects as YAML documents, without a YAML library.

The lab's core dependencies have no YAML library, and the objects are plain
dicts, lists, strings, numbers and booleans: block style for collections,
every string double-quoted as JSON writes it (a JSON string is a YAML
double-quoted scalar), so that no value is read back as another type
("on", "0440", "1.10"); multi-line strings (certificates, configs) as literal
blocks, which keep them readable.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from typing import Any

_PLAIN_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_./-]*$")


def _key(key: str) -> str:
    plain = _PLAIN_KEY.match(key) and key not in ("true", "false", "null")
    return key if plain else json.dumps(key)


def _scalar(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return json.dumps(value)
    if isinstance(value, str):
        return json.dumps(value)
    raise TypeError(f"cannot write {type(value).__name__} as YAML")


def _block(text: str, indent: int) -> list[str]:
    """A literal block scalar: the text as it is, each line indented."""
    pad = " " * indent
    head = "|" if text.endswith("\n") else "|-"
    if text.endswith("\n\n") or text[:1] in (" ", "\n"):
        return [json.dumps(text)]  # what a block cannot say exactly: leading or trailing blanks
    return [head, *(pad + line if line else "" for line in text.rstrip("\n").split("\n"))]


def _lines(value: Any, indent: int) -> list[str]:
    pad = " " * indent
    out: list[str] = []
    if isinstance(value, Mapping):
        if not value:
            return [pad + "{}"]
        for k, v in value.items():
            out += _entry(pad + _key(str(k)) + ":", v, indent)
        return out
    if isinstance(value, list | tuple):
        if not value:
            return [pad + "[]"]
        for item in value:
            if isinstance(item, Mapping) and item:
                inner = _lines(item, indent + 2)
                out.append(pad + "- " + inner[0][indent + 2 :])
                out += inner[1:]
            else:
                out += _entry(pad + "-", item, indent)
        return out
    return [pad + _scalar(value)]


def _entry(head: str, value: Any, indent: int) -> list[str]:
    if isinstance(value, Mapping | list | tuple) and value:
        return [head, *_lines(value, indent + 2)]
    if isinstance(value, Mapping | list | tuple):
        return [head + " " + ("{}" if isinstance(value, Mapping) else "[]")]
    if isinstance(value, str) and "\n" in value:
        block = _block(value, indent + 2)
        return [head + " " + block[0], *block[1:]]
    return [head + " " + _scalar(value)]


def dump(obj: Mapping[str, Any]) -> str:
    """One object as a YAML document (no leading ``---``)."""
    return "\n".join(_lines(obj, 0)) + "\n"


def dump_all(objects: Iterable[Mapping[str, Any]]) -> str:
    """Several objects as one stream of YAML documents."""
    return "".join("---\n" + dump(obj) for obj in objects)
