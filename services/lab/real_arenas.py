"""A real arena's processes: its bridge, the emulated Khepera of a lab without hardware,
and the cameras over it (what `wart up` and `wart host` start for a ``bridge`` or a
``camera`` of a lab description; the command lines, in one place, as in wiring.py).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from pathlib import Path

from common import keys
from common.keys import AliveKind
from services.lab.lab_maps import map_pose
from services.lab.supervisor import ChildSpec
from services.lab.wiring import Wiring, service_account


def emulator_link(w: Wiring, world: str) -> Path:
    """The stable path of an emulated Khepera's pty (what a real one's by-id path would be)."""
    return w.state_dir / "dev" / f"{world}-khepera"


# The emulated Khepera's wheels slip this much (the right half as much), so its
# odometry drifts as a real robot's does and the synthetic camera has something
# to correct: about 20 mm a metre driven.
EMULATED_SLIP = 0.03


def emulator_truth(w: Wiring, world: str) -> Path:
    """Where the emulated arena's true poses are written for its synthetic camera."""
    return w.state_dir / "dev" / f"{world}-truth.json"


def camera_spec(
    w: Wiring,
    world: str,
    source: str,
    *,
    name: str | None = None,
    calibration: Path | None = None,
    fps: float | None = None,
) -> ChildSpec:
    """A camera over a real arena; calibrated from its reference markers once they are in
    view when no calibration file exists yet (saved in the state dir for the next start)."""
    name = name or f"{world}-cam"
    calibration = calibration or w.state_dir / "cameras" / f"{name}.json"
    argv = ["camera", "--world", world, "--name", name, "--source", source]
    argv += ["--calibration", str(calibration), "--auto-calibrate"]
    if fps is not None:
        argv += ["--fps", f"{fps:g}"]
    return ChildSpec(
        name=f"camera {name}",
        argv=[*argv, *w.net_args("camera")],
        alive_key=keys.alive(w.realm, AliveKind.CAMERA, name),
        detail=f"over world {world}",
        prepare=functools.partial(calibration.parent.mkdir, parents=True, exist_ok=True),
    )


def bridge_specs(
    w: Wiring,
    world: str,
    ports: Sequence[str],
    *,
    emulate: str | None = None,
    login: bool = False,
    camera: bool = True,
) -> list[ChildSpec]:
    """A bridge, preceded by the emulated Khepera it drives when the lab has no hardware,
    and followed by a synthetic camera over that emulated arena (unless ``camera`` is off)."""
    ports = list(ports)
    specs: list[ChildSpec] = []
    if emulate:
        map_path = w.resolve_map(emulate)
        link = emulator_link(w, world)
        x, y, deg = map_pose(map_path)
        emulator = ["khepera-emulator", "--map", str(map_path), "--link", str(link)]
        if camera:
            emulator += ["--slip", f"{EMULATED_SLIP:g}", "--truth", str(emulator_truth(w, world))]
        specs.append(
            ChildSpec(
                name=f"khepera emulator {world}",
                argv=emulator,
                alive_key=None,  # not on the network: the bridge below is its presence
                detail=f"emulated Khepera at {link} ({map_path.name})",
                prepare=functools.partial(link.parent.mkdir, parents=True, exist_ok=True),
            )
        )
        taken = {port.partition("=")[2].partition("@")[0] for port in ports}
        agent = next(f"k{n}" for n in range(1, len(ports) + 2) if f"k{n}" not in taken)
        # The bridge's odometry starts where the emulated body stands, so both views agree.
        ports.append(f"{link}={agent}@{x:g},{y:g},{deg:g}")
    argv = ["bridge", "--world", world]
    for port in ports:
        argv += ["--port", port]
    if login:
        argv += w.login(service_account("bridge", world))
    specs.append(
        ChildSpec(
            name=f"bridge {world}",
            argv=[*argv, *w.net_args("bridge")],
            alive_key=keys.alive(w.realm, AliveKind.WORLD, world),
            detail=f"real world {world}, {len(ports)} robot(s)"
            + (" (one emulated)" if emulate else ""),
        )
    )
    if emulate and camera:
        specs.append(camera_spec(w, world, f"synthetic:{emulator_truth(w, world)}"))
    return specs
