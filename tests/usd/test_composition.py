"""Imperfect production stages (issues 37, 40, 41): composition problems are reported once each,
as warnings of the Composition rule unless a baked prim is composed through them, and bake,
validate and preview still run; USD's own diagnostics are never printed raw, never twice, never
cut before their cause.

The stage: tests/data/production/variant_unselected.usda, whose /World/Prop selects the variant
"good" while its unselected variants "empty" and "missing" reference a 0-byte layer
(variant_empty.usda) and a layer that does not exist. Before: ``usdahd validate`` and ``preview
--atlas`` exited 2 with a raw USD error (MissingReferenceValidator raised on the empty layer).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from usdahd import cli

ROOT = Path(__file__).resolve().parents[2]
PRODUCTION = ROOT / "tests" / "data" / "production"
FAST = ["--resolution", "8", "--samples", "16", "--bounces", "1", "--no-denoise"]
EMPTY = "variant look=empty (not selected) references @./variant_empty.usda@"
MISSING = "variant look=missing (not selected) references @./variant_missing.usda@"
EMPTY_CAUSE = "the file is empty (0 bytes): "
MISSING_CAUSE = "which cannot be opened: the file does not exist"
#: What USD's own printer writes (never to reach a user raw).
RAW = ("Warning: in ", "Error in '", "Error: in ", "_ReportErrors", "Tf.ErrorException")


def _main(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _subprocess(*argv, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run(
        [sys.executable, "-m", "usdahd", *map(str, argv)],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
        cwd=cwd,
    )


def _copy(folder: Path) -> Path:
    for p in PRODUCTION.glob("variant_*.usda"):
        shutil.copy(p, folder / p.name)
    assert (folder / "variant_empty.usda").stat().st_size == 0
    assert not (folder / "variant_missing.usda").exists()
    return folder / "variant_unselected.usda"


def _once(text: str, needle: str) -> None:
    assert text.count(needle) == 1, (needle, text)


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """The production stage baked once (in-process), its output layer and what was printed."""
    d = tmp_path_factory.mktemp("variant")
    src = _copy(d)
    proc = _subprocess("bake", src, *FAST)
    return src, d / "variant_unselected.lightmaps.usda", proc


# ------------------------------------------------------------------------------------- bake


def test_bake_runs_and_warns_once_per_broken_variant(baked):
    src, layer, proc = baked
    assert proc.returncode == 0, proc.stderr
    assert layer.exists()
    text = proc.stdout + proc.stderr
    for needle in (EMPTY, MISSING, EMPTY_CAUSE, MISSING_CAUSE, "is not a valid usda layer"):
        _once(text, needle)
    assert "/World/Floor:" in proc.stdout and "/World/Prop/Block:" in proc.stdout
    assert not any(r in text for r in RAW), text


def test_bake_in_process_quiet_warns_on_stderr(tmp_path, capsys):
    src = _copy(tmp_path)
    code, out, err = _main(capsys, "bake", src, *FAST, "-q")
    assert code == 0
    _once(err, EMPTY)
    _once(err, MISSING)
    assert EMPTY not in out and "/World/Floor:" in out  # -q: results stay on stdout


# --------------------------------------------------------------------------------- validate


def test_validate_exits_0_with_one_composition_warning_per_arc(baked, capsys):
    _, layer, _ = baked
    code, out, err = _main(capsys, "validate", "--json", layer)
    report = json.loads(out)
    assert code == 0 and report["exit_code"] == 0
    comp = [f for f in report["findings"] if f["rule"] == "Composition"]
    warnings = [f for f in comp if f["severity"] == "warning"]
    assert [(f["code"], f["prim"], f["data"]["variant"]) for f in warnings] == [
        ("UnselectedVariantArc", "/World/Prop", "look=empty"),
        ("UnselectedVariantArc", "/World/Prop", "look=missing"),
    ]
    assert EMPTY in warnings[0]["message"] and "is not a valid usda layer" in warnings[0]["message"]
    assert MISSING in warnings[1]["message"] and warnings[1]["message"].endswith(
        "Fix: repair or remove that reference (variant set 'look')."
    )
    # the layers are reported once: not again by MissingReferenceValidator or as USD notes
    assert report["counts"]["warning"] == 2 and report["counts"]["error"] == 0
    assert not [f for f in report["findings"] if f["code"] == "UnresolvableDependency"]
    assert not any("variant_" in d for d in report["usd_diagnostics"]), report["usd_diagnostics"]
    # MissingReferenceValidator raised on the empty layer: said once, as a note
    (skip,) = [f for f in comp if f["code"] == "DependencyCheckSkipped"]
    assert skip["severity"] == "info" and "is not a valid usda layer" in skip["message"]
    # every lightmap rule still ran on both baked prims
    iz = {f["prim"] for f in report["findings"] if f["rule"] == "IzCheck"}
    assert iz == {"/World/Floor", "/World/Prop/Block"}


def test_validate_subprocess_prints_no_raw_usd_text(baked):
    _, layer, _ = baked
    proc = _subprocess("validate", layer)
    assert proc.returncode == 0, proc.stderr
    _once(proc.stdout, EMPTY)
    _once(proc.stdout, MISSING)
    assert not any(r in proc.stdout + proc.stderr for r in RAW), proc.stderr
    assert "0 error(s), 2 warning(s)" in proc.stderr


def test_validate_prim_selection_still_reports_composition(baked, capsys):
    _, layer, _ = baked
    code, out, _ = _main(capsys, "validate", "--json", "--prim", "/World/Floor", layer)
    report = json.loads(out)
    assert code == 0
    codes = [f["code"] for f in report["findings"] if f["rule"] == "Composition"]
    assert codes.count("UnselectedVariantArc") == 2


def test_missing_layer_only_is_one_finding(tmp_path, capsys):
    """Without the empty layer MissingReferenceValidator runs; its UnresolvableDependency for the
    layer the Composition rule reports is dropped (one problem, one finding)."""
    src = _copy(tmp_path)
    src.write_text(src.read_text().replace("variant_empty.usda", "variant_gone.usda"))
    assert _main(capsys, "bake", src, *FAST, "-qq")[0] == 0
    code, out, _ = _main(
        capsys, "validate", "--json", tmp_path / "variant_unselected.lightmaps.usda"
    )
    report = json.loads(out)
    assert code == 0
    found = [(f["rule"], f["code"]) for f in report["findings"] if f["severity"] != "info"]
    assert found == [("Composition", "UnselectedVariantArc")] * 2, found


def _selected_arc(tmp_path: Path, prim: str) -> Path:
    """The production stage with a *selected* reference to a missing layer authored on
    ``prim`` (a sublayer-free edit of a copy)."""
    src = _copy(tmp_path)
    text = src.read_text()
    if prim == "/World/Floor":
        old = 'def Mesh "Floor"\n'
        new = 'def Mesh "Floor" (\n        prepend references = @./nowhere.usda@\n    )\n'
    else:  # a new prim outside every baked prim
        old = 'def DomeLight "Sky"'
        new = (
            'def Xform "Dressing" (\n        prepend references = @./nowhere.usda@\n    )\n'
            '    {\n    }\n\n    def DomeLight "Sky"'
        )
    assert old in text
    src.write_text(text.replace(old, new, 1))
    return src


def test_composed_error_outside_baked_prims_is_a_warning(tmp_path, capsys):
    src = _selected_arc(tmp_path, "/World/Dressing")
    code, out, err = _main(capsys, "bake", src, *FAST)
    assert code == 0
    _once(out, "composition error, that part of the scene is missing (no mesh is composed")
    _once(out, "Could not open asset @")
    code, out, _ = _main(
        capsys, "validate", "--json", tmp_path / "variant_unselected.lightmaps.usda"
    )
    report = json.loads(out)
    assert code == 0
    (f,) = [f for f in report["findings"] if f["code"] == "CompositionErrorUnbaked"]
    assert f["severity"] == "warning" and f["prim"] == "/World/Dressing"
    assert "nowhere.usda" in f["message"] and "no baked prim is composed from" in f["message"]


def test_composed_error_on_a_baked_prim_is_an_error(tmp_path, capsys):
    src = _selected_arc(tmp_path, "/World/Floor")
    assert _main(capsys, "bake", src, *FAST, "-qq")[0] == 0
    layer = tmp_path / "variant_unselected.lightmaps.usda"
    code, out, _ = _main(capsys, "validate", "--json", layer)
    report = json.loads(out)
    assert code == 1
    (f,) = [f for f in report["findings"] if f["code"] == "CompositionError"]
    assert f["severity"] == "error" and f["data"]["baked_prims"] == ["/World/Floor"]
    assert "nowhere.usda" in f["message"] and "re-bake" in f["message"]


# ---------------------------------------------------------------------------------- preview


def test_preview_and_atlas_run_and_warn_once(baked, tmp_path):
    _, layer, _ = baked
    for extra in ([], ["--atlas"]):
        out = tmp_path / f"view{len(extra)}.png"
        proc = _subprocess("preview", layer, "-o", out, "--backend", "embree", *extra)
        assert proc.returncode == 0, proc.stderr
        assert out.exists() and str(out) in proc.stdout
        _once(proc.stderr, EMPTY)
        _once(proc.stderr, MISSING)
        assert not any(r in proc.stderr for r in RAW), proc.stderr


# ------------------------------------------------------------------------------ diagnostics


def test_usd_diagnostics_are_trapped_and_reported_once(capfd):
    """A warning USD posts during a command is not printed by USD's printer; the command
    prints it once in usdahd's format, whole."""
    from pxr import Tf

    from usdahd.usd import diagnostics

    cause = "a cause at the very end of a long message " + "x" * 400 + " THE CAUSE"
    with diagnostics.capture() as diags:
        Tf.Warn(cause)
        Tf.Warn(cause)  # posted twice, reported once
    assert capfd.readouterr().err == ""
    lines = []
    assert diagnostics.report(diags, lines.append) == 1
    assert lines == [f"USD: {cause}"]


