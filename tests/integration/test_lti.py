"""LTI 1.3 (issue 36, items 8 and 9), with real processes: router, registry, lti, runner, grader.

A fake LMS (tests/kit/lti_platform.py: its own keys, JWKS, OIDC auth,
token and score endpoints on 127.0.0.1) launches people into the lab through
the real ``wart lti``: a Learner gets an account in the course and a page
cookie that logs them in; an Instructor becomes a teacher; the student's
graded submission reaches the platform's grade book, through a token endpoint
that fails at first; and each bad launch is refused in words, writing nothing.
"""

from __future__ import annotations

import html
import sqlite3
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import pytest

from common import keys
from common.auth import create_identity_key
from common.client.grader_client import GraderClient
from common.client.resume_cookie import parse_cookies
from common.lab_errors import LabError
from common.messages import LtiAccount, LtiAccountRequest
from services.lab import wiring
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.integration.test_grading import CONTROLLERS, COURSE, add_assignment
from tests.kit.agentkit import start_runner, together
from tests.kit.courses import import_roster
from tests.kit.lab import ProcessLab, make_lab
from tests.kit.lti_platform import (
    CLIENT_ID,
    DEPLOYMENT,
    INSTRUCTOR,
    FakePlatform,
    Launcher,
    form_fields,
    new_key,
)
from tests.kit.lti_tool import PAGE, start_lti
from tests.kit.procs import start_router, wart

pytestmark = pytest.mark.timeout(600)


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None


_opener = urllib.request.build_opener(_NoRedirect)


@dataclass
class Answer:
    status: int
    location: str
    cookies: list[str]
    text: str


def _open(request: urllib.request.Request | str) -> Answer:
    try:
        with _opener.open(request, timeout=20) as r:
            return Answer(r.status, r.headers.get("Location", ""), [], r.read().decode())
    except urllib.error.HTTPError as exc:
        return Answer(
            exc.code,
            exc.headers.get("Location", ""),
            exc.headers.get_all("Set-Cookie") or [],
            html.unescape(exc.read().decode()),  # an error page's words, as shown
        )


@dataclass
class LtiLab:
    lab: ProcessLab
    platform: FakePlatform
    tool: str

    def launch(self, who: Launcher | None = None, **post: str) -> Answer:
        """A whole launch as a browser does it: login -> platform auth -> launch post."""
        if who is not None:
            self.platform.next = who
        query = {
            "iss": self.platform.url,
            "login_hint": "hint-1",
            "target_link_uri": f"{self.tool}/lti/launch",
            "lti_message_hint": "msg-1",
            "client_id": CLIENT_ID,
            "lti_deployment_id": DEPLOYMENT,
        }
        login = _open(f"{self.tool}/lti/login?{urlencode(query)}")
        assert login.status == 303, login.text
        assert login.location.startswith(f"{self.platform.url}/auth?")
        auth = _open(login.location)
        assert auth.status == 200, auth.text
        fields = {**form_fields(auth.text), **post}
        body = urlencode({k: v for k, v in fields.items() if v != "-"}).encode()
        return _open(
            urllib.request.Request(
                f"{self.tool}/lti/launch",
                data=body,
                headers={"Content-Type": "application/x-www-form-urlencoded"},
                method="POST",
            )
        )

    def rows(self, sql: str, *args: object) -> list[tuple[Any, ...]]:
        con = sqlite3.connect(self.lab.db_path)
        try:
            return list(con.execute(sql, args))
        finally:
            con.close()


@contextmanager
def lti_lab(router: Router, procs: Procs, tmp: Path) -> Iterator[LtiLab]:
    lab = make_lab(router, procs, tmp)
    lab.start_registry()
    import_roster(lab)
    platform = FakePlatform()
    try:
        tool = start_lti(lab, tmp, platform)
        yield LtiLab(lab, platform, tool)
    finally:
        platform.close()


@pytest.fixture
def lti(router: Router, procs: Procs, tmp_path: Path) -> Iterator[LtiLab]:
    with lti_lab(router, procs, tmp_path) as lab:
        yield lab


