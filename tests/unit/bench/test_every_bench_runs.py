"""Every module of bench/ imports, and each runnable one answers --help both ways.

Benchmarks run rarely, so a name that moved or an import that only works in
this process went unnoticed until someone wanted a figure. Importing each
module catches the first; ``python -m bench.NAME --help`` run in this process
(the module's code run as __main__) and in an interpreter started as a user starts
one (at the repository's root, with no PYTHONPATH) the second, without
running any benchmark.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
import runpy
import subprocess
import sys

import pytest

from tests.conftest import REPO

MODULES = sorted(p.stem for p in (REPO / "bench").glob("*.py") if p.stem != "__init__")
MAIN = 'if __name__ == "__main__":'
RUNNABLE = [m for m in MODULES if MAIN in (REPO / "bench" / f"{m}.py").read_text()]


def test_the_bench_modules_are_found() -> None:
    assert {"engine_ab", "labproc", "bench_control_latency"} <= set(MODULES)


@pytest.mark.parametrize("module", MODULES)
def test_every_bench_module_imports(module: str) -> None:
    importlib.import_module(f"bench.{module}")


@pytest.mark.parametrize("module", RUNNABLE)
def test_help_as_a_module(module: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", [f"bench.{module}", "--help"])
    # As `python -m` does: the module runs fresh as __main__, not the imported copy.
    monkeypatch.delitem(sys.modules, f"bench.{module}", raising=False)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as done:
        runpy.run_module(f"bench.{module}", run_name="__main__", alter_sys=False)
    assert done.value.code in (0, None), out.getvalue()
    assert "usage:" in out.getvalue()


# One interpreter started as a user starts one (at the repository's root, no
# PYTHONPATH: only what `python -m` puts on sys.path), which runs each module's
# --help as __main__ in turn and says how each ended. One process each cost 33 s
# of CPU in a CI run (85 interpreters importing numpy, zenoh and pymunk), a
# quarter of a minute of the suite for the same check.
HELP_EACH = """
import contextlib, io, json, runpy, sys
results = {}
for module in sys.argv[1:]:
    sys.argv = [module, "--help"]
    out = io.StringIO()
    code = "returned without exiting"
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            runpy.run_module(module, run_name="__main__", alter_sys=True)
    except SystemExit as done:
        code = done.code
    except BaseException as exc:
        code = f"{type(exc).__name__}: {exc}"
    results[module] = [code, "usage:" in out.getvalue(), out.getvalue()[-600:]]
print(json.dumps(results))
"""


def test_help_as_a_command_for_every_runnable_module() -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, "-c", HELP_EACH, *(f"bench.{m}" for m in RUNNABLE)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads(done.stdout.strip().splitlines()[-1])
    assert sorted(results) == sorted(f"bench.{m}" for m in RUNNABLE)
    failed = {m: r for m, r in results.items() if r[0] not in (0, None) or not r[1]}
    assert not failed, failed
