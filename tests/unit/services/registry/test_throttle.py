"""The login throttle's waits, and the registry's option that sets the first."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.service import RequestError
from services.registry.main import main as registry_main
from services.registry.throttle import LoginThrottle, query_source

SOURCE = query_source("abc")


def wait_after(throttle: LoginThrottle, failures: int) -> float:
    """How long ``SOURCE`` is told to wait after ``failures`` failures on alice at t=0."""
    for _ in range(failures):
        throttle.failed("alice", SOURCE, 0.0)
    try:
        throttle.check("alice", SOURCE, 0.0)
    except RequestError as exc:
        return exc.retry_after
    return 0.0


@pytest.mark.parametrize(
    ("first", "expected"), [(2.0, [0, 2, 4, 8, 16]), (60.0, [0, 60, 120, 240, 300])]
)
def test_the_wait_doubles_from_the_first_up_to_the_cap(first: float, expected: list[float]) -> None:
    waits = [wait_after(LoginThrottle(first_wait=first), n) for n in range(2, 7)]
    assert waits == expected


def test_a_wait_ends_when_it_says() -> None:
    throttle = LoginThrottle(first_wait=5.0)
    for _ in range(3):
        throttle.failed("alice", SOURCE, 100.0)
    with pytest.raises(RequestError, match="try again in 3 s"):
        throttle.check("alice", SOURCE, 102.5)
    throttle.check("alice", SOURCE, 105.0)  # checked again: no error


def _registry_argv(tmp_path: Path, wait: str) -> list[str]:
    return [
        "--db",
        str(tmp_path / "r.db"),
        "--key-file",
        str(tmp_path / "r.key"),
        "--login-wait",
        wait,
    ]


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "inf", "301"])
def test_the_registry_refuses_a_login_wait_it_cannot_use(
    bad: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert registry_main(_registry_argv(tmp_path, bad)) == 2
    assert (
        "--login-wait: the first wait must be above 0 s and at most 300 s"
        in capsys.readouterr().err
    )
    assert not (tmp_path / "r.db").exists()  # refused before anything was made


def test_the_registry_refuses_a_login_wait_that_is_not_a_number(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit):
        registry_main(_registry_argv(tmp_path, "soon"))
    assert "--login-wait: invalid float value: 'soon'" in capsys.readouterr().err
