"""The login throttle's waits, and the registry's option that sets the first."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.service import RequestError
from services.registry.main import main as registry_main
from services.registry.throttle import LoginThrottle, network_of, query_source, vouched_source

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


def test_the_owners_place_answers_to_its_pair_alone_and_the_account_holds_new_places() -> None:
    throttle = LoginThrottle(first_wait=60.0)
    classroom = vouched_source("viewer", "203.0.113.7")
    throttle.succeeded("alice", classroom, 0.0)  # she logged in from there
    for i in range(5):  # five guesses from five new places put the account under attack
        throttle.failed("alice", query_source(f"s{i}"), 1.0)
    with pytest.raises(RequestError, match="try again in 60 s"):
        throttle.check("alice", query_source("new"), 1.0)
    throttle.check("alice", classroom, 1.0)  # her own place: checked
    for _ in range(5):  # a classmate guessing from the shared address
        throttle.failed("alice", classroom, 2.0)
    with pytest.raises(RequestError) as info:
        throttle.check("alice", classroom, 2.0)
    assert info.value.retry_after <= 60.0  # a short wait, never a lock


def test_addresses_of_one_network_count_together_and_the_admin_clears_them() -> None:
    throttle = LoginThrottle(network_free=30)
    assert network_of(vouched_source("viewer", "198.51.100.9")) == "viewer:198.51.100.0/24"
    assert network_of(vouched_source("viewer", "2001:db8::1")) == "viewer:2001:db8::/56"
    assert network_of(query_source("abc")) is None
    for i in range(30):  # thirty accounts, thirty addresses, one network
        throttle.failed(f"user{i}", vouched_source("viewer", f"198.51.100.{i}"), 0.0)
    with pytest.raises(RequestError):
        throttle.check("bob", vouched_source("viewer", "198.51.100.200"), 0.0)
    throttle.check("bob", vouched_source("viewer", "192.0.2.1"), 0.0)  # another network
    kinds = {b.kind for b in throttle.buckets(0.0)}
    assert kinds == {"pair", "source", "network", "account"}
    assert throttle.clear_source("viewer:198.51.100.0/24") == 1
    throttle.check("bob", vouched_source("viewer", "198.51.100.200"), 0.0)
    # Unlocking an account clears the sources that failed on it too (a shared address).
    shared = vouched_source("viewer", "192.0.2.50")
    for i in range(10):
        throttle.failed("carol" if i < 3 else f"x{i}", shared, 0.0)
    with pytest.raises(RequestError):
        throttle.check("dave", shared, 0.0)
    throttle.unlock("carol")
    throttle.check("dave", shared, 0.0)