def test_nested_capture_forwards_to_the_command(capfd):
    from pxr import Tf

    from usdahd.usd import diagnostics

    with diagnostics.capture() as outer:
        with diagnostics.capture(forward=True) as inner:
            Tf.Warn("inner warning")
    assert [d.message for d in inner] == ["inner warning"]
    assert [d.message for d in outer] == ["inner warning"]
    assert capfd.readouterr().err == ""


def test_selected_composition_error_is_printed_once_with_its_cause(tmp_path):
    """The composition error of a selected arc: before, USD printed ``Warning: in _ReportErrors
    at line 3326 of stage.cpp -- ...`` (sometimes twice) and usdahd repeated it cut at 300
    characters; now one usdahd line with the cause at its end."""
    src = _copy(tmp_path)
    long = "a_layer_name_long_enough_to_push_the_cause_past_any_cut_" * 3
    empty = tmp_path / f"{long}.usda"
    empty.write_text("")
    text = src.read_text().replace(
        'def DomeLight "Sky"',
        f'def Xform "Dressing" (\n        prepend references = @./{empty.name}@\n    )\n'
        '    {\n    }\n\n    def DomeLight "Sky"',
    )
    src.write_text(text)
    proc = _subprocess("bake", src, *FAST)
    assert proc.returncode == 0, proc.stderr
    both = proc.stdout + proc.stderr
    assert not any(r in both for r in RAW), both
    lines = [ln for ln in both.splitlines() if empty.name in ln and "composition error" in ln]
    assert len(lines) == 1, both
    assert (
        lines[0]
        .rstrip()
        .endswith(
            "is not a valid usda layer. Fix: repair or remove the arc (the file it names must "
            "exist and be a USD layer)"
        )
    )


