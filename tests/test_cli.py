"""The command line's one error path and its shared options (issue 18).

Every command takes ``--json`` and ``-q/--quiet`` from one parent parser; ``--json`` prints a
JSON object also on errors; warnings survive ``--quiet`` but not ``-qq``; every error a user
can cause is one ``usdahd CMD: error:`` line naming the file/prim/flag and the fix, exit 2 (or
1 for findings), never a traceback. Pre-flight checks fail before any tracing.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import usdahd
from tests import mounts
from usdahd import cli
from usdahd.pipeline import run

ROOT = Path(__file__).resolve().parents[1]
#: The folder holding the usdahd these tests import (the checkout for an editable install,
#: site-packages for a plain one): subprocesses run the same code, with the same numba cache.
USDAHD_PATH = str(Path(usdahd.__file__).resolve().parents[1])
SAMPLES = ROOT / "samples"
FAST = ["--resolution", "8", "--samples", "4", "--bounces", "0"]


def _copy(tmp_path: Path, name: str = "open_plane.usda") -> Path:
    shutil.copy2(SAMPLES / name, tmp_path / name)
    tex = SAMPLES / "textures"
    if name == "normal_wall.usda":
        shutil.copytree(tex, tmp_path / "textures")
    return tmp_path / name


def _main(capsys, *argv):
    code = cli.main(list(argv))
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    return code, cap.out, cap.err


def _error_line(err: str, command: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith(f"usdahd {command}: error: ")]
    assert len(lines) == 1, err
    return lines[0]


def _count_traces(monkeypatch) -> list[int]:
    """Replace the bake's trace/fit/write stages (what ``run.bake`` calls once its plan is
    made) by a recorder: the list it returns grows by one per call. The tests that expect a
    refusal before tracing assert it stays empty; the control below shows it does grow."""
    traced: list[int] = []
    monkeypatch.setattr(run, "bake_jobs", lambda *a, **k: traced.append(1))
    return traced


def test_trace_recorder_sees_a_bake_that_traces(tmp_path, capsys, monkeypatch):
    traced = _count_traces(monkeypatch)
    code, _, err = _main(capsys, "bake", str(_copy(tmp_path)), *FAST)
    assert code == 0, err
    assert traced == [1]


# ----------------------------------------------------------------------------- shared options


@pytest.mark.parametrize("command", sorted(cli.COMMANDS))
def test_every_command_takes_json_and_quiet(command):
    parser = cli.build_parser()
    positional = ["x"] if command in ("bake", "validate", "fit", "preview") else []
    if command == "preview":
        positional += ["-o", "x.png"]
    if command == "export":
        positional = ["gltf", "x", "-o", "x.glb"]
    args = parser.parse_args([command, "--json", "-qq", *positional])
    assert args.json is True and args.quiet == 2


def test_plugin_path_json(capsys):
    code, out, _ = _main(capsys, "plugin-path", "--json", "--quiet")
    assert code == 0
    report = json.loads(out)
    assert Path(report["plugin_path"]).is_dir()
    assert report["export"].startswith("export PXR_PLUGINPATH_NAME=")


@pytest.mark.parametrize(
    "argv, code, words",
    [
        (["bake", "{tmp}/nope.usda"], 2, ["nope.usda", "no such file"]),
        (["bake", "{tmp}"], 2, ["is a directory", "stage file"]),
        (["validate", "{tmp}/nope.usda"], 2, ["nope.usda"]),
        (["fit", "{tmp}/nope.npy"], 2, ["nope.npy"]),
        (["bake", "{plane}", "--prim", "/World/Nope"], 2, ["--prim /World/Nope", "no such prim"]),
        (["bake", "{plane}", "--model", "bogus"], 2, ["invalid arguments"]),
    ],
)
def test_json_is_printed_on_errors(tmp_path, capsys, argv, code, words):
    plane = _copy(tmp_path)
    argv = [a.format(tmp=tmp_path, plane=plane) for a in argv]
    if code == 2 and "bogus" in argv:
        with pytest.raises(SystemExit) as exc:
            cli.main([*argv, "--json"])
        assert exc.value.code == 2
        out = capsys.readouterr().out
    else:
        got, out, err = _main(capsys, *argv, "--json")
        assert got == code
        line = _error_line(err, argv[0])
        for w in words:
            assert w in line, line
    report = json.loads(out)
    assert report["exit_code"] == code and report["command"] == argv[0]
    for w in words:
        assert w in report["error"], report


def test_interrupt_exits_130_with_one_line(capsys, monkeypatch):
    def interrupted(args):
        raise KeyboardInterrupt

    from usdahd.commands import plugin_path

    monkeypatch.setattr(plugin_path, "run", interrupted)
    code, out, err = _main(capsys, "plugin-path", "--json")
    assert code == 130
    assert err.strip() == "usdahd plugin-path: interrupted"
    assert json.loads(out)["exit_code"] == 130


@pytest.mark.parametrize(
    "exc, words",
    [
        (PermissionError(errno.EACCES, "Permission denied", "/x/lightmaps"), ["/x/lightmaps"]),
        (OSError(errno.ENOSPC, "No space left on device", "/x/a.exr"), ["disk is full"]),
        (IsADirectoryError(errno.EISDIR, "Is a directory", "/x/t.png"), ["not a directory"]),
        (MemoryError(), ["out of memory", "--resolution"]),
        (ValueError("boom"), ["internal error ValueError", "report a bug"]),
    ],
)
def test_every_exception_maps_to_a_message_and_exit_2(capsys, monkeypatch, exc, words):
    from usdahd.commands import plugin_path

    def boom(args):
        raise exc

    monkeypatch.setattr(plugin_path, "run", boom)
    code, out, err = _main(capsys, "plugin-path")
    assert code == 2
    line = _error_line(err, "plugin-path")
    for w in words:
        assert w in line, line


# ------------------------------------------------------------------------- pre-flight checks


def test_directory_output_layer_is_refused(tmp_path, capsys):
    plane = _copy(tmp_path)
    (tmp_path / "out.usda").mkdir()
    code, _, err = _main(capsys, "bake", str(plane), "-o", str(tmp_path / "out.usda"), *FAST)
    assert code == 2 and "is a directory" in _error_line(err, "bake")


@pytest.mark.parametrize("kind", ["file", "dangling_symlink", "symlink"])
def test_lightmaps_folder_replaced_is_refused_before_tracing(tmp_path, capsys, kind, monkeypatch):
    plane = _copy(tmp_path)
    lm = tmp_path / "lightmaps"
    if kind == "file":
        lm.write_text("not a folder")
    elif kind == "dangling_symlink":
        lm.symlink_to(tmp_path / "gone")
    else:
        (tmp_path / "elsewhere").mkdir()
        lm.symlink_to(tmp_path / "elsewhere")
    traced = _count_traces(monkeypatch)
    for extra in ([], ["--dry-run"]):
        code, _, err = _main(capsys, "bake", str(plane), *FAST, *extra)
        assert code == 2, err
        line = _error_line(err, "bake")
        assert str(lm) in line and "-o" in line
    assert not traced


def _read_only_dir(path: Path) -> None:
    """Make ``path`` unwritable even for root: a read-only tmpfs mount (or chmod as a user)."""
    path.mkdir()
    if mounts.is_root():
        mounts.mount_tmpfs(path, "ro,size=1m")  # a failed mount as root fails the test
    else:
        path.chmod(0o555)


def _unmount(path: Path) -> None:
    if mounts.is_root():
        mounts.unmount(path)
    else:
        path.chmod(0o755)


def test_read_only_output_folder_fails_before_tracing(tmp_path, capsys, monkeypatch):
    plane = _copy(tmp_path)
    ro = tmp_path / "ro"
    _read_only_dir(ro)
    traced = _count_traces(monkeypatch)
    try:
        for extra in ([], ["--dry-run"]):
            code, out, err = _main(
                capsys, "bake", str(plane), "-o", str(ro / "x.lightmaps.usda"), "--json", *extra
            )
            assert code == 2
            line = _error_line(err, "bake")
            assert str(ro) in line and "writable" in line
            assert json.loads(out)["exit_code"] == 2
    finally:
        _unmount(ro)
    assert not traced


def test_denoise_without_pyoidn_fails_before_tracing(tmp_path, capsys, monkeypatch):
    import importlib.util

    plane = _copy(tmp_path)
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "pyoidn" else real(name, *a)
    )
    traced = _count_traces(monkeypatch)
    for extra in ([], ["--dry-run"], ["--denoise"]):  # denoising is the default
        code, _, err = _main(capsys, "bake", str(plane), *FAST, *extra)
        assert code == 2
        line = _error_line(err, "bake")
        assert "pip install pyoidn" in line and "--no-denoise" in line
    assert not traced
    # the named way out works without pyoidn
    assert _main(capsys, "bake", str(plane), *FAST, "--no-denoise")[0] == 0


def test_baking_an_output_layer_is_refused(tmp_path, capsys):
    plane = _copy(tmp_path)
    assert _main(capsys, "bake", str(plane), *FAST)[0] == 0
    layer = tmp_path / "open_plane.lightmaps.usda"
    code, _, err = _main(capsys, "bake", str(layer), *FAST)
    assert code == 2
    line = _error_line(err, "bake")
    assert "output layer of usdahd bake" in line and "source stage" in line
    assert not (tmp_path / "open_plane.lightmaps.lightmaps.usda").exists()


def test_apply_on_an_xform_names_the_prim(tmp_path, capsys):
    from pxr import Usd

    from usdahd.usd import schema

    plane = _copy(tmp_path)
    stage = Usd.Stage.Open(str(plane))
    # what a hand-edited stage can hold (schema.apply refuses non-meshes)
    stage.GetPrimAtPath("/World").AddAppliedSchema(schema.API_NAME)
    stage.GetRootLayer().Save()
    code, _, err = _main(capsys, "bake", str(plane), *FAST)
    assert code == 2
    line = _error_line(err, "bake")
    assert "/World (Xform)" in line and "not a Mesh" in line


def test_dry_run_reports_texel_total_and_would_create(tmp_path, capsys):
    stage = _copy(tmp_path, "cornell_box.usda")
    code, out, _ = _main(capsys, "bake", str(stage), "--dry-run", "--resolution", "16")
    assert code == 0
    assert "7 prim(s) to bake, 1792 texels in total" in out
    assert "(would be created)" in out and "(unchanged)" not in out
    code, out, _ = _main(capsys, "bake", str(stage), "--dry-run", "--json", "--resolution", "16")
    report = json.loads(out)
    assert report["texels_total"] == 7 * 16 * 16
    assert not (tmp_path / "lightmaps").exists()
    assert not list(tmp_path.glob(".*lock"))


def test_planned_memory_above_the_machine_is_refused_in_dry_run(tmp_path, capsys, monkeypatch):
    stage = _copy(tmp_path, "cornell_box.usda")
    monkeypatch.setattr(run, "MAX_BAKE_BYTES", 1000)
    code, _, err = _main(capsys, "bake", str(stage), "--dry-run", "--resolution", "16")
    assert code == 2
    line = _error_line(err, "bake")
    assert "1.79e+03 texels" in line and "--resolution" in line


# ------------------------------------------------------------------------------ quiet levels


def test_warnings_survive_quiet_but_not_qq(tmp_path, capsys):
    from pxr import Usd

    plane = _copy(tmp_path)
    stage = Usd.Stage.Open(str(plane))
    stage.RemovePrim("/World/Lights")  # nothing emits: "every lightmap is black"
    stage.GetRootLayer().Save()
    code, out, err = _main(capsys, "bake", str(plane), *FAST, "--quiet")
    # -q hides progress, not the results: the per-prim lines stay on stdout (issue 37),
    # the warnings go to stderr only
    assert code == 0 and "texels" in out and out.splitlines()[0].startswith("/")
    assert not [ln for ln in out.splitlines() if ln.lstrip().startswith("warning")]
    assert "output layer:" in out
    assert "warning: the stage has no lights" in err and "[1/" not in err
    code, out, err = _main(capsys, "bake", str(plane), *FAST, "--force", "-qq")
    assert code == 0 and out == "" and err == ""


# ------------------------------------------------------------------------------- progress


class _Tty:
    def __init__(self):
        self.text = ""

    def write(self, s):
        self.text += s

    def flush(self):
        pass

    def isatty(self):
        return True


def test_progress_log_ends_each_mesh_at_100_percent(capsys):
    import io

    from usdahd.progress import Progress

    stream = io.StringIO()
    bar = Progress("[1/1] /World/A", stream=stream)
    bar.update(1, 0)  # first update always prints
    bar.update(886, 1000)  # rate limited: not printed
    bar.close()
    lines = stream.getvalue().splitlines()
    assert lines[-1].startswith("[1/1] /World/A") and "100.0%" in lines[-1]
    assert "done in" in lines[-1]


def test_progress_on_a_terminal_pads_over_longer_lines():
    from usdahd import progress

    tty = _Tty()
    bar = progress.Progress("x" * 30, stream=tty)
    progress._draw(tty, True, "Q" * 90)
    bar.update(5, 10)
    last = tty.text.split("\r")[-1]
    assert len(last) >= 90 and "Q" not in last  # the longer line is fully overwritten
    progress.clear_line()
    assert tty.text.endswith("\r")


def test_compile_notice_and_eta_exclude_compile_time():
    import io
    import time

    import numba

    from usdahd import progress

    stream = io.StringIO()
    bar = progress.Progress("trace", stream=stream)
    t0 = time.perf_counter()
    with progress.CompileNotice(stream=stream) as notice:

        @numba.njit(cache=False)
        def fresh(x):  # never cached: always compiles
            s = 0.0
            for i in range(x.shape[0]):
                s += np.sin(x[i]) * np.cos(x[i]) + i
            return s

        fresh(np.arange(10.0))
    wall = time.perf_counter() - t0
    assert notice.announced
    text = stream.getvalue()
    assert "compiling kernels (first run only" in text
    assert "compiled kernels in" in text
    spent = notice.seconds()
    assert 0 < spent <= wall
    # the bar's clock excludes the compile: elapsed + compile == wall time since it started
    now = time.perf_counter()
    assert abs(bar._elapsed(now) + spent - (now - bar.start)) < 0.05


def test_compile_notice_silent_when_nothing_compiles():
    import io

    from usdahd import progress

    stream = io.StringIO()
    with progress.CompileNotice(stream=stream) as notice:
        np.sin(1.0)
    assert not notice.announced and stream.getvalue() == ""


# ------------------------------------------------------------------------------ subprocess


def test_subprocess_directory_stage_is_one_line(tmp_path):
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH)
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.strip() == (
        f"usdahd bake: error: {tmp_path}: is a directory; give a USD stage file (.usda/.usdc/.usd)"
    )


def test_importing_the_cli_loads_neither_usd_nor_numba():
    """``import usdahd.cli`` (every command's start) and building its parser (``usdahd
    --help``, ``usdahd fit``) stay light: USD, numba, OIDN and Embree load only when a command
    needs them (issue 43: start-up is part of a small bake's time; the parser loaded pxr
    through ``usdahd plugin-path``'s module until 2026-12-07, 0.15 s per command)."""
    code = (
        "import sys, usdahd.cli\n"
        "heavy = [m for m in ('pxr', 'numba', 'pyoidn', 'embreex', 'scipy') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
        "usdahd.cli.build_parser()\n"
        "heavy = [m for m in ('pxr', 'numba', 'pyoidn', 'embreex', 'scipy') if m in sys.modules]\n"
        "assert not heavy, ('build_parser', heavy)\n"
    )
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr


def test_bake_loads_numba_without_scipys_blas(tmp_path):
    """A bake (as a subprocess: a fresh interpreter) loads numba's array-math registry without
    importing scipy.linalg (cli._numba_without_scipy_blas: 0.13 s of CPU per command when SciPy
    is installed), and SciPy's BLAS still imports afterwards in the same process."""
    pytest.importorskip("scipy.linalg")
    stage = _copy(tmp_path)
    code = (
        "import sys\n"
        "from usdahd import cli\n"
        f"assert cli.main(['bake', {str(stage)!r}, *{FAST!r}, '-q']) == 0\n"
        "assert 'numba.np.arraymath' in sys.modules\n"
        "assert 'scipy.linalg' not in sys.modules, 'scipy.linalg imported'\n"
        "import scipy.linalg.cython_blas\n"
    )
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH)
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=900
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "open_plane.lightmaps.usda").is_file()


