"""``wart audit`` and ``wart ban``: what is typed is checked, what is exported reads back."""

from __future__ import annotations

import csv
import io
import json

import pytest

from common.messages import AuditEntry
from services.commands.audit import parse_time, render
from services.commands.ban import parse_duration

ENTRY = AuditEntry(
    id=7,
    at=1_764_153_720.0,  # 2025-11-26 10:42 UTC
    actor="ida",
    action="estop",
    target="ctx/arena",
    outcome="ok",
    detail='robot on its back, "k3"',
    source="session 0a1b2c3d",
    reporter="ctx-arena",
)


def test_times_and_durations() -> None:
    assert parse_time("2025-11-26T10:42", "--since") == 1_764_153_720.0
    assert parse_time("1764153720", "--since") == 1_764_153_720.0
    with pytest.raises(ValueError, match="--since: 'yesterday' is not a time"):
        parse_time("yesterday", "--since")
    assert parse_duration("1d") == 86400.0 and parse_duration("30m") == 1800.0
    for bad in ("forever", "0h", "-1d", "1y"):
        with pytest.raises(ValueError, match="30m, 12h, 1d or 2w"):
            parse_duration(bad)


def test_csv_and_json_read_back() -> None:
    rows = list(csv.DictReader(io.StringIO(render([ENTRY], "csv"))))
    assert rows[0]["at"] == "2025-11-26T10:42:00Z" and rows[0]["detail"] == ENTRY.detail
    data = json.loads(render([ENTRY], "json"))
    assert data[0]["actor"] == "ida" and data[0]["reporter"] == "ctx-arena"
    table = render([ENTRY], "table")
    assert "2025-11-26T10:42:00Z" in table and "estop" in table
    assert render([], "table") == "no audit lines match\n"
