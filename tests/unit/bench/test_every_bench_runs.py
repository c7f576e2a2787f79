"""Every module of bench/ imports, and each runnable one answers --help both ways.

Benchmarks run rarely, so a name that moved or an import that only works in
this process went unnoticed until someone wanted a figure. Importing each
module catches the first; ``python -m bench.NAME --help`` run in this process
(the module's code run as __main__) and in a process of its own (as a user
types it at the repository's root, with no PYTHONPATH) the second, without
running any benchmark.
"""

from __future__ import annotations

import contextlib
import importlib
import io
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


def test_help_as_a_command_for_every_runnable_module() -> None:
    """All at once (one process each, started together): a few seconds, not a minute."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    procs = {
        module: subprocess.Popen(
            [sys.executable, "-m", f"bench.{module}", "--help"],
            cwd=REPO,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for module in RUNNABLE
    }
    failed = {}
    for module, proc in procs.items():
        out, _ = proc.communicate(timeout=120)
        if proc.returncode != 0 or "usage:" not in out:
            failed[module] = out[-600:]
    assert not failed, failed
