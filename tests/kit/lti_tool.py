"""The lab's LTI tool (``wart lti``) on a test lab, facing a FakePlatform."""

from __future__ import annotations

from pathlib import Path

from common.auth import create_identity_key
from services.lab import wiring
from services.registry.accounts_db import RegistryDB
from tests.kit.lab import ProcessLab
from tests.kit.lti_platform import FakePlatform
from tests.kit.procs import free_port

LTI_ACCOUNT = wiring.service_account("lti", "lti")
PAGE = "http://127.0.0.1:8080/"


def start_lti(
    lab: ProcessLab, tmp: Path, platform: FakePlatform, page: str = PAGE, lab_address: str = ""
) -> str:
    """The lti service's account (role lti), its platforms file, the process; its URL."""
    key = create_identity_key(lab.wiring().identity(LTI_ACCOUNT))
    db = RegistryDB(lab.db_path)
    db.add_user(LTI_ACCOUNT, ["lti"], public_key=bytes(key.verify_key))
    db.close()
    port = free_port()
    tool = f"http://127.0.0.1:{port}"
    platform.tool_jwks_url = f"{tool}/lti/jwks"
    config = tmp / "lti.toml"
    config.write_text(
        "[tool]\n"
        f'url = "{tool}"\n'
        f'page = "{page}"\n'
        f'lab_address = "{lab_address or f"wart://127.0.0.1:{lab.router.port}/{lab.realm}"}"\n\n'
        + platform.toml({"link-1": "reach-goal"})
    )
    lab.start(wiring.lti_spec(lab.wiring(), config, http_port=port), name="lti")
    return tool
