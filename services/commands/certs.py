"""``wart certs``: the lab's small CA and its certificates (Zenoh TLS and mutual TLS).

    wart certs init    --dir PKI                       create the CA (ca.pem, ca.key)
    wart certs host    NAME --dir PKI --address IP [--dns NAME]   the router of host NAME
    wart certs service ROLE --host NAME --dir PKI      a process role on host NAME
    wart certs client  NAME --dir PKI [--role student|admin]      a person's tool
    wart certs lab     --lab FILE                      everything the lab file needs
    wart certs list    --dir PKI                       what exists, and when it expires
    wart certs client-config --lab FILE [--name student]   Zenoh config for people's tools

The certificate's common name is the role the routers' access rules match
(router, engine, agent, registry, student...). Files: PKI/ca.pem,
PKI/<host>/<role>.{pem,key}, PKI/clients/<name>.{pem,key}; keys are 0600.
Running a command again re-issues (rotates) the certificate; see
docs/DEPLOY.md for rotation. ``lab`` also creates the registry's key and the
service accounts' identity keys (PKI/<host>/identities/) and their public
halves (PKI/accounts.json, PKI/registry.pub), so the one PKI directory made on
the operator's machine carries every secret each host needs.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from common import cli
from common.keys import is_ident
from services.lab.certs import CA_CERT, CertError, init_ca, inspect, issue
from services.lab.labfile import LabFileError, load
from services.lab.pki import issue_lab
from services.lab.zsecurity import ROLES, client_tls, zenoh_security


def _list(pki: Path) -> int:
    if not (pki / CA_CERT).exists():
        return cli.fail(f"no CA in {pki}")
    for path in sorted(pki.rglob("*.pem")):
        info = inspect(path)
        where = path.relative_to(pki)
        flag = "  EXPIRES SOON" if info.days_left() < 30 else ""
        print(
            f"{where!s:<28} CN={info.common_name:<10} until {info.not_after:%Y-%m-%d} "
            f"({info.days_left():.0f} days){flag}  {', '.join(info.alt_names)}"
        )
    return 0


def main(argv: Sequence[str] | None = None, prog: str = "wart certs") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    sub = p.add_subparsers(dest="verb", required=True)
    s_init = sub.add_parser("init", help="create the lab's CA")
    s_init.add_argument("--dir", type=Path, required=True)
    s_init.add_argument("--force", action="store_true", help="replace an existing CA (re-keys all)")
    s_host = sub.add_parser("host", help="the router certificate of a host")
    s_host.add_argument("name")
    s_host.add_argument("--dir", type=Path, required=True)
    s_host.add_argument("--address", action="append", required=True, help="IP or DNS (repeatable)")
    s_host.add_argument("--dns", action="append", default=[], help="extra DNS name (repeatable)")
    s_svc = sub.add_parser("service", help="a process role's certificate on a host")
    s_svc.add_argument("role", choices=[r for r in ROLES if r not in ("student", "admin")])
    s_svc.add_argument("--host", required=True)
    s_svc.add_argument("--dir", type=Path, required=True)
    s_svc.add_argument("--address", action="append", default=[])
    s_cli = sub.add_parser("client", help="a person's tool certificate (CN = NAME)")
    s_cli.add_argument("name")
    s_cli.add_argument("--dir", type=Path, required=True)
    s_lab = sub.add_parser("lab", help="everything a lab file needs")
    s_lab.add_argument("--lab", type=Path, required=True)
    s_conf = sub.add_parser(
        "client-config", help="print the Zenoh config (JSON5) a person's tool needs: --config FILE"
    )
    s_conf.add_argument("--lab", type=Path, required=True)
    s_conf.add_argument("--name", default="student", help="client certificate name")
    s_list = sub.add_parser("list", help="certificates and their expiry")
    s_list.add_argument("--dir", type=Path, required=True)
    args, _ = cli.parse(p, argv)
    try:
        return _run(args)
    except (CertError, LabFileError, OSError) as exc:
        return cli.fail(str(exc))


def _run(args: argparse.Namespace) -> int:
    if args.verb == "init":
        issued = init_ca(args.dir, force=args.force)
        print(f"CA created: {issued.cert} (key {issued.key}, keep it off the hosts)")
    elif args.verb == "host":
        _check_name(args.name)
        issued = issue(
            args.dir, "router", alt_names=[*args.address, *args.dns], out_dir=args.dir / args.name
        )
        print(
            f"router certificate of {args.name}: {issued.cert} (until {issued.not_after:%Y-%m-%d})"
        )
    elif args.verb == "service":
        _check_name(args.host)
        issued = issue(args.dir, args.role, alt_names=args.address, out_dir=args.dir / args.host)
        print(f"{args.role} certificate on {args.host}: {issued.cert}")
    elif args.verb == "client":
        issued = issue(args.dir, args.name, out_dir=args.dir / "clients")
        print(f"client certificate {args.name}: {issued.cert} and {issued.key}")
    elif args.verb == "lab":
        issue_lab(load(args.lab))
    elif args.verb == "client-config":
        lab = load(args.lab)
        conf = zenoh_security(client_tls(lab.security.pki, args.name), lease_ms=lab.lease_ms)
        conf["connect"] = {"endpoints": [h.endpoint for h in lab.hosts]}
        print(json.dumps(conf, indent=2))
    elif args.verb == "list":
        return _list(args.dir)
    return 0


def _check_name(name: str) -> None:

    if not is_ident(name):
        raise CertError(f"host name {name!r} is not valid (letters, digits, '_', '-', '.')")


if __name__ == "__main__":
    sys.exit(main())
