"""The numba cache policy of the bake kernels (import before defining any ``cache=True`` kernel).

numba links every callee's code into its caller's library, so the cached bake kernel depends on
the sources of several modules; numba's on-disk cache only checks the cached function's own file.
Importing this module registers cache locators that stamp every cached function of
:data:`KERNEL_SOURCES` with all of their sources (size and mtime), so an edit to any of them
recompiles the kernels. No Embree, no I/O beyond ``os.stat``.
"""

from __future__ import annotations

import os

from numba.core import caching as _caching

__all__ = ["helper"]

#: Modules whose numba functions are compiled into one another (the bake kernel: numba links
#: every callee's code into its caller's library, where LLVM inlines the small ones).
#: numba's on-disk cache only checks the source file of the cached function itself, so an
#: edit to a callee in another module would leave a stale kernel in the cache; the
#: locators below stamp every cached function of these modules with all of their sources.
_PKG = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
KERNEL_SOURCES = tuple(
    os.path.join(_PKG, *parts)
    for parts in (
        ("bake", "kernels", "embree.py"),
        ("bake", "kernels", "trace.py"),
        ("bake", "trace.py"),
        ("bake", "kernels", "cache.py"),
        ("bake", "kernels", "layout.py"),
        ("bake", "kernels", "lights.py"),
        ("bake", "kernels", "shading.py"),
        ("bake", "kernels", "paths.py"),
        ("bake", "kernels", "integrate.py"),
        ("bake", "reference.py"),
        ("numerics", "sampling.py"),
        ("numerics", "sh.py"),
        ("scene", "lights", "base.py"),
    )
)


class _KernelStampMixin:
    @classmethod
    def from_function(cls, py_func, py_file):
        if os.path.abspath(py_file) not in KERNEL_SOURCES:
            return None
        return super().from_function(py_func, py_file)

    def get_source_stamp(self):
        stamps = []
        for path in KERNEL_SOURCES:
            st = os.stat(path)
            stamps.append((os.path.basename(path), st.st_mtime, st.st_size))
        return tuple(stamps)


def _register_cache_locators():
    extra = []
    for name in ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator"):
        base = getattr(_caching, name, None) or getattr(_caching, "_" + name, None)
        if base is not None:
            extra.append(type("Kernel" + name, (_KernelStampMixin, base), {}))
    impl = getattr(_caching, "CacheImpl", None) or getattr(_caching, "_CacheImpl", None)
    classes = getattr(impl, "_locator_classes", None)
    if classes is None or not extra:  # pragma: no cover - numba internals moved
        return False
    if not any(issubclass(c, _KernelStampMixin) for c in classes):
        impl._locator_classes = extra + list(classes)
    return True


#: False when numba's caching internals changed: cached kernels then only track their own file.
CACHE_TRACKS_ALL_SOURCES = _register_cache_locators()


# ----------------------------------------------------------------------------- kernel helpers
# numba compiles every ``@njit`` function a kernel calls as a dispatcher of its own, with a
# CPython wrapper and a C-callable (cfunc) wrapper that LLVM optimizes and turns into machine
# code, although a helper is only ever called (and inlined) from numba code. ``helper`` drops
# both wrappers: ~15 % less compile time for the bake kernel on its first run (benchmarks/
# startup.py). Without a Python entry point such a function must not be called from Python:
# its dispatcher raises TypeError instead (a call would otherwise jump to a null address).

#: Options of every kernel helper (no NRT: no allocation or reference counting in them).
HELPER_OPTIONS = {
    "_nrt": False,
    "error_model": "numpy",
    "no_cpython_wrapper": True,
    "no_cfunc_wrapper": True,
}


def _helper_dispatcher_class():
    from numba.core.registry import CPUDispatcher

    class HelperDispatcher(CPUDispatcher):
        """Dispatcher of a kernel helper: compiled for numba callers only."""

        def __call__(self, *args, **kws):
            raise TypeError(
                f"{self.py_func.__module__}.{self.py_func.__qualname__} is a numba kernel "
                "helper compiled without a Python entry point: call it from @njit code"
            )

    return HelperDispatcher


HelperDispatcher = _helper_dispatcher_class()


def helper(func):
    """``@njit(cache=True, **HELPER_OPTIONS)`` for a function called only from numba code."""
    from numba.core import config

    if config.DISABLE_JIT:  # pragma: no cover - NUMBA_DISABLE_JIT debugging
        return func
    disp = HelperDispatcher(
        py_func=func, locals={}, targetoptions={"nopython": True, **HELPER_OPTIONS}
    )
    disp.enable_caching()
    return disp
