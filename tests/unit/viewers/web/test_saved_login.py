"""The saved login's cookie: what the page keeps, and what the viewer accepts back."""

from __future__ import annotations

import logging

import pytest

from common.client.lab_address import parse_address
from common.client.resume_cookie import cookie_name, cookie_value, parse_cookies
from viewers.web.login import progress_words
from viewers.web.saved_login import (
    _TICKET_ANSWERS_UNLOGGED,
    CookieDesk,
    saved_login_cookie,
    set_cookie,
)


def test_a_cookie_round_trips_per_lab_and_damaged_ones_are_skipped() -> None:
    here = parse_address("wart://alice@lab.example.org:7447/lab")
    there = parse_address("wart://alice@other.example.org:7447/lab")
    assert cookie_name(here) != cookie_name(there)
    token = bytes(range(200))
    header = "; ".join(
        [
            "theme=dark",
            f"{cookie_name(here)}={cookie_value(here, token)}",
            f"{cookie_name(here)}x=junk.junk",  # a name that is not its address's
            f"{cookie_name(there)}={cookie_value(here, token)}",  # moved under another name
            "wart_resume_abc=%%%.%%%",  # not base64
        ]
    )
    saved = parse_cookies(header, "lab")
    assert [(s.address.lab_key, s.address.user, s.token) for s in saved] == [
        (here.lab_key, "alice", token)
    ]
    assert parse_cookies("", "lab") == []


def test_the_cookie_is_httponly_strict_and_set_only_by_a_one_time_ticket() -> None:
    here = parse_address("wart://alice@lab.example.org:7447/lab")
    cookie = set_cookie(cookie_name(here), cookie_value(here, b"\x01" * 40), 600, secure=False)
    assert "Max-Age=600" in cookie and "SameSite=Strict" in cookie and "Path=/" in cookie
    assert "HttpOnly" in cookie and "Secure" not in cookie
    assert set_cookie(cookie_name(here), "abc", 600, secure=True).endswith("; Secure")
    with pytest.raises(ValueError):
        set_cookie(cookie_name(here), "x; Domain=evil.example", 600, secure=False)
    with pytest.raises(ValueError):
        set_cookie("session", "abc", 600, secure=False)
    assert "Max-Age=0" in saved_login_cookie(here, None, secure=False)
    desk = CookieDesk()
    html = desk.html(cookie, 3)
    assert "<!-- 3 -->" in html and "wart_resume" not in html  # the page never sees it
    path = "/" + html.split('src="')[1].split('"')[0]
    answer = desk.answer(path)
    assert answer is not None and answer.status_code == 204
    assert answer.headers["Set-Cookie"] == cookie
    again = desk.answer(path)  # good once
    assert again is not None and again.status_code == 404 and "Set-Cookie" not in again.headers
    assert desk.answer("/index.html") is None  # viser's own pages are viser's


def test_a_slow_login_says_how_long_and_why() -> None:
    assert progress_words(2.4, 0).startswith("Logging in... 2 s: the lab is checking")
    assert "7 more logins wait here" in progress_words(5.0, 7)


def test_a_tickets_answer_is_logged_in_words_not_as_a_rejected_connection(
    caplog: pytest.LogCaptureFixture,
) -> None:
    desk = CookieDesk()
    path = "/" + desk.html("wart_resume_x=abc; Path=/", 1).split('src="')[1].split('"')[0]
    with caplog.at_level(logging.DEBUG, logger="wart.viewer.saved_login"):
        desk.answer(path)
        desk.answer(path)
    words = [r.getMessage() for r in caplog.records if r.name == "wart.viewer.saved_login"]
    assert words[0] == "a page's saved login stored in its cookie"
    assert "that browser keeps the login it had" in words[1]
    # websockets calls every answer but 101 "connection rejected": not so for a ticket's.
    drop = _TICKET_ANSWERS_UNLOGGED.filter
    record = logging.LogRecord(
        "websockets.server", logging.INFO, "", 0, "connection %s", None, None
    )
    assert not drop(
        logging.makeLogRecord({**record.__dict__, "args": ("rejected (204 No Content)",)})
    )
    assert drop(logging.makeLogRecord({**record.__dict__, "args": ("rejected (404 Not Found)",)}))
    assert drop(logging.makeLogRecord({**record.__dict__, "args": ("open",)}))
