"""docs/ARCHITECTURE.md stays true: every command, message type and key builder is in it."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from common import keys
from common.messages import all_message_types
from services.cli import SUBCOMMANDS

DOC = (Path(__file__).resolve().parents[2] / "docs" / "ARCHITECTURE.md").read_text()
MODULES = (Path(__file__).resolve().parents[2] / "docs" / "MODULES.md").read_text()


@pytest.mark.parametrize("command", sorted(SUBCOMMANDS))
def test_every_command_is_described(command: str) -> None:
    assert f"`wart {command}" in DOC, f"wart {command} is missing from docs/ARCHITECTURE.md"


@pytest.mark.parametrize("name", sorted(t.__name__ for t in all_message_types()))
def test_every_message_type_is_in_the_schema_tables(name: str) -> None:
    assert name in DOC, f"message {name} is missing from docs/ARCHITECTURE.md"


def test_every_key_suffix_is_in_the_key_table() -> None:
    """Each key builder's last chunk (frame, cmd, lease, spawn ...) appears in the doc."""
    missing = []
    for name, fn in inspect.getmembers(keys, inspect.isfunction):
        skip = ("_", "check_", "is_", "parse_", "wildcard")
        if fn.__module__ != keys.__name__ or name.startswith(skip):
            continue
        params = inspect.signature(fn).parameters
        sample = {
            "realm": "r",
            "ctx": "c",
            "world": "w",
            "agent": "a",
            "user": "u",
            "runner": "n",
            "host": "h",
            "kind": keys.AliveKind.CONTEXT,
            "ident": "i",
            "zid": "z",
            "camera": "c",
            "grader": "g",
            "competition": "competition",
            "course": "changed",  # grader_changed: the course is the last chunk
        }
        key = fn(**{p: sample[p] for p in params})
        last = key.rsplit("/", 1)[-1]
        if last not in ("**", "*", "r") and last not in DOC:
            missing.append(f"{name} ({key})")
    assert not missing, f"keys missing from docs/ARCHITECTURE.md: {missing}"


REPO = Path(__file__).resolve().parents[2]
_PATH = re.compile(
    r"(?<![\w./-])((?:services|common|viewers|tests|bench|docs|maps|deploy|examples)"
    r"/[\w./-]*\w)"
)


def _cited_paths() -> list[tuple[str, str]]:
    cited = []
    sources = [*sorted((REPO / "docs").glob("*.md")), REPO / "README.md"]
    for folder in ("common", "services", "viewers"):
        sources += sorted((REPO / folder).rglob("*.py"))
    for source in sources:
        for match in _PATH.finditer(source.read_text()):
            path = match.group(1)
            if any(c in path for c in "<>*{}") or path.endswith((".", "-")):
                continue
            cited.append((str(source.relative_to(REPO)), path))
    return cited


def test_every_path_the_docs_and_docstrings_cite_exists() -> None:
    def exists(path: str) -> bool:
        path = path.split(":")[0]  # file.py:12
        module, _, _attr = path.rpartition(".")  # services/x/y.Class
        return (REPO / path).exists() or bool(module and (REPO / f"{module}.py").exists())

    missing = sorted(
        f"{where}: {path}"
        for where, path in _cited_paths()
        if not exists(path) and not Path(path).stem.isupper()  # maps/NAME.json: a placeholder
    )
    assert not missing, "cited paths that do not exist:\n" + "\n".join(missing)


def _module_index() -> dict[str, set[str]]:
    """docs/MODULES.md: package (a ``## `pkg/``` heading) -> the modules its lines name."""
    index = {}
    for part in MODULES.split("\n## ")[1:]:
        heading, _, body = part.partition("\n")
        package = heading.strip().strip("`")
        index[package] = set(re.findall(r"`([\w]+\.py|[\w]+/)`", body))
    return index


def _on_disk(package: str) -> set[str]:
    folder = REPO / package
    names = {
        p.name
        for p in folder.glob("*.py")
        if p.name != "__init__.py" or package.endswith("controller/")
    }
    names |= {f"{p.name}/" for p in folder.iterdir() if (p / "__init__.py").exists()}
    return names


def test_the_module_index_names_every_module_and_no_other() -> None:
    index = _module_index()
    assert "common/" in index and "viewers/web/" in index, "module index not found"
    wrong = []
    for package, named in index.items():
        on_disk = _on_disk(package)
        if package in ("common/", "services/"):
            on_disk = {n for n in on_disk if not n.endswith("/")} | (named & on_disk)
        if missing := on_disk - named:
            wrong.append(f"{package}: not in the index: {sorted(missing)}")
        if gone := named - on_disk:
            wrong.append(f"{package}: no such module: {sorted(gone)}")
    packages = {
        f"{p.parent.relative_to(REPO)}/"
        for top in ("common", "services", "viewers")
        for p in (REPO / top).rglob("__init__.py")
        if p.parent.name != "agents"  # the robot types: listed as sim2d's agents/
    }
    if missing_packages := packages - set(index) - {"common/", "viewers/"}:
        wrong.append(f"packages without a row: {sorted(missing_packages)}")
    assert not wrong, "docs/MODULES.md is out of date:\n" + "\n".join(wrong)


@pytest.mark.parametrize(
    ("name", "max_lines", "max_bytes"),
    [("ARCHITECTURE.md", 700, 40_000), ("BENCHMARKS.md", 400, None), ("MODULES.md", 400, None)],
)
def test_the_reference_pages_stay_short(name: str, max_lines: int, max_bytes: int | None) -> None:
    """References of today, not diaries: history goes to docs/history/ and git."""
    text = (REPO / "docs" / name).read_text()
    lines = text.splitlines()
    assert len(lines) <= max_lines, f"docs/{name}: {len(lines)} lines (at most {max_lines})"
    if max_bytes is not None:
        size = len(text.encode())
        assert size <= max_bytes, f"docs/{name}: {size} bytes (at most {max_bytes})"
    if name != "BENCHMARKS.md":  # its tables carry whole commands on one row
        long = [n for n, line in enumerate(lines, 1) if len(line) > 300]
        assert not long, f"docs/{name}: lines over 300 characters: {long}"


def test_the_source_tells_no_history() -> None:
    """Docstrings and comments state contracts: which issue asked for a thing is git's."""
    cited = [
        f"{path.relative_to(REPO)}:{n}"
        for folder in ("common", "services", "viewers")
        for path in sorted((REPO / folder).rglob("*.py"))
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if re.search(r"\bissues? \d{2}\b", line)
    ]
    assert not cited, "lines that cite an issue (say what holds instead):\n" + "\n".join(cited)
