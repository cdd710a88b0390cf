"""tmpfs mounts for the full-disk and read-only-output tests (issue 40).

Those tests must run where it matters: CI (``.ci/run``) runs as root, and root can mount a
tmpfs, so as root a mount that fails is a test *failure* with the mount's own message (a
container without CAP_SYS_ADMIN must be given it, e.g. ``docker run --cap-add SYS_ADMIN``), never
a silent skip. Only a non-root run skips, saying why.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

#: Why a non-root run cannot run these tests.
NOT_ROOT = (
    "mounting a tmpfs (the full-disk / read-only-mount tests) needs root; CI runs as root "
    "(.ci/run), where these tests always run"
)


def is_root() -> bool:
    return os.geteuid() == 0


def mount_tmpfs(path: Path, options: str) -> None:
    """Mount a tmpfs with ``options`` (e.g. ``size=2m`` or ``ro,size=1m``) at ``path``, which
    must exist. Skips when not root; as root a failed mount fails the test."""
    if not is_root():
        pytest.skip(NOT_ROOT)
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)],
        capture_output=True,
        text=True,
    )
    if proc.returncode:
        pytest.fail(
            f"running as root but `mount -t tmpfs -o {options}` failed "
            f"({proc.stderr.strip() or proc.returncode}): give the container CAP_SYS_ADMIN "
            "(docker run --cap-add SYS_ADMIN); these tests must not be skipped in CI",
            pytrace=False,
        )


def unmount(path: Path) -> None:
    subprocess.run(["umount", str(path)], capture_output=True)
