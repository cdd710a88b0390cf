"""Cold start (issue 43 item 6): compile some of a bake's kernels in a second process.

With an empty numba cache (the first bake after ``pip install``) the bake compiles its kernels
one after the other on one core: the tracing kernel ``native_pass`` and its callees (~20 CPU
seconds), then the fit (~10) and the noise statistics (~3). :class:`Prefetch` starts one more
Python process (``python -m usdahd.bake.kernels.prefetch NAME ...``) that compiles the kernels
of :data:`GROUPS` the bake will need (from the signatures in :data:`MANIFEST`) and writes them to
numba's on-disk cache, while the bake compiles the rest itself, top-down as always. When the
bake reaches one of the second process's kernels, numba first looks in its cache
(``Dispatcher.compile`` -> ``Cache.load_overload``); :class:`Prefetch` wraps that look-up so it
waits until the second process has reported the kernel, then loads it. A cached library keeps its
LLVM bitcode for linking, so the caller inlines it exactly as when it compiled it itself.

Only kernels missing from the cache are handed over; nothing at all when the cache is warm
(no process is started). If the second process fails or is killed, its kernels are simply
compiled by the bake. ``USDAHD_COMPILE_JOBS=1`` turns it off.

The manifest holds each kernel's signature (pickled numba types); a kernel whose arguments
changed gets a stale signature, which costs the second process's time but never a wrong
result (the bake compiles what it needs). ``python -m benchmarks.startup --write-signatures``
rewrites it from a bake of ``usdahd warmup``'s stage in a new, empty numba cache (a callee of a
kernel loaded from the cache is never compiled, so its signature would be unknown);
tests/commands/test_startup_kernels.py checks it is current.
"""

from __future__ import annotations

import base64
import importlib
import json
import os
import pickle
import subprocess
import sys
import threading
import time
from pathlib import Path

__all__ = [
    "GROUPS",
    "MANIFEST",
    "Prefetch",
    "cpu_seconds",
    "dispatcher",
    "groups_for",
    "is_cached",
    "signatures",
    "write_manifest",
]

#: The kernels the second process compiles, by the part of the bake that needs them; in each
#: group, in the order the bake reaches them. "trace": the path tracer (``trace_paths``, the
#: bake kernel's largest callee, ~7 of its ~18 CPU seconds) and the kernel that solves the
#: traced texels' SH; the bake meanwhile compiles the rasteriser, the direct-light callees
#: (``_texel_delta``), the camera-ray tracer and, last, ``native_pass`` itself, and reaches
#: ``trace_paths`` about when the second process (~2 s to start) has it ready. "noise": the
#: denoiser's statistics, window means and blend (usdahd.numerics.noise, .windows,
#: usdahd.bake.blend);
#: "fit": the IrradZ models' fit (ahd, hhd, hlsh).
GROUPS = {
    "trace": (
        "usdahd.bake.kernels.paths.trace_paths",
        "usdahd.bake.kernels.integrate.native_result",
    ),
    "noise": (
        "usdahd.numerics.windows._box_mean_texels_numba",
        "usdahd.numerics.noise._tile_stats_numba",
        "usdahd.numerics.windows._neighbour_mean_numba",
        "usdahd.numerics.noise._bends_numba",
        "usdahd.bake.blend._blend_chart_numba",
    ),
    "fit": ("usdahd.models.irradz.kernel._fit_kernel",),
}

#: name -> [base64 of the pickled argument types, ...]
MANIFEST = Path(__file__).with_name("signatures.json")

_PKG_PARENT = str(Path(__file__).resolve().parents[3])


def groups_for(*, fit: bool, denoise: bool) -> list[str]:
    """The groups a bake needs: always "trace", "noise" when it denoises, "fit" when its model
    is fitted by the IrradZ kernel."""
    return ["trace"] + ["noise"] * bool(denoise) + ["fit"] * bool(fit)


def dispatcher(name: str):
    module, _, attr = name.rpartition(".")
    return getattr(importlib.import_module(module), attr)


def signatures() -> dict[str, list]:
    """The manifest: kernel name -> its argument-type tuples (unpickled numba types)."""
    try:
        raw = json.loads(MANIFEST.read_text())
    except (OSError, ValueError):
        return {}
    out = {}
    for name, sigs in raw.items():
        try:
            out[name] = [pickle.loads(base64.b64decode(s)) for s in sigs]
        except Exception:  # a type that no longer exists: leave the kernel to the bake
            continue
    return out


