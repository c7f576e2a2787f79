"""The client install's commands: they import nothing of the lab extra, and a lab command
run where the lab extra is missing says how to install it (no ImportError traceback).

tests/integration/test_client_install.py installs the client alone into a fresh
virtualenv and drives a robot with it; these checks run in the lab's own virtualenv.
"""

from __future__ import annotations

import importlib.metadata
import pkgutil
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from services import cli

REPO = Path(__file__).resolve().parents[3]

# What a laptop imports: the client commands, and the libraries they and a notebook use.
CLIENT_PACKAGES = ("common.client", "common.controller", "common.recording", "common.messages")


def client_modules() -> list[str]:
    tools = {" ".join(words): module for words, module in cli.SUBCOMMAND_TOOLS.items()}
    modules = [tools.get(name) or cli.SUBCOMMANDS[name][0] for name in sorted(cli.CLIENT_COMMANDS)]
    for name in CLIENT_PACKAGES:
        package = importlib.import_module(name)
        modules.append(name)
        modules += [f"{name}.{info.name}" for info in pkgutil.iter_modules(package.__path__)]
    return modules


def test_the_client_commands_import_nothing_of_the_lab_extra() -> None:
    lab = sorted({*cli.LAB_MODULES, "matplotlib"})
    code = (
        "import importlib, sys\n"
        f"for name in {client_modules()!r}: importlib.import_module(name)\n"
        f"print(sorted({{m.partition('.')[0] for m in sys.modules}} & set({lab!r})))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True
    )
    assert done.stdout.strip() == "[]", f"a client module imports the lab's: {done.stdout}"


def test_every_client_command_is_a_command() -> None:
    tools = {" ".join(words) for words in cli.SUBCOMMAND_TOOLS}
    assert set(cli.SUBCOMMANDS) | tools >= cli.CLIENT_COMMANDS


def _requirement_name(requirement: str) -> str:
    match = re.match(r"[A-Za-z0-9._-]+", requirement)
    assert match, requirement
    return match.group(0).lower()


def test_the_lab_modules_are_the_lab_extras_packages() -> None:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    lab = {_requirement_name(r) for r in project["optional-dependencies"]["lab"]}
    core = {_requirement_name(r) for r in project["dependencies"]}
    # each module of the check is the lab's, in the distribution the lab extra names
    distributions = importlib.metadata.packages_distributions()
    for module, package in cli.LAB_MODULES.items():
        assert package.lower() in lab, f"{package} is not in the lab extra"
        assert package.lower() in {d.lower() for d in distributions[module]}, module
    # and every package a service needs to start is in the check
    not_checked = {"setuptools", "matplotlib"}  # the ahead-of-time build; optional plots
    assert lab - not_checked == {p.lower() for p in cli.LAB_MODULES.values()}
    assert not core & lab


def test_a_lab_command_on_a_client_install_says_how_to_install_the_lab(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(cli, "missing_lab_packages", lambda: ["numba", "pymunk"])
    assert cli.main(["engine", "--help"]) == 2
    err = capsys.readouterr().err
    assert "wart engine: this command needs the lab's services: pip install 'wart-lab[lab]'" in err
    assert "without numba, pymunk" in err and "Traceback" not in err
    assert " *engine " in cli.usage() and " *record " not in cli.usage()
    # a client command runs as before
    with pytest.raises(SystemExit) as done:
        cli.main(["record", "--help"])
    assert done.value.code == 0
    assert "usage: wart record" in capsys.readouterr().out
