"""wart-race: a compass sensor, a racer robot type and a race context for the wart lab."""

from __future__ import annotations

from importlib import resources

# The racer's robot file: data the lab's registry validates and compiles (never executed).
RACER_FILE = resources.files("wart_race") / "racer.toml"
