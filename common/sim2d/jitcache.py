"""Numba's on-disk cache kept true across files: a kernel's cache goes stale with its callees'."""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path
from types import ModuleType

from numba.core.caching import NullCache
from numba.core.dispatcher import Dispatcher


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
