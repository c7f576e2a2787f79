"""``wart viewer``: one viser server, one Zenoh session, a WARTApp per browser.

:class:`WebViewer` is the browser side (viser server, frame pump, a
:class:`BrowserSession` per connected browser) and takes its lab connector as
a parameter, so tests and the benchmark run it on the in-memory demo lab.
:class:`ViewerService` puts it on the Zenoh network with the liveliness token
``wart/<realm>/alive/viewer/<id>``.

The actual address: viser silently takes the next port when the asked one is
busy, so the viewer prints ``viewer: http://HOST:PORT`` once it serves, and
writes the same URL to ``--url-file`` (``wart up`` reads it and prints it).
"""

from __future__ import annotations

import logging
import os
import socket
import sys
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path

import viser
import zenoh

from common import cli
from common.client.lab_address import LabAddress, SavedConnections, parse_address
from common.client.service_login import ServiceCredentials
from common.keys import AliveKind, check_ident
from common.service import Service, run_service
from common.zconfig import DEFAULT_PORT
from viewers.web.adapters import LabConnector
from viewers.web.client import BrowserSession
from viewers.web.connector import GatewayLogin, LiveConnector
from viewers.web.handover import HANDOVER_FILE, HandedOver, HandOverBook, PageJournal
from viewers.web.login import LoginDesk
from viewers.web.parking import DEFAULT_GRACE_S, ParkingLot
from viewers.web.pump import DEFAULT_RATE, FramePump
from viewers.web.saved_login import CookieDesk
from viewers.web.viser_fast import make_loop_safe, stop_dropping_pages

log = logging.getLogger("wart.viewer")

# Unsent bytes a browser's socket may hold in the kernel before the viewer stops
# writing to it (TCP_NOTSENT_LOWAT). Without it Linux autotunes a socket's send
# buffer up to net.ipv4.tcp_wmem's max (4 MiB here): a slow or stalled browser
# then has seconds of old frames queued in the kernel, and sees them in order
# (measured: 149 stale frames of 1,000 robots after a 8 s stall). With it the
# kernel holds less than one 1,000-robot frame beyond what is in flight; the rest
# waits in viser's per-client buffer, where each scene property keeps only its
# newest value, so a slow browser gets fewer, current frames and the pump (which
# only ever appends to that buffer) is never held up.
NOTSENT_LOWAT = 4 * 1024
WRITE_HIGH = 8 * 1024  # the socket's user-space buffer (websockets' default: 32 KiB)
_TCP_NOTSENT_LOWAT = getattr(socket, "TCP_NOTSENT_LOWAT", 25)  # Linux's number

PANEL_WIDTH_PX = 460  # the docked panel; 1280x800 leaves the arena 820x800