@pytest.fixture(scope="module")
def refusing_lti(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LtiLab]:
    """One lab for every bad launch: each writes nothing, so each finds it as the last left it."""
    tmp = tmp_path_factory.mktemp("refusing")
    procs = Procs(tmp)
    # The log prints 5 lines of one kind per window, then counts the rest (a flood of bad
    # launches is one line a window): a short window gives each case its own line.
    procs.env["WART_LOG_SUMMARY_S"] = "0.1"
    try:
        router = start_router(procs, f"t{uuid.uuid4().hex[:10]}")
        with lti_lab(router, procs, tmp) as lab:
            yield lab
    finally:
        procs.stop_all()


def test_the_platforms_file_is_checked_with_its_field(tmp_path: Path) -> None:
    bad = tmp_path / "lti.toml"
    bad.write_text(
        '[tool]\nurl = "http://127.0.0.1:1"\npage = "http://127.0.0.1:2/"\n'
        'lab_address = "wart://127.0.0.1:7447/lab"\n\n[[platform]]\nissuer = "x"\n'
        'client_id = "c"\ndeployment_ids = []\n'
    )
    key = create_identity_key(tmp_path / "id.key")
    done = wart(
        "lti", "--user", "lti-lti", "--identity", str(tmp_path / "id.key"),
        "--platforms", str(bad), "--state-dir", str(tmp_path / "s"),
        "--registry-key", bytes(key.verify_key).hex(),
    )  # fmt: skip
    assert done.returncode == 2
    assert f"{bad}: platform[0].deployment_ids: a list of the LMS's deployment ids" in done.stderr


def test_a_learner_and_an_instructor_launch_into_their_course(lti: LtiLab) -> None:
    users_before = lti.rows("SELECT COUNT(*) FROM users")[0][0]
    answer = lti.launch(Launcher(sub="u-1001", name="Lea Learner"))
    assert answer.status == 303, answer.text
    assert answer.location == PAGE
    # The page's saved-login cookie, as the viewer reads it from its websocket handshake.
    header = "; ".join(c.split(";")[0] for c in answer.cookies)
    saved = parse_cookies(header, lti.lab.realm)
    assert len(saved) == 1 and saved[0].address.port == lti.lab.router.port
    user = saved[0].address.user
    assert user is not None and user.startswith("lms-")
    assert lti.rows("SELECT COUNT(*) FROM users")[0][0] == users_before + 1
    assert lti.rows(
        "SELECT role, display_name FROM course_members WHERE course=? AND user=?", COURSE, user
    ) == [("student", "Lea Learner")]
    # The page logs in with it: a resume against the registry, good once.
    with lti.lab.client() as client:
        client.resume(saved[0].token)
        assert client.user == user
    with lti.lab.client() as client, pytest.raises(LabError, match="was revoked \\(used"):
        client.resume(saved[0].token)
    # The same platform user again: the same account, a new token.
    again = lti.launch(Launcher(sub="u-1001"))
    assert again.status == 303
    assert parse_cookies(again.cookies[0].split(";")[0], lti.lab.realm)[0].address.user == user
    assert lti.rows("SELECT COUNT(*) FROM users")[0][0] == users_before + 1
    # An instructor becomes a teacher of the course.
    teacher = lti.launch(Launcher(sub="t-7", name="Tess Teacher", roles=(INSTRUCTOR,)))
    assert teacher.status == 303, teacher.text
    tuser = parse_cookies(teacher.cookies[0].split(";")[0], lti.lab.realm)[0].address.user
    assert lti.rows("SELECT role FROM course_members WHERE course=? AND user=?", COURSE, tuser) == [
        ("teacher",)
    ]
    # Only the lti service's account may have the registry make accounts.
    request = LtiAccountRequest(issuer="https://x", subject="s", course=COURSE, role="teacher")
    with lti.lab.client("alice") as client, pytest.raises(LabError, match="not the lti service"):
        client._ask(keys.registry_lti(lti.lab.realm), request, LtiAccount, "lti")
    # The platform rolls its key over: the tool fetches the key set again for the new kid
    # (at most once per JWKS_COOLDOWN_S: a launch meanwhile is refused, and tried again).
    fetches = lti.platform.jwks_fetches
    lti.platform.key, lti.platform.kid = new_key(), "platform-key-2"
    wait_for(lambda: lti.launch(Launcher(sub="u-1001")).status == 303, 30, "the new key taken")
    assert lti.platform.jwks_fetches > fetches
    # The tool's own key: made once in the state directory, readable by its owner only.
    key_file = lti.lab.wiring().state_dir / "lti" / "lti-tool-key.pem"
    assert key_file.stat().st_mode & 0o777 == 0o600


