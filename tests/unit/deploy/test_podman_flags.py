"""deploy/container/podman-flags: overlay storage where podman can mount it, else vfs.

A stand-in ``podman`` first on PATH plays the two kinds of machine: one whose kernel
mounts overlays and one that refuses them (podman's own words).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[3] / "deploy" / "container" / "podman-flags"


def flags(tmp_path: Path, overlay_works: bool, **env: str) -> subprocess.CompletedProcess[str]:
    fake = tmp_path / "bin" / "podman"
    fake.parent.mkdir(exist_ok=True)
    answer = (
        "echo overlay"
        if overlay_works
        else ("echo 'Error: kernel does not support overlay fs' >&2; exit 125")
    )
    fake.write_text(f'#!/bin/sh\ncase "$*" in *"info"*) {answer};; esac\nexit 0\n')
    fake.chmod(0o755)
    environ = {k: v for k, v in os.environ.items() if k != "WART_PODMAN_FLAGS"}
    environ["PATH"] = f"{fake.parent}:{environ['PATH']}"
    return subprocess.run(
        [str(SCRIPT)], env={**environ, **env}, capture_output=True, text=True, timeout=30
    )


def test_overlay_where_the_kernel_mounts_it_in_a_store_of_its_own(tmp_path: Path) -> None:
    out = flags(tmp_path, overlay_works=True).stdout.split()
    assert out[out.index("--storage-driver") + 1] == "overlay"
    # a store keeps the driver it was made with: not podman's default one
    assert out[out.index("--root") + 1] == "/var/lib/containers/wart-overlay"
    assert {"--runtime", "runc", "--cgroup-manager", "cgroupfs"} <= set(out)


def test_vfs_where_overlay_is_refused(tmp_path: Path) -> None:
    done = flags(tmp_path, overlay_works=False)
    assert done.returncode == 0
    assert done.stdout.split() == [
        "--runtime", "runc", "--cgroup-manager", "cgroupfs", "--storage-driver", "vfs",
    ]  # fmt: skip


def test_the_operators_flags_win(tmp_path: Path) -> None:
    done = flags(tmp_path, overlay_works=True, WART_PODMAN_FLAGS="--runtime crun")
    assert done.stdout.strip() == "--runtime crun"


def test_an_unknown_option_is_refused_by_name() -> None:
    done = subprocess.run([str(SCRIPT), "--bogus"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 2
    assert "no options but --help" in done.stderr