class WebViewer:
    """The viser server and every browser's session; no Zenoh in here."""

    def __init__(
        self,
        connector: LabConnector,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        default_address: LabAddress | None = None,
        data_dir: Path | None = None,
        rate: float = DEFAULT_RATE,
        label: str = "WART lab",
        logins: LoginDesk | None = None,
        reload_grace_s: float = DEFAULT_GRACE_S,
    ) -> None:
        self.connector = connector
        # A page that goes keeps its lab sessions this long for a reload (parking.py).
        self.parking = ParkingLot(reload_grace_s)
        self.cookies = CookieDesk()  # saved logins' HttpOnly cookies (saved_login.py)
        self.default_address = default_address or LabAddress("127.0.0.1")
        self.saved = SavedConnections(data_dir / "connections.json" if data_dir else None)
        # What the pages had open when the last viewer here stopped (handover.py).
        self.handovers = HandOverBook(data_dir / HANDOVER_FILE if data_dir else None)
        self.pump = FramePump(rate)
        # Logins run on these threads, never on viser's callback threads (login.py).
        self.logins = logins or LoginDesk()
        self.sessions: dict[int, BrowserSession] = {}
        self._lock = threading.Lock()
        self._stopping = False
        self.server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
        self.host = host
        self.server.gui.configure_theme(
            control_width="large", show_logo=False, show_share_button=False
        )
        # Docked at the right edge: the arena keeps the rest of a laptop screen. Wide
        # enough for a line of code and for the plots (viser's default, 384 px, cut
        # Check's excerpt and most code lines on the right); a person can drag it.
        self.server.gui.main_panel.dock_right()
        self.server.gui.main_panel.set_width(PANEL_WIDTH_PX)
        self.server.on_client_connect(self._connected)
        self.server.on_client_disconnect(self._disconnected)
        self.pump.start()
        # The book noted as the pages go, so that a crash leaves it too (handover.py).
        self.journal = PageJournal(self.handovers, self.open_pages)
        self.journal.start()

    @property
    def port(self) -> int:
        return self.server.get_port()  # the real one: viser moves on if the asked one is busy

    @property
    def url(self) -> str:
        host = self.host
        if host in ("0.0.0.0", "::", ""):
            host = socket.gethostname()
        return f"http://{host}:{self.port}"

    def _connected(self, client: viser.ClientHandle) -> None:
        if self._stopping:
            # A page reloaded during the stop: a session begun here would be cut at once,
            # and its saved login tried on a closed desk. The page finds the next viewer.
            log.info(
                "browser %d connected while the viewer stops: left for the next one",
                client.client_id,
            )
            return
        limit_send_queue(self.server, client.client_id)
        if not make_loop_safe(client):
            log.warning(
                "viser's message buffer is not the one we know: browser %d may "
                "stall under load (viewers/web/viser_fast.py)",
                client.client_id,
            )
        session = BrowserSession(
            client,
            self.connector,
            self.saved,
            self.pump,
            self.default_address,
            self.logins,
            self.parking,
            self.cookies if self._cookies_served(client) else None,
            self.handovers,
        )
        with self._lock:
            self.sessions[client.client_id] = session
        log.info("browser %d connected (%d open)", client.client_id, len(self.sessions))

    def _cookies_served(self, client: viser.ClientHandle) -> bool:
        if self.cookies.install(self.server, client.client_id):
            return True
        log.warning(
            "viser's web server is not the one we know: browser %d gets no saved login "
            "(viewers/web/saved_login.py)",
            client.client_id,
        )
        return False

    def _disconnected(self, client: viser.ClientHandle) -> None:
        with self._lock:
            session = self.sessions.pop(client.client_id, None)
        if session is not None:
            session.close()  # logs the browser's users out of every lab
        log.info("browser %d left (%d open)", client.client_id, len(self.sessions))

    def send_backlog(self, client_id: int) -> tuple[int, int] | None:
        """What waits to go to one browser: (viser messages, bytes in the socket's
        user-space buffer); None once it has gone. For tests and the benchmark."""
        ws = self.server._websock_server  # viser 1.1.1 internals, read only
        state = ws._client_state_from_id.get(viser.infra.ClientId(client_id))
        conn = ws._live_connections.get(viser.infra.ClientId(client_id))
        if state is None or conn is None:
            return None
        return len(state.message_buffer.message_from_id), conn.transport.get_write_buffer_size()

    def open_pages(self) -> list[tuple[bytes, HandedOver]]:
        """What every page with a saved login has open, parked ones included."""
        with self._lock:
            sessions = list(self.sessions.values())
        pages = self.parking.pages()
        for session in sessions:
            pages += session.open_pages()
        return pages

    def stop(self) -> None:
        """Stop serving. Lab sessions with a saved login are handed over, not logged out
        (a restart or an upgrade must not end students' runs): their pages log in again
        on the next viewer at this address; the others are logged out."""
        self._stopping = True
        self.journal.stop()  # the hand-over below writes the book's last note
        handed_over = self.parking.close()  # first: the pages closed below do not park
        self.pump.stop()
        self.logins.close()
        with self._lock:
            sessions = list(self.sessions.values())
            self.sessions.clear()
        for session in sessions:
            handed_over += session.close(viewer_stops=True)
        self.handovers.note_open(handed_over)
        if handed_over:
            log.info(
                "viewer stopping: %d lab session(s) with a saved login left running, not "
                "logged out; their pages log in again on the next viewer at this address, "
                "back in the contexts they had open, and their runs go on",
                len(handed_over),
            )
        stop_dropping_pages(self.server)  # they go to the next viewer now, not in 6 s


def limit_send_queue(server: viser.ViserServer, client_id: int) -> bool:
    """Keep a browser's kernel send queue short (see NOTSENT_LOWAT); False if not possible.

    viser 1.1.1 has no hook for its accepted sockets, so the connection is taken
    from its websocket server's table (read only); a viser without it, or a
    platform without the option, leaves the socket as it was and says so.
    """
    try:
        conn = server._websock_server._live_connections.get(viser.infra.ClientId(client_id))
        sock = conn.transport.get_extra_info("socket") if conn is not None else None
        if conn is None or sock is None:
            log.warning("browser %d: no socket to limit; slow browsers may lag", client_id)
            return False
        sock.setsockopt(socket.IPPROTO_TCP, _TCP_NOTSENT_LOWAT, NOTSENT_LOWAT)
        # Above this websockets' send() waits (and viser's producer with it, so
        # frames coalesce in viser's buffer instead of queueing in this one).
        conn.transport.set_write_buffer_limits(high=WRITE_HIGH)
        return True
    except (AttributeError, OSError) as exc:
        log.warning("browser %d: could not limit its send queue (%s)", client_id, exc)
        return False


class ViewerService(Service):
    kind = AliveKind.VIEWER

    def __init__(
        self, session: zenoh.Session, realm: str, ident: str, **viewer_args: object
    ) -> None:
        super().__init__(session, realm, ident)
        self._viewer_args = viewer_args
        self.viewer: WebViewer | None = None
        self.url_file: Path | None = None

    def on_start(self) -> None:
        self.viewer = WebViewer(**self._viewer_args)  # type: ignore[arg-type]
        announce(self.viewer.url, self.url_file)

    def on_stop(self, timeout: float) -> None:
        if self.viewer is not None:
            self.viewer.stop()  # saved logins handed over, the others logged out
        closer = getattr(self._viewer_args.get("connector"), "close", None)
        if callable(closer):
            closer()  # the other labs' sessions


