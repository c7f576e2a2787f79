"""One browser's WARTApp: the address bar, its tabs, its labs, its world view.

Everything here is per viser client, so one person's login form, labs and
instructor buttons never show in another's page.
"""

from __future__ import annotations

import html
import logging
import threading
import time

import viser

from common.client.lab_address import (
    AddressError,
    LabAddress,
    SavedConnections,
    complete,
    parse_address,
)
from common.client.resume_cookie import SavedLogin, parse_cookies
from viewers.web.adapters import LabConnection, LabConnector, LoginError, LoginUnavailable
from viewers.web.arena_video import ArenaVideo
from viewers.web.chat_panel import ARENA_KINDS, ChatPanel
from viewers.web.front_tab import FrontTab
from viewers.web.handover import HandedOver, HandOverBook
from viewers.web.inputs import set_value
from viewers.web.labels import add_label_fixer
from viewers.web.lobby import LabTab
from viewers.web.login import LoginDesk, LoginForm
from viewers.web.page_style import add_page_style
from viewers.web.parking import ParkedLab, ParkingLot
from viewers.web.pump import FramePump
from viewers.web.run_output import as_html
from viewers.web.saved_login import CookieDesk, saved_login_cookie
from viewers.web.sure_clicks import add_sure_clicks
from viewers.web.tabs import PageTitle, TabSwitcher, tab_title
from viewers.web.text import escape_md
from viewers.web.viser_fast import browser_address, browser_cookies, browser_origin
from viewers.web.workbench import BenchMemory
from viewers.web.world_feed import WorldFeed
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.client")

# Reloads the page: the other tab's new login reaches the shared cookie once that tab has
# fetched its ticket, which a busy page can take seconds to do; so up to 3 times, 2, 4
# and 8 s apart, within a minute (a loop of reloads would hide the password form).
RELOAD_ONCE_JS = (
    "(() => { const key = 'wart-reloaded-for-saved-login';"
    " let seen = JSON.parse(sessionStorage.getItem(key) || '[]');"
    " seen = seen.filter(t => Date.now() - t < 60000);"
    " if (seen.length >= 3) return;"
    " seen.push(Date.now()); sessionStorage.setItem(key, JSON.stringify(seen));"
    " setTimeout(() => location.reload(), 2000 * 2 ** (seen.length - 1)); })()"
)
RELOAD_ONCE_HTML = (
    f'<img src="data:," alt="" style="display:none" onerror="{html.escape(RELOAD_ONCE_JS)}">'
)

NO_SAVED = "(saved and recent addresses)"
TITLE = "WART lab"  # the browser tab's title, after the lab's name once logged in
HELP = """### Welcome to the WART lab
Type a lab's address above and press **Connect**, e.g.
`wart://you@lab.example.org/lab` or just `lab.example.org`.
You can be connected to several labs at once: each gets its own tab."""