# ------------------------------------------------------------------------------- validate


@pytest.fixture
def baked_box(tmp_path, capsys):
    stage = _copy(tmp_path, "cornell_box.usda")
    assert _main(capsys, "bake", str(stage), *FAST, "--quiet")[0] == 0
    return tmp_path / "cornell_box.lightmaps.usda"


def test_validate_missing_texture_is_one_finding_and_usd_noise_is_separate(baked_box, capsys):
    from pxr import Usd

    from usdahd.usd import schema

    stage = Usd.Stage.Open(str(baked_box))
    records = {str(p.GetPath()): schema.read_results(p) for p in schema.prims_with_api(stage)}
    victim = Path(records["/World/Geometry/Floor"].textures["iz"])
    # the Floor's I_z file: its own, or the atlas page it shares with other records
    users = sorted(p for p, r in records.items() if Path(r.textures["iz"]) == victim)
    victim.unlink()
    code, out, err = _main(capsys, "validate", str(baked_box))
    assert code == 1
    errors = [ln for ln in out.splitlines() if ln.startswith("error")]
    assert len(errors) == len(users)  # one finding per prim naming the file
    assert all(victim.name in e for e in errors)
    assert any("/World/Geometry/Floor" in e for e in errors)
    assert "Ill-formed SdfPath" not in out
    code, out, err = _main(capsys, "validate", str(baked_box), "--json")
    report = json.loads(out)
    assert report["counts"]["error"] == len(users)
    assert all("Warning: in" not in d for d in report["usd_diagnostics"])


