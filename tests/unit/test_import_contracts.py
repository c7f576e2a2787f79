"""Which part of the house may import which: the layout's rules, checked from the source.

common/ is grouped by audience (docs/ARCHITECTURE.md §0): its root is the wire and
the service base every process needs; world/, client/ and controller/ serve one
audience each; sim2d/ and recording/ are libraries with no network in them.
Breaking a rule here is how a student's sandbox ends up needing zenoh, or a
library ends up starting a lab.
"""

from __future__ import annotations

import ast
import re
import sys
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PROJECT = ("common", "services", "viewers", "bench", "tests")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@cache
def _sources() -> dict[str, Path]:
    found = {}
    for top in PROJECT:
        for path in (REPO / top).rglob("*.py"):
            found[_module_name(path)] = path
    return found


def _from_base(node: ast.ImportFrom, package: str) -> str:
    """The module a ``from X import ...`` names, relative imports resolved against ``package``."""
    base = node.module or ""
    if node.level:
        anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
        base = ".".join([*anchor, base] if base else anchor)
    return base


@cache
def imports_of(module: str) -> frozenset[str]:
    """Every module name ``module`` imports, at any depth of its code (functions too)."""
    path = _sources()[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = _from_base(node, package)
            names.add(base)
            # `from common import keys` imports the module common.keys
            names.update(
                f"{base}.{alias.name}"
                for alias in node.names
                if f"{base}.{alias.name}" in _sources()
            )
    return frozenset(n for n in names if n)


def _project(name: str) -> bool:
    return name.split(".")[0] in PROJECT


def _inside(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def _modules_in(package: str) -> list[str]:
    return sorted(m for m in _sources() if _inside(m, package))


def _violations(package: str, allowed) -> list[str]:
    return sorted(
        f"{module} imports {name}"
        for module in _modules_in(package)
        for name in imports_of(module)
        if not allowed(name)
    )


def _reaches(module: str, target: str) -> list[str] | None:
    """An import chain from ``module`` to ``target`` (a third-party top name), or None."""
    seen: set[str] = set()
    stack: list[tuple[str, list[str]]] = [(module, [module])]
    while stack:
        current, chain = stack.pop()
        for name in imports_of(current):
            if name.split(".")[0] == target:
                return [*chain, name]
            for candidate in (name, name.rpartition(".")[0]):
                if candidate in _sources() and candidate not in seen:
                    seen.add(candidate)
                    stack.append((candidate, [*chain, candidate]))
    return None


def test_the_controller_package_needs_only_the_standard_library() -> None:
    """The sandbox copies common/controller/ and offers nothing else of the lab's."""
    stdlib = sys.stdlib_module_names | {"__future__"}

    def allowed(name: str) -> bool:
        return _inside(name, "common.controller") or name.split(".")[0] in stdlib

    assert not _violations("common.controller", allowed)


@pytest.mark.parametrize(
    "library",
    ["common.sim2d", "common.recording", "common.tracking", "common.robots", "common.twin"],
)
def test_the_libraries_never_reach_zenoh(library: str) -> None:
    chains = [c for m in _modules_in(library) if (c := _reaches(m, "zenoh"))]
    assert not chains, f"{library} reaches zenoh: " + " -> ".join(chains[0])


ROOT_SUBPACKAGES = (
    "common.twin",
    "common.world",
    "common.client",
    "common.controller",
    "common.sim2d",
    "common.recording",
    "common.robots",
)


def test_the_root_of_common_never_imports_its_subpackages() -> None:
    root = [m for m in _modules_in("common") if not any(_inside(m, s) for s in ROOT_SUBPACKAGES)]
    bad = sorted(
        f"{module} imports {name}"
        for module in root
        for name in imports_of(module)
        if any(_inside(name, s) for s in ROOT_SUBPACKAGES)
    )
    assert not bad


def test_common_never_imports_a_process_or_the_viewer() -> None:
    assert not _violations(
        "common", lambda n: not _inside(n, "services") and not _inside(n, "viewers")
    )


def test_the_world_package_never_imports_the_client_package() -> None:
    """Worlds (engine, bridge) load common.world; a user's connection is not theirs."""
    assert not _violations("common.world", lambda n: not _inside(n, "common.client"))


def test_the_lab_library_never_imports_a_command() -> None:
    """services/lab/ is the library that commands and hosts share, never the other way."""
    assert not _violations("services.lab", lambda n: not _inside(n, "services.commands"))


def test_commands_import_only_common_and_the_lab_library() -> None:
    def allowed(name: str) -> bool:
        if not _project(name):
            return True
        return any(_inside(name, p) for p in ("common", "services.lab", "services.commands"))

    assert not _violations("services.commands", allowed)


def test_the_precheck_cap_is_the_wire_cap() -> None:
    """precheck writes the upload cap again (it may import nothing); the two stay equal."""
    from common.controller.upload_gate import MAX_SOURCE_BYTES
    from common.messages.agent import MAX_UPLOAD_BYTES

    assert MAX_SOURCE_BYTES == MAX_UPLOAD_BYTES


def test_the_contract_check_sees_a_violation() -> None:
    """The checker itself: an import it should flag is flagged (an empty list means something)."""
    assert "zenoh" in imports_of("common.service")
    assert _reaches("common.service", "zenoh") is not None
    assert "common.keys" in imports_of("common.revocations")


# A process's package talks to another process over the wire, never by importing it.
# The exceptions, each with its reason; the list only shrinks.
CROSSINGS: dict[tuple[str, str], str] = {
    ("services.lab.provision", "services.registry.accounts_db"): (
        "the lab creates the registry's database, admin and service accounts before the "
        "registry starts"
    ),
    ("services.grader.course_cli", "services.registry.accounts_db"): (
        "`wart course` is an offline tool of the lab's database, as `wart users` is: it grants "
        "the grader's account deploy on a real arena's robot through RegistryDB's public API"
    ),
}


def _process_package(module: str) -> str | None:
    """``services.X`` of a module of a process's package (services/lab/ is the library)."""
    parts = module.split(".")
    if parts[0] != "services" or len(parts) < 3 or parts[1] in ("commands",):
        return None
    return ".".join(parts[:2])


def test_a_process_imports_only_common_the_lab_library_and_itself() -> None:
    crossings = []
    for module in _sources():
        package = _process_package(module)
        if package is None:
            continue
        for name in imports_of(module):
            if not _project(name) or _inside(name, "common") or _inside(name, package):
                continue
            if _inside(name, "services.lab") and package != "services.lab":
                continue
            if name == "services.cli" and package == "services.lab":
                continue  # the dispatcher's table of command names; it imports no process
            if (module, name) in CROSSINGS:
                continue
            crossings.append(f"{module} imports {name}")
    assert not crossings, "a process imports another's code:\n" + "\n".join(sorted(crossings))
    stale = [pair for pair in CROSSINGS if pair[1] not in imports_of(pair[0])]
    assert not stale, f"exceptions no longer needed (remove them): {stale}"


def test_the_viewer_imports_no_process() -> None:
    assert not _violations("viewers", lambda n: not _inside(n, "services"))


def _top_level_imports(module: str) -> set[str]:
    """Project modules ``module`` imports when it is imported (not in functions, not for
    type checking only): the edges an import loop at run time is made of."""
    path = _sources()[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = set()

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                visit(node.orelse)
                continue
            if isinstance(node, ast.If | ast.Try):
                visit(node.body)
                visit(getattr(node, "orelse", []))
                for handler in getattr(node, "handlers", []):
                    visit(handler.body)
                visit(getattr(node, "finalbody", []))
            elif isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = _from_base(node, package)
                names.update(
                    f"{base}.{a.name}" if f"{base}.{a.name}" in _sources() else base
                    for a in node.names
                )

    visit(ast.parse(path.read_text(), str(path)).body)
    return {n for n in names if n in _sources()}


def _loops(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def test_the_loop_check_sees_a_loop() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert _loops(graph) == [["a", "b", "c"]]


def test_no_import_loop_at_run_time() -> None:
    loops = _loops({m: _top_level_imports(m) for m in _sources()})
    assert not loops, "modules that import each other:\n" + "\n".join(map(str, loops))


def _unexplained_inner_imports(path: Path) -> list[str]:
    """Imports inside functions with no comment saying why, on the import's lines or within
    the three lines above (a comment over a small block of imports covers the block)."""
    lines = path.read_text().splitlines()
    found = []
    for function in ast.walk(ast.parse("\n".join(lines), str(path))):
        if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(function):
            if not isinstance(node, ast.Import | ast.ImportFrom):
                continue
            near = lines[max(0, node.lineno - 4) : node.end_lineno or node.lineno]
            if not any("#" in line for line in near):
                found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    return found


def test_imports_inside_functions_say_why() -> None:
    """An import in a function hides a dependency: only for a reason (an optional package,
    numba kept off a path, the sandbox's own copy), written beside it."""
    found = [
        place
        for top in ("common", "services", "viewers", "bench")
        for path in sorted((REPO / top).rglob("*.py"))
        for place in _unexplained_inner_imports(path)
    ]
    assert not found, "imports inside functions without a comment saying why:\n" + "\n".join(found)


def _declared_elsewhere(path: Path, root: Path = REPO) -> list[str]:
    """Fields a mixin (a class of no base and no constructor) declares but never sets:
    another class's state, read through ``self`` (bare annotations, or ``if TYPE_CHECKING:``
    ones). A dataclass declares fields its decorator sets: not flagged."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, ast.ClassDef) or node.decorator_list:
            continue
        if node.bases or node.keywords:
            continue  # a subclass: what it declares and leaves is its base's contract
        if any(isinstance(s, ast.FunctionDef) and s.name == "__init__" for s in node.body):
            continue  # a class with a constructor: what it declares and leaves is its contract
        body = list(node.body)
        for statement in node.body:
            if isinstance(statement, ast.If) and "TYPE_CHECKING" in ast.unparse(statement.test):
                body += statement.body
        declared = {
            ast.unparse(s.target) for s in body if isinstance(s, ast.AnnAssign) and s.value is None
        }
        assigned = {
            target.attr
            for sub in ast.walk(node)
            if isinstance(sub, ast.Assign | ast.AnnAssign | ast.AugAssign)
            for target in (sub.targets if isinstance(sub, ast.Assign) else [sub.target])
            if isinstance(target, ast.Attribute) and ast.unparse(target.value) == "self"
        }
        if foreign := sorted(declared - assigned):
            found.append(f"{path.relative_to(root)}: {node.name} declares {foreign}")
    return found


# Mixins still to be made parts of their class: none left. A ratchet: the list only shrinks.
STILL_MIXED: set[str] = set()


def test_a_class_declares_no_state_of_another_class() -> None:
    """A class owns its state: no mixin declares the fields of the class it is mixed into."""
    found = [
        place
        for top in PROJECT
        for path in sorted((REPO / top).rglob("*.py"))
        for place in _declared_elsewhere(path)
    ]
    new = [f for f in found if f.split(" declares ")[0] not in STILL_MIXED]
    assert not new, "state declared away from its class:\n" + "\n".join(new)
    gone = STILL_MIXED - {f.split(" declares ")[0] for f in found}
    assert not gone, f"no longer mixins: remove them from STILL_MIXED: {sorted(gone)}"


def test_the_mixin_check_sees_a_mixin(tmp_path: Path) -> None:
    source = tmp_path / "m.py"
    source.write_text(
        "class Part:\n    world: object\n    def f(self):\n        return self.world\n"
        "class Owned:\n    n: int\n    def set(self):\n        self.n = 1\n"
    )
    found = [line.split(": ", 1)[1] for line in _declared_elsewhere(source, tmp_path)]
    assert found == ["Part declares ['world']"]


# bench/ and tests/ share one kit (tests/kit/: the lab starters, waits, page and client
# helpers, the worlds the benchmarks measure); neither imports the other's own modules.
KIT = "tests.kit"
BENCH_TESTS = "tests.unit.bench"  # the tests of the benchmarks' own code


def test_bench_imports_from_tests_only_the_kit() -> None:
    assert not _violations("bench", lambda n: not _inside(n, "tests") or _inside(n, KIT))


def test_only_the_benchmarks_tests_import_bench() -> None:
    bad = sorted(
        f"{module} imports {name}"
        for module in _modules_in("tests")
        if not _inside(module, BENCH_TESTS)
        for name in imports_of(module)
        if _inside(name, "bench")
    )
    assert not bad


def test_the_kit_imports_no_benchmark_no_test_and_no_pytest() -> None:
    """Plain modules both sides load: fixtures stay in the conftest.py files."""
    assert _modules_in(KIT), "tests/kit/ is missing"
    assert not list((REPO / "tests" / "kit").rglob("conftest.py"))

    def allowed(name: str) -> bool:
        top = name.split(".")[0]
        return top not in ("bench", "pytest") and (top != "tests" or _inside(name, KIT))

    assert not _violations(KIT, allowed)


# Loading another checkout is these files' job: each says so beside its path line. The
# kit's fork server gives each forked process the sys.path a fresh interpreter would have.
PATH_EDITS_ALLOWED = frozenset(
    {"bench/engine_ab.py", "bench/bench_sensing.py", "tests/kit/forkserver.py"}
)
PATH_EDIT = re.compile(r"sys\.path\.(insert|append)\b")


def test_no_sys_path_edits_in_bench_or_tests() -> None:
    """Benchmarks run as `python -m bench.NAME` from the repository's root, tests under
    pytest: both find the project on the path without editing it."""
    found = sorted(
        str(path.relative_to(REPO))
        for top in ("bench", "tests")
        for path in (REPO / top).rglob("*.py")
        if PATH_EDIT.search(path.read_text())
        and str(path.relative_to(REPO)) not in PATH_EDITS_ALLOWED
    )
    assert not found, "sys.path edited in:\n" + "\n".join(found)
