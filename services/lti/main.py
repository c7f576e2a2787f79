"""``wart lti``: the command line; what the service does is service.py's docstring."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import zenoh

from common import cli
from common.client.service_login import ServiceCredentials
from common.service import run_service
from services.lti import service
from services.lti.config import ConfigError, load
from services.lti.service import LtiService
from services.lti.store import LtiStore
from services.lti.tool_key import load_or_create

REGISTER = """
Registering the tool in an LMS (the URLs are the [tool] url of the config + a path):
  Moodle (Site administration > Plugins > Activity modules > External tool >
  Manage tools > configure a tool manually): LTI version "LTI 1.3";
    Tool URL and Redirection URI(s)   <url>/lti/launch
    Initiate login URL                <url>/lti/login
    Public key type "Keyset URL":     <url>/lti/jwks
    Services: IMS LTI Assignment and Grade Services "Use this service for grade sync
    and column management"; Privacy: share the launcher's name (and email) with the tool;
    Custom parameters (per activity, optional): assignment=NAME
  Moodle then shows Platform ID (issuer), Client ID, Deployment ID, Public keyset URL
  (key_set_url), Access token URL (auth_token_url) and Authentication request URL
  (auth_login_url): copy them into a [[platform]] of the config.
  Canvas (Admin > Developer Keys > + LTI Key, method "Manual Entry"):
    Redirect URIs and Target Link URI <url>/lti/launch
    OpenID Connect Initiation Url     <url>/lti/login
    JWK Method "Public JWK URL":      <url>/lti/jwks
    LTI Advantage Services: "Can create and update submission results" (score)
  Canvas's issuer is https://canvas.instructure.com; its auth_login_url is
  <canvas>/api/lti/authorize_redirect, auth_token_url <canvas>/login/oauth2/token,
  key_set_url <canvas>/api/lti/security/jwks; the client_id is the developer key's id
  and the deployment id is shown when the key is added to a course or account.
The page and this tool must share a host name (cookies ignore the port): the launch
sets the page's saved-login cookie and sends the browser to [tool] page.
"""


def main(argv: Sequence[str] | None = None, prog: str = "wart lti") -> int:
    p = cli.parser(prog, (service.__doc__ or "") + REGISTER)
    cli.add_account_arguments(
        p, "lti", "the service's id (default lti)", "its service account (role 'lti')"
    )
    p.add_argument(
        "--platforms",
        type=Path,
        required=True,
        help="the platforms file (TOML; see docs/COURSES.md)",
    )
    p.add_argument(
        "--state-dir",
        type=Path,
        required=True,
        help="where the tool's RSA key (lti-tool-key.pem, 0600) and its database live",
    )
    p.add_argument("--http-host", default="127.0.0.1", help="address to serve on (127.0.0.1)")
    p.add_argument("--http-port", type=int, default=8090, help="port to serve on (8090)")
    args, options = cli.parse_networked(p, argv)
    try:
        credentials = ServiceCredentials.of_service("lti", args, options)
        config = load(args.platforms)
        key, made = load_or_create(args.state_dir / "lti-tool-key.pem")
    except (ValueError, ConfigError) as exc:
        return cli.fail(str(exc))
    if not 0 <= args.http_port <= 65535:
        return cli.fail("--http-port must be 0..65535")
    if made:
        print(f"made the tool's key {args.state_dir / 'lti-tool-key.pem'} (kid {key.kid})")
    print(f"LTI tool: login {config.login_url}, launch {config.launch_url}, keys {config.jwks_url}",
          flush=True)  # fmt: skip
    store = LtiStore(args.state_dir / "lti.db")

    def build(session: zenoh.Session) -> LtiService:
        login = credentials.login(session, options.realm, f"lti {args.name}")
        return LtiService(
            session,
            options.realm,
            args.name,
            config=config,
            login=login,
            registry_key=credentials.registry_key,
            store=store,
            key=key,
            http_host=args.http_host,
            http_port=args.http_port,
        )

    try:
        return run_service(f"lti {args.name}", options, build)
    finally:
        store.close()


if __name__ == "__main__":
    sys.exit(main())