def test_validate_messages_name_the_tolerance_and_never_advise_the_baked_model(baked_box, capsys):
    """IzCheck says where its tolerance comes from (not a bare 5e-4 next to a 0.475 error);
    an EncodingError on an hhd bake never advises baking with hhd."""
    code, out, _ = _main(capsys, "validate", str(baked_box), "--rmse-threshold", "1e-9")
    iz = [ln for ln in out.splitlines() if "IzCheck" in ln]
    assert iz and all("tolerance from the quantization" in ln for ln in iz)
    enc = [ln for ln in out.splitlines() if "EncodingError" in ln]
    fixes = [ln.split("Fix:", 1)[1] for ln in enc if "Fix:" in ln]
    assert fixes and not any("hhd" in f for f in fixes), fixes


# ------------------------------------------------- bad inputs that cannot be committed files


def test_fifo_as_texture_does_not_hang(tmp_path):
    """A FIFO as a material texture: refused as not a regular file (opening it would block)."""
    shutil.copy2(ROOT / "tests" / "data" / "bad_stages" / "texture_is_directory.usda", tmp_path)
    stage = tmp_path / "texture_is_directory.usda"
    os.mkfifo(tmp_path / "pipe.png")
    stage.write_text(stage.read_text().replace("@./@", "@./pipe.png@"))
    assert "@./pipe.png@" in stage.read_text()
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH)
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), *FAST, "--json"],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert any("pipe.png" in w and "not a regular file" in w for w in report["warnings"])


