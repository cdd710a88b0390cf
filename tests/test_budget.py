"""usdahd.budget.cap_malloc_arenas: the console commands cap glibc's malloc arenas (peak memory:
memory a thread frees stays in its arena, where the main thread does not reuse it; the
classroom bake peaked at 1.55 GiB with glibc's default and 1.31 GiB with 2 arenas)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from usdahd import budget, cli

glibc = pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
    reason="malloc arenas are glibc's",
)

# six threads malloc and free at once, then glibc's malloc_stats() lists the arenas they made
PROBE = r"""
import ctypes, sys, threading
cap = sys.argv[1]
if cap != "none":
    from usdahd import budget
    print(budget.cap_malloc_arenas(int(cap)), flush=True)
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)
barrier = threading.Barrier(6)
def work():
    barrier.wait()
    for _ in range(2000):
        libc.free(libc.malloc(4096))
threads = [threading.Thread(target=work) for _ in range(6)]
[t.start() for t in threads]
[t.join() for t in threads]
libc.malloc_stats()
"""


def _arenas(cap: str, arena_max: str | None = None) -> tuple[int, str]:
    """(arenas listed by malloc_stats, what the cap returned) in a fresh process."""
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    if arena_max is not None:
        env["MALLOC_ARENA_MAX"] = arena_max
    r = subprocess.run([sys.executable, "-c", PROBE, cap], capture_output=True, text=True,
                       env=env, check=True)  # fmt: skip
    return sum(line.startswith("Arena") for line in r.stderr.splitlines()), r.stdout.strip()


@glibc
def test_the_cap_holds_the_arenas_threads_make():
    free, _ = _arenas("none")
    assert free > 2  # glibc's default: an arena per thread that meets contention
    for cap in (1, 2):
        n, said = _arenas(str(cap))
        assert said == "True" and n <= cap


@glibc
def test_an_arena_max_already_set_wins():
    n, said = _arenas("1", arena_max="3")
    assert said == "False" and 1 < n <= 3


def test_the_commands_that_run_threads_cap_the_arenas_first(monkeypatch, tmp_path, capsys):
    calls = []
    monkeypatch.setattr(budget, "cap_malloc_arenas", lambda: calls.append(1) or True)
    assert cli.main(["bake", str(tmp_path / "missing.usda")]) == 2
    assert "missing.usda" in capsys.readouterr().err
    assert calls == [1]
    assert set(cli.ARENA_COMMANDS) == {"bake", "validate", "preview", "warmup"}
