"""Hostile inputs and farm faults (issue 40): bounded time and memory on hostile geometry and
files, write failures that name the file and the fix, Ctrl-C while importing, and the
full-disk / read-only-mount tests running where CI runs them (as root).

The lock rows of the issue are in tests/pipeline/test_locks.py.
"""

from __future__ import annotations

import io
import json
import os
import resource
import shutil
import signal
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

import usdahd
from tests import mounts
from usdahd import cli, images
from usdahd.errors import ImageError, InputError
from usdahd.usd import normals as N

ROOT = Path(__file__).resolve().parents[1]
USDAHD_PATH = str(Path(usdahd.__file__).resolve().parents[1])
SAMPLE = ROOT / "samples" / "cornell_box.usda"
SKY = ROOT / "samples" / "sh" / "sky_sun.npy"
GIB = 2**30


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for k in ("USDAHD_FAULT", "USDAHD_MEMORY_BUDGET"):
        env.pop(k, None)
    env.update(extra)
    return env


#: Runs argv[1:] and reports its peak RSS: a fresh process whose only child is the command.
_MEASURE = (
    "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
    "print('PEAK_RSS_KB', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, "
    "file=sys.stderr); sys.exit(r.returncode)"
)


def _run_measured(argv, timeout: float, cwd: Path, preexec=None, **env):
    """Run ``argv``; returns (returncode, stdout, stderr, wall seconds, peak RSS bytes of the
    command). The whole process group is killed after ``timeout`` seconds (returncode -9)."""

    def setup():
        os.setsid()
        if preexec is not None:
            preexec()

    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-c", _MEASURE, *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(**env),
        preexec_fn=setup,
        cwd=cwd,  # never the checkout: `-m` puts the cwd first on sys.path
    )
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        return -9, out, err, time.monotonic() - t0, 0
    wall = time.monotonic() - t0
    lines = err.splitlines()
    rss = int(lines[-1].split()[1]) * 1024 if lines and lines[-1].startswith("PEAK_RSS_KB") else 0
    return proc.returncode, out, "\n".join(lines[:-1]) + "\n", wall, rss


# ----------------------------------------------------------------- degenerate geometry


def _quads_plus_collapsed(n: int):
    """4 quads (a 2x2 grid, 9 points) plus ``n`` triangles whose corners are all point 9, which
    sits on point 0: (points (10, 3), counts, indices)."""
    g = np.array([[x, y, 0.0] for y in range(3) for x in range(3)])
    pts = np.concatenate([g, g[:1]])
    quads = [a + d for y in range(2) for x in range(2) for a in [y * 3 + x] for d in (0, 1, 4, 3)]
    idx = np.concatenate([np.array(quads), np.full(3 * n, 9)])
    counts = np.concatenate([np.full(4, 4), np.full(n, 3)])
    return pts, counts, idx


