"""The saved login's cookie: what the page keeps, and what the viewer accepts back."""

from __future__ import annotations

import pytest

from common.client.lab_address import parse_address
from common.client.resume_cookie import cookie_name, cookie_value, parse_cookies
from viewers.web.login import progress_words
from viewers.web.saved_login import cookie_script, saved_login_html


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


def test_the_script_sets_only_base64url_text_and_a_forgetting_one_expires() -> None:
    here = parse_address("wart://alice@lab.example.org:7447/lab")
    html = cookie_script(cookie_name(here), cookie_value(here, b"\x01" * 40), 600)
    assert "max-age=600" in html and "SameSite=Strict" in html and "path=/" in html
    with pytest.raises(ValueError):
        cookie_script(cookie_name(here), "x'; alert(1); '", 600)
    with pytest.raises(ValueError):
        cookie_script("session", "abc", 600)
    forget = saved_login_html(here, None, 3)
    assert "max-age=0" in forget and "<!-- 3 -->" in forget
    assert saved_login_html(here, None, 4) != forget  # each call re-runs in the page


def test_a_slow_login_says_how_long_and_why() -> None:
    assert progress_words(2.4, 0).startswith("Logging in... 2 s: the lab is checking")
    assert "7 more logins wait here" in progress_words(5.0, 7)
