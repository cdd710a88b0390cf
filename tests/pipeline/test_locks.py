"""The bake lock on a farm (issue 40), with real processes: a waiting bake names the holder (host,
pid, since when), gives up after ``--lock-timeout`` with exit 2 when the holder is hung (stopped),
a dead holder never blocks, and no lock file is left beside the layer when a bake ends.

The holder is stopped or killed at an exact point with ``USDAHD_FAULT`` (see
:data:`usdahd.pipeline.FAULT_POINTS`), so nothing depends on timing except the timeout itself.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import usdahd
from tests import procs
from usdahd import cli
from usdahd.pipeline import outputs

ROOT = Path(__file__).resolve().parents[2]
USDAHD_PATH = str(Path(usdahd.__file__).resolve().parents[1])
SAMPLE = ROOT / "samples" / "cornell_box.usda"
TINY = ["--resolution", "8", "--samples", "4", "--bounces", "0"]

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("USDAHD_FAULT", None)
    env.update(extra)
    return env


def _popen(stage: Path, *args: str, **env) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "usdahd", "bake", str(stage), *TINY, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(**env),
        cwd=stage.parent,  # not the checkout: `-m` puts the cwd first on sys.path
    )


def _stray(folder: Path) -> list[str]:
    return sorted(f.name for f in folder.iterdir() if f.name.endswith(".lock"))


@pytest.fixture
def stage(tmp_path):
    dst = tmp_path / SAMPLE.name
    shutil.copy2(SAMPLE, dst)
    return dst


@pytest.fixture
def stopped_holder(stage):
    """A bake of ``stage`` stopped (SIGSTOP, alive) while it holds the lock, after tracing."""
    proc = _popen(stage, "--force", USDAHD_FAULT="traced", USDAHD_FAULT_SIGNAL="STOP")
    try:
        procs.wait_stopped(proc.pid)
        yield proc
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)
            proc.kill()
        proc.communicate()


def test_no_lock_file_is_left_beside_the_layer(stage, capsys):
    assert cli.main(["bake", str(stage), *TINY, "--quiet"]) == 0
    assert cli.main(["bake", str(stage), *TINY, "--quiet", "--force"]) == 0
    capsys.readouterr()
    assert (stage.parent / "cornell_box.lightmaps.usda").is_file()
    assert _stray(stage.parent) == []


def test_stopped_holder_times_out_with_exit_2_naming_it(stage, stopped_holder):
    holder = json.loads(outputs.lock_path(stage.parent / "cornell_box.lightmaps.usda").read_text())
    assert holder["pid"] == stopped_holder.pid and holder["host"] == socket.gethostname()
    t0 = time.monotonic()
    waiter = _popen(stage, "--lock-timeout", "2", "--json")
    out, err = waiter.communicate(timeout=300)
    waited = time.monotonic() - t0
    assert waiter.returncode == 2, err
    line = [ln for ln in err.splitlines() if ln.startswith("usdahd bake: error: ")]
    assert len(line) == 1, err
    for word in (f"pid {stopped_holder.pid}", socket.gethostname(), "since", "stopped"):
        assert word in line[0], line
    assert "--lock-timeout 2" in line[0] and "cornell_box.lightmaps.usda" in line[0]
    assert json.loads(out)["exit_code"] == 2
    # it waited (the message came first) and gave up after about 2 s, not at once or never
    assert "waiting for it to finish" in err and "giving up after 2 s" in err
    assert 2.0 <= waited < 120, waited
    # the holder resumes and finishes; then nothing is left beside the layer
    os.kill(stopped_holder.pid, signal.SIGCONT)
    _, err1 = stopped_holder.communicate(timeout=600)
    assert stopped_holder.returncode == 0, err1
    assert _stray(stage.parent) == []


def test_waiting_bake_names_the_holder_then_runs_after_it(stage, stopped_holder):
    waiter = _popen(stage, "--quiet")
    line = waiter.stderr.readline()  # B blocks on the lock and says who holds it
    assert "another usdahd bake" in line and "waiting" in line, line
    assert f"pid {stopped_holder.pid} on host {socket.gethostname()}" in line, line
    assert "since 2" in line and "s ago" in line and "stopped" in line, line
    assert waiter.poll() is None
    os.kill(stopped_holder.pid, signal.SIGCONT)
    _, err1 = stopped_holder.communicate(timeout=600)
    _, err2 = waiter.communicate(timeout=600)
    assert stopped_holder.returncode == 0, err1
    assert waiter.returncode == 0, err2
    assert _stray(stage.parent) == []


def test_a_dead_holder_never_blocks(stage):
    killed = _popen(stage, "--force", USDAHD_FAULT="traced")  # SIGKILL holding the lock
    _, err = killed.communicate(timeout=600)
    assert killed.returncode == -signal.SIGKILL, err
    lock = stage.parent / ".cornell_box.lightmaps.usda.lock"
    assert json.loads(lock.read_text())["pid"] == killed.pid  # left behind by the kill
    again = _popen(stage, "--lock-timeout", "0")  # would exit 2 if it had to wait at all
    _, err = again.communicate(timeout=600)
    assert again.returncode == 0, err
    assert "waiting" not in err
    assert _stray(stage.parent) == []  # and the stale file is gone


def test_negative_lock_timeout_is_a_usage_error(stage, capsys):
    assert cli.main(["bake", str(stage), *TINY, "--lock-timeout", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--lock-timeout must be >= 0" in err


CRITICAL = textwrap.dedent(
    """
    import os, sys, time
    from pathlib import Path
    from usdahd.pipeline.outputs import output_lock
    from usdahd.pipeline.settings import BakeOptions

    out, log = Path(sys.argv[1]), sys.argv[2]
    for _ in range(int(sys.argv[3])):
        with output_lock(out, BakeOptions(quiet=2, lock_timeout=120)):
            with open(log, "a") as f:
                f.write(f"in {os.getpid()}\\n")
            time.sleep(0.01)
            with open(log, "a") as f:
                f.write(f"out {os.getpid()}\\n")
    """
)


def test_lock_is_exclusive_across_processes_while_its_file_is_removed(tmp_path):
    """Four processes take the lock 15 times each; the holder removes the lock file every time
    it lets go, so waiters keep locking files that are then unlinked. The log shows one holder
    at a time (every "in" followed by the same pid's "out") and no lock file remains."""
    out, log = tmp_path / "x.lightmaps.usda", tmp_path / "log"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", CRITICAL, str(out), str(log), "15"],
            env=_env(),
            cwd=tmp_path,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(4)
    ]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    lines = log.read_text().split()
    pairs = list(zip(lines[0::4], lines[1::4], lines[2::4], lines[3::4], strict=True))
    assert len(pairs) == 60
    for a, pid_a, b, pid_b in pairs:
        assert (a, b) == ("in", "out") and pid_a == pid_b
    assert _stray(tmp_path) == []
