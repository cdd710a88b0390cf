"""The opt-in Retrace rule (``usdahd validate --retrace N``, issue 17).

Real bakes of the samples at 16 x 16 (default samples and bounces) are re-traced with the
baker's integrator: default bakes pass, a ``--bounces 1`` bake of the closed Cornell box and a
bake whose irradiance textures and SH sidecar were both scaled by 1.1 are caught. The
statistics are checked against scipy's Student t and, for their false-alarm rate, on synthetic
data where the null hypothesis holds exactly. The replay of the bake's own random stream
(usdahd.validate.replay) reproduces a --no-denoise bake bit for bit and catches a 1 % scale of
a 16 x 16 bake on every prim; its two-stage texel count keeps alpha and reaches 95 % power on
synthetic populations.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import usdahd.usd  # noqa: F401  (registers the plugins first)
from tests.scenes import ROOT, SAMPLES, copy_sample, sample_stages
from usdahd import cli
from usdahd import validate as V
from usdahd.errors import UsageError
from usdahd.validate import replay as RP
from usdahd.validate import retrace as RT

BAKE = ["--resolution", "16", "--quiet"]  # default samples (256) and bounces
RETRACE = ["--retrace", "48"]  # 256 samples per texel (the default), cheap: 48 texels


def _bake(tmp: Path, sample: str, name: str, *flags) -> Path:
    """Bake samples/<sample> into tmp/<name>/x.lightmaps.usda (the source copied to tmp)."""
    src = tmp / sample
    if not src.exists():
        copy_sample(tmp, sample)
    out = tmp / name / "x.lightmaps.usda"
    assert cli.main(["bake", str(src), "-o", str(out), *BAKE, *flags]) == 0
    return out


def _results(layer: Path) -> dict:
    from pxr import Usd

    from usdahd.usd import schema

    stage = Usd.Stage.Open(str(layer))
    return {str(p.GetPath()): schema.read_results(p) for p in schema.prims_with_api(stage)}


def _scaled_copy(layer: Path, name: str, factor: float, sidecar: bool = True) -> Path:
    """A copy of a bake with its irradiance textures and the SH sidecar scaled by factor.

    Consistently: the sidecar's l_1^0 coefficients are set so that its I_z equals the I_z
    the rescaled (float16-rounded) textures decode to, so IzCheck still passes.
    """
    from usdahd import images, models
    from usdahd.numerics import sh as shm
    from usdahd.usd import schema

    dst = layer.parent.parent / name
    shutil.copytree(layer.parent, dst)
    new = dst / layer.name
    done = set()  # an atlas page is shared by several records: scale each file once
    for res in _results(new).values():
        mod = models.get(res.model)
        lay = {t.role: t for t in mod.layout(res.ratio)}
        if res.textures[schema.SIDECAR_ROLE] in done:
            continue
        done.add(res.textures[schema.SIDECAR_ROLE])
        for role, path in res.textures.items():
            if role == schema.SIDECAR_ROLE or lay[role].color_space != "lin_rec709_scene":
                continue  # only irradiance-valued textures scale (not ratios, directions)
            img = images.read(path)
            px = (img.pixels.astype(np.float64) * factor).astype(img.pixels.dtype)
            _rewrite(path, img, px)
        side_path = res.textures[schema.SIDECAR_ROLE]
        if not sidecar:
            os.unlink(side_path)
            continue
        side = images.read(side_path)
        px = side.pixels.astype(np.float64)
        px[..., [i for i, c in enumerate(side.channels) if c != "A"]] *= factor
        chans = {t.role: images.read(res.textures[t.role]).pixels for t in lay.values()}
        h, w = px.shape[:2]
        flat = {k: v.reshape(h * w, -1) for k, v in chans.items()}
        dec = mod.decode(flat, ratio=res.ratio, factors=res.factors)
        iz = np.asarray(dec["iz"], np.float64).reshape(h, w, 3)
        for c, ch in enumerate("RGB"):
            px[..., side.channels.index(f"{ch}2")] = iz[..., c] / shm.IZ_FROM_L10
        px[side.pixels[..., side.channels.index("A")] <= 0.5] = 0.0
        _rewrite(side_path, side, px.astype(side.pixels.dtype))
    _record_digests(new)
    return new


def _record_digests(layer: Path) -> None:
    """Re-record the file digests the bake stores (as a bake with consistently wrong light
    would have them), so only the physics can tell."""
    from pxr import Usd

    from usdahd.usd import schema

    stage = Usd.Stage.Open(str(layer))
    for prim in schema.prims_with_api(stage):
        for role, path in schema.read_results(prim).textures.items():
            attr = prim.GetAttribute(schema.digest_property_name(role))
            if attr and attr.HasAuthoredValue() and os.path.isfile(path):
                attr.Set(schema.file_digest(path))
    stage.GetRootLayer().Save()


def _rewrite(path, img, pixels):
    from usdahd import images

    attrs = {k: v for k, v in img.attributes.items() if k.startswith("usdahd:")}
    images.write(
        path,
        pixels,
        color_space=img.color_space,
        channels=img.channels,
        format=img.format,
        attributes=attrs,
    )


def _validate(layer: Path, capsys, *flags) -> tuple[int, list[dict]]:
    capsys.readouterr()
    code = cli.main(["validate", str(layer), "--json", *flags])
    report = json.loads(capsys.readouterr().out)
    return code, report["findings"]


def _retrace(findings) -> dict:
    """prim -> list of Retrace findings."""
    out: dict = {}
    for f in findings:
        if f["rule"] == RT.RULE:
            out.setdefault(f["prim"], []).append(f)
    return out


@pytest.fixture(scope="module")
def cornell(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("retrace")
    return {
        "default": _bake(tmp, "cornell_box.usda", "default"),  # denoised (the default)
        # without denoising, so the per-texel test (off for denoised bakes) runs as well
        "plain": _bake(tmp, "cornell_box.usda", "plain", "--no-denoise"),
        "bounces1": _bake(tmp, "cornell_box.usda", "bounces1", "--bounces", "1", "--no-denoise"),
    }


# -------------------------------------------------------------------------------- statistics


def test_student_t_table_values_and_bad_arguments():
    # textbook table values: t_{10, 0.975} = 2.228139, t_{1, 0.995} = 63.656741 (Cauchy),
    # t_{5, 0.999} = 5.893430; the Cauchy tail is 1/2 - atan(t)/pi in closed form
    assert RT.t_isf(0.025, 10) == pytest.approx(2.228139, abs=1e-6)
    assert RT.t_isf(0.005, 1) == pytest.approx(63.656741, abs=1e-5)
    assert RT.t_isf(0.001, 5) == pytest.approx(5.893430, abs=1e-6)
    for t in (0.1, 1.0, 7.0, 300.0):
        assert RT.t_sf(t, 1) == pytest.approx(0.5 - np.arctan(t) / np.pi, rel=1e-10)
    assert RT.t_sf(1.5, float("inf")) == pytest.approx(0.0668072, abs=1e-7)
    with pytest.raises(UsageError, match="0 < p <= 0.5"):
        RT.t_isf(0.7, 5)
    with pytest.raises(UsageError, match="dof > 0"):
        RT.t_sf(1.0, 0)


def test_student_t_matches_scipy():
    st = pytest.importorskip("scipy.stats")
    for dof in (1, 2, 3, 7, 15, 63, 255, 4095, 1e6):
        # lgamma's cancellation at huge dof costs digits (never used: dof = texels - 1)
        rel = 1e-9 if dof < 1e5 else 1e-7
        for t in (0.0, 0.3, 1.0, 2.5, 6.0, 20.0):
            assert RT.t_sf(t, dof) == pytest.approx(st.t.sf(t, dof), rel=rel, abs=1e-300)
            assert RT.t_sf(-t, dof) == pytest.approx(st.t.sf(-t, dof), rel=rel)
        for p in (0.5, 0.25, 0.025, 1e-3, 1e-6, 1e-9):
            assert RT.t_isf(p, dof) == pytest.approx(st.t.isf(p, dof), rel=rel, abs=1e-12)
    assert RT.t_sf(2.0, float("inf")) == pytest.approx(st.norm.sf(2.0), rel=1e-12)


def _synthetic(rng, n, k, factor, truth_scale=1.0, bias=1.0):
    """Baked (n, 3) and batches (k, n, 3) with batch sd 5% and bake variance = factor x it."""
    truth = truth_scale * rng.uniform(0.2, 2.0, size=(n, 3))
    sd = 0.05 * truth * rng.uniform(0.5, 2.0, size=(n, 1))
    batches = truth + sd * rng.standard_normal((k, n, 3))
    baked = bias * truth + np.sqrt(factor) * sd * rng.standard_normal((n, 3))
    return baked, batches


def test_false_alarm_rate_on_synthetic_null_is_at_most_alpha():
    """H0 exact (bake noise exactly at its bound), no margin: the per-prim rate <= alpha."""
    rng = np.random.default_rng(7)
    alpha, trials = 0.1, 3000
    fails = mean_fails = 0
    for _ in range(trials):
        baked, batches = _synthetic(rng, n=32, k=16, factor=1.0)
        st = RT.compare(baked, batches, bake_factor=1.0, margin=0.0, alpha=alpha)
        mean_fails += bool(st["mean_fail"].any())
        fails += bool(st["mean_fail"].any() or st["texel_fail"].any())
    rate = fails / trials
    sigma = np.sqrt(alpha * (1 - alpha) / trials)
    assert rate <= alpha + 3 * sigma, rate
    # not vacuous: the mean test alone, at alpha/2 split over 3 channels, does fire
    assert mean_fails / trials > 0.2 * alpha / 2, mean_fails


def test_synthetic_bias_of_ten_percent_is_detected():
    rng = np.random.default_rng(3)
    hits = 0
    for _ in range(200):
        baked, batches = _synthetic(rng, n=48, k=16, factor=1.0, bias=1.1)
        st = RT.compare(baked, batches, bake_factor=1.0, margin=0.03, alpha=1e-3)
        hits += bool(st["mean_fail"].any())
        assert np.all(st["ratio"] > 1.05)
    assert hits == 200


def test_per_texel_outlier_is_found_and_masked_texels_are_not_tested():
    rng = np.random.default_rng(11)
    baked, batches = _synthetic(rng, n=40, k=16, factor=0.25)
    baked[5] *= 3.0  # one texel with three times the light (a leak)
    st = RT.compare(baked, batches, bake_factor=0.25, margin=0.03, alpha=1e-3)
    assert np.nonzero(st["texel_fail"].any(axis=1))[0].tolist() == [5]
    mask = np.ones(40, bool)
    mask[5] = False
    st = RT.compare(baked, batches, bake_factor=0.25, margin=0.03, alpha=1e-3, texel_mask=mask)
    assert not st["texel_fail"].any() and st["texels_tested"] == 39


def test_heavy_tailed_bake_noise_trips_only_the_per_texel_warning():
    """1% of 256-sample estimates carry a firefly of +100% (zero-mean overall), in the bake and
    in the retrace batches alike: the mean test stays quiet; the Gaussian per-texel bound does
    not hold for such tails, which is why it is a warning (docs/validate.md)."""
    rng = np.random.default_rng(5)
    texel = mean = 0
    for _ in range(300):
        truth = rng.uniform(0.2, 2.0, size=(96, 3))

        def draw(shape, truth=truth):
            fire = rng.random(shape[:-1] + (1,)) < 0.01
            return truth * (1 + 0.05 * rng.standard_normal(shape) + fire - 0.01)

        st = RT.compare(draw((96, 3)), draw((16, 96, 3)), bake_factor=1.0, margin=0.03, alpha=1e-3)
        mean += bool(st["mean_fail"].any())
        texel += bool(st["texel_fail"].any())
    assert mean == 0
    assert texel > 30  # far above alpha: the tail assumption is what breaks


def test_dark_channels_are_not_ratio_tested_and_bad_shapes_raise():
    rng = np.random.default_rng(1)
    baked, batches = _synthetic(rng, n=16, k=8, factor=1.0)
    baked[:, 2] = 0.5  # blue: no light in the retrace, some in the bake
    batches[:, :, 2] = 0.0
    st = RT.compare(baked, batches, bake_factor=1.0, margin=0.03, alpha=1e-3)
    assert st["tested"].tolist() == [True, True, False] and np.isnan(st["ratio"][2])
    with pytest.raises(UsageError, match="batches"):
        RT.compare(baked, batches[0], bake_factor=1.0, margin=0.0, alpha=0.1)
    with pytest.raises(UsageError, match="K >= 2"):
        RT.compare(baked, batches[:1], bake_factor=1.0, margin=0.0, alpha=0.1)


def test_small_prims_spend_the_same_budget_on_fewer_texels():
    o = RT.RetraceOptions(texels=1024, samples=256)
    assert RT.texel_samples(1024, o) == RT.texel_samples(5000, o) == 256
    assert RT.texel_samples(256, o) == 1024  # 1024 x 256 paths either way
    assert RT.texel_samples(100, o) == 2621
    assert RT.texel_samples(4, o) == 256 * RT.BUDGET_FACTOR  # capped


@pytest.mark.parametrize("texels, power", [(400, 0.95), (256, 0.80)])
def test_one_percent_power_and_false_alarms_on_the_synthetic_model(texels, power):
    """The mean test's power from the estimator's variance, at the default budget (N = 1024 x
    S = 256 paths per prim, spread over the prim's candidate texels) and a raw bake noise of
    2.6% per texel at 256 samples (plain Monte Carlo, measured on the Cornell box at 16 x 16:
    the ``standard_error_model`` of the retrace), denoising aside: a prim with 400 candidate
    texels catches a 1% scale either way with >= 95% probability; one with 256 (a 16 x 16 map's
    wall) with >= 80% (the bake's own noise is the limit). A clean bake is flagged at most
    alpha = 1% of the time. Over 2000 seeded trials, with tests/stats.py's standard error; the
    reported SE is the scatter of R over trials (what the test is derived from)."""
    from tests.stats import SIGMAS, standard_error

    rng = np.random.default_rng(41)
    o = RT.RetraceOptions()
    k, s = RT.batch_plan(RT.texel_samples(texels, o), 256, o)
    raw = 0.026  # relative sd of a texel at 256 samples
    hits: dict = {1.0: [], 1.01: [], 0.99: []}
    ratios, ses = [], []
    for _ in range(2000):
        truth = rng.uniform(0.2, 2.0, size=(texels, 1)) * np.array([1.0, 0.9, 0.8])
        batches = truth * (1 + raw * np.sqrt(256 / s) * rng.standard_normal((k, texels, 3)))
        bake = truth * (1 + raw * rng.standard_normal((texels, 3)))
        for f in hits:
            st = RT.compare(
                f * bake, batches, bake_factor=RT.bake_variance_factor(s, 256), margin=o.margin,
                alpha=o.alpha, denoised=True,
            )  # fmt: skip
            hits[f].append(bool(st["mean_fail"].any()))
            if f == 1.0:
                ratios.append(st["ratio"][0])
                ses.append(st["se"][0])
    assert abs(standard_error(ratios) * np.sqrt(len(ratios)) / np.mean(ses) - 1) < 0.1
    for f, h in hits.items():
        rate = float(np.mean(h))
        err = max(standard_error(np.asarray(h, float)), np.sqrt(0.01 * 0.99 / len(h)))
        if f == 1.0:
            assert rate <= o.alpha + SIGMAS * err, rate
        else:
            assert rate >= power, (f, rate)


def test_batch_plan_and_bake_variance_factor():
    o = RT.RetraceOptions()
    assert RT.batch_plan(4096, 256, o) == (16, 256)
    assert RT.batch_plan(4096, 16, o) == (256, 16)  # batches never exceed the bake's samples
    assert RT.batch_plan(4096, 4096, o) == (16, 256)
    assert RT.bake_variance_factor(64, 256) == 0.25
    assert RT.bake_variance_factor(64, 16) == 16.0  # (s / S)^2 when extrapolating down


def test_interior_mask_and_texel_choice():
    # a 7 x 7 chart 0 with a 1-texel chart 1 at (6, 6): interior = centre 3 x 3 minus none
    ys, xs = np.mgrid[0:7, 0:7]
    xy = np.stack([xs.ravel(), ys.ravel()], axis=1)
    chart = np.zeros(len(xy), int)
    chart[-1] = 1
    got = RT.interior_mask(xy, chart, (7, 7))
    want = np.zeros((7, 7), bool)
    want[2:5, 2:5] = True
    want[4, 4] = False  # its 5 x 5 neighbourhood contains the other chart's texel
    assert got.reshape(7, 7).tolist() == want.tolist()
    a = RT.pick_texels(np.arange(100), 10, 5)
    assert len(set(a)) == 10 and (np.diff(a) > 0).all()
    assert (a == RT.pick_texels(np.arange(100), 10, 5)).all()
    assert not (a == RT.pick_texels(np.arange(100), 10, 6)).all()
    assert RT.pick_texels(np.arange(3), 10, 5).tolist() == [0, 1, 2]
    assert RT.retrace_seed(0, "/A") != RT.retrace_seed(1, "/A") != RT.retrace_seed(0, "/B")


# --------------------------------------------------------------------------- real retraces


@pytest.mark.parametrize("sample", sample_stages())
def test_default_bake_of_every_sample_passes(tmp_path, capsys, sample):
    layer = _bake(tmp_path, sample, "default")
    code, found = _validate(layer, capsys, *RETRACE)
    assert code == 0, [f["message"] for f in found if f["severity"] != "info"]
    per_prim = _retrace(found)
    assert set(per_prim) == set(_results(layer))
    for prim, fs in per_prim.items():
        # the mean test passes; isolated fireflies of a default bake may add RetraceOutlier
        # warnings (floor_lamp's 5 cm lamp 15 cm above the floor does), never an error
        codes = [f["code"] for f in fs]
        assert codes and set(codes) <= {"RetraceOk", "RetraceOutlier"}, fs
        assert all(f["severity"] != "error" for f in fs), (prim, fs)
        d = fs[0]["data"]
        assert d["texels"] >= 16 and d["samples"] >= 256 and d["bounces"] == RT.RETRACE_BOUNCES
        assert d["rays"] > 0 and d["seconds"] > 0


def test_bounces_1_bake_of_the_closed_box_is_caught(cornell, capsys):
    code, found = _validate(cornell["bounces1"], capsys, *RETRACE)
    assert code == 1
    per_prim = _retrace(found)
    assert len(per_prim) == 7
    for prim, fs in per_prim.items():
        mism = [f for f in fs if f["code"] == "RetraceMismatch"]
        assert mism, (prim, fs)
        assert "bounces=1" in mism[0]["message"] and "Fix:" in mism[0]["message"]
        ratios = [r for r in mism[0]["data"]["ratio"] if r is not None]
        assert max(ratios) < 0.95  # indirect light missing: darker in every channel
        for f in fs:  # per-texel outliers are warnings (bake noise can be heavy-tailed)
            assert f["severity"] == ("error" if f["code"] == "RetraceMismatch" else "warning")
    assert any(f["code"] == "RetraceOutlier" for fs in per_prim.values() for f in fs)
    # the other rules cannot see it: only Retrace fails
    assert {f["rule"] for f in found if f["severity"] == "error"} == {RT.RULE}


def test_textures_and_sidecar_scaled_together_are_caught(cornell, capsys):
    scaled = _scaled_copy(cornell["default"], "scaled", 1.1)
    code, found = _validate(scaled, capsys)
    # I_z is consistent with the sidecar, so IzCheck's irradiance test passes; IzCheck's code
    # test (a re-encode of the sidecar) may still see the few codes the rescale rounded
    # differently, which is all the other rules may report
    others = [f for f in found if f["severity"] == "error" and f["code"] != "CodeMismatch"]
    assert not others, others
    code, found = _validate(scaled, capsys, *RETRACE)
    assert code == 1
    per_prim = _retrace(found)
    assert len(per_prim) == 7
    for prim, fs in per_prim.items():
        mism = [f for f in fs if f["code"] == "RetraceMismatch"]
        assert mism and "brighter" in mism[0]["message"], (prim, fs)
        for r in mism[0]["data"]["ratio"]:
            assert 1.05 < r < 1.15
    errors = {f["rule"] for f in found if f["severity"] == "error" and f["code"] != "CodeMismatch"}
    assert errors == {RT.RULE}


def test_without_a_sidecar_the_decoded_textures_are_compared(cornell, capsys):
    scaled = _scaled_copy(cornell["default"], "scaled_nosidecar", 1.1, sidecar=False)
    _, found = _validate(scaled, capsys, *RETRACE)
    per_prim = _retrace(found)
    assert len(per_prim) == 7
    for fs in per_prim.values():
        assert "RetraceMismatch" in [f["code"] for f in fs]


@pytest.mark.parametrize("bake", ["default", "plain"])
def test_false_alarms_over_seeds_on_a_clean_bake(cornell, capsys, bake):
    """5 retrace seeds x 7 prims of the default (denoised) and of a --no-denoise Cornell box
    bake (which has the per-texel test too): no finding (the bound is alpha = 1e-3 per prim;
    with the 3% margin the rate on a clean bake is far lower)."""
    findings = 0
    for seed in range(5):
        code, found = _validate(cornell[bake], capsys, *RETRACE, "--retrace-seed", str(seed))
        per_prim = _retrace(found)
        assert len(per_prim) == 7
        findings += sum(f["code"] != "RetraceOk" for fs in per_prim.values() for f in fs)
        assert code == 0
    assert findings == 0


def test_denoised_bake_passes_with_the_widened_per_texel_test(cornell, capsys):
    pytest.importorskip("pyoidn")
    code, found = _validate(cornell["default"], capsys, *RETRACE)
    assert code == 0
    for fs in _retrace(found).values():
        assert [f["code"] for f in fs] == ["RetraceOk"]
        assert "denoised bake (per-texel bound widened)" in fs[0]["message"]
        assert fs[0]["data"]["texels_per_texel_test"] > 0 and fs[0]["data"]["denoised"]


def test_stage_without_light(tmp_path, capsys):
    """A dark stage bakes to 0 and passes; a bake whose lights were removed afterwards fails."""
    from pxr import Usd

    layer = _bake(tmp_path, "open_plane.usda", "lit")
    src = tmp_path / "open_plane.usda"
    stage = Usd.Stage.Open(str(src))
    stage.RemovePrim("/World/Lights")
    stage.GetRootLayer().Save()
    _, found = _validate(layer, capsys, *RETRACE)  # the old bake over the now dark stage
    (f,) = _retrace(found)["/World/Geometry/Plane"]
    assert f["code"] == "RetraceMismatch" and "no light source" in f["message"]
    dark = _bake(tmp_path, "open_plane.usda", "dark")
    code, found = _validate(dark, capsys, *RETRACE)
    (f,) = _retrace(found)["/World/Geometry/Plane"]
    assert code == 0 and f["code"] == "RetraceOk" and "no light source" in f["message"]


def test_exception_in_the_rule_is_an_internal_error(cornell, capsys, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("synthetic failure")

    monkeypatch.setattr(RT, "_check", boom)
    assert cli.main(["validate", str(cornell["default"]), *RETRACE, "--quiet"]) == 2
    out = capsys.readouterr().out
    assert "Retrace: rule Retrace could not run: RuntimeError: synthetic failure" in out


def test_uvs_changed_since_the_bake_skip_with_a_reason(cornell, capsys):
    from pxr import Usd, UsdGeom, Vt

    dst = cornell["default"].parent.parent / "moved_uvs"
    shutil.copytree(cornell["default"].parent, dst)
    layer = dst / cornell["default"].name
    stage = Usd.Stage.Open(str(layer))
    pv = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Geometry/Floor")).GetPrimvar("st")
    uv = np.asarray(pv.Get()) * 0.5
    pv.Set(Vt.Vec2fArray.FromNumpy(uv.astype(np.float32)))
    stage.GetRootLayer().Save()
    _, found = _validate(layer, capsys, *RETRACE)
    floor = _retrace(found)["/World/Geometry/Floor"]
    assert [f["code"] for f in floor] == ["Skipped"]
    assert "UVs changed since the bake" in floor[0]["message"]


def test_too_few_texels_and_hidden_prims_skip_with_a_reason(cornell, tmp_path, capsys):
    from pxr import Usd, UsdGeom

    src = tmp_path / "open_plane.usda"
    shutil.copy(SAMPLES / "open_plane.usda", src)
    tiny = tmp_path / "tiny" / "x.lightmaps.usda"
    assert cli.main(["bake", str(src), "-o", str(tiny), "--resolution", "1", "--quiet"]) == 0
    _, found = _validate(tiny, capsys, *RETRACE)
    (f,) = _retrace(found)["/World/Geometry/Plane"]
    assert f["code"] == "Skipped" and "only 1 covered texel centre" in f["message"]
    layer = _bake(tmp_path, "open_plane.usda", "hidden")
    stage = Usd.Stage.Open(str(layer))
    UsdGeom.Imageable(stage.GetPrimAtPath("/World/Geometry/Plane")).MakeInvisible()
    stage.GetRootLayer().Save()
    _, found = _validate(layer, capsys, *RETRACE)  # the only mesh hidden: no scene at all
    (f,) = _retrace(found)["/World/Geometry/Plane"]
    assert f["code"] == "Skipped" and "cannot be read as a scene" in f["message"]
    dst = cornell["default"].parent.parent / "hidden_floor"
    shutil.copytree(cornell["default"].parent, dst)
    layer = dst / cornell["default"].name
    stage = Usd.Stage.Open(str(layer))
    UsdGeom.Imageable(stage.GetPrimAtPath("/World/Geometry/Floor")).MakeInvisible()
    stage.GetRootLayer().Save()
    _, found = _validate(layer, capsys, *RETRACE)
    (f,) = _retrace(found)["/World/Geometry/Floor"]
    assert f["code"] == "Skipped" and "not a visible mesh" in f["message"]


def test_cli_usage_errors(cornell, capsys):
    layer = str(cornell["default"])
    for argv, needle in [
        (["--retrace", "0"], "at least 4 texels"),
        (["--retrace-samples", "1024"], "need --retrace N"),
        (["--retrace-seed", "3"], "need --retrace N"),
        (["--retrace", "16", "--retrace-samples", "8"], "at least 32"),
    ]:
        assert cli.main(["validate", layer, *argv]) == 2
        assert needle in capsys.readouterr().err
    assert RT.OPTIONS == RT.RetraceOptions()  # nothing changed by the CLI
    assert cli.main(["validate", "--list-rules"]) == 0
    out = capsys.readouterr().out
    assert RT.DESCRIPTION in out and RT.KEYWORD in out


# --------------------------------------------------------------------------- UsdValidation


def test_plugin_declares_the_rule_opt_in():
    from pxr import UsdValidation

    text = (ROOT / "plugins/usdAhdValidators/plugInfo.json").read_text()
    info = json.loads("\n".join(ln for ln in text.splitlines() if not ln.lstrip().startswith("#")))
    d = info["Plugins"][0]["Info"]["Validators"][RT.RULE]
    # no schemaTypes: includeAllAncestors would pull a schema-typed validator into every
    # context of the default keyword (the rule checks for the API itself)
    assert d == {"doc": RT.DESCRIPTION, "keywords": [RT.KEYWORD]}
    reg = UsdValidation.ValidationRegistry()
    default = {m.name for m in reg.GetValidatorMetadataForKeyword(V.KEYWORD)}
    assert RT.validator_name() not in default  # not run by the default keyword
    assert [m.name for m in reg.GetValidatorMetadataForKeyword(RT.KEYWORD)] == [RT.validator_name()]
    assert reg.GetOrLoadValidatorByName(RT.validator_name()) is not None
    assert RT.register() == []  # idempotent


def test_default_keyword_context_does_not_retrace(cornell, monkeypatch):
    from pxr import Usd, UsdValidation

    def boom(*a, **k):
        raise AssertionError("Retrace ran without being asked for")

    monkeypatch.setattr(RT, "check_retrace", boom)
    stage = Usd.Stage.Open(str(cornell["bounces1"]))
    for ancestors in (True, False):  # True is the constructor's default
        ctx = UsdValidation.ValidationContext(keywords=[V.KEYWORD], includeAllAncestors=ancestors)
        errors = ctx.Validate(stage)
        assert not [e for e in errors if e.GetType() == UsdValidation.ValidationErrorType.Error]


_PLAIN = textwrap.dedent(
    """
    import json, sys
    from pxr import Usd, UsdValidation
    assert not [m for m in sys.modules if m.split(".")[0] == "usdahd"]  # nothing imported yet
    ctx = UsdValidation.ValidationContext(keywords=["UsdAhdRetrace"])  # Plug imports usdahd
    assert "usdahd.validate.retrace" in sys.modules
    stage = Usd.Stage.Open(sys.argv[1])
    out = sorted([e.GetValidator().GetMetadata().name, str(e.GetName()),
                  str(e.GetType().displayName)] for e in ctx.Validate(stage))
    print(json.dumps(out))
    """
)


def test_plain_usd_validation_runs_the_opt_in_rule(cornell):
    """Only PXR_PLUGINPATH_NAME set; the context asks for the Retrace keyword (defaults)."""
    from usdahd.usd import plugin

    env = {k: v for k, v in os.environ.items() if not k.startswith("PXR_")}
    env["PXR_PLUGINPATH_NAME"] = plugin.plugin_path()
    env["PYTHONPATH"] = str(ROOT)
    proc = subprocess.run(
        [sys.executable, "-c", _PLAIN, str(cornell["bounces1"])],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        cwd=str(ROOT),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = json.loads(proc.stdout.strip().splitlines()[-1])
    mism = [f for f in found if f[1] == "RetraceMismatch"]
    assert len(mism) == 7 and all(f[0] == RT.validator_name() and f[2] == "Error" for f in mism)


# --------------------------------------------------------------------------------- replay


def _population(rng, n, heavy=False):
    """A synthetic prim: raw replays p and the denoiser's changes d (sum over the population
    exactly 0, as the denoiser restores the chart's sum); heavy: 2 % of texels carry a firefly
    the denoiser removes (d of -100 %)."""
    level = rng.uniform(0.2, 1.0, (n, 1)) * np.array([[1.0, 0.9, 0.8]])
    p = level * (1.0 + 0.05 * rng.standard_normal((n, 3)))
    d = 0.05 * level * rng.standard_normal((n, 3))
    if heavy:
        fire = rng.random(n) < 0.02
        p[fire] *= 2.0
        d[fire] -= 0.5 * p[fire]
    d -= d.sum(axis=0) / n  # the chart's sum restored
    return p + d, p


@pytest.mark.parametrize("heavy", [False, True])
def test_replay_two_stage_rule_keeps_alpha_and_reaches_the_power(heavy):
    """The replay test on synthetic populations of 6000 texels (seeded): the first 1024
    replayed texels' scatter sets how many more are replayed (needed_texels); a clean bake is
    flagged on <= alpha of the trials, a 1 % rescale caught on >= 95 %."""
    rng = np.random.default_rng(11 + heavy)
    alpha, margin, n_pop, trials = 0.01 * RP.REPLAY_ALPHA, 0.002, 6000, 400
    flagged = {1.0: 0, 1.01: 0, 0.99: 0}
    grew = 0
    for _ in range(trials):
        b, p = _population(rng, n_pop, heavy)
        order = rng.permutation(n_pop)
        for f in flagged:
            n = 1024
            st = RP.compare_replay(
                f * b[order[:n]], p[order[:n]], n_pop, margin=margin, alpha=alpha
            )
            need = RP.needed_texels(st, n_pop, margin)
            if need > n:
                grew += f == 1.0
                n = min(n_pop, need)
                st = RP.compare_replay(
                    f * b[order[:n]], p[order[:n]], n_pop, margin=margin, alpha=alpha
                )
            flagged[f] += bool(st["fail"].any())
    assert flagged[1.0] <= 0.01 * trials, flagged
    assert flagged[1.01] >= 0.95 * trials and flagged[0.99] >= 0.95 * trials, flagged
    assert grew > 0 if heavy else True  # the fireflies' scatter asks for more texels


def test_replay_of_the_whole_population_has_no_sampling_error():
    rng = np.random.default_rng(3)
    b, p = _population(rng, 500)
    st = RP.compare_replay(b, p, 500, margin=0.002, alpha=0.0025)
    assert st["fpc"] == 0.0 and np.allclose(st["se"], 0.0) and np.allclose(st["bound"], 0.002)
    assert np.allclose(st["ratio"], 1.0) and not st["fail"].any()
    assert RP.needed_texels(st, 500, 0.002) == 500
    st = RP.compare_replay(1.0025 * b, p, 500, margin=0.002, alpha=0.0025)
    assert st["fail"].all()  # 0.25 % beyond the 0.2 % margin
    assert RP.replay_count(5000, 1024, 256, 256) == 1024
    assert RP.replay_count(300, 1024, 256, 256) == 300
    assert RP.replay_count(5000, 1024, 256, 64) == 4096


def test_replay_reproduces_a_no_denoise_bake_bit_for_bit(cornell):
    """The replay of every estimated texel of a --no-denoise bake equals the sidecar's I_z
    (the bake's own random numbers, paths and estimator), so the bake's noise cancels."""
    from pxr import Usd

    from usdahd.bake import integrate
    from usdahd.usd import schema

    stage = Usd.Stage.Open(str(cornell["plain"]))
    for prim in schema.prims_with_api(stage):
        got = RT.prim_candidates(prim)
        bake, scene, tracer, mesh, texels, rows, _, est = got
        st = bake.results.settings
        assert RP.replay_problem(bake.results, st, tracer) is None
        mi = scene.meshes.index(mesh)
        path = str(prim.GetPath())
        seed, spp, bounces = RP.bake_seed(st["seed"], path), st["samples"], st["bounces"]
        iz, bf, rays = RP.replay_iz(
            scene, tracer, texels, est, seed=seed, samples=spp, bounces=bounces, mesh=mi
        )
        sub = texels.take(est)
        inside = integrate.inside_geometry(tracer, sub, tracer.texel_offsets(sub, mi), bf, mesh=mi)
        baked = RT.baked_iz(bake, rows[est])[~inside]
        assert rays > 0 and len(baked) > 100
        np.testing.assert_allclose(baked, iz[~inside], rtol=1e-6, atol=1e-7, err_msg=path)


def test_replay_is_skipped_with_a_reason_where_it_would_not_be_exact(cornell):
    from dataclasses import replace

    from pxr import Usd

    from usdahd.usd import schema

    stage = Usd.Stage.Open(str(cornell["default"]))
    got = RT.prim_candidates(next(iter(schema.prims_with_api(stage))))
    assert not isinstance(got, str), got
    bake, scene, tracer = got[:3]
    res, st = bake.results, dict(bake.results.settings)
    assert RP.replay_problem(res, st, tracer) is None
    old = replace(res, generator="usdahd 0.0.1")
    assert "not usdahd" in RP.replay_problem(old, st, tracer)
    assert "adaptive" in RP.replay_problem(res, dict(st, adaptive=True), tracer)
    assert "seed" in RP.replay_problem(res, {k: v for k, v in st.items() if k != "seed"}, tracer)


@pytest.mark.parametrize("factor", [1.01, 0.99])
def test_one_percent_scale_is_caught_on_a_small_bake(cornell, capsys, factor):
    """The Cornell box at 16 x 16 (default samples, denoised): textures and sidecar scaled by
    1 % are caught on every prim by the replay (the independent retrace cannot tell 1 % from
    this bake's noise on the boxes); the clean bake passes (test above)."""
    scaled = _scaled_copy(cornell["default"], f"scaled{factor}", factor)
    code, found = _validate(scaled, capsys, "--retrace", "256")  # 256 texels: all at 16 x 16
    per_prim = _retrace(found)
    assert code == 1 and len(per_prim) == 7
    word = "brighter" if factor > 1 else "darker"
    for prim, fs in per_prim.items():
        rep = [f for f in fs if "own random stream" in f["message"]]
        assert rep and rep[0]["code"] == "RetraceMismatch" and word in rep[0]["message"], fs
        d = rep[0]["data"]
        assert d["replayed"] and d["replay_texels"] == d["replay_population"]
        assert all(abs(r - factor) < 2e-4 for r in d["replay_ratio"]), (prim, d["replay_ratio"])
        assert d["replay_bound"] == [RT.DENOISE_BIAS_BOUND] * 3


# ------------------------------------------------------------------------------------ slow


@pytest.mark.slow
def test_thorough_false_alarms_and_power_at_32(tmp_path, capsys):
    """Every sample at 32 x 32, 128 texels, 8 seeds: no finding on default bakes; a 1.1 scale
    of the Cornell box's textures and sidecar is caught on every prim."""
    findings = 0
    for sample in sample_stages():
        src = copy_sample(tmp_path / sample.replace(".usda", ""), sample)
        out = src.parent / "bake" / "x.lightmaps.usda"
        assert cli.main(["bake", str(src), "-o", str(out), "--resolution", "32", "--quiet"]) == 0
        for seed in range(8):
            code, found = _validate(out, capsys, "--retrace", "128", "--retrace-seed", str(seed))
            findings += sum(f["code"] != "RetraceOk" for fs in _retrace(found).values() for f in fs)
        if sample == "cornell_box.usda":
            scaled = _scaled_copy(out, "scaled", 1.1)
            _, found = _validate(scaled, capsys, "--retrace", "128")
            per_prim = _retrace(found)
            assert all("RetraceMismatch" in [f["code"] for f in fs] for fs in per_prim.values())
    assert findings == 0


@pytest.mark.slow
def test_one_percent_scale_is_caught_at_32(tmp_path, capsys):
    """The Cornell box baked at 32 x 32 (default samples, denoised), the default retrace
    (--retrace 1024, 256 samples): the clean bake raises no finding; textures and sidecar
    scaled by 1.01, 0.99, 1.02 or 0.98 are caught on every prim (the replay)."""
    src = copy_sample(tmp_path, "cornell_box.usda")
    out = tmp_path / "bake" / "x.lightmaps.usda"
    assert cli.main(["bake", str(src), "-o", str(out), "--resolution", "32", "--quiet"]) == 0
    code, found = _validate(out, capsys, "--retrace", "1024")
    assert code == 0 and len(_retrace(found)) == 7
    assert all(f["code"] == "RetraceOk" for fs in _retrace(found).values() for f in fs)
    for factor, word in (
        (1.01, "brighter"),
        (0.99, "darker"),
        (1.02, "brighter"),
        (0.98, "darker"),
    ):
        scaled = _scaled_copy(out, f"scaled{factor}", factor)
        code, found = _validate(scaled, capsys, "--retrace", "1024")
        per_prim = _retrace(found)
        assert code == 1 and len(per_prim) == 7
        for prim, fs in per_prim.items():
            mism = [f for f in fs if f["code"] == "RetraceMismatch"]
            assert mism and word in mism[0]["message"], (prim, fs)
