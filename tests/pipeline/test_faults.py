"""Faults during a bake (issue 18): SIGKILL/SIGINT at every commit point, two bakes of one
output at once, a full disk. After each the previous bake is intact and validates clean, the
error is one clear line, and a re-run succeeds and leaves no stray file.

Kill points are exact: ``USDAHD_FAULT=<point>`` makes the bake signal itself there
(:data:`usdahd.pipeline.FAULT_POINTS`), so every test is deterministic.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import usdahd
from tests import mounts, procs
from usdahd import cli, pipeline
from usdahd.usd.author import referenced_assets

ROOT = Path(__file__).resolve().parents[2]
#: The folder holding the usdahd these tests import (the checkout for an editable install,
#: site-packages for a plain one): subprocesses run the same code, with the same numba cache.
USDAHD_PATH = str(Path(usdahd.__file__).resolve().parents[1])
SAMPLE = ROOT / "samples" / "cornell_box.usda"
TINY = ["--samples", "4", "--bounces", "0"]


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("USDAHD_FAULT", None)
    env.update(extra)
    return env


def _interactive_sigint() -> None:
    """Child setup: SIGINT at its default, as in a terminal. A job started in the background of
    a non-interactive shell (``cmd &``, which is how CI scripts often run) inherits SIGINT
    *ignored*, and Python then keeps ignoring it (no KeyboardInterrupt), as nohup intends; the
    SIGINT tests are about the interactive Ctrl-C case, so they must not inherit that."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _popen(stage: Path, *args: str, **env) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "usdahd", "bake", str(stage), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(**env),
        preexec_fn=_interactive_sigint,
    )


def _bake(stage: Path, *args: str, **env) -> subprocess.CompletedProcess:
    proc = _popen(stage, *args, **env)
    out, err = proc.communicate(timeout=600)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _validate(layer: Path, capsys) -> int:
    code = cli.main(["validate", "--quiet", str(layer)])
    capsys.readouterr()
    return code


def _resolutions(layer: Path) -> set[tuple[int, int]]:
    from pxr import Sdf, Usd

    from usdahd.usd import schema

    Sdf.Layer.FindOrOpen(str(layer)).Reload(force=True)
    stage = Usd.Stage.Open(str(layer))
    return {schema.read_results(p).resolution for p in schema.prims_with_api(stage)}


def _snapshot(layer: Path) -> dict[Path, bytes]:
    """The layer and every file it references, by content."""
    files = {layer: layer.read_bytes()}
    for f in referenced_assets(layer):
        files[f] = f.read_bytes()
    return files


def _assert_tidy(layer: Path) -> None:
    """Nothing but referenced textures in lightmaps/, no temp layers beside the layer."""
    refs = referenced_assets(layer)
    for f in (layer.parent / "lightmaps").iterdir():
        assert f.resolve() in refs, f"stray file {f.name}"
    # the lock file too: a bake removes it when it ends (issue 40)
    stray = [f.name for f in layer.parent.iterdir() if f.name.startswith(f".{layer.stem}.")]
    assert stray == [], stray


@pytest.fixture
def baked(tmp_path, capsys):
    stage = tmp_path / SAMPLE.name
    shutil.copy2(SAMPLE, stage)
    assert cli.main(["bake", str(stage), "--resolution", "8", *TINY, "--quiet"]) == 0
    capsys.readouterr()
    layer = tmp_path / "cornell_box.lightmaps.usda"
    assert _validate(layer, capsys) == 0
    return stage, layer


@pytest.mark.parametrize("point", pipeline.FAULT_POINTS)
def test_sigkill_at_each_point_leaves_the_previous_bake_valid(baked, capsys, point):
    stage, layer = baked
    before = _snapshot(layer)
    proc = _bake(stage, "--force", "--resolution", "16", *TINY, USDAHD_FAULT=point)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert _validate(layer, capsys) == 0
    if point == "layer_replaced":  # killed after the commit: the new bake is whole
        assert _resolutions(layer) == {(16, 16)}
    else:
        assert _snapshot(layer) == before  # layer and every texture it names untouched
        assert _resolutions(layer) == {(8, 8)}
    again = _bake(stage, "--resolution", "16", *TINY, "--quiet")
    assert again.returncode == 0, again.stderr
    assert _validate(layer, capsys) == 0
    assert _resolutions(layer) == {(16, 16)}
    _assert_tidy(layer)  # the re-run removed what the killed bake left


