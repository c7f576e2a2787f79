"""A course for the grading runs: its name and the reach-the-goal assignment's file."""

from __future__ import annotations

import textwrap

COURSE = "robotics-26"


def assignment_toml(name: str, **fields: str) -> str:
    """The reach-the-goal assignment; ``fields`` replace its top-level lines."""
    values = {
        "name": f'"{name}"',
        "course": f'"{COURSE}"',
        "map": '"empty"',
        "robot": '"k1"',
        "time_limit": "3.0",
        "episodes": "2",
        "opens": "2026-01-01T00:00:00Z",
        "deadline": "2099-01-01T00:00:00Z",
        "quota": "5",
        **fields,
    }
    head = "\n".join(f"{k} = {v}" for k, v in values.items())
    return head + textwrap.dedent(
        """

        [[start]]
        x = 300
        y = 500
        heading_deg = 0

        [[zones]]
        id = "goal"
        shape = "circle"
        x = 420
        y = 500
        radius = 60

        [score]
        name = "points"
        unit = "pts"
        order = "higher"
        rule = '100 * reached("goal") - 5 * collisions() - time_to("goal")'
        """
    )
