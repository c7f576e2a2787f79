"""Live plots of a robot's IR and wheels in a notebook cell (ipywidgets and matplotlib,
the ``notebook`` extra): one Output widget, drawn again as samples come in.

The figure is drawn to PNG without pyplot (no GUI backend, no global figure state),
so it draws the same under JupyterLab, VS Code, Colab and nbclient.
"""

from __future__ import annotations

import importlib.util
import io
from collections.abc import Sequence
from typing import Any

from common.messages import SensorSample

WINDOW_S = 20.0  # the plots show the last 20 s of the run


def plots_available() -> bool:
    """ipywidgets, IPython and matplotlib are installed (looked up, not imported)."""
    return all(importlib.util.find_spec(m) is not None for m in ("ipywidgets", "matplotlib"))


class LivePlot:
    """IR proximity (one line a sensor) and measured wheel speeds over the run's time."""

    def __init__(self, agent: str) -> None:
        # optional (the notebook extra): plots_available() was asked first
        import ipywidgets
        from IPython.display import display
        from matplotlib.figure import Figure

        self.agent = agent
        self.draws = 0
        self.output = ipywidgets.Output()
        self._figure: Any = Figure(figsize=(10, 3.2), layout="constrained")
        self._ir, self._wheels = self._figure.subplots(1, 2)
        display(self.output)

    def draw(self, samples: Sequence[SensorSample]) -> None:
        """Draw the samples so far (the last WINDOW_S of them) in the widget."""
        from IPython.display import Image  # optional, as above

        ir, wheels = self._ir, self._wheels
        ir.clear()
        wheels.clear()
        if samples:
            t0 = samples[0].sim_time
            shown = [s for s in samples if s.sim_time >= samples[-1].sim_time - WINDOW_S]
            times = [s.sim_time - t0 for s in shown]
            for i in range(len(shown[-1].proximity)):
                ir.plot(times, [s.proximity[i] if i < len(s.proximity) else 0 for s in shown])
            wheels.plot(times, [s.speeds[0] for s in shown], label="left")
            wheels.plot(times, [s.speeds[1] for s in shown], label="right")
            wheels.legend(loc="upper left")
        ir.set_title(f"{self.agent}: IR proximity")
        ir.set_xlabel("s")
        wheels.set_title(f"{self.agent}: wheel speeds")
        wheels.set_xlabel("s")
        png = io.BytesIO()
        self._figure.savefig(png, format="png", dpi=72)
        self.output.clear_output(wait=True)
        self.output.append_display_data(Image(data=png.getvalue(), format="png"))
        self.draws += 1
