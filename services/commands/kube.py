"""``wart kube``: a lab file's host on Kubernetes (or podman), and what its pods run.

    wart kube render --lab lab.toml --name K > lab.yaml     # kubectl apply -f lab.yaml
    wart kube render --lab lab.toml --name K --out k8s/     # a file per object, kustomization
    wart kube render --lab lab.toml --name K --mode podman > pods.yaml  # podman kube play
    wart kube provision ... -- registry ...   # the registry pod: its database, then it
    wart kube host --lab lab.toml --name K    # the cluster's host: arenas on request as pods

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

from common import cli, keys
from common.service import close_session, open_session, stop_on_signals
from common.zconfig import ConfigError, NetworkOptions, add_network_arguments, options_from_args
from services.lab import provision
from services.lab.kube.manifests import MODES, PARTS, KubeOptions, Renderer, render
from services.lab.kube.objects import object_name
from services.lab.kube.yamlout import dump, dump_all
from services.lab.labfile import LabFileError, load
from services.lab.supervisor import AliveWatch, Supervisor


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


def _host(args: argparse.Namespace, options: NetworkOptions) -> int:
    # Here, not at the top: the kubernetes package is an optional dependency (the
    # `kubernetes` extra, in the image), needed only by a lab in a cluster.
    try:
        from kubernetes import client as k8s
        from kubernetes import config as k8s_config

        # it imports kubernetes too (the same reason)
        from services.lab.kube.arenas import ArenaWorkloads, ClusterHosting, ClusterPlan
        from services.lab.kube.runner_scale import RunnerScaler
    except ImportError:
        return cli.fail(
            "wart kube host needs the kubernetes package: pip install 'wart-lab[kubernetes]'"
        )
    if not options.registry_key:
        return cli.fail("the registry's public key is needed: --registry-key or WART_REGISTRY_KEY")
    try:
        lab = load(args.lab)
        host = lab.host(args.name)
        renderer = Renderer(lab, host, KubeOptions(image=args.image, namespace=args.namespace))
    except (LabFileError, OSError, ValueError) as exc:
        return cli.fail(str(exc))
    if args.api_server:
        conf = k8s.Configuration()
        conf.host = args.api_server
        api = k8s.ApiClient(conf)
    else:
        try:
            k8s_config.load_incluster_config()  # the pod's service account
        except k8s_config.ConfigException:
            k8s_config.load_kube_config()  # an operator's machine
        api = k8s.ApiClient()
    stop = stop_on_signals()
    try:
        session = open_session(options, stop=stop)
    except ConnectionError as exc:
        return cli.fail(str(exc), code=1)
    supervisor = Supervisor(args.state_dir / "logs")
    supervisor.watch = AliveWatch(session, keys.alive_all(lab.realm))
    plan = ClusterPlan(
        wiring=renderer.wiring,
        registry_key=options.registry_key,
        limits=lab.limits,
        no_arenas_reason="" if host.arenas else "this host takes no arenas (arenas = false)",
        local_dir=args.state_dir,
    )
    hosting = ClusterHosting(session, plan, supervisor, ArenaWorkloads(renderer, api)).start()
    for svc in host.services:  # the lab file's own arenas: listed, never stopped on request
        if svc.kind == "engine":
            world, robots = str(svc.params["world"]), int(svc.params.get("robots", 0))
            hosting.adopt(world, str(svc.params["map"]), [], robots)
    scaled = {object_name("runner", s.ident): sc for s in host.services if (sc := s.scale)}
    scaler = None
    if scaled:
        scaler = RunnerScaler(
            session, lab.realm, api, args.namespace, scaled, period=args.scale_period
        ).start()
    print(
        f"host {host.name} of lab '{lab.realm}': arenas on request are workloads in "
        f"namespace {args.namespace} ({api.configuration.host})"
        + (f"; runners scaled on the grader's queue: {', '.join(scaled)}" if scaled else ""),
        flush=True,
    )
    stop.wait()
    if scaler is not None:
        scaler.stop()
    hosting.stop()
    supervisor.watch.close()
    close_session(session)
    return 0


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
    h = sub.add_parser("host", help="arenas on request as workloads (the cluster's host pod)")
    h.add_argument("--lab", type=Path, required=True, help="the lab file")
    h.add_argument("--name", required=True, help="the host of the lab file the cluster plays")
    h.add_argument("--image", default="localhost/wart:latest", help="the arenas' image")
    h.add_argument("--namespace", default="wart", help="where arenas are made (default wart)")
    h.add_argument(
        "--api-server",
        metavar="URL",
        help="the Kubernetes API's address (default: the pod's service account, else kubeconfig)",
    )
    h.add_argument(
        "--state-dir", type=Path, default=Path("/var/lib/wart"), help="its own files (maps made)"
    )
    h.add_argument(
        "--scale-period",
        type=float,
        default=5.0,
        help="seconds between two looks at the grader's queue (scaled runners; default 5)",
    )
    add_network_arguments(h)
    args, _ = cli.parse(p, argv)
    if args.verb == "render":
        return _render(args)
    if args.verb == "host":
        try:
            options = options_from_args(args)
        except ConfigError as exc:
            return cli.fail(str(exc))
        if not 0.1 <= args.scale_period <= 3600:
            return cli.fail(f"--scale-period: {args.scale_period} is out of range (0.1 to 3600)")
        return _host(args, options)
    return _provision(args)
