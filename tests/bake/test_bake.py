"""`usdahd bake` end to end on tiny bakes: outputs, incremental skipping, atomicity, bad input."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.scenes import ROOT, SAMPLES, copy_sample, sample_stages
from usdahd import cli, models
from usdahd.numerics import sh as shmod
from usdahd.usd import schema

FAST = ["--resolution", "8", "--samples", "16", "--bounces", "0", "--quiet"]


def _bake(argv, capsys=None):
    code = cli.main(["bake", *argv])
    out = capsys.readouterr() if capsys else None
    return code, out


def _results(layer):
    from pxr import Usd

    from usdahd.usd import schema

    stage = Usd.Stage.Open(str(layer))
    return {str(p.GetPath()): schema.read_results(p) for p in schema.prims_with_api(stage)}


def _decoded_iz(res):
    from usdahd import images

    mod = models.get(res.model)
    lay = mod.layout(res.ratio)
    chans = {lt.role: schema.read_record_pixels(res, lt.role, lt.channels) for lt in lay}
    side = images.read(res.textures["sh"], channels=_sidecar_channels()).pixels
    cover = side[..., -1] > 0
    dec = mod.decode({k: v[cover] for k, v in chans.items()}, ratio=res.ratio, factors=res.factors)
    z = np.broadcast_to(np.array([0, 0, 1.0]), (int(cover.sum()), 3))
    return mod.evaluate(dec, z), shmod.iz(side[cover][:, :27].reshape(-1, 3, 9))


def _sidecar_channels():
    from usdahd.usd import schema

    return schema.SH_SIDECAR_CHANNELS


def test_open_plane_bakes_iz_one_and_leaves_source_untouched(tmp_path, capsys):
    stage = copy_sample(tmp_path, "open_plane.usda")
    before = stage.read_bytes()
    code, out = _bake([str(stage), "--json", *FAST[:-1], "--samples", "64"], capsys)
    assert code == 0, out.err
    report = json.loads(out.out)
    assert report["exit_code"] == 0
    layer = tmp_path / "open_plane.lightmaps.usda"
    assert layer.is_file() and report["written"]
    assert stage.read_bytes() == before
    res = _results(layer)
    assert list(res) == ["/World/Geometry/Plane"]
    r = res["/World/Geometry/Plane"]
    assert r.model == "hhd" and r.resolution == (8, 8)
    for role, f in r.textures.items():
        assert Path(f).is_file(), role
    got, want = _decoded_iz(r)
    # Uniform dome of radiance 1: I_z = 1 (Monte Carlo noise only in higher bands).
    np.testing.assert_allclose(want, 1.0, atol=0.05)
    # I(z) decoded through the engine path equals the baked I_z up to float16 storage.
    np.testing.assert_allclose(got, want, rtol=2e-3)
    # Asset paths are relative to the output layer.
    assert all(a.startswith("./lightmaps/") for a in r.asset_paths.values())


def test_second_run_skips_everything_and_rewrites_nothing(tmp_path, capsys):
    stage = copy_sample(tmp_path, "cornell_box.usda")
    code, _ = _bake([str(stage), *FAST], capsys)
    assert code == 0
    layer = tmp_path / "cornell_box.lightmaps.usda"
    files = sorted((tmp_path / "lightmaps").iterdir())
    stamps = {f: f.stat().st_mtime_ns for f in files + [layer]}
    code, out = _bake([str(stage), "--json", *FAST], capsys)
    assert code == 0
    report = json.loads(out.out)
    assert {p["status"] for p in report["prims"]} == {"skipped"}
    assert sum(p.get("rays", 0) for p in report["prims"]) == 0
    assert not report["written"]
    assert {f: f.stat().st_mtime_ns for f in stamps} == stamps


def test_changed_setting_rebakes_only_that_prim(tmp_path, capsys):
    stage = copy_sample(tmp_path, "cornell_box.usda")
    assert _bake([str(stage), *FAST], capsys)[0] == 0
    first = _results(tmp_path / "cornell_box.lightmaps.usda")
    target = sorted(first)[0]
    code, out = _bake(
        [str(stage), "--json", "--prim", target, *FAST[:-1], "--samples", "8"], capsys
    )
    assert code == 0, out.err
    report = json.loads(out.out)
    assert [p["path"] for p in report["prims"] if p["status"] == "baked"] == [target]
    second = _results(tmp_path / "cornell_box.lightmaps.usda")
    assert set(second) == set(first)  # prims not selected keep their results
    assert second[target].content_hash != first[target].content_hash
    for path in set(first) - {target}:
        assert second[path].content_hash == first[path].content_hash


def test_dry_run_writes_nothing(tmp_path, capsys):
    stage = copy_sample(tmp_path, "open_plane.usda")
    code, out = _bake([str(stage), "--dry-run", "--json", *FAST], capsys)
    assert code == 0
    assert json.loads(out.out)["prims"][0]["status"] == "planned"
    assert not (tmp_path / "open_plane.lightmaps.usda").exists()
    assert not (tmp_path / "lightmaps").exists()


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["missing.usda"], "no such file"),
        (["{stage}", "--model", "nope"], "invalid choice"),
        (["{stage}", "--samples", "0"], "--samples"),
        (["{stage}", "--resolution", "100000"], "resolution"),
        (["{stage}", "-o", "{stage}"], "overwrite the source"),
        (["{stage}", "--model", "sh_l2", "--ratio", "rgb"], "ratio"),
    ],
)
def test_bad_usage_exits_2_with_a_clear_message(tmp_path, capsys, argv, needle):
    stage = copy_sample(tmp_path, "open_plane.usda")
    argv = [a.format(stage=stage) for a in argv]
    if argv[0] == "missing.usda":
        argv[0] = str(tmp_path / "missing.usda")
    try:
        code = cli.main(["bake", *argv])
    except SystemExit as exc:  # argparse errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2
    assert needle in err
    assert "Traceback" not in err


def test_no_uvs_with_unwrap_off_fails_that_prim(tmp_path, capsys):
    from pxr import Usd, UsdGeom

    stage_path = copy_sample(tmp_path, "open_plane.usda")
    stage = Usd.Stage.Open(str(stage_path))
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Geometry/Plane")).RemovePrimvar("st")
    stage.GetRootLayer().Save()
    code, out = _bake([str(stage_path), "--no-unwrap", *FAST], capsys)
    assert code == 1
    assert "/World/Geometry/Plane" in out.err and "--no-unwrap" in out.err
    # With unwrapping on it bakes and authors the UV set in the output layer only.
    code, out = _bake([str(stage_path), "--json", *FAST[:-1]], capsys)
    assert code == 0, out.err
    report = json.loads(out.out)
    assert any("xatlas" in w for w in report["prims"][0]["warnings"])
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "open_plane.lightmaps.usda"))
    assert layer.GetAttributeAtPath("/World/Geometry/Plane.primvars:st") is not None


def _run(args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run(
        [sys.executable, "-m", "usdahd", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        **kw,
    )


def test_bake_as_subprocess_json(tmp_path):
    stage = copy_sample(tmp_path, "open_plane.usda")
    proc = _run(["bake", str(stage), "--json", *FAST])
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["prims"][0]["status"] == "baked"
    assert report["prims"][0]["texels"] > 0


def test_killed_bake_leaves_previous_output_valid(tmp_path):
    stage = copy_sample(tmp_path, "cornell_box.usda")
    assert _run(["bake", str(stage), *FAST]).returncode == 0
    layer = tmp_path / "cornell_box.lightmaps.usda"
    before = layer.read_bytes()
    files = {f: f.read_bytes() for f in (tmp_path / "lightmaps").iterdir()}
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "usdahd",
            "bake",
            str(stage),
            "--force",
            "--resolution",
            "32",
            "--samples",
            "4096",
            "--bounces",
            "3",
            "--quiet",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    time.sleep(4.0)
    assert proc.poll() is None, "the long bake finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert layer.read_bytes() == before
    for f, data in files.items():
        assert f.read_bytes() == data
    assert _run(["bake", str(stage), *FAST]).returncode == 0  # and it re-runs cleanly


@pytest.mark.parametrize("name", sample_stages())
def test_fresh_bake_of_every_sample_validates_clean(tmp_path, capsys, name):
    stage = copy_sample(tmp_path, name)
    code, out = _bake(
        [str(stage), "--resolution", "16", "--samples", "16", "--bounces", "1", "--quiet"], capsys
    )
    assert code == 0, out.err
    layer = tmp_path / name.replace(".usda", ".lightmaps.usda")
    code = cli.main(["validate", str(layer), "--json"])
    found = json.loads(capsys.readouterr().out)
    assert code == 0, found


def test_denoise_flag_bakes_valid_finite_output(tmp_path, capsys):
    pytest.importorskip("pyoidn")
    stage = copy_sample(tmp_path, "open_plane.usda")
    code, out = _bake(
        [str(stage), "--denoise", "--resolution", "16", "--samples", "8", "--quiet"], capsys
    )
    assert code == 0, out.err
    layer = tmp_path / "open_plane.lightmaps.usda"
    got, want = _decoded_iz(_results(layer)["/World/Geometry/Plane"])
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, want, rtol=2e-3)
    assert cli.main(["validate", str(layer), "--quiet"]) == 0
    # by default too, and it says so on stderr (with the way to skip it)
    code, out = _bake([str(stage), "--resolution", "16", "--samples", "8", "--force"], capsys)
    assert code == 0 and "denoised in " in out.err and "--no-denoise" in out.err
    code, out = _bake([str(stage), "--resolution", "16", "--samples", "8", "--force",
                       "--no-denoise"], capsys)  # fmt: skip
    assert code == 0 and "denoised in " not in out.err


def test_denoise_trusts_the_integrators_own_variance(tmp_path, capsys, monkeypatch):
    """--denoise gets each texel's noise from the integrator (the smaller of stats
    iz_variance and iz_variance_halves, denoise.integrator_iz_variance, through
    denoise.sh_variance, pooled over VARIANCE_POOL), not from second differences, which a
    shadow edge inflates (that estimate multiplied exterior_sun_sky's error by 2.5,
    docs/time-to-quality.md)."""
    pytest.importorskip("pyoidn")
    from usdahd.bake import denoise

    seen = []
    real = denoise.denoise_records

    def spy(records, **kw):  # every prim's charts in one call (shared OIDN mosaics)
        seen.extend(r.get("variance") for r in records)
        assert kw.get("variance_bound") and kw.get("variance_pool") == denoise.VARIANCE_POOL
        return real(records, **kw)

    monkeypatch.setattr(denoise, "denoise_records", spy)
    stage = copy_sample(tmp_path, "open_plane.usda")
    code, out = _bake(
        [str(stage), "--denoise", "--resolution", "16", "--samples", "8", "--quiet"], capsys
    )
    assert code == 0, out.err
    (var,) = seen
    assert var is not None and var.ndim == 3 and var.shape[1:] == (3, 9)
    assert np.isfinite(var).all() and (var > 0).any()


def test_prim_selection_keeps_unwrapped_uvs_of_other_prims(tmp_path, capsys):
    from pxr import Sdf, Usd, UsdGeom

    stage_path = copy_sample(tmp_path, "cornell_box.usda")
    stage = Usd.Stage.Open(str(stage_path))
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Geometry/Floor")).RemovePrimvar("st")
    stage.GetRootLayer().Save()
    code, out = _bake([str(stage_path), *FAST], capsys)
    assert code == 0, out.err
    layer_path = tmp_path / "cornell_box.lightmaps.usda"
    uv = Sdf.Path("/World/Geometry/Floor.primvars:st")
    first = Sdf.Layer.OpenAsAnonymous(str(layer_path))  # keep the layer alive while reading
    before = list(first.GetAttributeAtPath(uv).default)
    code, out = _bake(
        [str(stage_path), "--prim", "/World/Geometry/Ceiling", "--force", *FAST], capsys
    )
    assert code == 0, out.err
    second = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    after = second.GetAttributeAtPath(uv)
    assert after is not None and list(after.default) == before


def test_stage_without_light_sources_traces_nothing_and_says_so(tmp_path, capsys):
    from pxr import Usd

    stage_path = copy_sample(tmp_path, "open_plane.usda")
    stage = Usd.Stage.Open(str(stage_path))
    stage.RemovePrim("/World/Lights")
    stage.GetRootLayer().Save()
    code, out = _bake([str(stage_path), "--json", *FAST[:-1]], capsys)
    assert code == 0, out.err
    report = json.loads(out.out)
    assert any("no lights" in w for w in report["warnings"])
    assert report["prims"][0]["rays"] == 0
    got, want = _decoded_iz(
        _results(tmp_path / "open_plane.lightmaps.usda")["/World/Geometry/Plane"]
    )
    assert not got.any() and not want.any()


def test_partly_degenerate_uv_set_is_unwrapped_into_a_new_primvar(tmp_path, capsys):
    from pxr import Usd, UsdGeom

    stage_path = copy_sample(tmp_path, "open_plane.usda")
    stage = Usd.Stage.Open(str(stage_path))
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Geometry/Plane")).GetPrimvar("st")
    st = np.array(pv.Get())
    st[: len(st) // 3] = st[0]  # a third of the vertices collapse onto one UV point
    pv.Set(st)
    stage.GetRootLayer().Save()
    code, out = _bake([str(stage_path), "--json", *FAST[:-1]], capsys)
    assert code == 0, out.err
    warnings = json.loads(out.out)["prims"][0]["warnings"]
    assert any("zero-area UV triangles" in w and "st_lightmap" in w for w in warnings)
    res = _results(tmp_path / "open_plane.lightmaps.usda")["/World/Geometry/Plane"]
    assert res.uv_primvar == "st_lightmap"


def test_unauthored_meters_per_unit_and_tiny_maps_are_warned(tmp_path, capsys):
    text = (SAMPLES / "open_plane.usda").read_text().replace("    metersPerUnit = 1\n", "")
    stage = tmp_path / "cm.usda"
    stage.write_text(text)
    code, out = _bake([str(stage), "--dry-run", "--json", "--quiet"], capsys)
    assert code == 0, out.err
    report = json.loads(out.out)
    assert any("metersPerUnit" in w for w in report["warnings"])
    # 4 m at USD's fallback 0.01 m/unit, a 4 cm stage: the automatic density's floor by stage
    # size still puts STAGE_MIN_TEXELS texels across it (docs/texels.md), so the map does not
    # depend on the units; an explicit 16 texels/m gives a 1x1 map, flagged.
    from usdahd.pipeline.density import STAGE_MIN_TEXELS

    assert report["texel_density"]["stage_extent"] == pytest.approx(0.04)
    assert STAGE_MIN_TEXELS <= report["prims"][0]["resolution"][0] <= 1.2 * STAGE_MIN_TEXELS
    assert not any("gives only" in w for w in report["prims"][0]["warnings"])
    argv = [str(stage), "--dry-run", "--json", "--quiet", "--texel-density", "16"]
    code, out = _bake(argv, capsys)
    assert code == 0, out.err
    report = json.loads(out.out)
    assert any("gives only" in w for w in report["prims"][0]["warnings"])


def test_rerun_reuses_the_previous_unwrap_instead_of_calling_xatlas(tmp_path, capsys, monkeypatch):
    from pxr import Usd, UsdGeom

    from usdahd.bake import unwrap as unwrap_mod

    stage_path = copy_sample(tmp_path, "open_plane.usda")
    stage = Usd.Stage.Open(str(stage_path))
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Geometry/Plane")).RemovePrimvar("st")
    stage.GetRootLayer().Save()
    assert _bake([str(stage_path), *FAST], capsys)[0] == 0

    def no_xatlas(*args, **kwargs):
        raise AssertionError("xatlas called again for an unchanged mesh")

    monkeypatch.setattr(unwrap_mod, "unwrap", no_xatlas)
    code, out = _bake([str(stage_path), "--json", *FAST[:-1]], capsys)
    assert code == 0, out.err
    prim = json.loads(out.out)["prims"][0]
    assert prim["status"] == "skipped"
    # normal behaviour, so a note, not a warning (issue 18)
    assert any("reusing" in n for n in prim["notes"])
    assert not any("reusing" in w for w in prim["warnings"])
