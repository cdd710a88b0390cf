"""numba on-disk cache policy: invalidate a module's cached kernels when the modules they read
constants from change.

numba's cache (``@njit(cache=True)``) freezes module-level globals into the compiled code and
keys the cache index only on the *defining* file's mtime and size. A kernel that reads a
constant imported from another module (``DZ_FLOOR = encoding.DZ_MIN``) keeps the old value
after that other module is edited: a stale kernel, silently. :func:`track` folds a hash of the
sources of the constant-providing modules into each kernel's cache stamp, so editing any of
them recompiles the kernel (tested in tests/numerics/test_numba_cache.py).

Usage, at the end of a kernel module::

    from usdahd.numerics import encoding, numba_cache, sh
    numba_cache.track(globals(), encoding, sh)
"""

from __future__ import annotations

import hashlib
import inspect
from types import ModuleType

__all__ = ["CompiledKernels", "track"]


def source_digest(*modules: ModuleType) -> str:
    """sha256 hex digest of the source files of ``modules`` (in the given order)."""
    h = hashlib.sha256()
    for mod in modules:
        path = inspect.getsourcefile(mod)
        h.update(str(mod.__name__).encode())
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()


def track(namespace: dict, *modules: ModuleType) -> list[str]:
    """Fold :func:`source_digest` of ``modules`` into the on-disk cache stamp of every cached
    numba dispatcher in ``namespace`` (a module's ``globals()``). Call it after the kernels
    are defined and before they are first compiled (at import). returns the names tracked."""
    digest = source_digest(*modules)
    tracked = []
    for name, obj in list(namespace.items()):
        cache = getattr(obj, "_cache", None)
        cache_file = getattr(cache, "_cache_file", None)
        stamp = getattr(cache_file, "_source_stamp", None)
        if stamp is None or getattr(obj, "py_func", None) is None:
            continue
        if isinstance(stamp, tuple) and len(stamp) == 3 and stamp[0] == "tracked":
            stamp = stamp[1]
        cache_file._source_stamp = ("tracked", stamp, digest)
        tracked.append(name)
    return tracked


class CompiledKernels:
    """Context manager: ``names``, the set of qualified names (``module.qualname``) of the
    functions numba compiles while it is open, from numba's ``numba:compile`` events (a kernel
    loaded from the on-disk cache fires none). One listener for warmup, the cold-start
    prefetch process and the startup tests."""

    def __init__(self) -> None:
        self.names: set[str] = set()
        self._listener = None

    def __enter__(self) -> CompiledKernels:
        from numba.core import event as ev

        names = self.names

        class _Listener(ev.Listener):
            def on_start(self, event):
                pass

            def on_end(self, event):
                f = event.data["dispatcher"].py_func
                names.add(f"{f.__module__}.{f.__qualname__}")

        self._listener = _Listener()
        ev.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> bool:
        if self._listener is not None:
            from numba.core import event as ev

            ev.unregister("numba:compile", self._listener)
            self._listener = None
        return False
