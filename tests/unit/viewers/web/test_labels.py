"""The label fixer's markup: one hidden image whose onerror carries the fixed script."""

from __future__ import annotations

import html
import re

import pytest

from viewers.web.labels import LABEL_FIX_JS, label_fixer_html, script_image_html
from viewers.web.sure_clicks import sure_clicks_html


def test_the_script_is_one_escaped_attribute_of_a_hidden_image() -> None:
    markup = label_fixer_html()
    shape = r'<img src="data:," alt="" style="display:none" onerror="([^"]*)">'
    match = re.fullmatch(shape, markup)
    assert match is not None  # no quote of the script ends the attribute early
    script = html.unescape(match.group(1))
    assert "aria-labelledby" in script and "MutationObserver" in script
    assert "window.__wartLabels" in script  # once per page, however often it is added
    assert "<" not in match.group(1) and ">" not in match.group(1)
    assert script.split() == LABEL_FIX_JS.split()  # the same code, on one line


def test_a_line_comment_is_refused_not_left_to_swallow_the_rest_of_the_line() -> None:
    # The script goes in as one line: "// note" would silently comment out all after it.
    with pytest.raises(ValueError, match="// comment"):
        script_image_html("var a = 1;  // note\nwindow.__ran = a;")
    assert "http://x" in html.unescape(script_image_html("var u = 'http://x';"))
    sure_clicks_html()  # the page scripts the viewer adds build
    label_fixer_html()