class BrowserSession:
    def __init__(
        self,
        client: viser.ClientHandle,
        connector: LabConnector,
        saved: SavedConnections,
        pump: FramePump,
        default_address: LabAddress,
        logins: LoginDesk,
        parking: ParkingLot | None = None,
        cookies: CookieDesk | None = None,
        handovers: HandOverBook | None = None,
    ) -> None:
        self.client = client
        self.handovers = handovers
        # Sets and deletes saved logins (saved_login.py); None: this viewer saves none.
        self.cookies = cookies
        # (not `parking or ...`: an empty lot has no length, and is falsy)
        self.parking = parking if parking is not None else ParkingLot(grace_s=0)
        self.logins = logins
        self.connector = connector
        self.saved = saved
        self.pump = pump
        self.default = default_address
        self.labs: dict[tuple[str, int, str], LabTab] = {}
        self.login: LoginForm | None = None
        self.watching: ChatPanel | None = None
        self._lock = threading.RLock()
        self.closed = False
        gui = client.gui
        # The page reaches the browser once its handlers are registered (see LoginForm).
        with client.atomic():
            self._build(gui, default_address)
        self.view = WorldView(client)
        self.video = ArenaVideo(self.view)  # a real arena's camera under its robots
        pump.attach(self.view)
        self._refresh_recent()
        for kept in parse_cookies(browser_cookies(client), default_address.realm):
            self._resume(kept)

    def _build(self, gui: viser.GuiApi, default_address: LabAddress) -> None:
        add_label_fixer(gui)  # every labelled input gets its accessible name (labels.py)
        add_sure_clicks(gui)  # clicks and values viser's page drops are sent (sure_clicks.py)
        add_page_style(gui)  # wide tables scroll; the panel's edge shows its grip
        self.address = gui.add_text(
            "Address", default_address.url(), hint="wart://user@host:port/realm[/context]"
        )
        self.recent = gui.add_dropdown("Saved", (NO_SAVED,))
        with gui.add_folder("Address actions", expand_by_default=True):
            self.connect_button = gui.add_button("Connect", color="green", icon=viser.Icon.PLUG)
            self.save_button = gui.add_button("Save address", icon=viser.Icon.STAR)
        self.notice = gui.add_markdown("", visible=False)
        self._cookie = gui.add_html("")  # fetches the cookie's ticket (saved_login.py)
        self._cookies_set = 0
        self.tabs = gui.add_tab_group()
        self.home = self.tabs.add_tab("Start", icon=viser.Icon.INFO_CIRCLE)
        with self.home:
            gui.add_markdown(HELP)
        self.switcher = TabSwitcher(gui)  # takes the page to a new lab's or arena's tab
        self.title = PageTitle(gui, TITLE)
        # The world view follows the arena tab in front (front_tab.py).
        self.front = FrontTab(gui, self._front_changed)
        self.connect_button.on_click(lambda _: self.connect(self.address.value))
        self.save_button.on_click(lambda _: self.save_address())
        self.recent.on_update(lambda _: self._recent_chosen())
        self.address.on_update(lambda _: self._complete())

    # -- address bar

    def say_notice(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    def _candidates(self) -> list[str]:
        seen: list[str] = []
        for tab in list(self.labs.values()):
            for url in self.saved.for_user(tab.connection.user):
                if url not in seen:
                    seen.append(url)
        default = self.default.url()
        return seen if default in seen else [*seen, default]

    def _refresh_recent(self, typed: str = "") -> None:
        options = complete(typed, self._candidates()) if typed else self._candidates()
        self.recent.options = (NO_SAVED, *options)

    def _complete(self) -> None:
        self._refresh_recent(self.address.value)

    def _recent_chosen(self) -> None:
        if self.recent.value != NO_SAVED:
            set_value(self.address, self.recent.value)

    def save_address(self) -> None:
        try:
            address = parse_address(self.address.value, default_realm=self.default.realm)
        except AddressError as exc:
            self.say_notice(str(exc))
            return
        tab = self.labs.get(address.lab_key)
        users = [tab.connection.user] if tab else [t.connection.user for t in self.labs.values()]
        if not users:
            self.say_notice("Log in first: saved addresses are kept for your user.")
            return
        for user in users:
            self.saved.save(user, address)
        self.notice.visible = False
        self._refresh_recent()

    def connect(self, text: str) -> None:
        try:
            address = parse_address(text, default_realm=self.default.realm)
        except AddressError as exc:
            self.say_notice(str(exc))
            return
        self.notice.visible = False
        tab = self.labs.get(address.lab_key)
        if tab is not None:
            if address.context:
                tab.join(address.context)
            else:
                self.say_notice(f"You are already connected to {address.label}.")
            return
        login = self.login
        if login is not None and not login.closed:
            if login.address.lab_key == address.lab_key:
                # A second click on a slow page: the form being typed into stays.
                return
            login.close()
        self.login = LoginForm(
            self.client,
            self.connector,
            address,
            lambda conn: self._logged_in(conn, address),
            self.logins,
        )

    def _resume(self, saved: SavedLogin) -> None:
        """Log in again with the saved login this browser sent (a reload): no password."""
        address = saved.address
        self.say_notice(f"Logging in again to {address.label} as {address.user} (saved login)...")

        def run() -> None:
            parked = self.parking.claim(address.lab_key, address.user or "", saved.token)
            try:
                kept = parked is not None and self.parking.still_good(parked)
            except LoginUnavailable as exc:  # still parked: the next load may take it
                self._resume_failed(address, str(exc), refused=False)
                return
            if parked is not None and kept:
                # A reload within the grace: the same session, its runs and tabs, no login.
                self.notice.visible = False
                self._logged_in(parked.connection, address, kept=parked)
                return
            began = time.monotonic()
            try:
                connection = self.connector.resume(
                    address,
                    saved.token,
                    via=f"browser-{self.client.client_id}",
                    seen_from=browser_address(self.client),
                )
            except (LoginUnavailable, OSError, TimeoutError) as exc:
                self._resume_failed(address, str(exc), refused=False)
                return
            except LoginError as exc:
                self._resume_failed(address, str(exc))
                return
            log.info(
                "browser %d: %s logged in again to %s with a saved login after %.1f s",
                self.client.client_id,
                connection.user,
                address.label,
                time.monotonic() - began,
            )
            self.notice.visible = False
            books = self.handovers
            reopen = books.take(saved.token, connection.user) if books is not None else None
            self._logged_in(connection, address, reopen=reopen)

        def too_late() -> None:
            why = "this viewer is busy, many people are logging in at once"
            self._resume_failed(address, why, refused=False)

        self.logins.submit(run, too_late)

    def _resume_failed(self, address: LabAddress, why: str, *, refused: bool = True) -> None:
        """The password form, with why. ``refused=False``: the lab could not answer now (down,
        busy); the saved login was not refused and stays for the next load."""
        client_id = self.client.client_id
        if refused:
            log.info("browser %d: saved login to %s refused: %s", client_id, address.label, why)
        else:
            log.info(
                "browser %d: saved login to %s not tried now: %s", client_id, address.label, why
            )
        if refused and "(used" not in why:
            # A used token: another tab of this browser resumed with it first and saved
            # its new one under the same name, which a deletion would take away.
            self._save_login(address, None)
        if self.closed:
            return
        self.connect(address.url())  # the password form, for that lab and user
        words = f"Could not log in again with your saved login: {why}"
        if not refused:
            words += ". It is kept: reload the page in a minute, or log in with your password"
        elif "(used" in why:
            # Another tab of this browser came back first with the same cookie and stored
            # the login it was given: a reload sends that one (RELOAD_ONCE_JS: up to 3 times).
            words = (
                "Another tab of this browser logged in again first with this saved login: "
                "this tab reloads to use the one it was given. If it does not, log in with "
                "your password"
            )
            self._cookie.content = RELOAD_ONCE_HTML
        if self.login is not None:
            self.login.show_error(words)
        else:
            self.say_notice(words)

    def _save_login(self, address: LabAddress, token: bytes | None) -> None:
        """Keep (or with None, forget) this lab's saved login in the browser's cookie."""
        if self.cookies is None:
            return
        self._cookies_set += 1
        secure = browser_origin(self.client).startswith("https://")
        cookie = saved_login_cookie(address, token, secure=secure)
        self._cookie.content = self.cookies.html(cookie, self._cookies_set)

    def _logged_in(
        self,
        connection: LabConnection,
        address: LabAddress,
        kept: ParkedLab | None = None,
        reopen: HandedOver | None = None,
    ) -> None:
        """``kept``: the session this page left for a reload; ``reopen``: what the page had
        open when the viewer before this one stopped (its session was handed over)."""
        self.login = None
        if self.closed:  # the page closed while the login was on its way
            if kept is not None and self.parking.park(connection, kept.memory, kept.events):
                return
            connection.logout(keep_resume=connection.resume_token is not None)
            return
        if connection.resume_token is not None:
            self._save_login(address.with_user(connection.user), connection.resume_token)
            if self.handovers is not None:  # another tab of this browser may bring it back
                self.handovers.issued(connection.resume_token)
        self.saved.add_recent(connection.user, address.with_user(connection.user))
        tab = LabTab(
            self.client,
            self.tabs,
            connection,
            on_logout=self._logged_out,
            on_watch=self.watch,
            on_context=self._context_opened,
            on_context_closed=self._context_closed,
            kept=kept,
        )
        with self._lock:
            self.labs[address.lab_key] = tab
        self.parking.attach(connection)
        set_value(self.address, address.with_user(connection.user).url())
        self._refresh_recent()
        # The lab's tab is where the person goes next: the page shows it (tabs.py).
        self._bring_to_front(tab.tab_name, tab_title(address))
        self.title.set(f"{tab.tab_name} · {TITLE}")
        # Also said in words (headless clients and the benchmark wait for these words).
        self.client.add_notification(
            title=f"Logged in to {address.label}",
            body=f"as {connection.user}: "
            + (
                "your session was kept while the page was away; nothing was lost."
                if kept is not None
                else "the web viewer restarted; your runs went on, and your tabs are back."
                if reopen is not None
                else f"its lobby is the tab '{tab.tab_name}'."
            ),
            auto_close_seconds=5.0,
        )
        shown = tab.panels.get(kept.memory.watching or "") if kept is not None else None
        if shown is not None:  # the arena the page showed, in front again
            self._bring_to_front(shown.tab_name, shown.tab_title)
            shown.show_world()
        if reopen is not None:
            # The one in view last: joining brings a context's tab to the front.
            shown_last = [reopen.watching] if reopen.watching else []
            for ctx in [c for c in reopen.contexts if c != reopen.watching] + shown_last:
                text = reopen.editor(ctx)
                put_back = None
                if text is not None:  # the editor's text, saved or not, its robot, its output
                    put_back = BenchMemory.of_text(
                        text.file_name,
                        text.code,
                        text.target,
                        as_html(text.printed),
                        text.printed_on,
                    )
                tab.join(ctx, editor=put_back)
        if address.context:
            tab.join(address.context)

    def _logged_out(self, tab: LabTab) -> None:
        self._save_login(tab.connection.address, None)  # "Log out" forgets the saved login
        self.parking.detach(tab.connection)
        with self._lock:
            for key, value in list(self.labs.items()):
                if value is tab:
                    del self.labs[key]
        self._refresh_recent()

    # -- the world view

    def _bring_to_front(self, label: str, title: str) -> None:
        """The page goes to that tab; its reports from before it got there are stale."""
        self.front.expect(label)
        self.switcher.show(label, title)

    def _panels(self) -> list[ChatPanel]:
        """Every context's panel, in every lab this page is logged in to."""
        with self._lock:
            return [p for tab in self.labs.values() for p in list(tab.panels.values())]

    def _context_opened(self, panel: ChatPanel) -> None:
        # Joining is asking to go there: the page shows the new tab, and an arena's world.
        panels = self._panels()
        for other in panels:
            other.in_front = other is panel
        self._bring_to_front(panel.tab_name, panel.tab_title)
        if panel.kind in ARENA_KINDS:
            panel.show_world()

    def _front_changed(self, labels: tuple[str, ...]) -> None:
        """A tab came to the front: if it is an arena's, the view shows that arena."""
        panels = self._panels()
        for each in panels:
            each.in_front = each.tab_name in labels
        for label in labels:
            panel = next((p for p in panels if p.tab_name == label), None)
            if panel is not None and panel.kind in ARENA_KINDS:
                if panel is not self.watching:
                    log.info("the page put %s in front: its arena is shown", label)
                    panel.show_world()
                return

    def _context_closed(self, panel: ChatPanel) -> None:
        if self.watching is panel:
            self.watching = None
            self.view.hide()

    def watch(self, feed: WorldFeed, panel: ChatPanel) -> None:
        """Show ``feed`` (an arena live, or one of its recordings) bound to ``panel``."""
        if self.watching is panel and self.view.feed is feed:
            return  # shown and bound already: the selection and the panels stay
        if self.watching is not None:  # the same panel too: it rebinds to the new feed
            self.watching.unbind()
        self.view.show(feed)
        panel.bind(self.view, feed)
        self.watching = panel

    # -- the browser went away

    def open_pages(self) -> list[tuple[bytes, HandedOver]]:
        """What this page has open in each lab it has a saved login to (none if parking is
        off: such a session is logged out when the viewer stops), for the next viewer."""
        if self.closed or not self.parking.enabled:
            return []
        watching = self.watching
        with self._lock:
            tabs = list(self.labs.values())
        return [
            (token, self._page_of(tab, watching))
            for tab in tabs
            if (token := tab.connection.resume_token) is not None
        ]

    @staticmethod
    def _page_of(tab: LabTab, watching: object) -> HandedOver:
        panels = list(tab.panels.items())  # one copy: the page's own thread adds to it
        opened = [
            (ctx, panel.workbench.memory() if panel.workbench else None) for ctx, panel in panels
        ]
        shown = next((ctx for ctx, panel in panels if panel is watching), None)
        return HandedOver.of(tab.connection.user, opened, shown)

    def close(self, *, viewer_stops: bool = False) -> list[tuple[bytes, HandedOver]]:
        """The browser went away: stop drawing, then park or log out of every lab.

        A lab with a saved login is parked (parking.py): a reload within the grace
        takes its session back. Nothing here touches the page: its connection is
        closed, and a GUI update queued now would only be dropped with a warning.
        Otherwise the lab must still be told (rooms left, presence gone,
        subscriptions undeclared). ``viewer_stops``: the page stays and the viewer
        goes; a lab with a saved login is handed over instead (LabConnection.hand_over),
        for the page to log in again on the next viewer. Returns each one's saved login
        and what the page had open there.
        """
        handed_over: list[tuple[bytes, HandedOver]] = []
        self.closed = True
        self.pump.detach(self.view)
        self.view.feed = None
        watching = self.watching
        with self._lock:
            tabs = list(self.labs.values())
            self.labs.clear()
        for tab in tabs:
            try:
                token = tab.connection.resume_token if self.parking.enabled else None
                shown = next((c for c, p in tab.panels.items() if p is watching), None)
                if token is not None and viewer_stops:
                    page = self._page_of(tab, watching)
                    tab.hand_over()
                    handed_over.append((token, page))
                    continue
                if token is not None:
                    memory, events = tab.park(shown)
                    if self.parking.park(tab.connection, memory, events):
                        continue  # kept for a reload (parking.py)
                    events.close()
                else:
                    self.parking.detach(tab.connection)
                tab.shutdown()
            except Exception:
                log.exception("while closing %s for a departed browser", tab.label)
        return handed_over
