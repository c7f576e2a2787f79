"""Numba's on-disk cache for the kernels: true across files, shared across checkouts.

True across files: a kernel's cache goes stale with its callees' (:func:`stamp_with_callees`).

Shared across checkouts: numba keeps a cache beside its source (``__pycache__``),
so a fresh clone, a second worktree or a CI run compiled every kernel again
(a minute or more of a core). :class:`SharedCacheLocator` keeps the kernels of this
package in ``$WART_NUMBA_CACHE`` (default ``~/.cache/wart/numba/``), in one
folder per source file's contents: another checkout of the same file loads them.
Numba's own ``NUMBA_CACHE_DIR``, where set, wins (the container image sets it).
Imported by every module that defines kernels, before its first one.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import shutil
import sys
from pathlib import Path
from types import ModuleType

import numba
from numba.core import caching, config
from numba.core.caching import NullCache, UserProvidedCacheLocator
from numba.core.dispatcher import Dispatcher

HERE = Path(__file__).resolve().parent
log = logging.getLogger("wart.kernels")
_WARNED: list[bool] = []  # the relative WART_NUMBA_CACHE said once a process
KEPT = 4  # folders kept per source file: the newest, by when they were last used


def shared_root() -> Path:
    """Where the kernels' caches are kept for every checkout (WART_NUMBA_CACHE, else ~/.cache)."""
    given = os.environ.get("WART_NUMBA_CACHE")
    base = Path(given).expanduser() if given else Path.home() / ".cache" / "wart" / "numba"
    python = f"py{sys.version_info.major}{sys.version_info.minor}"
    return base / f"numba{numba.__version__}-{python}"


class SharedCacheLocator(UserProvidedCacheLocator):
    """Numba's cache locator for this package's kernels: a folder named by the file's contents.

    The index in it is still stamped with the contents (numba's) and the callees'
    (:func:`stamp_with_callees`), so a folder never serves other code.
    """

    def __init__(self, py_func: object, py_file: str) -> None:
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno  # type: ignore[attr-defined]
        self._cache_path = _FOLDERS.get(py_file) or _folder_for(py_file)

    @classmethod
    def from_function(cls, py_func: object, py_file: str) -> SharedCacheLocator | None:
        if getattr(config, "CACHE_DIR", "") or Path(py_file).resolve().parent != HERE:
            return None  # NUMBA_CACHE_DIR's (numba's own locator), or not a kernel of ours
        if not shared_root().is_absolute():  # no home directory (a sandbox), or a relative path
            if os.environ.get("WART_NUMBA_CACHE") and not _WARNED:
                _WARNED.append(True)
                log.warning(
                    "WART_NUMBA_CACHE=%s is not an absolute path: ignored, numba caches the "
                    "kernels beside their sources",
                    os.environ["WART_NUMBA_CACHE"],
                )
            return None
        try:
            self = cls(py_func, py_file)
            self.ensure_cache_path()
        except OSError:  # no writable home: numba's next locator (``__pycache__``)
            return None
        return self


_FOLDERS: dict[str, str] = {}  # source file -> its cache folder, made once a process


def _folder_for(py_file: str) -> str:
    source = Path(py_file)
    digest = hashlib.sha256(source.read_bytes()).hexdigest()[:16]
    folder = shared_root() / f"{source.stem}-{digest}"
    folder.mkdir(parents=True, exist_ok=True)
    os.utime(folder)  # used now: pruning keeps the folders used last
    others = sorted(
        (f for f in folder.parent.glob(f"{source.stem}-*") if f.name != folder.name),
        key=lambda f: f.stat().st_mtime,
        reverse=True,
    )
    for old in others[KEPT - 1 :]:
        with contextlib.suppress(OSError):  # another process may be pruning it too
            shutil.rmtree(old)
    _FOLDERS[py_file] = str(folder)
    return str(folder)


def _share_between_checkouts() -> None:
    # Numba's list of locators is internal: without it, its own (``__pycache__``) serve.
    locators = getattr(getattr(caching, "CacheImpl", None), "_locator_classes", None)
    if isinstance(locators, list) and SharedCacheLocator not in locators:
        locators.insert(0, SharedCacheLocator)


_share_between_checkouts()


def stamp_with_callees(module_name: str, *modules: ModuleType) -> None:
    """Make the on-disk caches of ``module_name``'s kernels stale when one of ``modules`` changes.

    Numba keys a cached function on its own source file only, yet a cached
    caller holds the machine code of every compiled function it calls: edit
    a callee's file and the caller's cache would still load, calling the old
    code with the new layouts (it crashed, the one time it happened). So each
    cache's stamp gets these modules' contents too. Numba's attributes for it
    are internal: if they are gone, the kernel is not cached at all (a compile
    at start) rather than cached stale. Called at the end of a module, once
    its kernels are defined.
    """
    digest = hashlib.sha256()
    for module in modules:
        digest.update(Path(str(module.__file__)).read_bytes())
    for value in list(vars(sys.modules[module_name]).values()):
        if not isinstance(value, Dispatcher) or value.py_func.__module__ != module_name:
            continue  # not a kernel, or one this module imported
        cache = getattr(value, "_cache", None)
        cache_file = getattr(cache, "_cache_file", None)
        if cache_file is None or not hasattr(cache_file, "_source_stamp"):
            setattr(value, "_cache", NullCache())  # noqa: B010 (numba's internal slot)
            continue
        cache_file._source_stamp = (cache_file._source_stamp, digest.digest())