@pytest.mark.parametrize(
    ("case", "status", "words"),
    [
        ("bad signature", 401, "the id_token's signature does not verify"),
        ("unknown kid", 401, "signed with key 'stranger', which the platform's key set"),
        ("expired", 401, "the id_token has expired"),
        ("wrong aud", 401, "the id_token is not for this tool (aud is not 'wart-tool-1')"),
        ("unknown deployment", 403, "deployment 'deploy-9' of http://127.0.0.1:"),
        ("version 1.1", 400, "LTI version '1.1.0': this tool speaks LTI 1.3.0"),
        ("missing state", 400, "the launch has no 'state'"),
        ("unknown state", 400, "the launch's state is unknown, used or expired"),
    ],
)
def test_a_bad_launch_is_refused_in_words_and_writes_nothing(
    refusing_lti: LtiLab, case: str, status: int, words: str
) -> None:
    lti = refusing_lti
    platform = lti.platform
    stranger = new_key()

    def tamper(claims: dict[str, Any], header: dict[str, Any]) -> tuple[Any, str]:
        if case == "bad signature":
            return platform.sign(claims, key=stranger), ""
        if case == "unknown kid":
            return platform.sign(claims, key=stranger, kid="stranger"), ""
        if case == "expired":
            claims["exp"] = claims["iat"] = int(time.time()) - 600
        elif case == "wrong aud":
            claims["aud"] = claims["azp"] = "someone-else"
        elif case == "unknown deployment":
            claims["https://purl.imsglobal.org/spec/lti/claim/deployment_id"] = "deploy-9"
        elif case == "version 1.1":
            claims["https://purl.imsglobal.org/spec/lti/claim/version"] = "1.1.0"
        return platform.sign(claims), ""

    platform.tamper = tamper
    before = lti.rows("SELECT COUNT(*) FROM users")[0][0]
    log_file = lti.lab.procs.tmp / "lti.log"
    logged = len(log_file.read_text())
    post = {"state": "-"} if case == "missing state" else {}
    if case == "unknown state":
        post = {"state": "made-up-state"}
    if case in ("missing state", "unknown state"):
        platform.tamper = None
    try:
        answer = lti.launch(Launcher(sub=f"bad-{case}"), **post)
    finally:
        platform.tamper = None  # the next case starts from an honest platform
    assert answer.status == status, answer.text
    assert words in answer.text, answer.text
    assert "LTI launch refused" in answer.text and not answer.cookies
    assert lti.rows("SELECT COUNT(*) FROM users")[0][0] == before
    assert lti.rows("SELECT COUNT(*) FROM lti_links") == [(0,)]
    # Said in the log too, in this launch's own lines.
    wait_for(lambda: words.split("'")[0] in log_file.read_text()[logged:], 10, "the refusal logged")


def test_a_replayed_launch_is_refused(lti: LtiLab) -> None:
    first = lti.launch(Launcher(sub="u-55"))
    assert first.status == 303
    token = lti.platform.last_id_token
    before = lti.rows("SELECT COUNT(*) FROM users")[0][0]
    # A fresh login, and the old id_token (its nonce used) posted with the new state.
    lti.platform.tamper = lambda claims, header: (token, "")
    replay = lti.launch()
    assert replay.status == 401
    assert "the id_token's nonce was used before: a replayed launch" in replay.text
    assert lti.rows("SELECT COUNT(*) FROM users")[0][0] == before
    # A banned account's launch is refused as its login would be.
    user = parse_cookies(first.cookies[0].split(";")[0], lti.lab.realm)[0].address.user
    assert user is not None
    with lti.lab.client("admin") as admin:
        admin.ban(user, "copied a classmate's controller")
    lti.platform.tamper = None
    banned = lti.launch(Launcher(sub="u-55"))
    assert banned.status == 403
    assert "you are banned until an admin lifts it: copied a classmate's controller" in banned.text


