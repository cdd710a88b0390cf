"""The README's quick start works in order on a fresh clone (issue 18).

Command 1 installs and bakes the sample Cornell box into ``samples/``; command 2 installs and
runs the tests. Command 1's outputs must not change what command 2 collects or make it fail.
The equivalents run here in a fresh copy of every tracked file, as a new git repository (the
installed usdahd is used instead of a new virtualenv: installing is tested by the packaging
tests and CI).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import usdahd

ROOT = Path(__file__).resolve().parents[1]
#: The folder holding the usdahd these tests import (the checkout for an editable install,
#: site-packages for a plain one): subprocesses run the same code, with the same numba cache.
USDAHD_PATH = str(Path(usdahd.__file__).resolve().parents[1])
README = ROOT / "README.md"


def _commands() -> list[str]:
    blocks = re.findall(r"```sh\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    return [b.strip() for b in blocks]


def test_readme_quick_start_is_the_two_commands():
    bake, tests = _commands()[:2]
    assert bake.endswith("pip install . && usdahd warmup && usdahd bake samples/cornell_box.usda")
    assert tests.endswith("pip install '.[test]' && pip install -e benchmarks/ && pytest")


def _clone(tmp_path: Path) -> Path:
    """A fresh-clone-like tree: every file git tracks (working-tree versions), in a new git
    repository, minus the ``usdahd/`` package so the installed one (numba cache warm) runs."""
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs git and a git checkout")
    files = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True
    ).stdout.split(b"\0")
    dest = tmp_path / "clone"
    for rel in (f.decode() for f in files if f):
        if rel.startswith("usdahd/") or not (ROOT / rel).is_file():
            continue
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, dest / rel)
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    for cmd in (["init", "-q"], ["add", "-A"], ["commit", "-qm", "clone"]):
        subprocess.run([*git, *cmd], cwd=dest, check=True, capture_output=True)
    return dest


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=USDAHD_PATH + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _bake(clone: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", "samples/cornell_box.usda", *extra],
        cwd=clone,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=900,
    )


def _collect(clone: Path) -> list[str]:
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"],
        cwd=clone,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return sorted(ln for ln in proc.stdout.splitlines() if "::" in ln)


def _untracked(clone: Path) -> str:
    return subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all", "samples"],
        cwd=clone,
        capture_output=True,
        text=True,
    ).stdout


def test_command_1_outputs_do_not_change_what_command_2_collects(tmp_path):
    """Fast equivalent: bake the sample where command 1 does (tiny settings), then the test
    collection is the same as before, and git sees no new file."""
    clone = _clone(tmp_path)
    before = _collect(clone)
    proc = _bake(clone, "--resolution", "8", "--samples", "4", "--bounces", "0", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert (clone / "samples" / "cornell_box.lightmaps.usda").is_file()
    assert (clone / "samples" / "lightmaps").is_dir()
    after = _collect(clone)
    assert after == before, sorted(set(after) ^ set(before))
    assert not any(".lightmaps.usd" in t for t in after)
    assert _untracked(clone) == "", "bake outputs must be ignored by git"


@pytest.mark.slow
def test_readme_commands_in_order(tmp_path):
    """Command 1 verbatim (default settings), its validate hint, then the tests that glob the
    samples, in the same clone."""
    clone = _clone(tmp_path)
    proc = _bake(clone)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    val = subprocess.run(
        [sys.executable, "-m", "usdahd", "validate", "samples/cornell_box.lightmaps.usda"],
        cwd=clone,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=600,
    )
    assert val.returncode == 0, val.stdout + val.stderr
    tests = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "tests/bake/test_bake.py",
            "tests/test_samples.py",
            "-k",
            "every_sample or regenerate or size_budget",
        ],
        cwd=clone,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=1800,
    )
    assert tests.returncode == 0, tests.stdout[-3000:]
    assert " passed" in tests.stdout and "failed" not in tests.stdout
