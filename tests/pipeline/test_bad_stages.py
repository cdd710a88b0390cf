"""The bad-input corpus (tests/data/bad_stages, manifest cases.json): every case through
``usdahd bake``, asserting its exit code, its message (keyword and prim path), no traceback,
and that every texture written is finite. In-process for every case, plus a few subprocesses
(``python -m usdahd bake``) for the real process status and stderr.

Bakes are tiny (8x8, 8 samples, no bounces): this file checks plumbing, not lighting.
"""

from __future__ import annotations

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
from usdahd import cli, images

ROOT = Path(__file__).resolve().parents[2]
#: The folder holding the usdahd these tests import (the checkout for an editable install,
#: site-packages for a plain one): subprocesses run the same code, with the same numba cache.
USDAHD_PATH = str(Path(usdahd.__file__).resolve().parents[1])
BAD_DIR = ROOT / "tests" / "data" / "bad_stages"
MANIFEST = json.loads((BAD_DIR / "cases.json").read_text(encoding="utf-8"))
CASES = {c["id"]: c for c in MANIFEST["cases"]}
TINY = ["--resolution", "8", "--samples", "8", "--bounces", "0", "--quiet"]
#: Cases whose expectation needs a change in a file this corpus does not own (pipeline.py);
#: strict xfail, so they flag themselves once the change lands.
PENDING: dict[str, str] = {}
#: Strings that would appear in an escaped path (display_name_escape).
ESCAPE = Path("/tmp/usdahd_escape")


def _copy_case(case: dict, dest: Path) -> Path:
    for name in [case["file"], *case["aux"]]:
        if (BAD_DIR / name).exists():
            shutil.copy2(BAD_DIR / name, dest / name)
    return dest / case["file"]


def _messages(report: dict | None, stderr: str) -> tuple[str, str]:
    """(error text, warning text) a user sees. Errors: stderr (the bake prints every failed
    prim's error there, even with --quiet/--json, so it must name the prim itself). Warnings:
    the --json report's, per-prim ones prefixed by the prim path (the human-readable report
    prints them under the prim's line). The stage path is not included: file names in the
    corpus contain the keywords."""
    warnings = []
    if report is not None:
        warnings += report.get("warnings", [])
        for p in report["prims"]:
            warnings += [f"{p['path']}: {w}" for w in p.get("warnings", [])]
    return stderr, "\n".join(warnings)


def _written_files(out_dir: Path) -> list[Path]:
    return sorted(p for p in out_dir.rglob("*") if p.is_file())


def _assert_textures_finite(report: dict) -> list[Path]:
    paths = []
    for p in report["prims"]:
        if p.get("status") != "baked":
            continue
        assert p.get("texels", 0) > 0, p["path"]
    lm = Path(report["output"]).parent / "lightmaps"
    for f in sorted(lm.glob("*")) if lm.is_dir() else []:
        if f.name.startswith("."):
            continue
        img = images.read(f)
        px = np.asarray(img.pixels)
        assert np.isfinite(px.astype(np.float64)).all(), f.name
        paths.append(f)
    return paths


def _setup(case: dict, stage: Path, cleanups: list) -> Path:
    """Apply the case's ``setup`` (defects a committed file cannot hold); returns the stage."""
    setup = case.get("setup")
    folder = stage.parent
    if setup == "lightmaps_file":
        (folder / "lightmaps").write_text("not a folder")
    elif setup == "lightmaps_dangling_symlink":
        (folder / "lightmaps").symlink_to(folder / "gone")
    elif setup == "readonly_lightmaps":
        lm = folder / "lightmaps"
        lm.mkdir()
        if mounts.is_root():
            mounts.mount_tmpfs(lm, "ro,size=1m")  # a failed mount as root fails the test
            cleanups.append(lambda: mounts.unmount(lm))
        else:
            lm.chmod(0o555)
            cleanups.append(lambda: lm.chmod(0o755))
    elif setup == "output_is_directory":
        (folder / f"{stage.stem}.lightmaps.usda").mkdir()
    elif setup == "readonly_layer":
        layer = folder / f"{stage.stem}.lightmaps.usda"
        layer.write_text("#usda 1.0\n")
        layer.chmod(0o444)
    elif setup == "fifo_texture":
        os.mkfifo(folder / "pipe.png")
    elif setup == "non_utf8_name":
        renamed = folder / os.fsdecode(b"caf\xe9_" + stage.name.encode())
        stage.rename(renamed)
        stage = renamed
    elif setup is not None:
        raise AssertionError(f"unknown setup {setup!r}")
    return stage


def _run_in_process(case: dict, tmp_path: Path, capsys) -> tuple[int, dict | None, str, str]:
    stage = _copy_case(case, tmp_path) if case["exists"] else tmp_path / case["file"]
    cleanups: list = []
    try:
        stage = _setup(case, stage, cleanups)
        rc = cli.main(["bake", str(stage), *case["args"], *TINY, "--json"])
    finally:
        for undo in cleanups:
            undo()
    cap = capsys.readouterr()
    report = json.loads(cap.out) if cap.out.strip() else None
    if report is not None and "prims" not in report:
        # --json on an error: one object {"command", "exit_code", "error"}
        assert report["exit_code"] == rc and report["error"] in cap.err, (report, cap.err)
        report = None
    return rc, report, cap.out, cap.err