def test_materialx_file_that_does_not_compose_is_one_warning(tmp_path, capsys):
    """Two materials referencing a .mtlx file (usd-core from the index has no MaterialX file
    format): one warning naming MaterialX and both prims, not an error of the lightmap rules
    (the chess set's 19 CompositionError findings of issue 37)."""
    src = _copy(tmp_path)
    (tmp_path / "look.mtlx").write_text(
        '<?xml version="1.0"?>\n<materialx version="1.38">\n</materialx>\n'
    )
    src.write_text(
        src.read_text().replace(
            'def DomeLight "Sky"',
            'def Material "MxLook" (\n        prepend references = @./look.mtlx@</MaterialX>\n'
            "    )\n    {\n    }\n\n"
            'def Material "MxLook2" (\n        prepend references = @./look.mtlx@</MaterialX>\n'
            '    )\n    {\n    }\n\n    def DomeLight "Sky"',
        )
    )
    assert _main(capsys, "bake", src, *FAST, "-qq")[0] == 0
    code, out, _ = _main(
        capsys, "validate", "--json", tmp_path / "variant_unselected.lightmaps.usda"
    )
    report = json.loads(out)
    assert code == 0 and report["counts"]["error"] == 0
    (f,) = [f for f in report["findings"] if "look.mtlx" in f["message"]]
    assert f["prim"] == "/World/MxLook" and f["data"]["also"] == ["/World/MxLook2"]
    assert (f["rule"], f["severity"], f["code"]) == (
        "Composition",
        "warning",
        "CompositionErrorUnbaked",
    )
    assert f["message"].startswith("MaterialX file could not be composed: ")
    assert "look.mtlx" in f["message"] and "fix the binding" not in f["message"]


