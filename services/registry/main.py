"""``wart registry``: the command line; what the service does is service.py's docstring."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from common import cli
from common.auth import (
    key_fingerprint,
)
from common.service import run_service
from services.registry import service
from services.registry.accounts_db import RegistryDB, provision
from services.registry.service import Registry
from services.registry.throttle import LoginThrottle


def main(argv: Sequence[str] | None = None, prog: str = "wart registry") -> int:
    p = cli.parser(prog, service.__doc__ or "")
    p.add_argument("--db", type=Path, required=True, help="the SQLite database (created if absent)")
    p.add_argument(
        "--key-file",
        type=Path,
        required=True,
        help="the registry's Ed25519 key (created if absent; keep it secret)",
    )
    p.add_argument("--name", help="rename the server (shown in the directory)")
    p.add_argument(
        "--login-wait",
        type=float,
        default=2.0,
        metavar="SECONDS",
        help="after a source's free failed logins, how long it waits; each further failure"
        " doubles it, up to 300 s (default 2)",
    )
    args, options = cli.parse_networked(p, argv)
    try:
        throttle = LoginThrottle(first_wait=args.login_wait)
    except ValueError as exc:
        return cli.fail(f"--login-wait: {exc}")
    try:
        identity, password, created = provision(args.db, args.key_file)
    except (ValueError, OSError) as exc:
        return cli.fail(str(exc))
    key_hex = identity.verify_key.hex()
    if options.registry_key and options.registry_key.lower() != key_hex:
        return cli.fail(
            f"--registry-key does not match the key in {args.key_file} "
            f"(that key's fingerprint is {key_fingerprint(identity.verify_key)})"
        )
    say = "created" if created else "loaded"
    print(f"registry key {say}: {key_hex}", flush=True)
    print(f"  fingerprint {key_fingerprint(identity.verify_key)}; pin it with --registry-key")
    if password is not None:
        print(
            f"first start: created user 'admin' with password {password}\n"
            f"  (also written to {args.db.parent / 'admin-password.txt'}); log in with\n"
            f"  wart chat lobby --user admin --registry-key {key_hex}",
            flush=True,
        )
    db = RegistryDB(args.db)
    if args.name:
        db.set_setting("server_name", args.name)
    try:
        return run_service(
            "registry",
            options,
            lambda session: Registry(session, options.realm, db, identity, throttle=throttle),
        )
    finally:
        db.close()


if __name__ == "__main__":
    sys.exit(main())
