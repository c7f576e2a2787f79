"""A request on a session that closed under the caller fails in the lab's words.

The page's mailbox-claims thread asks the registry after a login, at low priority;
a browser that leaves meanwhile closes that client's session. The request must
end in a LabError the thread logs, not a raw Zenoh error that kills the thread
(and with it every later page user's mailbox).
"""

from __future__ import annotations

import pytest
import zenoh

from common import keys
from common.ask import QueryFailed
from common.client.lab_client import LabClient
from common.lab_errors import LabError
from common.messages import DirectoryReply, DirectoryRequest


def test_a_request_to_the_registry_on_a_closed_session_is_a_lab_error() -> None:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    client = LabClient(session, "lab", bytes(32), presence=False)
    session.close()
    with pytest.raises(LabError) as refused:
        client._ask(
            keys.registry_directory("lab"), DirectoryRequest(), DirectoryReply, "who is online",
            signed=False,
        )  # fmt: skip
    assert isinstance(refused.value, QueryFailed)
    assert str(refused.value).startswith("who is online: ")
