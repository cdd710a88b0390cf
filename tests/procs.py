"""Process helpers shared by the tests that stop and kill real bakes (test_faults, test_locks)."""

from __future__ import annotations

import time


def wait_stopped(pid: int, timeout: float = 300.0) -> None:
    """Wait until process ``pid`` is stopped (state T in /proc/PID/stat), at most timeout s."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with open(f"/proc/{pid}/stat") as f:
            if f.read().rsplit(")", 1)[1].split()[0] == "T":
                return
        time.sleep(0.05)
    raise AssertionError("the first bake never reached its stop point")
