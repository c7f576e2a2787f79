"""The resume cookie: a lab's address and the registry's resume token, as a browser keeps them.

The web page sets it after a password login and logs in with it again on a reload
(viewers/web/saved_login.py); the LTI tool sets it on a launch, so the student
arrives logged in (services/lti/service.py). One format for both, here.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
from dataclasses import dataclass

from common.client.lab_address import AddressError, LabAddress, parse_address

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
