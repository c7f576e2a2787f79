"""The lti service's platforms file (TOML): which LMSs may launch into the lab, and how.

Checked whole at start; every problem is reported with the file and the field
(``lti.toml: platform[1].key_set_url: ...``), and nothing starts until it is right.

    [tool]
    url = "https://lab.example.org:8090"   # where browsers and the LMS reach this tool
    page = "https://lab.example.org:8080/" # the lab's page, where a launch lands
    lab_address = "wart://lab.example.org:7447/lab"  # the lab the page logs in to
    grader = "grader"                      # whose graded submissions are passed back

    [[platform]]
    issuer = "https://moodle.example.org"
    client_id = "Xb3kT9"
    deployment_ids = ["1"]
    auth_login_url = "https://moodle.example.org/mod/lti/auth.php"
    auth_token_url = "https://moodle.example.org/mod/lti/token.php"
    key_set_url = "https://moodle.example.org/mod/lti/certs.php"
    score_maximum = 100                    # what a score is out of in the LMS's grade book
    [platform.courses]                     # an LMS course (its context id or label) -> a course
    "42" = "robotics-26"
    [platform.assignments]                 # a resource link id -> an assignment
    "link-7" = "reach-goal"

A course the file does not map is found by the context's label when a course of
that name exists; an assignment by the link's custom parameter ``assignment=NAME``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from common.keys import is_ident


class ConfigError(ValueError):
    """The file is wrong; the message names the file and the field."""


@dataclass(frozen=True)
class Platform:
    issuer: str
    client_id: str
    deployment_ids: tuple[str, ...]
    auth_login_url: str
    auth_token_url: str
    key_set_url: str
    score_maximum: float = 100.0
    courses: dict[str, str] = field(default_factory=dict)
    assignments: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class LtiConfig:
    url: str  # the tool's base URL, no trailing slash
    page: str
    lab_address: str
    grader: str
    platforms: tuple[Platform, ...]

    def platform(self, issuer: str, client_id: str | None = None) -> Platform | None:
        for p in self.platforms:
            if p.issuer == issuer and (client_id is None or p.client_id == client_id):
                return p
        return None

    @property
    def login_url(self) -> str:
        return f"{self.url}/lti/login"

    @property
    def launch_url(self) -> str:
        return f"{self.url}/lti/launch"

    @property
    def jwks_url(self) -> str:
        return f"{self.url}/lti/jwks"


def _url(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{where}: a URL is needed (text, e.g. https://lms.example.org/...)")
    parts = urlsplit(value)
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise ConfigError(f"{where}: {value!r} is not an http(s) URL")
    return value


def _text(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip() or len(value) > 255:
        raise ConfigError(f"{where}: text of 1 to 255 characters is needed")
    return value


def _idents(where: str, value: Any) -> dict[str, str]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: a table of names is needed")
    out = {}
    for k, v in value.items():
        if not isinstance(v, str) or not is_ident(v):
            raise ConfigError(f"{where}.{k}: {v!r} is not a lab name (letters, digits, _ - .)")
        out[str(k)] = v
    return out


def _only(where: str, table: dict[str, Any], known: set[str]) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(
            f"{where}: unknown field(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
        )


def _platform(where: str, t: Any) -> Platform:
    if not isinstance(t, dict):
        raise ConfigError(f"{where}: a table is needed ([[platform]])")
    _only(
        where,
        t,
        {
            "issuer",
            "client_id",
            "deployment_ids",
            "auth_login_url",
            "auth_token_url",
            "key_set_url",
            "score_maximum",
            "courses",
            "assignments",
        },
    )
    deployments = t.get("deployment_ids")
    if (
        not isinstance(deployments, list)
        or not deployments
        or not all(isinstance(d, str) and d for d in deployments)
    ):
        raise ConfigError(f"{where}.deployment_ids: a list of the LMS's deployment ids is needed")
    maximum = t.get("score_maximum", 100)
    if (
        isinstance(maximum, bool)
        or not isinstance(maximum, int | float)
        or not math.isfinite(maximum)
        or maximum <= 0
    ):
        raise ConfigError(f"{where}.score_maximum: a number above 0 is needed")
    return Platform(
        issuer=_text(f"{where}.issuer", t.get("issuer")),
        client_id=_text(f"{where}.client_id", t.get("client_id")),
        deployment_ids=tuple(deployments),
        auth_login_url=_url(f"{where}.auth_login_url", t.get("auth_login_url")),
        auth_token_url=_url(f"{where}.auth_token_url", t.get("auth_token_url")),
        key_set_url=_url(f"{where}.key_set_url", t.get("key_set_url")),
        score_maximum=float(maximum),
        courses=_idents(f"{where}.courses", t.get("courses")),
        assignments=_idents(f"{where}.assignments", t.get("assignments")),
    )


def parse(text: str, name: str = "lti.toml") -> LtiConfig:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{name}: not TOML: {exc}") from None
    _only(name, data, {"tool", "platform"})
    tool = data.get("tool")
    if not isinstance(tool, dict):
        raise ConfigError(f"{name}: tool: a [tool] table is needed (url, page, lab_address)")
    _only(f"{name}: tool", tool, {"url", "page", "lab_address", "grader"})
    lab_address = tool.get("lab_address")
    if not isinstance(lab_address, str) or not lab_address.startswith("wart://"):
        raise ConfigError(
            f"{name}: tool.lab_address: the address the page logs in to is needed, "
            "e.g. wart://lab.example.org:7447/lab"
        )
    grader = tool.get("grader", "grader")
    if not isinstance(grader, str) or not is_ident(grader):
        raise ConfigError(f"{name}: tool.grader: {grader!r} is not a grader's name")
    platforms = data.get("platform")
    if not isinstance(platforms, list) or not platforms:
        raise ConfigError(f"{name}: platform: at least one [[platform]] is needed")
    found = tuple(_platform(f"{name}: platform[{i}]", t) for i, t in enumerate(platforms))
    seen: set[tuple[str, str]] = set()
    for i, p in enumerate(found):
        if (p.issuer, p.client_id) in seen:
            raise ConfigError(f"{name}: platform[{i}]: {p.issuer} {p.client_id} is there twice")
        seen.add((p.issuer, p.client_id))
    return LtiConfig(
        url=_url(f"{name}: tool.url", tool.get("url")).rstrip("/"),
        page=_url(f"{name}: tool.page", tool.get("page")),
        lab_address=lab_address,
        grader=grader,
        platforms=found,
    )


def load(path: Path) -> LtiConfig:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read it: {exc}") from None
    return parse(text, str(path))
