"""The race compass: every robot's heading at once, from the world's pose array."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from common.robots.schema import ApiCall, ComponentType, Param


class RaceCompass(ComponentType):
    name = "race_compass"
    doc = (
        "A compass: the robot's heading in tenths of a degree, 0..3599, counter-clockwise "
        "from the arena's +x axis (east), with Gaussian noise of noise_deg."
    )
    params = (Param("noise_deg", "number", "Gaussian noise σ", "°", 0.5, lo=0.0, hi=45.0),)
    api = (ApiCall("{name}()", "Reading of 1 heading (0.1°)", "where the robot faces"),)
    version = "0.1.0"

    @classmethod
    def reading_size(cls, values: Mapping[str, Any]) -> int:
        return 1

    @classmethod
    def measure(cls, world: Any, slots: Any, values: Mapping[str, Any], key: int) -> Any:
        heading = np.degrees(world.agent_pose[slots, 2])
        sigma = float(values["noise_deg"])
        if sigma > 0:
            heading = heading + np.random.default_rng(key).normal(0.0, sigma, len(slots))
        tenths = np.mod(np.rint(heading * 10), 3600)
        return tenths.astype(np.int32).reshape(-1, 1)
