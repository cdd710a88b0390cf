"""Executors: run independent bake tasks (per mesh / per tile) and collect their results.

A task is a picklable-in-spirit callable with no shared mutable state except the read-only
Tracer; results come back in submission order, so output never depends on scheduling. The
local default uses a thread pool over both cores (Embree queries and most numpy kernels release
the GIL). A cluster backend only needs to implement :class:`Executor.map`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import Any


class Executor:
    """Interface: ``map(fn, tasks) -> list`` of ``fn(task)`` in task order."""

    def map(self, fn: Callable[[Any], Any], tasks: Iterable[Any]) -> list:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class SerialExecutor(Executor):
    """Runs tasks one after the other in this thread (debugging, profiling)."""

    def map(self, fn, tasks):
        return [fn(t) for t in tasks]


class LocalExecutor(Executor):
    """Thread pool on this machine; ``workers`` defaults to the CPU count (2 here)."""

    def __init__(self, workers: int | None = None):
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        self._pool = ThreadPoolExecutor(self.workers) if self.workers > 1 else None

    def map(self, fn, tasks):
        tasks = list(tasks)
        if self._pool is None or len(tasks) <= 1:
            return [fn(t) for t in tasks]
        return list(self._pool.map(fn, tasks))

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


def split_tiles(n: int, tile: int) -> list[slice]:
    """Contiguous slices of at most ``tile`` items covering ``range(n)`` (task granularity)."""
    return [slice(s, min(n, s + tile)) for s in range(0, n, max(1, tile))]


def default_executor() -> Executor:
    return LocalExecutor()
