"""``wart throttles``: the registry's login throttles, and clearing them (admins).

Failed logins are counted per account, per (account, source), per source and per
network of the addresses the viewer vouches for (docs/SECURITY.md "Failed logins").
This lists every count with the wait it imposes now, and forgets one account's
(``--unlock``: its own failures and those of the sources that made them) or one
source's or network's (``--clear``, the key as listed). Each clearing lands in the
audit trail.

    wart throttles --user admin
    wart throttles --user admin --unlock alice
    wart throttles --user admin --clear viewer-web:10.0.0.0/24

The password comes from --password-file, WART_PASSWORD or a prompt.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from common import cli, keys
from common.zconfig import NetworkOptions
from services.commands.arena import add_lab_arguments, lab_login, run_lab_command


def main(argv: Sequence[str] | None = None, prog: str = "wart throttles") -> int:
    p = cli.parser(prog, __doc__ or "")
    add_lab_arguments(p)
    p.add_argument("--user", required=True, help="an account with the admin permission")
    p.add_argument("--password-file", help="read the password from this file")
    verb = p.add_mutually_exclusive_group()
    verb.add_argument("--unlock", metavar="ACCOUNT", help="forget the account's failed logins")
    verb.add_argument("--clear", metavar="SOURCE", help="forget one source's or network's")
    return run_lab_command(p, argv, _run)


def _run(args: argparse.Namespace, options: NetworkOptions) -> int:
    # Everything typed is checked before the network is touched.
    if args.unlock:
        keys.check_ident("account", args.unlock)
    if args.clear is not None and not 0 < len(args.clear) <= 256:
        raise ValueError("--clear: a source as listed (1 to 256 characters)")
    with lab_login(args, options) as client:
        if args.unlock:
            print(client.unlock_logins(args.unlock))
        elif args.clear:
            print(client.clear_throttle(args.clear))
        else:
            throttles = client.throttles()
            for t in throttles:
                wait = f"waits {t.wait_s:.0f} s" if t.wait_s > 0 else "not slowed"
                print(f"{t.kind:<8} {t.key:<48} {t.failures:>5} failed  {wait}")
            if not throttles:
                print("no failed logins")
    return 0


if __name__ == "__main__":
    sys.exit(main())
