"""The LTI tool's pure parts: the platforms file's checks, the score a platform gets,
the one-time store of logins, the course a launch maps to; the launch itself is
tested against a fake LMS in tests/integration/test_lti.py."""

from __future__ import annotations

import time

import pytest

from services.lti.ags import score_body, scores_url
from services.lti.config import ConfigError, parse
from services.lti.launch import Launch, Launcher, LaunchError
from services.lti.store import Outgoing

GOOD = """
[tool]
url = "https://lab.example.org:8090/"
page = "https://lab.example.org:8080/"
lab_address = "wart://lab.example.org:7447/lab"

[[platform]]
issuer = "https://moodle.example.org"
client_id = "abc"
deployment_ids = ["1"]
auth_login_url = "https://moodle.example.org/mod/lti/auth.php"
auth_token_url = "https://moodle.example.org/mod/lti/token.php"
key_set_url = "https://moodle.example.org/mod/lti/certs.php"
[platform.courses]
"42" = "robotics-26"
"""


def test_a_good_file_gives_the_urls_to_register() -> None:
    config = parse(GOOD)
    assert config.url == "https://lab.example.org:8090"
    assert config.login_url == "https://lab.example.org:8090/lti/login"
    assert config.launch_url == "https://lab.example.org:8090/lti/launch"
    assert config.jwks_url == "https://lab.example.org:8090/lti/jwks"
    (p,) = config.platforms
    assert p.score_maximum == 100 and p.courses == {"42": "robotics-26"}
    assert config.platform("https://moodle.example.org", "abc") is p
    assert config.platform("https://moodle.example.org", "other") is None


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (('key_set_url = "https', 'key_set_url = "ftp'), "platform[0].key_set_url: 'ftp:"),
        (('deployment_ids = ["1"]', "deployment_ids = []"), "platform[0].deployment_ids"),
        (('"42" = "robotics-26"', '"42" = "no good/name"'), "platform[0].courses.42"),
        (('client_id = "abc"', 'client_id = "abc"\ncolour = 1'), "unknown field(s) colour"),
        (('lab_address = "wart:', 'lab_address = "http:'), "tool.lab_address"),
        (("[tool]", "[tool"), "not TOML"),
    ],
)
def test_a_bad_file_is_refused_with_its_field(change: tuple[str, str], words: str) -> None:
    with pytest.raises(ConfigError, match=r"lti\.toml: ") as caught:
        parse(GOOD.replace(*change))
    assert words in str(caught.value)


def test_the_score_is_clamped_into_the_grade_book_and_dated_in_utc() -> None:
    out = Outgoing("s1", "u", "a", "iss", "c", "sub-9", "https://x/li?t=1", 123.0, 100.0, 0.0, 0)
    body = score_body(out)
    assert body["userId"] == "sub-9" and body["scoreGiven"] == 100.0
    assert body["timestamp"] == "1970-01-01T00:00:00.000+00:00"
    assert scores_url("https://lms/api/lineitems/7/lineitem?type_id=1") == (
        "https://lms/api/lineitems/7/lineitem/scores?type_id=1"
    )


def test_a_login_state_is_good_once_and_a_launch_maps_roles() -> None:
    launcher = Launcher(parse(GOOD))
    url = launcher.login({"iss": "https://moodle.example.org", "login_hint": "h"})
    assert url.startswith("https://moodle.example.org/mod/lti/auth.php?")
    state = url.split("state=")[1].split("&")[0]
    assert launcher.once.take(state) is not None
    assert launcher.once.take(state) is None  # used
    with pytest.raises(LaunchError, match="knows no platform https://evil"):
        launcher.login({"iss": "https://evil", "login_hint": "h"})
    with pytest.raises(LaunchError, match=r"deployment '9' of https://moodle\.example\.org"):
        launcher.login({"iss": "https://moodle.example.org", "login_hint": "h",
                        "lti_deployment_id": "9"})  # fmt: skip
    assert launcher.once.use_nonce("n", time.time() + 60)
    assert not launcher.once.use_nonce("n", time.time() + 60)


@pytest.mark.parametrize(
    ("roles", "role"),
    [
        (("http://purl.imsglobal.org/vocab/lis/v2/membership#Learner",), "student"),
        (("http://purl.imsglobal.org/vocab/lis/v2/membership#Instructor",), "teacher"),
        (("http://purl.imsglobal.org/vocab/lis/v2/membership#TeachingAssistant",), "teacher"),
        (("http://purl.imsglobal.org/vocab/lis/v2/membership#Mentor",), None),
    ],
)
def test_lti_roles_map_to_course_roles(roles: tuple[str, ...], role: str | None) -> None:
    p = parse(GOOD).platforms[0]
    launch = Launch(p, "s", "", "", roles, "1", "42", "R101", "link", {}, None, ())
    assert launch.role == role