def test_a_usd_warning_during_bake_is_reported_once_in_usdahd_format(tmp_path):
    """A binding authored without MaterialBindingAPI: USD warns from UsdShade (before, its
    printer wrote ``Warning: in BindingsAtPrim at line 669 of .../materialBindingAPI.cpp --
    ...`` beside usdahd's output). Now one ``usdahd bake: warning: USD: ...`` line, whole."""
    src = _copy(tmp_path)
    text = src.read_text()
    old = '        uniform token subdivisionScheme = "none"\n    }\n\n    def DistantLight'
    new = (
        '        uniform token subdivisionScheme = "none"\n'
        "        rel material:binding = </World/Looks/Grey>\n    }\n\n"
        '    def Scope "Looks"\n    {\n        def Material "Grey"\n        {\n        }\n    }\n\n'
        "    def DistantLight"
    )
    assert old in text
    src.write_text(text.replace(old, new, 1))
    proc = _subprocess("bake", src, *FAST, "-q")
    assert proc.returncode == 0, proc.stderr
    expected = (
        "usdahd bake: warning: USD: Found material bindings on prim at path (/World/Floor) but "
        "MaterialBindingAPI is not applied on the prim"
    )
    assert proc.stderr.splitlines().count(expected) == 1, proc.stderr
    assert "MaterialBindingAPI" not in proc.stdout
    assert not any(r in proc.stdout + proc.stderr for r in RAW), proc.stderr


def test_a_raw_usd_error_is_described_by_its_cause(tmp_path):
    """An uncaught Tf.ErrorException becomes ``USD: <message>``, whole, without USD's
    ``Error in 'pxrInternal_...::_ReadFromAsset' at line 323 in file ...`` in front."""
    from pxr import Sdf, Tf

    folder = tmp_path / ("d" * 150) / ("e" * 150)  # a path past the old 300-character cut
    folder.mkdir(parents=True)
    empty = folder / "empty.usda"
    empty.write_text("")
    with pytest.raises(Tf.ErrorException) as info:
        Sdf.Layer.FindOrOpen(str(empty))
    message, code = cli.describe_error(info.value)
    assert code == 2 and message == f"USD: <{empty}> is not a valid usda layer"


def test_preview_in_process_warns_once(baked, tmp_path, capsys):
    _, layer, _ = baked
    out = tmp_path / "inproc.png"
    code, stdout, err = _main(capsys, "preview", layer, "-o", out, "--size", "32", "24", "--json")
    assert code == 0 and json.loads(stdout)["meshes"] == 2 and out.exists()
    _once(err, EMPTY)
    _once(err, MISSING)
