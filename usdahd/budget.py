"""The memory budget every reader of an untrusted array or image checks a file's declared size
against *before* allocating or inflating anything (issue 40: a 3 MB ``.npz`` whose member
inflates to 2.7 GB, a PNG header claiming 100000 x 100000 pixels).

The budget is half of the smallest of: the machine's physical memory, the cgroup's memory
limit (``memory.max``, a container's or a farm slot's), and the address space left under
``ulimit -v`` (RLIMIT_AS). Half, because the reader's copy is rarely the only one (a
float64 conversion, the fit's outputs, an encoder's buffer). ``USDAHD_MEMORY_BUDGET`` (bytes,
or with a suffix K, M, G, T: ``USDAHD_MEMORY_BUDGET=8G``) replaces it.

Only numpy-free standard library: importable from any layer.
"""

from __future__ import annotations

import os
import re
import sys

__all__ = ["cap_malloc_arenas", "check"]

#: Environment variable that sets the budget (bytes; K/M/G/T suffixes, powers of 1024).
ENV = "USDAHD_MEMORY_BUDGET"
_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def human(n: float) -> str:
    """``2700000128`` -> ``"2.5 GiB"`` (powers of 1024, as ``ulimit -v`` and ``free`` count)."""
    if n < 1024:
        return f"{n:.0f} B"
    for unit in ("KiB", "MiB", "GiB", "TiB"):
        n /= 1024
        if n < 1024 or unit == "TiB":
            return f"{n:.1f} {unit}"
    return f"{n:.1f} TiB"  # pragma: no cover


def parse_size(text: str) -> int:
    """``"8G"`` -> 8 * 2**30; ValueError for anything else."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([KMGT]?)i?B?\s*", text, re.IGNORECASE)
    if not m:
        raise ValueError(f"not a size: {text!r} (give bytes, or e.g. 512M, 8G)")
    return int(float(m.group(1)) * _UNITS[m.group(2).upper()])


def _vm_size() -> int:
    """The address space this process already maps (bytes; 0 when unknown)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _cgroup_limit() -> int | None:
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path) as f:
                text = f.read().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < 2**60:
            return int(text)
    return None


def budget() -> tuple[int, str]:
    """(bytes, why): the memory budget and a phrase saying where it comes from."""
    env = os.environ.get(ENV, "").strip()
    if env:
        try:
            return parse_size(env), f"{ENV}={env}"
        except ValueError:
            pass  # a bad value is reported by check(); fall back to the computed budget
    limits: list[tuple[int, str]] = []
    try:
        phys = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        limits.append((phys, f"{human(phys)} of physical memory"))
    except (ValueError, OSError, AttributeError):
        pass
    cg = _cgroup_limit()
    if cg is not None:
        limits.append((cg, f"the {human(cg)} cgroup memory limit"))
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY:
            left = max(0, soft - _vm_size())
            limits.append((left, f"{human(left)} of address space left under ulimit -v"))
    except (ImportError, ValueError, OSError):
        pass
    if not limits:
        return 4 * 2**30, "a 4.0 GiB default (no memory size found)"
    size, what = min(limits)
    return size // 2, f"half of {what}; {ENV} sets it"


def check(size: int, what: str, fix: str, error: type | None = None) -> None:
    """Raise ``error`` (default InputError; one line) when ``size`` bytes exceed the budget,
    before anything is allocated. what : the file and the thing that would be allocated
    ("x.npz: the 'sh' array inflates to"); fix : what the user can do."""
    from usdahd.errors import InputError

    error = error or InputError

    env = os.environ.get(ENV, "").strip()
    if env:
        try:
            parse_size(env)
        except ValueError as exc:
            raise InputError(f"{ENV}: {exc}") from None
    limit, why = budget()
    if size > limit:
        raise error(
            f"{what} {human(size)}, above the memory budget of {human(limit)} ({why}); {fix}"
        )


#: glibc malloc arenas a usdahd command's process may use (``M_ARENA_MAX``; glibc's default
#: is 8 per core). Memory a thread frees stays in its own arena, where the main thread's
#: allocations do not reuse it: with prims traced on pool threads, the classroom at the
#: defaults (`/usr/bin/time -v usdahd bake classroom.usdc --json -q`, 918,992 texels, 2
#: cores, 2026-12-07) peaked at 1,624,548 kB by default, 1,371,744 kB with 2 arenas and
#: 1,297,492 kB with 1, in the same wall time (1:41-1:46); 32^2 and 128^2 bakes of the samples
#: equal within their scatter (docs/scenes.md).
MALLOC_ARENAS = 2


def cap_malloc_arenas(n: int = MALLOC_ARENAS) -> bool:
    """Cap this process's glibc malloc arenas at ``n`` (``mallopt(M_ARENA_MAX, n)``), for the
    arenas created from now on: call it first thing in a process of our own (the console
    commands do; a host application embedding usdahd decides for itself, e.g. with
    ``MALLOC_ARENA_MAX=2`` in its environment). A ``MALLOC_ARENA_MAX`` already set wins.
    Returns whether the cap was set (False off glibc)."""
    if os.environ.get("MALLOC_ARENA_MAX") or not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # no C library symbols, or not glibc's
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(-8, int(n)))  # M_ARENA_MAX (glibc's malloc.h)