def test_non_utf8_file_name_is_one_message(tmp_path, capsys):
    name = os.fsdecode(b"caf\xe9.usda")
    shutil.copy2(SAMPLES / "open_plane.usda", tmp_path / name)
    code, out, err = _main(capsys, "bake", str(tmp_path / name), *FAST, "--json")
    assert code == 2
    line = _error_line(err, "bake")
    assert "caf\\xe9.usda" in line and "not valid UTF-8" in line and "rename" in line
    assert json.loads(out)["exit_code"] == 2


def test_read_only_override_layer_is_refused_before_tracing(tmp_path, capsys, monkeypatch):
    plane = _copy(tmp_path)
    assert _main(capsys, "bake", str(plane), *FAST)[0] == 0
    layer = tmp_path / "open_plane.lightmaps.usda"
    layer.chmod(0o444)
    before = layer.read_bytes()
    traced = _count_traces(monkeypatch)
    code, _, err = _main(capsys, "bake", str(plane), *FAST, "--force")
    assert code == 2 and not traced
    line = _error_line(err, "bake")
    assert str(layer) in line and "read-only" in line and "chmod" in line
    assert layer.read_bytes() == before


def test_output_path_under_a_file_is_refused(tmp_path, capsys):
    plane = _copy(tmp_path)
    (tmp_path / "afile").write_text("x")
    code, _, err = _main(capsys, "bake", str(plane), "-o", str(tmp_path / "afile" / "x.usda"))
    assert code == 2
    assert "not a folder" in _error_line(err, "bake")


