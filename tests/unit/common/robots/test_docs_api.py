"""docs/CONTROLLERS.md lists each shipped type's API as the schemas give it, word for word."""

from __future__ import annotations

from pathlib import Path

from common.robots import registry
from common.robots.describe import controllers_markdown

DOC = Path(__file__).resolve().parents[4] / "docs" / "CONTROLLERS.md"


def test_the_controllers_page_lists_each_shipped_type_s_api_from_the_schemas() -> None:
    text = DOC.read_text()
    begin, end = "<!-- robot-api:begin -->\n", "<!-- robot-api:end -->"
    assert begin in text and end in text
    written = text.split(begin, 1)[1].split(end, 1)[0]
    expected = controllers_markdown(registry.build(plugins=False))
    assert written == expected, (
        "docs/CONTROLLERS.md is out of date; paste common.robots.describe.controllers_markdown()"
    )
    assert "gripper" not in written.split("#### `epuck`")[1]  # the e-puck has none
