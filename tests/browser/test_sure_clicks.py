"""A click or a typed value that viser's page drops in its message throttle still counts.

viser's page keeps only the newest GUI message in a 50 ms window: a click sent
between two edits of a text field, in one go, is replaced by the second edit;
an edit followed by a click is replaced by the click. A student meets it as a
button that does nothing, or one that acts on the text before the last edit (a
busy laptop widens the window). The page's script (viewers/web/sure_clicks.py)
sends the replaced message, in its place in the order.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import viser

from tests.browser.conftest import new_test_context, page_url, wait_until
from tests.kit.procs import free_port
from viewers.web.labels import add_label_fixer
from viewers.web.sure_clicks import add_sure_clicks

# An edit of the Address field, a click on Connect, and another edit, in one task:
# the throttle cannot fire in between, so the click is the replaced message.
CLICK_BETWEEN_TWO_EDITS = """([inputId, buttonId]) => {
  const input = document.getElementById(inputId);
  const setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set;
  const address = input.value;
  setter.call(input, address + "x");
  input.dispatchEvent(new Event("input", { bubbles: true }));
  document.getElementById(buttonId).click();
  setter.call(input, address);
  input.dispatchEvent(new Event("input", { bubbles: true }));
}"""


def address_and_connect(page) -> tuple[str, str]:
    """The element ids of the start page's Address input and Connect button, once the
    page's script (an image's error handler) runs: a click before it is not its to see."""
    connect = page.button("Connect")
    connect.wait_for()
    wait_until(lambda: page.p.evaluate("!!window.__wartSureClicks"), 30, "the sure-clicks script")
    button_id = connect.get_attribute("id")
    input_id = page.input_after_label("Address").get_attribute("id")
    assert button_id and input_id
    return input_id, button_id


def test_a_click_replaced_by_an_edit_still_connects(open_page) -> None:
    page = open_page()
    input_id, button_id = address_and_connect(page)
    already = page.sent_count

    page.p.evaluate(CLICK_BETWEEN_TWO_EDITS, [input_id, button_id])

    # What the student sees: the login form, as if the click had gone at once.
    page.button("Log in").wait_for(timeout=30_000)
    # Sent once, by the page's script, never twice.
    clicks = [data for n, data in list(page.sent) if n >= already and button_id.encode() in data]
    assert len(clicks) == 1
    assert page.p.evaluate("window.__wartSureClicks.clicks") == 1


def test_a_click_the_throttle_only_delays_is_not_sent_twice(open_page) -> None:
    page = open_page()
    input_id, button_id = address_and_connect(page)
    already = page.sent_count

    # An edit, then the click in the same task: the click waits for the throttle's
    # timer and leaves then, by viser's own page. Nothing must send it again.
    page.p.evaluate(
        """([inputId, buttonId]) => {
          const input = document.getElementById(inputId);
          const setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set;
          setter.call(input, input.value + " ");
          input.dispatchEvent(new Event("input", { bubbles: true }));
          document.getElementById(buttonId).click();
        }""",
        [input_id, button_id],
    )
    assert page.sent_since(already, button_id.encode(), 10.0), "the delayed click never left"
    # The script looks every 100 ms until it sees the click leave; a wrong resend would
    # have come with the look that followed.
    page.p.wait_for_timeout(500)
    clicks = [data for n, data in list(page.sent) if n >= already and button_id.encode() in data]
    assert len(clicks) == 1
    assert page.p.evaluate("window.__wartSureClicks.clicks") == 0


# A click on Connect that viser's own handler never sees: stopped at the button, before
# it bubbles to React's listener at the root. What a click that misses its handler, or
# one thrown away with a remounted container's throttle, looks like from the page: no
# message leaves after it, its own or another.
CLICK_THE_HANDLER_MISSES = """buttonId => {
  const button = document.getElementById(buttonId);
  button.addEventListener("click", e => e.stopPropagation(), { once: true });
  button.click();
}"""


# Each Worker gets its own postMessage, so the page's messages pass by the prototype the
# script wraps: the script never learns the worker, as on a page whose first messages
# left before the script came and which has sent none since.
WORKER_UNSEEN = """(() => {
  const Original = window.Worker;
  window.Worker = function (...args) {
    const worker = new Original(...args);
    const post = Original.prototype.postMessage;
    worker.postMessage = function (...a) { return post.apply(worker, a); };
    return worker;
  };
  window.Worker.prototype = Original.prototype;
})();"""


@pytest.mark.parametrize("init", [None, WORKER_UNSEEN], ids=["worker-seen", "worker-unseen"])
def test_a_click_that_never_reached_the_throttle_is_sent_once(open_page, init) -> None:
    page = open_page(init=init)
    _, button_id = address_and_connect(page)
    already = page.sent_count

    page.p.evaluate(CLICK_THE_HANDLER_MISSES, button_id)

    page.button("Log in").wait_for(timeout=30_000)
    page.p.wait_for_timeout(500)  # a second send would follow within the next looks
    clicks = [data for n, data in list(page.sent) if n >= already and button_id.encode() in data]
    assert len(clicks) == 1
    assert page.p.evaluate("window.__wartSureClicks") == {"clicks": 0, "values": 0, "lost": 1}


# Two edits of the Address field and a click on Connect, in one task: the second
# edit waits in the throttle and the click replaces it.
EDIT_THEN_CLICK = """([inputId, buttonId, first, last]) => {
  const input = document.getElementById(inputId);
  const setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set;
  for (const text of [first, last]) {
    setter.call(input, text);
    input.dispatchEvent(new Event("input", { bubbles: true }));
  }
  document.getElementById(buttonId).click();
}"""


def test_a_click_acts_on_the_text_typed_just_before_it(open_page) -> None:
    page = open_page()
    input_id, button_id = address_and_connect(page)

    page.p.evaluate(
        EDIT_THEN_CLICK, [input_id, button_id, "wart://127.0.0.1:7447/other", "no such address"]
    )

    # Connect read what the student last typed (an address it refuses), not the
    # address before the last edit (which would have opened the login form).
    page.wait_text("an address has no spaces", timeout=30_000)
    assert page.button("Log in").count() == 0
    assert page.p.evaluate("window.__wartSureClicks.values") == 1
    assert page.p.evaluate("window.__wartSureClicks.clicks") == 0


# An edit, an option chosen in the open dropdown, and a click on Run, in one task:
# the edit leaves at once, the choice waits in the throttle and Run replaces it.
EDIT_CHOOSE_RUN = """([inputId, buttonId]) => {
  const input = document.getElementById(inputId);
  const setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set;
  setter.call(input, "alice");
  input.dispatchEvent(new Event("input", { bubbles: true }));
  document.querySelector('[role=option][value="k1"]').click();
  document.getElementById(buttonId).click();
}"""


@pytest.fixture
def run_on_page(chromium: object) -> Iterator[tuple[object, list[str]]]:
    """A page with a name, a robot chooser and Run; Run records the robot the server has."""
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    add_label_fixer(server.gui)
    add_sure_clicks(server.gui)
    server.gui.add_text("Name", "")
    robot = server.gui.add_dropdown("Run on", ("k0", "k1", "k2"))
    ran: list[str] = []
    server.gui.add_button("Run").on_click(lambda _: ran.append(robot.value))
    context = new_test_context(chromium)
    page = context.new_page()  # type: ignore[attr-defined]
    page.goto(page_url(f"http://127.0.0.1:{server.get_port()}/"))
    try:
        yield page, ran
    finally:
        context.close()  # type: ignore[attr-defined]
        server.stop()


def test_a_robot_chosen_just_before_run_is_the_one_that_runs(run_on_page) -> None:
    page, ran = run_on_page
    chooser = page.get_by_role("combobox")
    chooser.wait_for()
    chooser.click()  # opens the list; sends nothing
    page.locator('[role=option][value="k1"]').wait_for()
    name_id = page.get_by_label("Name").get_attribute("id")
    run_id = page.get_by_role("button", name="Run", exact=True).get_attribute("id")
    assert name_id and run_id

    page.evaluate(EDIT_CHOOSE_RUN, [name_id, run_id])

    wait_until(lambda: len(ran) == 1, 30, "Run to reach the server")
    assert ran == ["k1"]  # not the k0 it had before the choice
    assert page.evaluate("window.__wartSureClicks.values") == 1


# In one task: an edit in the modal (its own throttle: it leaves at once), a click on
# Go in the modal (it waits for that throttle's timer), an edit in the panel (the
# panel's throttle: it leaves at once, before Go). The script must not take the
# panel's message for Go's replacement and send Go a second time.
MODAL_THEN_PANEL = """([secretId, goId, noteId]) => {
  const setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set;
  const type = (id, text) => {
    const input = document.getElementById(id);
    setter.call(input, text);
    input.dispatchEvent(new Event("input", { bubbles: true }));
  };
  type(secretId, "s3cret");
  document.getElementById(goId).click();
  type(noteId, "a note");
}"""


def test_a_click_in_a_modal_is_not_sent_twice_for_a_message_of_the_panel(chromium) -> None:
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    add_label_fixer(server.gui)
    add_sure_clicks(server.gui)
    server.gui.add_text("Note", "")
    gone: list[str] = []
    with server.gui.add_modal("Unlock"):
        secret = server.gui.add_text("Secret", "")
        server.gui.add_button("Go").on_click(lambda _: gone.append(secret.value))
    context = new_test_context(chromium)
    try:
        page = context.new_page()  # type: ignore[attr-defined]
        page.goto(page_url(f"http://127.0.0.1:{server.get_port()}/"))
        go = page.get_by_role("button", name="Go", exact=True)
        go.wait_for()
        ids = [
            page.get_by_label("Secret").get_attribute("id"),
            go.get_attribute("id"),
            page.get_by_label("Note").get_attribute("id"),
        ]
        assert all(ids)

        page.evaluate(MODAL_THEN_PANEL, ids)

        wait_until(lambda: len(gone) >= 1, 30, "Go to reach the server")
        page.wait_for_timeout(1_000)  # a wrong resend would have come 100 ms after the click
        assert gone == ["s3cret"]
        assert page.evaluate("window.__wartSureClicks.clicks") == 0
    finally:
        context.close()  # type: ignore[attr-defined]
        server.stop()