def is_cached(disp, sig) -> bool:
    """Whether numba's on-disk cache holds ``disp`` compiled for ``sig`` (reads its index)."""
    cache = getattr(disp, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    if cache_file is None:  # NullCache: not cached at all
        return True
    try:
        key = cache._index_key(sig, disp.targetctx.codegen())
        return key in cache_file._load_index()
    except Exception:
        return True  # numba internals moved: do not start anything


def _die_with_parent() -> None:
    """In the second process: end with SIGKILL when the bake's process ends, however it ends
    (``os._exit``, a signal), so no compile outlives the bake (Linux's PR_SET_PDEATHSIG)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None).prctl(1, signal.SIGKILL)
    except Exception:
        pass
    if str(os.getppid()) != os.environ.get("USDAHD_PREFETCH_PARENT", str(os.getppid())):
        os._exit(0)  # the parent ended before prctl


def cpu_seconds(pid: int) -> float | None:
    """user + system CPU seconds of a running process (``/proc/PID/stat``), None elsewhere."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def _enabled() -> bool:
    from numba.core import config

    return os.environ.get("USDAHD_COMPILE_JOBS", "2") != "1" and not config.DISABLE_JIT


class Prefetch:
    """Context manager: compile the missing kernels of ``groups`` in a second process, and
    make this process wait for (then load) those kernels instead of compiling them too.

    ``then`` (``"module:function"``) runs in the second process after the kernels (``usdahd
    warmup`` fits every model there); :attr:`report` holds the second process's report once it
    has ended (:meth:`wait`): the kernels it compiled, ``then``'s return value, its seconds.
    :attr:`last` is the last Prefetch that started a process."""

    #: A Prefetch is running in this process (a bake inside ``usdahd warmup``): no second one.
    _active = False
    last = None

    def __init__(self, groups, *, then: str | None = None):
        self.groups = list(groups)
        self.extra = ("--then", then) if then else ()
        self.names: list[str] = []
        self.done: dict[str, str] = {}
        self.report: dict | None = None
        self.proc = None
        self.waited = 0.0
        self.owner = False
        self._events: dict[str, threading.Event] = {}
        self._wrapped: list = []
        self._reader = None

    def __enter__(self):
        if Prefetch._active or not _enabled():
            return self
        Prefetch._active = self.owner = True
        sigs = signatures()
        for g in self.groups:
            for name in GROUPS[g]:
                if name not in sigs:
                    continue
                try:
                    disp = dispatcher(name)
                except Exception:
                    continue
                missing = [s for s in sigs[name] if tuple(s) not in disp.overloads]
                if not all(is_cached(disp, s) for s in missing):
                    self.names.append(name)
                    self._events[name] = threading.Event()
                    self._wrap(name, disp)
        if not self.names and not self.extra:
            return self
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (_PKG_PARENT, env.get("PYTHONPATH")) if p)
        env["USDAHD_PREFETCH_PARENT"] = str(os.getpid())
        cmd = [sys.executable, "-m", "usdahd.bake.kernels.prefetch", *self.names, *self.extra]
        log = os.environ.get("USDAHD_PREFETCH_LOG")  # the second process's stderr (debugging)
        try:
            self.proc = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=open(log, "ab") if log else subprocess.DEVNULL,  # noqa: SIM115
                env=env,
                text=True,
            )
        except OSError:
            self._unwrap()
            return self
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        Prefetch.last = self
        return self

    def _read(self):
        for line in self.proc.stdout:
            word, _, rest = line.rstrip("\n").partition(" ")
            if word in ("done", "failed"):
                self.done[rest] = word
                ev = self._events.get(rest)
                if ev is not None:
                    ev.set()
            elif word == "report":
                self.report = json.loads(rest)
        for ev in self._events.values():  # the process ended: nobody else will compile them
            ev.set()

    def _wrap(self, name, disp):
        cache = disp._cache
        orig = cache.load_overload
        ev = self._events[name]
        me = self

        def load_overload(sig, target_context):
            if not ev.is_set():
                t0 = time.perf_counter()
                ev.wait()
                me.waited += time.perf_counter() - t0
            return orig(sig, target_context)

        cache.load_overload = load_overload
        self._wrapped.append(cache)

    def _unwrap(self):
        for cache in self._wrapped:
            cache.__dict__.pop("load_overload", None)
        self._wrapped = []
        for ev in self._events.values():
            ev.set()

    def wait(self):
        """Wait for the second process to end and its report to be read."""
        if self.proc is not None:
            self.proc.wait()
            self._reader.join(10)  # it drains the pipe after the exit

    def __exit__(self, *exc):
        if self.owner:
            Prefetch._active = self.owner = False
        self._unwrap()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()  # the bake ended first (an error, or a kernel it never reached)
            self.proc.wait()


def write_manifest() -> dict[str, int]:
    """Write the signatures of :data:`GROUPS`' kernels as compiled in this process to
    :data:`MANIFEST` (after a bake that compiled them all: ``python -m benchmarks.startup
    --write-signatures``); returns name -> count."""
    out = {}
    for names in GROUPS.values():
        for name in names:
            sigs = dispatcher(name).signatures
            if not sigs:
                raise RuntimeError(f"{name} was not compiled: run with an empty NUMBA_CACHE_DIR")
            out[name] = [base64.b64encode(pickle.dumps(tuple(s))).decode() for s in sigs]
    tmp = MANIFEST.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, MANIFEST)
    return {k: len(v) for k, v in out.items()}


def _child(argv: list[str]) -> int:
    """The second process: compile each named kernel from the manifest, report each one
    (``done NAME`` / ``failed NAME``); then run ``--then module:function`` if given; last, a
    ``report {json}`` line: the kernels it compiled (numba's compile events), the function's
    return value and its (wall, CPU) seconds."""
    _die_with_parent()
    from usdahd.numerics.numba_cache import CompiledKernels

    then = None
    if "--then" in argv:
        i = argv.index("--then")
        then, argv = argv[i + 1], argv[:i] + argv[i + 2 :]
    t0, c0 = time.perf_counter(), time.process_time()
    recorder = CompiledKernels().__enter__()  # open for the life of this process
    compiled = recorder.names
    sigs = signatures()
    for name in argv:
        try:
            disp = dispatcher(name)
            for s in sigs[name]:
                disp.compile(s)
            print("done", name, flush=True)
        except Exception:
            print("failed", name, flush=True)
    result = None
    if then:
        module, _, attr = then.partition(":")
        result = getattr(importlib.import_module(module), attr)()
    rep = {
        "compiled": sorted(n for n in compiled if n.startswith("usdahd")),
        "result": result,
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }
    print("report " + json.dumps(rep), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