def test_error_after_a_progress_line_starts_on_a_clean_line(capsys, monkeypatch):
    """ "interrupted" and errors are never printed onto a half-drawn progress bar."""
    from usdahd import progress
    from usdahd.commands import plugin_path

    tty = _Tty()
    bar = progress.Progress("[1/1] /World/A", stream=tty)

    def interrupted(args):
        bar.update(5, 10)
        raise KeyboardInterrupt

    monkeypatch.setattr(plugin_path, "run", interrupted)
    assert cli.main(["plugin-path"]) == 130
    assert tty.text.startswith("\r[1/1] /World/A")
    assert tty.text.endswith("\r")  # erased before the message
    assert progress._open_line["stream"] is None


@pytest.mark.parametrize("full", [False, True], ids=["fast exit", "USDAHD_FULL_EXIT"])
def test_console_script_runs_atexit_handlers_flushes_and_keeps_the_exit_status(tmp_path, full):
    """The console script (usdahd.console.main) ends the process with ``os._exit`` once the
    command is done, skipping the interpreter's teardown (~0.2 s of a small bake): atexit
    handlers still run, stdout is complete (the --json report parses), the exit status is the
    command's, and nothing after main() runs; with USDAHD_FULL_EXIT=1 it returns normally."""
    stage = _copy(tmp_path)
    code = (
        "import atexit, sys; atexit.register(lambda: print('atexit ran', flush=True)); "
        f"sys.argv = ['usdahd', 'bake', {str(stage)!r}, '--dry-run', '--json']; "
        "from usdahd.console import main; rc = main(); print('returned', rc)"
    )
    env = {k: v for k, v in os.environ.items() if k != "USDAHD_FULL_EXIT"}
    env.update(PYTHONPATH=USDAHD_PATH, **({"USDAHD_FULL_EXIT": "1"} if full else {}))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       cwd=tmp_path, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    report, _, tail = r.stdout.rpartition("}\n")
    assert json.loads(report + "}")["dry_run"] is True
    assert ("returned 0" in tail) is full
    assert "atexit ran" in tail
    # an error keeps its status (2) through the fast exit
    bad = code.replace(str(stage), str(tmp_path / "missing.usda"))
    r = subprocess.run([sys.executable, "-c", bad], capture_output=True, text=True, env=env,
                       cwd=tmp_path, timeout=300)  # fmt: skip
    assert r.returncode == (0 if full else 2), r.stderr  # full: main() returned 2, the script 0
    assert "no such file" in r.stdout + r.stderr
