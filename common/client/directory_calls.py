"""A logged-in user's questions to the registry about the lab and their own session:
who and what is online, and whether the session's saved login is still good.

A LabClient's part (``client.directory()``, ``client.check_resume()`` are its
calls bound as the client's own), given the realm, the client's ask and a way to
read the session's resume token.
"""

from __future__ import annotations

from collections.abc import Callable

from common import keys
from common.client.client_ask import ClientAsk
from common.lab_errors import NotLoggedIn
from common.messages import DirectoryReply, DirectoryRequest, OkReply, ResumeCheck


class DirectoryCalls:
    def __init__(self, realm: str, ask: ClientAsk, resume_token: Callable[[], bytes | None]):
        self.realm = realm
        self._ask = ask
        self._resume_token = resume_token

    def directory(self) -> DirectoryReply:
        return self._ask(
            keys.registry_directory(self.realm), DirectoryRequest(), DirectoryReply, "directory"
        )

    def check_resume(self) -> None:
        """Ask whether this session's resume token is still good; LabError in words if not.

        Asking does not use it up (a viewer asks before it hands a parked page's
        session back: viewers/web/parking.py).
        """
        token = self._resume_token()
        if token is None:
            raise NotLoggedIn("this session has no saved login")
        self._ask(
            keys.registry_directory(self.realm), ResumeCheck(token=token), OkReply, "saved login"
        )