@needs_sandbox
def test_a_launched_students_score_reaches_the_platform(lti: LtiLab, tmp_path: Path) -> None:
    lab = lti.lab
    add_assignment(lab, tmp_path, "reach-goal", episodes="1", seeds="[7]")
    together(lambda: start_runner(lab), lab.start_grader)
    answer = lti.launch(Launcher(sub="u-2002", name="Sam Student", assignment="reach-goal"))
    assert answer.status == 303, answer.text
    saved = parse_cookies(answer.cookies[0].split(";")[0], lab.realm)[0]
    lti.platform.token_failures = 1000  # the platform's token endpoint fails for now
    with lab.client() as client:
        client.resume(saved.token)
        grader = GraderClient(client)
        accepted = grader.submit("reach-goal", (CONTROLLERS / "works.py").read_bytes(), "works.py")
        graded = grader.wait_graded("reach-goal", accepted.submission, 240)
    assert graded.status == "graded" and graded.mean is not None
    log_path = lab.procs.tmp / "lti.log"
    words = "not posted yet: the access token: the platform answered 503"
    wait_for(lambda: words in log_path.read_text(), 60, "a failed post")
    # The tool restarts while the score waits: it is kept, and posted once the LMS is back.
    lti_proc = next(p for p in lab.procs.started if p.name == "lti")
    lti_proc.stop()
    lti.platform.token_failures = 1
    spec = wiring.lti_spec(
        lab.wiring(), tmp_path / "lti.toml", http_port=int(lti.tool.rsplit(":")[-1])
    )
    lab.start(spec, name="lti-again")
    wait_for(lambda: lti.platform.scores, timeout=120)
    (score,) = lti.platform.scores
    assert score["userId"] == "u-2002"
    assert score["scoreGiven"] == pytest.approx(graded.mean, abs=1e-3)
    assert score["scoreMaximum"] == 100
    assert score["activityProgress"] == "Completed"
    assert score["gradingProgress"] == "FullyGraded"
    assert score["timestamp"].endswith("+00:00")
    assert lti.platform.score_auth[0].startswith("Bearer tok-")
    # The tool logs the post once the platform has answered it: wait for the line.
    posted = f"score of {accepted.submission} for {saved.address.user} (reach-goal) posted"
    again_log = lab.procs.tmp / "lti-again.log"
    wait_for(lambda: posted in again_log.read_text(), 30, "the post logged")
    assert words in again_log.read_text()  # the first try after the restart failed too, and waited
    # A student without a launch of this assignment (alice, from the roster): nothing posted.
    with lab.client("alice") as client:
        works = (CONTROLLERS / "works.py").read_bytes()
        other = GraderClient(client).submit("reach-goal", works, "works.py")
        GraderClient(client).wait_graded("reach-goal", other.submission, 240)
    time.sleep(1.0)  # the announcement would have arrived by now
    assert len(lti.platform.scores) == 1
    # The tool is down while Sam's next submission is graded: at its next start it asks
    # the grader for what it missed, and that score arrives too (and the first not again).
    relaunch = lti.launch(Launcher(sub="u-2002", name="Sam Student", assignment="reach-goal"))
    sams_next_login = parse_cookies(relaunch.cookies[0].split(";")[0], lab.realm)[0].token
    next(p for p in lab.procs.started if p.name == "lti-again").stop()
    with lab.client() as client:
        client.resume(sams_next_login)
        grader = GraderClient(client)
        second = grader.submit("reach-goal", (CONTROLLERS / "works.py").read_bytes(), "works.py")
        assert grader.wait_graded("reach-goal", second.submission, 240).status == "graded"
    lab.start(spec, name="lti-third")
    wait_for(lambda: len(lti.platform.scores) == 2, timeout=120, what="the missed score")
    assert lti.platform.scores[1]["userId"] == "u-2002"
    assert lti.platform.scores[1]["comment"] == f"wart submission {second.submission}"
    log = (lab.procs.tmp / "lti-third.log").read_text()
    assert f"score of {second.submission} was not announced to us: catching up" in log
