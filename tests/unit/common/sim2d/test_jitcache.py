"""Numba's cache of the kernels is shared by every checkout on a machine (common/sim2d/jitcache.py):
a fresh clone loads what another compiled, and never the code of another version."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

SIM2D = Path(__file__).resolve().parents[4] / "common" / "sim2d"
# One small kernel module and what it imports: a checkout of the package in miniature.
FILES = ("jitcache.py", "packs.py", "noise.py")
RUN = (
    "import numpy as np; from common.sim2d import noise; "
    "print(noise.normals(np.uint64(7), 0, 3).tolist()); s = noise.normals.stats; "
    "print(s.cache_path); print(sum(s.cache_hits.values()), sum(s.cache_misses.values()))"
)


def checkout(root: Path) -> Path:
    package = root / "common" / "sim2d"
    package.mkdir(parents=True)
    (root / "common" / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    for name in FILES:
        shutil.copy(SIM2D / name, package / name)
    return root


def run_kernel(root: Path, cache: Path) -> tuple[str, Path, tuple[int, int]]:
    env = {**os.environ, "PYTHONPATH": str(root), "WART_NUMBA_CACHE": str(cache)}
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run(
        [sys.executable, "-c", RUN], cwd=root, env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    values, path, counts = out.stdout.strip().splitlines()
    hits, misses = (int(n) for n in counts.split())
    return values, Path(path), (hits, misses)


def test_a_second_checkout_loads_the_kernels_the_first_compiled(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    first = run_kernel(checkout(tmp_path / "one"), cache)
    second = run_kernel(checkout(tmp_path / "two"), cache)
    assert first[2] == (0, 1), "compiled in the first checkout"
    assert second[2] == (1, 0), "loaded in the second, not compiled again"
    assert first[0] == second[0]
    assert first[1] == second[1] and first[1].parent.parent == cache
    assert first[1].name.startswith("noise-")
    assert not list((tmp_path / "one").rglob("*.nbi")), "nothing cached inside the checkout"


def test_an_edited_kernel_file_is_compiled_again_and_both_versions_stay(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    run_kernel(checkout(tmp_path / "old"), cache)
    edited = checkout(tmp_path / "new")
    noise = edited / "common" / "sim2d" / "noise.py"
    noise.write_text(noise.read_text() + "\n# another version of the file\n")
    _, folder, counts = run_kernel(edited, cache)
    assert counts == (0, 1), "another version's machine code is never loaded"
    assert len(list(folder.parent.glob("noise-*"))) == 2
    assert run_kernel(tmp_path / "old", cache)[2] == (1, 0), "the old version's is still there"


def test_numba_cache_dir_where_set_wins(tmp_path: Path) -> None:
    root = checkout(tmp_path / "c")
    env = {**os.environ, "PYTHONPATH": str(root), "WART_NUMBA_CACHE": str(tmp_path / "ours")}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "numbas")
    out = subprocess.run(
        [sys.executable, "-c", RUN], cwd=root, env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert str(tmp_path / "numbas") in out.stdout.splitlines()[1]
    assert not (tmp_path / "ours").exists()


def test_a_relative_cache_path_is_said_and_ignored(tmp_path: Path) -> None:
    root = checkout(tmp_path / "c")
    env = {**os.environ, "PYTHONPATH": str(root), "WART_NUMBA_CACHE": "cache-here"}
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run(
        [sys.executable, "-c", RUN], cwd=root, env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr
    assert "WART_NUMBA_CACHE=cache-here is not an absolute path: ignored" in out.stderr
    assert out.stderr.count("WART_NUMBA_CACHE") == 1, "said once"
    assert not (root / "cache-here").exists()
