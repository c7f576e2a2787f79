"""A text the server puts in the editor reaches the page, even one the server holds already.

A page's resend can cross the server's newest text on the way: the server then
holds the page's older text, or the page shows another than the server's. A real
viser server and a headless client speaking its protocol (tests/kit/viser_client.py).
"""

from __future__ import annotations

import asyncio
import time

import viser

from tests.kit.procs import free_port
from tests.kit.viser_client import ViserClient, run_in_thread
from viewers.web.code_editor import show_text

WAIT = 30.0  # the bound within which the page must show the text


async def _page_after_crossing(url: str, code: viser.GuiTextHandle) -> str:
    page = ViserClient(url, "student")
    try:
        await page.connect()
        area = await page.wait_for(lambda: page.find("Controller code", "GuiTextMessage"), WAIT)
        # The page's resend of the file it had reaches the server after the server
        # opened another: the server holds the old file...
        await page.type_into("Controller code", "the old file", WAIT)
        deadline = time.monotonic() + WAIT
        while code.value != "the old file":
            assert time.monotonic() < deadline, "the server never heard the page's text"
            await asyncio.sleep(0.01)
        # ...while the page shows the file the server sent before.
        area.value = "the newer file"
        # Now the student opens the old file again.
        show_text(code, "the old file")
        await page.wait_for(lambda: area.value == "the old file", WAIT)
        return str(area.value)
    finally:
        await page.close()


def test_a_file_opened_reaches_a_page_whose_resend_crossed_it() -> None:
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        code = server.gui.add_text("Controller code", "the newer file", multiline=True)
        shown = run_in_thread(_page_after_crossing(f"ws://127.0.0.1:{server.get_port()}", code))
        assert shown == "the old file"
    finally:
        server.stop()
