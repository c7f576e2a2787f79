"""A saved login in the browser: the registry's resume token kept in a cookie.

After a password login the page gets a cookie holding the lab's address and the
registry's resume token (services/registry/resume.py); when the page is loaded
again (a reload, a new tab) the browser sends it with the websocket handshake and
the viewer logs it in again without a password check. The cookie is set by a
script in the page (viser has no way to set one on its HTTP responses), so it is
not HttpOnly: the page runs no script but the viewer's own. It is SameSite=Strict
(another site's page cannot make the browser send it), path /, and lasts as long
as the token. The person's "Log out" deletes it and revokes the token; closing the
page does neither.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import time
from dataclasses import dataclass

from common.messages import MessageError, ResumeGrant, SignedResume, decode
from viewers.web.address import AddressError, LabAddress, parse_address

PREFIX = "wart_resume_"
MAX_COOKIES = 8  # saved logins tried at one page load (one per lab: a handful at most)


@dataclass(frozen=True)
class SavedLogin:
    address: LabAddress
    token: bytes


def cookie_name(address: LabAddress) -> str:
    """One cookie per lab (host, port, realm): a login to another lab keeps its own."""
    digest = hashlib.blake2b(repr(address.lab_key).encode(), digest_size=6).hexdigest()
    return PREFIX + digest


def _b64(data: bytes) -> str:
    return base64.urlsafe_b64encode(data).decode().rstrip("=")


def _unb64(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def cookie_value(address: LabAddress, token: bytes) -> str:
    """``<address>.<token>``, each base64url: no character a cookie or a script quotes."""
    return f"{_b64(address.url().encode())}.{_b64(token)}"


def parse_cookies(header: str, default_realm: str) -> list[SavedLogin]:
    """The saved logins in a Cookie header; a damaged one is skipped (it is the browser's)."""
    found: list[SavedLogin] = []
    for part in header.split(";"):
        name, _, value = part.strip().partition("=")
        if not name.startswith(PREFIX) or "." not in value:
            continue
        url, _, token = value.partition(".")
        try:
            address = parse_address(_unb64(url).decode(), default_realm=default_realm)
            raw = _unb64(token)
        except (AddressError, ValueError, UnicodeDecodeError, binascii.Error):
            continue
        if name == cookie_name(address) and raw and address.user:
            found.append(SavedLogin(address, raw))
        if len(found) >= MAX_COOKIES:
            break
    return found


def cookie_script(name: str, value: str, max_age: int) -> str:
    """HTML whose image's ``onerror`` sets (or, with max_age 0, deletes) one cookie."""
    if not name.startswith(PREFIX) or not all(c.isalnum() or c in "_-." for c in name + value):
        raise ValueError("a saved-login cookie is base64url text only")
    cookie = f"{name}={value}; path=/; max-age={max(0, int(max_age))}; SameSite=Strict"
    # The name and value are checked above to be [A-Za-z0-9_.-]: nothing to escape.
    script = f"document.cookie={json.dumps(cookie)}"
    return f'<img src="data:," alt="" style="display:none" onerror=\'{script}\'>'


def saved_login_html(address: LabAddress, token: bytes | None, serial: int) -> str:
    """The page element that saves ``token`` for ``address``'s lab (None: forgets it).

    ``serial`` changes the markup each time, so the page replaces the element and
    its image's ``onerror`` runs again.
    """
    name = cookie_name(address)
    if token is None:
        return f"<!-- {serial} -->" + cookie_script(name, "", 0)
    try:
        ends = decode(decode(token, SignedResume).grant, ResumeGrant).expires_at
    except MessageError:
        return f"<!-- {serial} -->" + cookie_script(name, "", 0)
    value = cookie_value(address, token)
    return f"<!-- {serial} -->" + cookie_script(name, value, int(ends - time.time()))
