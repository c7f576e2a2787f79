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

import json
import time

from common.client.lab_address import LabAddress
from common.client.resume_cookie import PREFIX, cookie_name, cookie_value
from common.messages import MessageError, ResumeGrant, SignedResume, decode


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