def test_collapsed_faces_leave_the_normals_of_the_rest_unchanged():
    """Normals of a mesh with collapsed faces = the rule on the mesh without them (an
    independent run of the rule); the collapsed corners take the average at their point."""
    pts, counts, idx = _quads_plus_collapsed(50)
    rng = np.random.default_rng(3)
    pts[:9, 2] = rng.normal(scale=0.3, size=9)  # a bent grid: the crease rule has work to do
    # extra collapsed faces made of distinct indices at one position, and a collinear one
    pts = np.concatenate([pts, pts[[4, 4, 4]], [[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    counts = np.concatenate([counts, [3, 3]])
    idx = np.concatenate([idx, [10, 11, 12], [13, 14, 15]])
    assert N.collapsed_faces(pts, counts, idx).tolist() == [False] * 4 + [True] * 51 + [False]
    for rule in (N.RULE_CREASE, N.RULE_SMOOTH):
        got = N.compute_normals(pts, counts, idx, rule)
        alone = N.compute_normals(pts, counts[:4], idx[:16], rule)
        np.testing.assert_array_equal(got[:16], alone)
        # point 9 is its own point (no live face uses it): +Z; points 10-12 likewise
        np.testing.assert_array_equal(got[16 : 16 + 150], np.tile([0, 0, 1], (150, 1)))


def _degenerate_stage(path: Path, n: int) -> None:
    from pxr import Usd, UsdGeom, UsdLux, Vt

    pts, counts, idx = _quads_plus_collapsed(n)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, "Z")
    UsdGeom.Xform.Define(stage, "/World")
    mesh = UsdGeom.Mesh.Define(stage, "/World/Floor")
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(idx.astype(np.int32)))
    mesh.GetSubdivisionSchemeAttr().Set("none")
    UsdLux.DistantLight.Define(stage, "/World/Sun").CreateIntensityAttr(3.0)
    stage.GetRootLayer().Save()


@pytest.mark.slow
def test_a_million_degenerate_triangles_bake_in_seconds_with_one_warning(tmp_path, capsys):
    """Issue 40's first row: 4 quads + 1,000,000 triangles with all corners equal, as .usdc.
    Was still running after 150 s (the crease-angle normals paired every corner at the shared
    point: 10^12 pairs); must bake within 30 s and 1 GiB with one warning naming the count and
    the prim."""
    warm = tmp_path / "warm"
    warm.mkdir()
    shutil.copy2(SAMPLE, warm / SAMPLE.name)  # compile/cache the kernels outside the timing
    assert cli.main(["bake", str(warm / SAMPLE.name), "--resolution", "8", "--samples", "4"]) == 0
    capsys.readouterr()
    stage = tmp_path / "degenerate.usdc"
    _degenerate_stage(stage, 1_000_000)
    argv = [sys.executable, "-m", "usdahd", "bake", str(stage), "--resolution", "16"]
    code, out, err, wall, rss = _run_measured(argv + ["--samples", "16"], 120, tmp_path)
    assert code == 0, err[-2000:]
    assert wall < 30, f"{wall:.1f} s"
    assert 0 < rss < GIB, f"peak RSS {rss / 2**20:.0f} MiB"
    print(f"degenerate bake: {wall:.1f} s, peak RSS {rss / 2**20:.0f} MiB")
    lines = [ln for ln in (out + err).splitlines() if "degenerate (zero-area)" in ln]
    assert len(lines) == 1, lines
    assert "1000000 degenerate" in lines[0] and "/World/Floor" in lines[0], lines
    assert "Traceback" not in err


# ------------------------------------------------------------------------ fit inputs


def _npz_bomb(path: Path, texels: int, block_texels: int = 65536) -> None:
    """An .npz whose 'sh' member declares (texels, 3, 9) float64 zeros (216 bytes per texel
    inflated) in about 1/1000 of that on disk, written in about a second: identical deflate
    blocks (each ends with a full flush, so its bytes do not depend on the blocks before it),
    in a zip64 archive written by hand. numpy's own np.load reads it back (tested below)."""
    head = io.BytesIO()
    np.lib.format.write_array_header_2_0(
        head, {"descr": "<f8", "fortran_order": False, "shape": (texels, 3, 9)}
    )
    head = head.getvalue()
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = comp.compress(head) + comp.flush(zlib.Z_FULL_FLUSH)
    zero = bytes(216 * block_texels)
    full, rest = divmod(texels, block_texels)
    block = comp.compress(zero) + comp.flush(zlib.Z_FULL_FLUSH)
    tail = comp.compress(zero[: 216 * rest]) + comp.flush(zlib.Z_FINISH)
    crc = zlib.crc32(head)
    for _ in range(full):
        crc = zlib.crc32(zero, crc)
    crc = zlib.crc32(zero[: 216 * rest], crc)
    size, csize = len(head) + 216 * texels, len(first) + full * len(block) + len(tail)
    name, big = b"sh.npy", 0xFFFFFFFF
    local = struct.pack("<IHHHHHIIIHH", 0x04034B50, 45, 0, 8, 0, 0x21, crc, big, big, 6, 20)
    with open(path, "wb") as f:
        f.write(local + name + struct.pack("<HHQQ", 1, 16, size, csize))
        f.write(first)
        for _ in range(full):
            f.write(block)
        f.write(tail)
        cd_at = f.tell()
        cd = struct.pack(
            "<IHHHHHHIIIHHHHHII", 0x02014B50, 45, 45, 0, 8, 0, 0x21, crc, big, big, 6, 28, 0, 0,
            0, 0, big,
        )  # fmt: skip
        cd += name + struct.pack("<HHQQQ", 1, 24, size, csize, 0)
        f.write(cd)
        end64 = f.tell()
        f.write(struct.pack("<IQHHIIQQQQ", 0x06064B50, 44, 45, 45, 0, 0, 1, 1, len(cd), cd_at))
        f.write(struct.pack("<IIQI", 0x07064B50, 0, end64, 1))
        f.write(struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 1, 1, len(cd), big, 0))


def test_npz_bomb_writer_makes_a_file_numpy_reads(tmp_path):
    path = tmp_path / "small.npz"
    _npz_bomb(path, 70_001)
    sh = np.load(path)["sh"]  # numpy's reader checks the CRC and sizes
    assert sh.shape == (70_001, 3, 9) and not sh.any()


def _limit_address_space(limit: int):
    def pre():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return pre


def test_npz_bomb_is_refused_before_inflating(tmp_path):
    """Issue 40's second row: a ~3 MB .npz whose 'sh' member inflates to 2.7 GB, run under a
    3 GB address-space limit. Was still running after 240 s; must refuse in one line naming the
    size and the budget, within 30 s and 1 GiB."""
    bomb = tmp_path / "bomb.npz"
    _npz_bomb(bomb, 12_500_000)  # 2.7e9 bytes inflated
    assert bomb.stat().st_size < 4e6
    argv = [sys.executable, "-m", "usdahd", "fit", str(bomb), "--json"]
    code, out, err, wall, rss = _run_measured(
        argv, 60, tmp_path, preexec=_limit_address_space(3 * 10**9)
    )
    assert code == 2, err[-2000:]
    assert wall < 30 and 0 < rss < GIB, (wall, rss)
    print(f"npz bomb: {wall:.1f} s, peak RSS {rss / 2**20:.0f} MiB")
    line = [ln for ln in err.splitlines() if ln.startswith("usdahd fit: error: ")]
    assert len(line) == 1, err
    for word in (str(bomb), "inflates to 2.5 GiB", "memory budget", "ulimit -v"):
        assert word in line[0], line
    assert json.loads(out)["exit_code"] == 2


def test_budget_refuses_a_large_npy_before_mapping_it(tmp_path, capsys, monkeypatch):
    path = tmp_path / "sh.npy"
    np.save(path, np.resize(np.load(SKY), (5000, 3, 9)).astype(np.float32))
    monkeypatch.setenv("USDAHD_MEMORY_BUDGET", "512K")
    assert cli.main(["fit", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err
    assert "needs 1.0 MiB, above the memory budget of 512.0 KiB (USDAHD_MEMORY_BUDGET=512K)" in err
    monkeypatch.setenv("USDAHD_MEMORY_BUDGET", "lots")
    assert cli.main(["fit", str(path)]) == 2
    assert "USDAHD_MEMORY_BUDGET: not a size: 'lots'" in capsys.readouterr().err


@pytest.mark.parametrize("dtype", ["<f8", ">f8", ">f4", "<f4"])
@pytest.mark.parametrize("container", ["npy", "npz"])
def test_fortran_ordered_and_non_native_arrays_are_fitted_as_they_are(
    tmp_path, capsys, dtype, container
):
    """Issue 40's third row: a Fortran-ordered (2, 4, 3, 9) array was refused ("save it with
    np.ascontiguousarray"); a library takes it as it is. Non-native byte order too. The fitted
    parameters equal those of the same values saved C-ordered, native, float64."""
    rng = np.random.default_rng(7)
    sh = np.resize(np.load(SKY), (8, 3, 9)).reshape(2, 4, 3, 9) * rng.uniform(
        0.5, 1.5, (2, 4, 1, 1)
    )
    sh = sh.astype(dtype).astype(np.float64)  # the values the file can hold exactly
    ref, odd = tmp_path / "ref.npy", tmp_path / f"odd.{container}"
    np.save(ref, sh)
    fortran = np.asfortranarray(sh.astype(dtype))
    assert fortran.flags.f_contiguous and not fortran.flags.c_contiguous
    if container == "npy":
        np.save(odd, fortran)
    else:
        np.savez_compressed(odd, sh=fortran)
    stored = np.load(odd, mmap_mode="r") if container == "npy" else np.load(odd)["sh"]
    assert stored.flags.f_contiguous and not stored.flags.c_contiguous  # as the file holds it
    assert stored.dtype == np.dtype(dtype)
    outs = []
    for src in (ref, odd):
        out = tmp_path / f"{src.stem}.params.npz"
        assert cli.main(["fit", str(src), "-o", str(out), "--json"]) == 0, capsys.readouterr()
        outs.append(dict(np.load(out)))
        capsys.readouterr()
    assert outs[0].keys() == outs[1].keys()
    for k in outs[0]:
        np.testing.assert_array_equal(outs[0][k], outs[1][k])
        assert outs[0][k].shape[:2] == (2, 4)


# ---------------------------------------------------------------------------- images


def test_image_readers_check_the_budget_before_decoding(tmp_path, monkeypatch):
    path = tmp_path / "big.exr"
    images.write(path, np.zeros((1024, 1024, 4), np.float32), color_space="raw")
    monkeypatch.setenv("USDAHD_MEMORY_BUDGET", "8M")
    want = "(1024 x 1024 pixels, 4 channels) decodes to 16.0 MiB, above the memory budget of 8.0"
    with pytest.raises(ImageError, match=r"big\.exr: the image") as exc:
        images.read(path)
    assert want in str(exc.value)
    with pytest.raises(ImageError) as exc:
        images.read_texels(path)
    assert want in str(exc.value)
    with pytest.raises(OSError) as exc:  # the validator's reader: reported as Unreadable
        images.read_native(path)
    assert want in str(exc.value)
    monkeypatch.setenv("USDAHD_MEMORY_BUDGET", "64M")
    assert images.read(path).pixels.shape == (1024, 1024, 4)


def test_images_write_never_leaves_a_cut_file_on_a_full_disk(tmp_path):
    """Issue 40's ``images.write`` row: OpenImageIO reports a short PNG write only through
    has_error, a TIFF's only after close(), and a failed final flush not at all; at every fill
    level of a small disk a write either raises ImageError naming the file and the full disk,
    or the file reads back bit-exact."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounts.mount_tmpfs(disk, "size=1m")
    rng = np.random.default_rng(0)
    cases = {
        ".png": rng.integers(0, 256, (160, 160, 4), dtype=np.uint8),  # ~100 KB, incompressible
        ".exr": rng.random((64, 64, 4)).astype(np.float16),
        ".tif": rng.integers(0, 256, (160, 160, 4), dtype=np.uint8),
    }
    raised = written = 0
    try:
        for ext, pixels in cases.items():
            for leave_kib in range(0, 140, 4):
                for f in disk.iterdir():
                    f.unlink()
                free = shutil.disk_usage(disk).free
                (disk / "filler").write_bytes(b"\0" * max(0, free - leave_kib * 1024))
                target = disk / f"x{ext}"
                try:
                    images.write(target, pixels, color_space="raw")
                except ImageError as exc:
                    assert str(exc).startswith(f"{target}: ") and "disk is full" in str(exc), exc
                    assert sorted(f.name for f in disk.iterdir()) == ["filler"]  # no temp left
                    raised += 1
                    continue
                np.testing.assert_array_equal(images.read(target).pixels, pixels)
                written += 1
    finally:
        mounts.unmount(disk)
    assert raised > 10 and written > 10, (raised, written)


# ------------------------------------------------------------------ write failures


def test_immutable_override_layer_is_named_with_the_fix(tmp_path, capsys):
    """Issue 40's fourth row: the override layer made immutable (chattr +i) before a re-bake;
    the error named a temp file. It must name the layer and say how to clear the flag."""
    if not mounts.is_root() or shutil.which("chattr") is None:
        pytest.skip("chattr +i needs root and chattr (e2fsprogs); CI runs as root")
    stage = tmp_path / SAMPLE.name
    shutil.copy2(SAMPLE, stage)
    tiny = ["--resolution", "8", "--samples", "4", "--bounces", "0", "--quiet"]
    assert cli.main(["bake", str(stage), *tiny]) == 0
    layer = tmp_path / "cornell_box.lightmaps.usda"
    before = layer.read_bytes()
    proc = subprocess.run(["chattr", "+i", str(layer)], capture_output=True, text=True)
    if proc.returncode:
        pytest.skip(f"this file system has no immutable flag: {proc.stderr.strip()}")
    try:
        capsys.readouterr()
        assert cli.main(["bake", str(stage), *tiny, "--force", "--resolution", "12"]) == 2
        err = capsys.readouterr().err
    finally:
        subprocess.run(["chattr", "-i", str(layer)], capture_output=True)
    line = [ln for ln in err.splitlines() if ln.startswith("usdahd bake: error: ")]
    assert len(line) == 1, err
    assert line[0].startswith(f"usdahd bake: error: {layer}: cannot replace the output layer")
    assert f"chattr -i {layer}" in line[0] and "-o" in line[0], line
    assert layer.read_bytes() == before
    strays = [f.name for f in tmp_path.iterdir() if f.name.startswith(".")]
    assert strays == [], strays


# ------------------------------------------------------------------------- Ctrl-C


def _console_script() -> Path:
    script = Path(sys.executable).parent / "usdahd"
    if not script.is_file():
        pytest.skip(f"no usdahd console script beside {sys.executable} (pip install the package)")
    return script


@pytest.mark.parametrize(
    "argv, library",
    [
        (["fit", str(SKY)], "_multiarray_umath"),  # numpy's core, early in the imports
        (["bake", str(SAMPLE), "--dry-run"], "libusd_"),  # pxr, late in the imports
    ],
    ids=["numpy", "pxr"],
)
def test_ctrl_c_while_importing_exits_130_with_one_line(tmp_path, argv, library):
    """Issue 40's Ctrl-C row: SIGINT while the console script is importing (the moment the
    named shared library is mapped into the process, found in /proc/PID/maps) gave a
    traceback. It must exit 130 with one line."""
    if not Path("/proc/self/maps").is_file():
        pytest.skip("needs /proc/PID/maps (Linux) to find the moment of the import")
    script = _console_script()
    proc = subprocess.Popen(
        [str(script), *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        cwd=tmp_path,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    end = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < end:
        try:
            if library in Path(f"/proc/{proc.pid}/maps").read_text():
                break
        except (FileNotFoundError, ProcessLookupError):
            break
        time.sleep(0.0005)
    assert proc.poll() is None, "the command finished before the library was loaded"
    os.kill(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert "Traceback" not in err, err
    assert proc.returncode == 130, (proc.returncode, err)
    assert err.endswith(": interrupted\n") and err.count("\n") == 1, err


# ------------------------------------------------------------- tests that must run


def test_mount_tests_fail_instead_of_skipping_as_root_without_the_capability():
    """Issue 40's row on the full-disk and read-only-mount tests: they skipped whenever a tmpfs
    could not be mounted, so CI (root) could skip them silently. Run one as root *without*
    CAP_SYS_ADMIN: it must fail and say why, not skip."""
    if not mounts.is_root():
        pytest.skip(mounts.NOT_ROOT)
    if shutil.which("setpriv") is None:
        pytest.skip("setpriv (util-linux) is needed to drop CAP_SYS_ADMIN for the child")
    proc = subprocess.run(
        ["setpriv", "--bounding-set", "-sys_admin", "--", sys.executable, "-m", "pytest",
         "-q", "-p", "no:cacheprovider", "-rs", "--timeout", "300",
         "tests/pipeline/test_faults.py::test_full_disk_keeps_the_previous_bake_and_a_rerun_succeeds[16]"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=600,
    )  # fmt: skip
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0, text[-3000:]
    summary = proc.stdout.strip().splitlines()[-1]  # e.g. "1 error in 8.68s"
    assert "skipped" not in summary and ("error" in summary or "failed" in summary), summary
    assert "CAP_SYS_ADMIN" in text and "must not be skipped" in text, text[-3000:]


def test_budget_rejects_nothing_it_should_accept(monkeypatch):
    """The default budget is half of the smallest limit and never below a sample's needs."""
    from usdahd import budget

    monkeypatch.delenv("USDAHD_MEMORY_BUDGET", raising=False)
    size, why = budget.budget()
    assert size >= 64 * 2**20 and "half of" in why
    budget.check(27 * 8 * 1000, "x", "y")  # a small array passes
    with pytest.raises(InputError, match=r"^x 1\.0 TiB, above the memory budget"):
        budget.check(2**40, "x", "y")


def test_fit_output_on_a_full_disk_names_the_file(tmp_path, capsys):
    """A write that fails through usdahd.io_util.atomic_path (here ``usdahd fit -o`` on a full
    disk) names the file the user asked for, not the hidden temp file, and the fix."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounts.mount_tmpfs(disk, "size=256k")
    src = tmp_path / "sh.npy"
    np.save(src, np.resize(np.load(SKY), (20000, 3, 9)))
    try:
        free = shutil.disk_usage(disk).free
        (disk / "filler").write_bytes(b"\0" * (free - 4096))
        target = disk / "params.npz"
        assert cli.main(["fit", str(src), "-o", str(target), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"usdahd fit: error: {target}: No space left on device; ")
        assert "the disk is full" in err and err.count("\n") == 1
        assert sorted(f.name for f in disk.iterdir()) == ["filler"]
    finally:
        mounts.unmount(disk)


def test_an_error_caused_by_ctrl_c_exits_130_not_internal_error(monkeypatch, capsys):
    """A Ctrl-C inside a C extension's import comes out as another exception (numpy raises
    ImportError "IMPORTANT: PLEASE READ THIS" with the interrupt in its context; seen once in
    test_ctrl_c_while_importing_exits_130_with_one_line[numpy]): it is the interrupt, exit 130,
    not "internal error" exit 2."""
    from usdahd import console

    def import_interrupted(args, command):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise ImportError("IMPORTANT: PLEASE READ THIS FOR ADVICE") from None

    def other_error(args, command):
        raise RuntimeError("a C extension failed while the interrupt was pending")

    monkeypatch.setattr(cli, "_run_captured", import_interrupted)
    assert cli.main(["validate", "missing.usda"]) == 130
    assert capsys.readouterr().err.strip() == "usdahd validate: interrupted"
    # the console script's SIGINT handler records the Ctrl-C even when nothing chains it
    monkeypatch.setattr(cli, "_run_captured", other_error)
    assert cli.main(["validate", "missing.usda", "--json"]) == 2  # no Ctrl-C: an internal error
    capsys.readouterr()
    monkeypatch.setattr(console, "_INTERRUPTS", [1])
    assert cli.main(["validate", "missing.usda", "--json"]) == 130
    out = capsys.readouterr()
    assert json.loads(out.out)["exit_code"] == 130 and "interrupted" in out.err
