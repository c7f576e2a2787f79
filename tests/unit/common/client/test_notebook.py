"""The notebook API's answers before any lab is reached, and a run's arrays.

tests/integration/test_notebooks.py runs the example notebooks against a real lab."""

from __future__ import annotations

import pytest

from common.client import notebook
from common.client.agent_client import DriveResult
from common.client.notebook import Lab, Run
from common.lab_errors import LabError, RegistryUnreachable
from common.messages import SensorSample


def test_a_login_without_the_registry_key_says_where_it_comes_from(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("WART_REGISTRY_KEY", raising=False)
    with pytest.raises(LabError, match=r"registry key is needed: .* WART_REGISTRY_KEY"):
        Lab.login("alice", connect="tcp/127.0.0.1:1", password="x")


def test_the_password_is_asked_hidden_unless_wart_password_gives_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    asked: list[str] = []
    monkeypatch.setattr(notebook.getpass, "getpass", lambda prompt: asked.append(prompt) or "pw")

    def unreachable(*_args: object, **_kw: object) -> None:
        raise ConnectionError("no router at tcp/127.0.0.1:1")

    monkeypatch.setattr(notebook, "open_session", unreachable)
    monkeypatch.delenv("WART_PASSWORD", raising=False)
    login = {"connect": "tcp/127.0.0.1:1", "registry_key": "00" * 32}
    with pytest.raises(RegistryUnreachable, match="no router"):
        Lab.login("alice", **login)
    assert asked == ["password for alice: "]
    monkeypatch.setenv("WART_PASSWORD", "from the environment")
    with pytest.raises(RegistryUnreachable):
        Lab.login("alice", **login)
    assert asked == ["password for alice: "]  # not asked again


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [
        ({"user": "al ice"}, "user"),
        ({"user": "alice", "connect": "lab.example.org:7447"}, "is not a Zenoh endpoint"),
        ({"user": "alice", "context": "../etc"}, "context"),
    ],
)
def test_a_bad_login_argument_is_a_clear_error(kwargs: dict[str, str], says: str) -> None:
    with pytest.raises(LabError, match=says):
        Lab.login(**kwargs, registry_key="00" * 32, password="x")  # type: ignore[arg-type]


def sample(tick: int, proximity: list[int], speeds: tuple[int, int]) -> SensorSample:
    return SensorSample(
        world="w1", agent="k1", tick=tick, sim_time=10 + tick * 0.02, proximity=proximity,
        ambient=[500] * 8, counters=(tick, 2 * tick), speeds=speeds, leds=[0, 0],
    )  # fmt: skip


def test_a_runs_samples_are_numpy_arrays_one_row_a_sample() -> None:
    run = Run("k1", DriveResult("k1-1-abc", "finished", "its slot ended", iterations=3))
    run.samples = [sample(0, [1] * 8, (5, 5)), sample(1, [2] * 8, (6, 4))]
    assert run.proximity.shape == (2, 8) and run.proximity[1, 0] == 2
    assert run.speeds.tolist() == [[5, 5], [6, 4]]
    assert run.counters[1].tolist() == [1, 2]
    assert run.times.tolist() == pytest.approx([0.0, 0.02])
    assert repr(run) == "<Run of k1, k1-1-abc: finished: its slot ended; 3 steps, 2 samples>"
    assert Run("k1", DriveResult("", "interrupted", "")).proximity.shape == (0, 0)