@pytest.mark.parametrize("point", ["first_texture_committed", "layer_exported"])
def test_sigint_exits_130_and_cleans_up(baked, capsys, point):
    stage, layer = baked
    before = _snapshot(layer)
    proc = _bake(
        stage, "--force", "--resolution", "16", *TINY, USDAHD_FAULT=point, USDAHD_FAULT_SIGNAL="INT"
    )
    assert proc.returncode == 130, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == "usdahd bake: interrupted"
    assert _snapshot(layer) == before
    assert _validate(layer, capsys) == 0
    _assert_tidy(layer)  # Ctrl-C cleans up at once, no re-run needed


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_two_bakes_of_one_output_at_once_are_serialised(baked, capsys):
    stage, layer = baked
    # A stops itself while holding the lock (after tracing, before writing anything).
    first = _popen(
        stage,
        "--force",
        "--resolution",
        "16",
        *TINY,
        USDAHD_FAULT="traced",
        USDAHD_FAULT_SIGNAL="STOP",
    )
    try:
        procs.wait_stopped(first.pid)
        second = _popen(stage, "--resolution", "12", *TINY, "--quiet")
        line = second.stderr.readline()  # B blocks on the lock and says so
        assert "another usdahd bake" in line and "waiting" in line, line
        assert second.poll() is None
        os.kill(first.pid, signal.SIGCONT)
        out1, err1 = first.communicate(timeout=600)
        out2, err2 = second.communicate(timeout=600)
    finally:
        for p in (first,):
            if p.poll() is None:
                os.kill(p.pid, signal.SIGCONT)
                p.kill()
    assert first.returncode == 0, err1
    assert second.returncode == 0, err2
    # B planned after A committed: every prim at B's resolution, nothing mixed, clean.
    assert _resolutions(layer) == {(12, 12)}
    assert _validate(layer, capsys) == 0
    _assert_tidy(layer)


@pytest.fixture
def small_disk(tmp_path):
    mnt = tmp_path / "disk"
    mnt.mkdir()
    mounts.mount_tmpfs(mnt, "size=2m")  # as root (CI) a failed mount fails; else a skip
    try:
        yield mnt
    finally:
        mounts.unmount(mnt)


def _fill(folder: Path, leave_kib: int) -> Path:
    filler = folder / "filler"
    free = shutil.disk_usage(folder).free
    with open(filler, "wb") as f:
        f.write(b"\0" * max(0, free - leave_kib * 1024))
    return filler


@pytest.mark.parametrize("leave_kib", [16, 96, 320])
def test_full_disk_keeps_the_previous_bake_and_a_rerun_succeeds(small_disk, capsys, leave_kib):
    stage = small_disk / SAMPLE.name
    shutil.copy2(SAMPLE, stage)
    layer = small_disk / "cornell_box.lightmaps.usda"
    assert _bake(stage, "--resolution", "8", *TINY, "--quiet").returncode == 0
    before = _snapshot(layer)
    filler = _fill(small_disk, leave_kib)
    proc = _bake(stage, "--force", "--resolution", "32", *TINY, "--quiet")
    assert proc.returncode in (1, 2), proc.stderr
    assert "Traceback" not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("usdahd bake: error: ")]
    assert errors and all("disk is full" in e or "no space left" in e for e in errors), errors
    # Prims that could not be written keep their previous record and files.
    assert _validate(layer, capsys) == 0
    if proc.returncode == 2:
        assert _snapshot(layer) == before
    filler.unlink()
    again = _bake(stage, "--resolution", "32", *TINY, "--quiet")
    assert again.returncode == 0, again.stderr
    assert _resolutions(layer) == {(32, 32)}
    assert _validate(layer, capsys) == 0
    _assert_tidy(layer)
