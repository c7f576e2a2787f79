"""``wart kube``: a lab file's host on Kubernetes (or podman), and what its pods run.

    wart kube render --lab lab.toml --name K > lab.yaml     # kubectl apply -f lab.yaml
    wart kube render --lab lab.toml --name K --out k8s/     # a file per object, kustomization
    wart kube render --lab lab.toml --name K --mode podman > pods.yaml  # podman kube play
    wart kube provision ... -- registry ...   # the registry pod: its database, then it

The cluster plays one host of the lab file (its router, its services): run
``wart certs lab`` first (the host's ``names`` list ``wart-router``, the name
pods reach the router by). docs/DEPLOY.md, "On Kubernetes", says the rest.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from common import cli
from services.lab import provision
from services.lab.kube.manifests import MODES, PARTS, KubeOptions, render
from services.lab.kube.yamlout import dump, dump_all
from services.lab.labfile import LabFileError, load


def _render(args: argparse.Namespace) -> int:
    options = KubeOptions(
        image=args.image,
        namespace=args.namespace,
        mode=args.mode,
        state_size=args.state_size,
        storage_class=args.storage_class,
        part=args.part,
        router_service_type=args.router_service,
    )
    try:
        rendered = render(load(args.lab), args.name, options)
    except (LabFileError, OSError, ValueError) as exc:
        return cli.fail(str(exc))
    for why in rendered.skipped:
        print(f"not rendered: {why}", file=sys.stderr)
    if args.out is None:
        sys.stdout.write(dump_all(rendered.objects))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    names = []
    for obj in rendered.objects:
        name = f"{obj['kind'].lower()}-{obj['metadata']['name']}.yaml"
        (args.out / name).write_text(dump(obj))
        names.append(name)
    kustomization = {
        "apiVersion": "kustomize.config.k8s.io/v1beta1",
        "kind": "Kustomization",
        "resources": names,
    }
    (args.out / "kustomization.yaml").write_text(dump(kustomization))
    print(f"{len(names)} objects in {args.out} (and its kustomization.yaml)", file=sys.stderr)
    return 0


def _provision(args: argparse.Namespace) -> int:
    try:
        expected = args.registry_pub_file.read_text().strip()
        done = provision.provision_registry_host(
            args.state_dir, args.registry_key_file, args.accounts, expected
        )
    except (LabFileError, OSError, ValueError) as exc:
        return cli.fail(str(exc))
    if done.admin_password is not None:
        print(
            f"first start: user 'admin', password {done.admin_password} "
            f"(kept in {args.state_dir / 'admin-password.txt'})",
            flush=True,
        )
    else:
        print(f"registry database in {args.state_dir} is ready", flush=True)
    then = [a for a in args.then if a != "--"]
    if not then:
        return 0
    # This process becomes the command (the registry): its signals, its exit status.
    os.execv(sys.executable, [sys.executable, "-m", "services.cli", *then])


def main(argv: Sequence[str] | None = None, prog: str = "wart kube") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    sub = p.add_subparsers(dest="verb", required=True)
    r = sub.add_parser("render", help="a lab file's host as Kubernetes objects (YAML)")
    r.add_argument("--lab", type=Path, required=True, help="the lab file")
    r.add_argument("--name", required=True, help="the host of the lab file the cluster plays")
    r.add_argument("--mode", choices=MODES, default="kubernetes", help="podman: pods it can play")
    r.add_argument("--image", default="localhost/wart:latest", help="the image (deploy/container)")
    r.add_argument("--namespace", default="wart", help="the namespace (default wart)")
    r.add_argument("--state-size", default="1Gi", help="each stateful service's volume")
    r.add_argument("--storage-class", help="the volumes' storage class (default: the cluster's)")
    r.add_argument(
        "--router-service",
        choices=("ClusterIP", "NodePort", "LoadBalancer"),
        default="ClusterIP",
        help="the router Service's type (NodePort/LoadBalancer: students' tools outside)",
    )
    r.add_argument(
        "--part",
        choices=PARTS,
        default="all",
        help="workloads: without what comes from the lab's PKI (its ConfigMap wart-lab, the "
        "Secrets of certificates and keys), to keep in git; pki: only that (default all)",
    )
    r.add_argument("--out", type=Path, help="a directory: one file per object (default stdout)")
    v = sub.add_parser("provision", help="the registry's database: admin, service accounts")
    v.add_argument("--state-dir", type=Path, required=True)
    v.add_argument("--registry-key-file", type=Path, required=True)
    v.add_argument("--accounts", type=Path, required=True, help="accounts.json of wart certs lab")
    v.add_argument(
        "--registry-pub-file", type=Path, required=True, help="registry.pub of wart certs lab"
    )
    v.add_argument(
        "then",
        nargs=argparse.REMAINDER,
        metavar="-- COMMAND",
        help="then become `wart COMMAND ...` (wart kube provision ... -- registry ...)",
    )
    args, _ = cli.parse(p, argv)
    if args.verb == "render":
        return _render(args)
    return _provision(args)