def _params():
    out = []
    for cid, case in CASES.items():
        marks = []
        if cid in PENDING:
            marks.append(pytest.mark.xfail(reason=PENDING[cid], strict=True))
        out.append(pytest.param(case, id=cid, marks=marks))
    return out


@pytest.mark.parametrize("case", _params())
def test_case_in_process(case, tmp_path, capsys):
    escape_before = ESCAPE.exists()
    rc, report, out, err = _run_in_process(case, tmp_path, capsys)
    assert "Traceback" not in out + err
    assert rc == case["exit_code"], (rc, err, report)
    errors, warnings = _messages(report, err)
    if case["exit_code"] == 2:
        # one line on stderr naming the problem; stdout holds only the JSON error object
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("usdahd bake: error: "), err
        assert report is None
        assert json.loads(out)["exit_code"] == 2
    text = {"error": errors, "warning": warnings, "none": errors + warnings}[case["severity"]]
    if case["message"]:
        assert case["message"].lower() in text.lower(), (case["message"], text)
    if case["prim"]:
        assert case["prim"].lower() in text.lower(), (case["prim"], text)
    if report is None:
        return
    status = {p["path"]: p["status"] for p in report["prims"]}
    if case["exit_code"] == 1:
        failed = [p for p in report["prims"] if p["status"] == "failed"]
        assert failed and all("\n" not in p["error"] for p in failed)
        if case["prim"]:
            assert case["prim"] in {p["path"] for p in failed}
        # the rest of the stage still bakes
        if "/World/Good" in status:
            assert status["/World/Good"] == "baked", status
    if case["exit_code"] == 0:
        assert "failed" not in status.values(), report
        assert "baked" in status.values(), report
    files = _assert_textures_finite(report)
    if case["exit_code"] in (0, 1):
        assert files, "a baked stage must write textures"
    check = case["check"]
    baked = [p["path"] for p in report["prims"] if p["status"] == "baked"]
    # one file stem per prim, or per atlas page (the default) holding several prims
    owners = len(report["atlas"]["pages"]) if "atlas" in report else len(baked)
    if check == "distinct_texture_names":
        stems = {f.name.split(".")[1] for f in files}
        assert len(stems) == owners and len(baked) >= 2, (stems, baked)
        names = [f.name for f in files]
        assert len({n.lower() for n in names}) == len(names), "collide on case-insensitive FS"
    elif check == "texture_names_fit":
        assert all(len(f.name.encode("utf-8")) <= 255 for f in files)
        assert len({f.name.split(".")[1] for f in files}) == owners
    elif check == "inside_output_dir":
        root = tmp_path.resolve()
        for f in _written_files(tmp_path):
            assert f.resolve().is_relative_to(root), f
        from usdahd.usd.author import referenced_assets

        for path in referenced_assets(Path(report["output"])):
            assert path.resolve().is_relative_to(root), path
        assert ESCAPE.exists() == escape_before
    elif check == "no_warning":
        assert not warnings.strip(), warnings


def test_texture_names_distinct_across_collision_cases(tmp_path, capsys):
    """Collision cases: each prim's files are named from the output layer and its own path
    (sanitized + hash), so no two prims share a stem, even when the sanitized paths are equal:
    ``<layer prefix>.<prim stem>.<role>.<content hash>.<ext>``."""
    from usdahd.pipeline import sanitize

    for cid in ("name_collision", "case_collision", "long_names", "unicode_names"):
        d = tmp_path / cid
        d.mkdir()
        case = dict(CASES[cid], args=[*CASES[cid]["args"], "--atlas", "off"])  # own files
        rc, report, _, _ = _run_in_process(case, d, capsys)
        assert rc == 0
        baked = [p["path"] for p in report["prims"] if p["status"] == "baked"]
        stems = [sanitize(p) for p in baked]
        assert len(set(stems)) == len(stems) == len({s.lower() for s in stems})
        on_disk = {f.name.split(".")[1] for f in (d / "lightmaps").iterdir()}
        assert on_disk == set(stems)


# --------------------------------------------------------------------------------------------
# As a user runs it: real processes, real exit status, human-readable output.

SUBPROCESS = {
    "not_usd_png": ["--quiet"],
    "dome_texture_missing": ["--quiet"],
    "nan_points": ["--quiet"],
    "uv_string": ["--quiet"],
    "zero_intensity": [],  # a warning: printed in the human-readable report (stdout)
}


@pytest.mark.parametrize("cid", list(SUBPROCESS))
def test_case_subprocess(cid, tmp_path):
    case = CASES[cid]
    stage = _copy_case(case, tmp_path)
    env = dict(os.environ, PYTHONPATH=USDAHD_PATH + os.pathsep + os.environ.get("PYTHONPATH", ""))
    args = [*case["args"], "--resolution", "8", "--samples", "8", "--bounces", "0"]
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), *args, *SUBPROCESS[cid]],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    both = proc.stdout + proc.stderr
    assert "Traceback" not in both
    assert proc.returncode == case["exit_code"], both
    ours = [ln for ln in both.splitlines() if ln.startswith("usdahd bake: error: ")]
    if case["exit_code"]:
        assert ours, both
        text = "\n".join(ours)
    else:
        assert not ours, both
        text = "\n".join(ln for ln in proc.stdout.splitlines() if "warning" in ln)
    assert case["message"].lower() in text.lower(), text
    if case["prim"]:
        assert case["prim"].lower() in both.lower()
