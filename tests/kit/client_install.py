"""A student's laptop: a fresh virtualenv with the project installed from this repository
without the `lab` extra (pyproject.toml), and ``wart`` run from it as a person runs it.

The virtualenv is made with uv (./dev installs it beside the lab's Python) from uv's
cache, in seconds. Every module the client tries to import, found or not, whose top-level
name is one of the lab extra's is written to a log (an audit hook installed by a .pth
file), so that a guarded ``try: import numba`` counts as much as a plain one.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from services.cli import LAB_MODULES
from tests.kit.procs import REPO, Proc, wart_env

# The lab-only modules the audit hook reports: the lab extra's, matplotlib (plots, the
# lab's and the notebook extra's) and the engine's compiled kernels' compiler.
LAB_ONLY = (*LAB_MODULES, "matplotlib", "llvmlite")

_AUDIT = """\
import os, sys

_LAB_ONLY = {lab_only!r}
_LOG = os.environ.get("WART_LAB_IMPORT_LOG")


def _hook(event, args):
    if event == "import" and args[0].partition(".")[0] in _LAB_ONLY:
        with open(_LOG, "a") as log:
            log.write(f"{{os.getpid()}} {{args[0]}}\\n")


if _LOG:
    sys.addaudithook(_hook)
"""


def uv() -> str | None:
    """uv beside the lab's Python (./dev installs it there), else on PATH."""
    beside = Path(sys.executable).with_name("uv")
    return str(beside) if beside.exists() else shutil.which("uv")


@dataclass
class ClientInstall:
    """A virtualenv with the project installed with ``extras`` (none: the client alone)."""

    root: Path
    import_log: Path
    seconds: float  # how long making it took (uv's cache warm or not)

    @property
    def python(self) -> Path:
        return self.root / "bin" / "python"

    def env(self, extra: dict[str, str] | None = None) -> dict[str, str]:
        """The kit's environment for a ``wart`` process, but nothing of the repository's
        sources on the path: the installed copy runs."""
        env = wart_env({"WART_LAB_IMPORT_LOG": str(self.import_log), **(extra or {})})
        env.pop("PYTHONPATH", None)
        env["VIRTUAL_ENV"] = str(self.root)
        env["PATH"] = f"{self.root / 'bin'}{os.pathsep}{env.get('PATH', '')}"
        return env

    def wart(
        self, *args: str, env: dict[str, str] | None = None, timeout: float = 60.0
    ) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [str(self.root / "bin" / "wart"), *args],
            cwd=self.root,
            env=self.env(env),
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    def start(
        self, name: str, args: Sequence[str], logs: Path, env: dict[str, str] | None = None
    ) -> Proc:
        """``wart ARGS`` in the background, its output in LOGS/NAME.log."""
        log_path = logs / f"{name}.log"
        with open(log_path, "wb") as out:
            popen = subprocess.Popen(
                [str(self.root / "bin" / "wart"), *args],
                cwd=self.root,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=self.env(env),
                start_new_session=True,
            )
        return Proc(name, popen, log_path)

    def lab_imports(self) -> list[str]:
        """The lab-only modules any process of this install tried to import."""
        if not self.import_log.exists():
            return []
        return sorted({line.split()[1] for line in self.import_log.read_text().splitlines()})

    def installed(self) -> set[str]:
        """The distributions installed (lower case)."""
        done = subprocess.run(
            [uv() or "uv", "pip", "list", "--python", str(self.python), "--format", "freeze"],
            capture_output=True,
            text=True,
            check=True,
        )
        return {line.split("==")[0].lower() for line in done.stdout.splitlines() if line}


def source_copy(into: Path) -> Path:
    """The checkout's files as git sees them (tracked, and new ones not ignored), copied
    to ``into``: a build writes build/ and an egg-info into the tree it builds, and the
    checkout is shared with the rest of the suite and the image build. Outside a git
    checkout, the checkout itself."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        capture_output=True,
        check=False,
    )
    if listed.returncode != 0:
        return REPO
    for name in filter(None, listed.stdout.decode().split("\0")):
        source = REPO / name
        if source.is_file():  # a tracked file deleted in the working tree is not copied
            target = into / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    return into


def make_client_install(root: Path, extras: Sequence[str] = ()) -> ClientInstall:
    """A fresh virtualenv at ROOT with the project (not editable, built from a copy of
    the checkout: :func:`source_copy`) and ``extras`` installed."""
    tool = uv()
    if tool is None:
        raise RuntimeError("uv is needed to make a client virtualenv (./dev installs it)")
    started = time.monotonic()
    subprocess.run(
        [tool, "venv", "-q", "--python", sys.executable, str(root)],
        check=True,
        capture_output=True,
    )
    project = source_copy(root.with_name(root.name + "-source"))
    wanted = f"{project}[{','.join(extras)}]" if extras else str(project)
    done = subprocess.run(
        [tool, "pip", "install", "-q", "--python", str(root / "bin" / "python"), wanted],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        raise RuntimeError(f"uv pip install {wanted} failed:\n{done.stderr}")
    seconds = time.monotonic() - started
    site = subprocess.run(
        [
            str(root / "bin" / "python"),
            "-c",
            "import sysconfig; print(sysconfig.get_path('purelib'))",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(site) / "_wart_lab_import_audit.py").write_text(_AUDIT.format(lab_only=LAB_ONLY))
    (Path(site) / "_wart_lab_import_audit.pth").write_text("import _wart_lab_import_audit\n")
    return ClientInstall(root=root, import_log=root / "lab-imports.log", seconds=seconds)