def announce(url: str, url_file: Path | None) -> None:
    """Say where the page is: on stdout and, atomically, in ``url_file``."""
    print(f"viewer: {url}", flush=True)
    if url_file is None:
        return
    url_file.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=url_file.parent, prefix=".viewer-url.")
    with os.fdopen(fd, "w") as out:
        out.write(url + "\n")
    os.replace(tmp, url_file)


def default_data_dir(realm: str) -> Path:
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "wart" / realm / "viewer"


def main(argv: Sequence[str] | None = None, prog: str = "wart viewer") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument(
        "--http-port",
        type=int,
        default=8080,
        help="web port (default 8080; the next free one if busy)",
    )
    p.add_argument(
        "--host", default="127.0.0.1", help="web interface to listen on (default 127.0.0.1)"
    )
    p.add_argument("--id", default="web", help="this viewer's id in the lab (default web)")
    p.add_argument("--url-file", type=Path, help="write the page's actual URL to this file")
    p.add_argument(
        "--data-dir", type=Path, help="saved connections (default ~/.local/state/wart/REALM/viewer)"
    )
    p.add_argument("--lab-address", help="what the address bar starts with (default: this lab)")
    p.add_argument(
        "--rate",
        type=float,
        default=DEFAULT_RATE,
        help="world frames per second to each browser (default 25)",
    )
    p.add_argument(
        "--reload-grace",
        type=float,
        default=DEFAULT_GRACE_S,
        metavar="SECONDS",
        help="how long a closed or reloading page's lab session (its runs, joined arenas, "
        f"editor) is kept for it to come back (default {DEFAULT_GRACE_S:g}; 0: off)",
    )
    p.add_argument(
        "--demo",
        action="store_true",
        help="serve an in-memory demo lab (users ana/ana-pw, ben/ben-pw)",
    )
    p.add_argument(
        "--demo-robots", type=int, default=20, help="robots in the demo arena (default 20)"
    )
    p.add_argument(
        "--user",
        help="this viewer's service account (role gateway, optional): it vouches for each "
        "browser's address at login, so the registry slows failed logins per browser",
    )
    p.add_argument("--identity", type=Path, help="that account's Ed25519 key file")
    args, options = cli.parse_networked(p, argv)
    if not 0 < args.http_port < 65536:
        p.error(f"--http-port {args.http_port} is not a TCP port (1 to 65535)")
    if not 0 < args.rate <= 60:
        p.error(f"--rate {args.rate} must be between 0 and 60")
    if not 0 <= args.reload_grace <= 86400:
        p.error(f"--reload-grace {args.reload_grace:g}: give 0 (off) to 86400 seconds (a day)")
    try:
        check_ident("viewer id", args.id)
        router = options.effective_connect[0] if options.effective_connect else ""
        host, _, port = router.partition("/")[2].rpartition(":")
        default = parse_address(
            args.lab_address or f"{host or '127.0.0.1'}:{port or DEFAULT_PORT}/{options.realm}",
            default_realm=options.realm,
        )
    except ValueError as exc:
        p.error(str(exc))
    gateway_credentials = None
    if args.user and not args.demo:
        if args.identity is None:
            p.error("--user needs --identity (the account's key file)")
        try:
            gateway_credentials = ServiceCredentials.from_options(
                options.registry_key, args.user, args.identity, "viewer"
            )
        except (ValueError, OSError) as exc:
            p.error(str(exc))
    data_dir: Path = args.data_dir or default_data_dir(options.realm)
    if not args.demo and not options.registry_key:
        p.error(
            "--registry-key is required: the viewer must know its lab's registry key to check "
            "logins (wart up passes it; or use --demo)"
        )

    def build(session: zenoh.Session) -> Service:
        connector: LabConnector
        if args.demo:
            from viewers.web.demo_lab import DemoConnector, DemoLab  # --demo only

            lab = DemoLab("Demo lab", robots=args.demo_robots)
            connector = DemoConnector((default.realm, lab))
        else:
            # The gateway: this process's one session to its own lab, and a
            # LabClient per logged-in browser user on it (viewers/web/live.py).
            gateway = None
            if gateway_credentials is not None:
                gateway = GatewayLogin(session, options.realm, gateway_credentials)
            connector = LiveConnector(
                session, default, options.registry_key, data_dir=data_dir, gateway=gateway
            )
        service = ViewerService(
            session,
            options.realm,
            args.id,
            connector=connector,
            host=args.host,
            port=args.http_port,
            default_address=default,
            data_dir=data_dir,
            rate=args.rate,
            reload_grace_s=args.reload_grace,
        )
        service.url_file = args.url_file
        return service

    return run_service("viewer", options, build)


if __name__ == "__main__":
    sys.exit(main())
