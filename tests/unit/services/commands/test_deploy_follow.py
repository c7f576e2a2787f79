"""When `wart deploy` asks the context about its request, and what it says of the answer."""

from __future__ import annotations

import time

import pytest

from common.messages import AgentContextState, RequestStatusReply
from services.commands import deploy
from services.commands.deploy import Follow


class FakeAgents:
    """The parts of AgentClient that Follow reads."""

    def __init__(self) -> None:
        self.latest_state: AgentContextState | None = None
        self.where: tuple[int, float | None] | None = (1, None)
        self.last_heard = time.monotonic()
        self.answers: list[RequestStatusReply | None] = []
        self.asked = 0

    def position(self, _rid: str) -> tuple[int, float | None] | None:
        return self.where

    def request_status(self, _rid: str) -> RequestStatusReply | None:
        self.asked += 1
        return self.answers.pop(0)


STATE = AgentContextState(ctx="arena", world="w1", slot_seconds=60, enabled=True, agents=[], at=0)


def follow_of(agents: FakeAgents) -> Follow:
    return Follow(agents, "k1-1-abcdef")  # type: ignore[arg-type]


def test_a_request_missing_from_the_queues_is_asked_about_at_once_then_every_few_s() -> None:
    agents = FakeAgents()
    follow = follow_of(agents)
    assert not follow.due(running=False)  # in the queue, news lately: nothing to ask
    agents.latest_state, agents.where = STATE, None
    assert follow.due(running=False)
    agents.answers.append(RequestStatusReply(request_id="k1-1-abcdef", at=0))
    follow.ask("arena")
    assert not follow.due(running=False)  # just asked


def test_silence_and_an_overrun_slot_are_asked_about() -> None:
    agents = FakeAgents()
    follow = follow_of(agents)
    agents.last_heard = time.monotonic() - deploy.SILENT_AFTER_S - 1
    assert follow.due(running=False)
    agents.last_heard = time.monotonic()
    follow.slot_end = time.time() - deploy.SLOT_END_GRACE_S - 1
    assert follow.due(running=True)


def test_a_silent_context_is_said_once_and_its_return_too(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    agents = FakeAgents()
    follow = follow_of(agents)
    agents.answers += [None, None, RequestStatusReply(request_id="k1-1-abcdef", at=0)]
    assert follow.ask("arena") is None and follow.ask("arena") is None
    assert not follow.down_too_long()
    monkeypatch.setattr(deploy, "CONTEXT_DOWN_GIVE_UP_S", 0.0)
    assert follow.down_too_long()
    assert follow.ask("arena") is not None
    out = capsys.readouterr().out.splitlines()
    assert out == [
        "the arena arena is not answering (stopped or restarting?): waiting for it",
        "the arena arena answers again",
    ]


def test_the_lost_and_down_messages_speak_to_a_student() -> None:
    lost = deploy.lost_message("arena", "k1-1-abcdef")
    assert "has no record of request k1-1-abcdef: it was lost" in lost
    assert "deploy the file again" in lost
    down = deploy.down_message("arena", "k1-1-abcdef")
    assert "it is down" in down and "lost" not in down
