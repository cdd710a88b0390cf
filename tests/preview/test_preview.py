"""usdahd preview: the Embree fallback (issue 14)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from usdahd import cli, images, models
from usdahd.commands import preview as P
from usdahd.preview import raytrace
from usdahd.usd import schema

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
SIZE = (96, 72)


@pytest.fixture(scope="module")
def layer(tmp_path_factory):
    d = tmp_path_factory.mktemp("preview")
    shutil.copy(SAMPLES / "cornell_box.usda", d)
    argv = ["bake", str(d / "cornell_box.usda"), "--resolution", "16", "--samples", "16"]
    assert cli.main([*argv, "--bounces", "1", "--quiet"]) == 0
    return d / "cornell_box.lightmaps.usda"


def _both(layer):
    from usdahd.usd.reader import load_scene

    stage, meshes, up = P.baked_meshes(str(layer))
    vp = P.auto_camera(np.concatenate([np.asarray(m.points) for m, *_ in meshes]), up, 96 / 72)
    items, traced = [], []
    for mesh, res, tangent, sign in meshes:
        layout = models.get(res.model).layout(res.ratio)
        tex = [schema.read_record_pixels(res, t.role, t.channels) for t in layout]
        items.append((P.vertex_data(mesh, tangent, sign), res.model, res.ratio, tex, res.factors))
        traced.append((mesh, res.model, res.ratio, tex, res.factors))
    _, dev = P.device()
    g = P.render(dev, items, vp, SIZE)
    scene = load_scene(stage, uv_name=meshes[0][1].uv_primvar)
    e = raytrace.render(scene, traced, vp, SIZE)
    return g, e, meshes


def test_embree_image_matches_wgpu(layer):
    """Same coverage and the same pixels: within 1e-4 relative on every covered pixel (measured:
    max 4.8e-5, median 2e-7; float32 + filtering order). The auto framing looks down through the
    ceiling's back face: wgpu culls it, so the fallback must too (before it did not, and its 532
    ceiling pixels differed by a median 62 % from wgpu's back and side walls)."""
    g, e, meshes = _both(layer)
    cov = g[..., 3] > 0
    assert np.array_equal(cov, e[..., 3] > 0)
    rel = np.abs(e[..., :3] - g[..., :3]).max(-1) / np.maximum(g[..., :3].max(-1), 1e-6)
    rel = rel[cov]
    assert rel.max() < 1e-4
    assert np.median(rel) < 1e-5


def test_embree_culls_back_faces(layer):
    """The primary rays the auto camera sends through the ceiling (it sits above it, the ceiling
    faces down) hit its back face first; front_hits passes them through to the walls behind,
    along the same ray (the hit points stay on the original rays)."""
    import copy

    from usdahd.bake.trace import Tracer
    from usdahd.usd.reader import load_scene

    stage, meshes, up = P.baked_meshes(str(layer))
    vp = P.auto_camera(np.concatenate([np.asarray(m.points) for m, *_ in meshes]), up, 96 / 72)
    names = [m.path.rsplit("/", 1)[-1] for m, *_ in meshes]
    sc = copy.copy(load_scene(stage, uv_name=meshes[0][1].uv_primvar))
    sc.meshes = [m for m, *_ in meshes]
    tracer = Tracer(sc)
    try:
        o, d = raytrace.primary_rays(vp, SIZE)
        raw = tracer.intersect(o, d)
        hit = raytrace.front_hits(tracer, o, d)
        ceiling = (raw["tri"] >= 0) & (tracer.tri_mesh[np.maximum(raw["tri"], 0)] == 0)
        assert names[0] == "Ceiling" and ceiling.sum() > 100
        tri = hit["tri"]
        assert np.array_equal(raw["tri"] >= 0, tri >= 0)
        assert not np.any(tracer.tri_mesh[tri[tri >= 0]] == 0)
        ng = tracer.geom_normal[tri[tri >= 0]]
        assert np.all(np.einsum("ij,ij->i", ng, d[tri >= 0]) < 0)
        moved = np.nonzero(ceiling)[0]
        p = tracer.hit_points(tri[moved], hit["u"][moved], hit["v"][moved])
        off = np.cross(p - o[moved], d[moved])  # distance of the hit point from its ray
        assert np.abs(off).max() < 1e-5 * tracer.extent
    finally:
        tracer.close()


def test_preview_pixels_match_the_sidecar(layer):
    """Independent of both renderers: at every covered pixel the front-facing surface's lightmap
    UV samples the bake's own SH sidecar I_z (bilinear, like the sampler); wgpu and the fallback
    both agree with it to the model's fit error (measured: median 1.5e-4, 90th percentile
    2.7e-4 relative for hhd/luminance)."""
    import copy

    from usdahd.bake.trace import Tracer
    from usdahd.numerics import sh as shm
    from usdahd.usd.reader import load_scene

    g, e, meshes = _both(layer)
    stage, _, up = P.baked_meshes(str(layer))
    vp = P.auto_camera(np.concatenate([np.asarray(m.points) for m, *_ in meshes]), up, 96 / 72)
    sc = copy.copy(load_scene(stage, uv_name=meshes[0][1].uv_primvar))
    sc.meshes = [m for m, *_ in meshes]
    tracer = Tracer(sc)
    try:
        hit = raytrace.front_hits(tracer, *raytrace.primary_rays(vp, SIZE))
    finally:
        tracer.close()
    ref = np.zeros((SIZE[0] * SIZE[1], 3))
    for k, (mesh, res, *_) in enumerate(meshes):
        sel = np.nonzero((hit["tri"] >= 0) & (tracer.tri_mesh[np.maximum(hit["tri"], 0)] == k))[0]
        data = schema.read_record_pixels(res, schema.SIDECAR_ROLE, schema.SH_SIDECAR_CHANNELS)
        h, w = data.shape[:2]
        iz = np.maximum(shm.iz(data[..., :27].astype(np.float64).reshape(h, w, 3, 9)), 0.0)
        st = np.asarray(mesh.uv, np.float64)[tracer.tri_local[hit["tri"][sel]]]
        a, b = hit["u"][sel, None].astype(np.float64), hit["v"][sel, None].astype(np.float64)
        st = (1 - a - b) * st[:, 0] + a * st[:, 1] + b * st[:, 2]
        ref[sel] = raytrace.bilinear(iz, np.stack([st[:, 0], 1.0 - st[:, 1]], -1))
    cov = g[..., 3].ravel() > 0
    ref = ref[cov]
    for img in (g, e):
        got = img[..., :3].reshape(-1, 3)[cov]
        rel = np.abs(got - ref).max(-1) / np.maximum(ref.max(-1), 1e-6)
        assert np.median(rel) < 1e-3 and np.percentile(rel, 90) < 2e-3


def test_no_adapter_falls_back_to_embree(layer, tmp_path, capsys, monkeypatch):
    from usdahd.preview import gpu

    monkeypatch.setattr(gpu, "request_adapter", lambda: None)
    out = tmp_path / "v.png"
    argv = ["preview", str(layer), "-o", str(out), "--size", *map(str, SIZE), "--json"]
    assert cli.main(argv) == 0
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if "no Vulkan adapter" in ln]
    assert len(lines) == 1 and "apt-get install mesa-vulkan-drivers" in lines[0]
    assert "Traceback" not in cap.err
    report = json.loads(cap.out)
    assert report["backend"] == "embree" and out.exists()
    assert cli.main([*argv[:-1], "--backend", "wgpu"]) != 0  # forced wgpu: a usage error
    assert "no Vulkan adapter found" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# --compare: the path-traced reference of the same view


COMPARE_SIZE = ["--size", "96", "72"]


@pytest.fixture(scope="module")
def full_bake(tmp_path_factory):
    """samples/cornell_box.usda baked as shipped (its authored settings: 34 x 34, 256 samples,
    64 bounces)."""
    d = tmp_path_factory.mktemp("preview_full")
    shutil.copy(SAMPLES / "cornell_box.usda", d)
    assert cli.main(["bake", str(d / "cornell_box.usda"), "--quiet"]) == 0
    return d / "cornell_box.lightmaps.usda"


def _compare(layer, out, capsys, *extra):
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(out), *COMPARE_SIZE, "--compare", "--json", *extra]
    assert cli.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_compare_cornell_baked_view_within_5_percent_of_the_path_traced_view(
    full_bake, tmp_path, capsys
):
    """The done-when of issue 14: the preview's baked-lighting image of the cornell sample is
    within 5 % relRMSE of --compare's path-traced view at the same (automatic) camera.

    Measured (2 x 2 footprint, wgpu, 2026-12-06): relRMSE 1.3 %, bias -0.1 %, reference noise
    1.2 % (1024 samples per pixel; 2536 pixels); one point per pixel 1.3 %, noise 1.0 % (2498
    pixels; 2.6 % when first written, at an earlier plan). The reference's Monte Carlo noise is
    independent of the bake, so it adds in quadrature: E[relRMSE^2] = (preview error)^2 +
    noise^2. The assertion is on the *raw* relRMSE, noise included, so the noise can only make
    the test harder, never let a worse preview pass; and the noise is required to be small (<
    1.5 %: a raw 5 % with 1.5 % noise still means sqrt(5^2 - 1.5^2) = 4.8 % of preview error),
    so the bound measures the bake and not the reference."""
    out = tmp_path / "cmp.png"
    rep = _compare(full_bake, out, capsys, "--compare-samples", "1024")
    c = rep["compare"]
    assert c["samples"] == 1024 and c["batches"] == 8 and c["bounces"] == 64
    assert c["footprint"] == 2 and c["samples_per_point"] == 256  # 2 x 2 points per pixel
    assert c["pixels"] == round(rep["covered_fraction"] * 96 * 72)
    assert c["pixels"] <= c["points"] <= 4 * c["pixels"]
    assert c["inside_geometry"] == 0
    assert c["reference_noise"] < 0.015
    assert c["relrmse"] < 0.05
    assert abs(c["bias"]) < 0.02
    assert c["relrmse_denoised"] <= c["relrmse"]
    assert set(c) == _documented_fields("compare` field"), "docs/preview.md drifted"
    img = images.read(out).pixels
    assert img.shape[:2] == (72, 3 * 96 + 2 * 4)  # preview | reference | heat map
    heat = img[:, 2 * 96 + 8 :]
    assert heat[0, 0].max() == 0 and heat.max() > 0  # uncovered black, errors coloured


def _documented_fields(header: str) -> set[str]:
    """The backticked names in the first column of the docs/preview.md table under header."""
    import re

    text = (SAMPLES.parent / "docs" / "preview.md").read_text(encoding="utf-8")
    table = text.split(header, 1)[1].split("\n\n", 1)[0]
    names = set()
    for row in table.splitlines()[2:]:
        names |= set(re.findall(r"`([a-z_]+)`", row.split("|")[1]))
    return names


def test_compare_noise_estimate_matches_the_scatter_between_seeds(full_bake):
    """The reference's noise estimate (batch scatter) predicts how much two references of
    different seeds differ: E|r0 - r1|^2 = Var r0 + Var r1. Within 20 % (measured ratio 1.05). The
    same seed gives the same reference bit for bit."""
    from usdahd.preview import compare

    stage, meshes, up = P.baked_meshes(str(full_bake))
    vp = P.auto_camera(np.concatenate([np.asarray(m.points) for m, *_ in meshes]), up, 96 / 72)
    kw = dict(samples=64, bounces=None)
    a = compare.reference(stage, meshes, vp, (96, 72), seed=0, **kw)
    b = compare.reference(stage, meshes, vp, (96, 72), seed=1, **kw)
    again = compare.reference(stage, meshes, vp, (96, 72), seed=0, **kw).image
    r0, v0, i0, r1, v1 = a.image, a.var, a.info, b.image, b.var
    assert np.array_equal(r0, again)
    assert i0["bounces"] == 64 and i0["samples"] == 64  # the bake's recorded bounces
    cov = r0[..., 3] > 0
    d2 = float(((r0[..., :3] - r1[..., :3])[cov] ** 2).sum())
    predicted = float((v0[cov] + v1[cov]).sum())
    assert 0.8 < d2 / predicted < 1.25


def test_compare_sees_missing_indirect_light(full_bake, tmp_path, capsys):
    """The comparison can fail: against a direct-light-only reference (--compare-bounces 0) the
    64-bounce bake is far brighter (measured relRMSE 45 %, bias +51 %)."""
    rep = _compare(
        full_bake, tmp_path / "d.png", capsys, "--compare-samples", "32", "--compare-bounces", "0"
    )
    c = rep["compare"]
    assert c["bounces"] == 0
    assert c["relrmse"] > 0.2 and c["bias"] > 0.2


def test_compare_statistics_are_the_same_on_the_embree_fallback(layer, tmp_path, capsys):
    """The fallback renders the same preview (test_embree_image_matches_wgpu) and traces the
    same reference (same seed, same visible points): the statistics agree."""
    a = _compare(layer, tmp_path / "a.png", capsys, "--compare-samples", "16")["compare"]
    b = _compare(
        layer, tmp_path / "b.png", capsys, "--compare-samples", "16", "--backend", "embree"
    )
    b = b["compare"]
    assert a["pixels"] == b["pixels"] and a["bounces"] == b["bounces"] == 1
    assert a["reference_noise"] == b["reference_noise"]
    assert abs(a["relrmse"] - b["relrmse"]) < 1e-4 * a["relrmse"]


def test_compare_statistics_unit():
    """relRMSE, bias and the noise subtraction on a hand-made pair: b = 1.1 r everywhere."""
    from usdahd.preview import compare

    ref = np.zeros((2, 3, 4), np.float32)
    ref[..., :3] = np.arange(1, 19, dtype=np.float32).reshape(2, 3, 3)
    ref[..., 3] = 1.0
    ref[0, 0, 3] = 0.0  # not covered: left out
    baked = ref.copy()
    baked[..., :3] *= 1.1
    var = np.full((2, 3, 3), 1e-4)
    st = compare.error_stats(baked, ref, var)
    r = ref[..., :3][ref[..., 3] > 0].astype(np.float64)
    assert st["pixels"] == 5
    assert st["relrmse"] == pytest.approx(0.1, rel=1e-6)
    assert st["bias"] == pytest.approx(0.1, rel=1e-6)
    noise = np.sqrt(15 * 1e-4 / (r * r).sum())
    assert st["reference_noise"] == pytest.approx(noise)
    assert st["relrmse_denoised"] == pytest.approx(np.sqrt(0.01 - noise**2), rel=1e-6)
    heat = compare.heat_map(baked, ref)
    assert heat[0, 0].max() == 0 and heat.shape == (2, 3, 3)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--compare-samples", "8"], "--compare-samples is an option of --compare; add --compare"),
        (["--seed", "0"], "--seed is an option of --compare; add --compare"),
        (["--compare", "--compare-samples", "1"], "--compare-samples 1: the reference needs at"),
        (["--compare", "--compare-bounces", "-1"], "--compare-bounces -1: bounces must be >= 0"),
    ],
)
def test_compare_bad_options(layer, tmp_path, capsys, extra, message):
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(tmp_path / "x.png"), *COMPARE_SIZE, *extra]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "x.png").exists()


def test_compare_subprocess(layer, tmp_path):
    """As a user runs it: one JSON report on stdout, the three-panel PNG; a bad option is one
    error line and exit code 2."""
    import os
    import subprocess
    import sys

    import usdahd

    env = dict(os.environ, PYTHONPATH=str(Path(usdahd.__file__).resolve().parents[1]))
    out = tmp_path / "s.png"
    base = [sys.executable, "-m", "usdahd", "preview", str(layer), "-o", str(out)]
    argv = [*base, "--size", "32", "24", "--compare", "--compare-samples", "8", "--json"]
    proc = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["compare"]["samples"] == 8 and rep["compare"]["relrmse"] > 0
    assert images.read(out).pixels.shape[:2] == (24, 3 * 32 + 8)
    bad = subprocess.run(
        [*base, "--compare", "--compare-samples", "0"],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert bad.returncode == 2 and bad.stdout == ""
    assert (
        bad.stderr.strip()
        .splitlines()[-1]
        .startswith(
            "usdahd preview: error: --compare-samples 0: the reference needs at least 2 samples"
        )
    )


# ---------------------------------------------------------------------------------------------
# --atlas: the contact sheet of every lightmap texture


def _atlas(layer, out, capsys, *extra):
    capsys.readouterr()
    assert cli.main(["preview", str(layer), "-o", str(out), "--atlas", "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_atlas_tiles_are_the_textures_with_chart_outlines(layer, tmp_path, capsys):
    """Every texture of every baked prim is a tile; a tile pixel inside a texel away from chart
    boundaries shows the texture's display value at that texel (nearest magnification), and
    exactly the pixels on chart boundaries (from the baker's rasteriser) are the outline
    colour."""
    from usdahd.preview import atlas

    out = tmp_path / "atlas.png"
    rep = _atlas(layer, out, capsys)
    _, meshes, _ = P.baked_meshes(str(layer))
    by_path = {m.path: (m, r) for m, r, *_ in meshes}
    expected = sum(len(models.get(r.model).layout(r.ratio)) for _, r, *_ in meshes)
    assert len(rep["tiles"]) == expected == 14 and rep["meshes"] == 7
    assert rep["flagged"] == [] and rep["outline_pixels"] > 0
    sheet = images.read(out).pixels
    assert list(sheet.shape[1::-1]) == rep["size"]
    for t in rep["tiles"]:
        mesh, res = by_path[t["prim"]]
        role = next(lay for lay in models.get(res.model).layout(res.ratio) if lay.role == t["role"])
        px = schema.read_record_pixels(res, role.role, role.channels)
        charts = atlas.chart_image(mesh, res.resolution)
        s = atlas.magnification(res.resolution)
        assert (t["width"], t["height"]) == (px.shape[1] * s, px.shape[0] * s)
        got = sheet[t["y"] : t["y"] + t["height"], t["x"] : t["x"] + t["width"]]
        want, edge = atlas.tile(px, charts, [], s)
        assert np.array_equal(got, want)
        assert np.all(got[edge] == atlas.OUTLINE)
        centre = atlas.display(px, charts >= 0)  # the texel centres, where no outline runs
        c = s // 2
        assert np.array_equal(got[c::s, c::s], centre)
        # an outline pixel wherever the chart id changes between neighbouring texels
        ys, xs = np.nonzero(charts[:, 1:] != charts[:, :-1])
        assert np.all(edge[ys * s + c, (xs + 1) * s])


def test_atlas_marks_the_texels_validate_flags(layer, tmp_path, capsys):
    """A negative I_z written into one texel of the floor's I_z texture: usdahd validate's
    TexelValues names that texel, and the sheet frames it in the flag colour in both of the
    floor's tiles."""
    from usdahd.preview import atlas

    d = tmp_path / "copy"
    shutil.copytree(layer.parent, d)
    copied = d / layer.name
    _, meshes, _ = P.baked_meshes(str(copied))
    floor = next(r for m, r, *_ in meshes if m.path.endswith("/Floor"))
    img = images.read(floor.textures["iz"])
    px = img.pixels.copy()
    ox, oy = floor.rect()[:2] if floor.atlas else (0, 0)  # texel (7, 5) of the floor's own grid
    px[5 + oy, 7 + ox] = -1.0
    images.write(floor.textures["iz"], px, color_space=img.color_space, channels=img.channels)
    rep = _atlas(copied, tmp_path / "a.png", capsys)
    marks = [f for f in rep["flagged"] if f["prim"] == "/World/Geometry/Floor"]
    assert {"texel": [7, 5], "finding": "TexelValues/NegativeIz"} in [
        {k: f[k] for k in ("texel", "finding")} for f in marks
    ]
    sheet = images.read(tmp_path / "a.png").pixels
    tiles = [t for t in rep["tiles"] if t["prim"] == "/World/Geometry/Floor"]
    assert len(tiles) == 2
    for t in tiles:
        s = atlas.magnification(floor.resolution)
        x0, y0 = t["x"] + 7 * s - 1, t["y"] + 5 * s - 1
        assert np.all(sheet[y0, x0 : x0 + s + 1] == atlas.FLAG)  # the frame's top edge
        assert np.all(sheet[y0 : y0 + s + 1, x0] == atlas.FLAG)  # and its left edge


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--camera", "/Cam"], "--camera does not apply to --atlas"),
        (["--size", "64", "48"], "--size does not apply to --atlas"),
        (["--compare"], "--compare does not apply to --atlas"),
    ],
)
def test_atlas_bad_options(layer, tmp_path, capsys, extra, message):
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(tmp_path / "x.png"), "--atlas", *extra]
    assert cli.main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_atlas_of_an_unbaked_stage_is_an_error(tmp_path, capsys):
    stage = tmp_path / "cornell_box.usda"
    shutil.copy(SAMPLES / "cornell_box.usda", stage)
    argv = ["preview", str(stage), "-o", str(tmp_path / "x.png"), "--atlas"]
    assert cli.main(argv) == 2
    assert "no baked prim (formatVersion 0); run usdahd bake first" in capsys.readouterr().err


def test_compare_of_the_open_plane_is_noise_only(tmp_path, capsys):
    """samples/open_plane.usda: under a uniform dome of radiance 1 the preview is exactly the
    analytic I = 1, so all the difference is the reference's noise: relRMSE matches the noise
    estimate (measured ratio 0.98 at 16 samples), relrmse_denoised is about 0 and the
    reference's mean is 1 within its standard error."""
    stage = tmp_path / "open_plane.usda"
    shutil.copy(SAMPLES / "open_plane.usda", stage)
    assert cli.main(["bake", str(stage), "--resolution", "8", "--samples", "16", "--quiet"]) == 0
    layer = tmp_path / "open_plane.lightmaps.usda"
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(tmp_path / "p.png"), "--size", "48", "36"]
    assert cli.main([*argv, "--compare", "--compare-samples", "16", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    c = rep["compare"]
    assert rep["luminance"]["min"] == rep["luminance"]["max"] == pytest.approx(1.0, abs=1e-3)
    assert c["pixels"] > 100
    assert 0.8 < c["relrmse"] / c["reference_noise"] < 1.2
    assert c["relrmse_denoised"] < 0.5 * c["reference_noise"]
    se = c["reference_noise"] / np.sqrt(c["pixels"])  # of the mean over independent pixels
    assert abs(c["reference_mean_rgb"][1] - 1.0) < 4 * se


def test_atlas_subprocess(layer, tmp_path):
    """--atlas as a user runs it: the JSON report on stdout and the sheet; --atlas with --size
    is one error line and exit code 2."""
    import os
    import subprocess
    import sys

    import usdahd

    env = dict(os.environ, PYTHONPATH=str(Path(usdahd.__file__).resolve().parents[1]))
    out = tmp_path / "sheet.png"
    base = [sys.executable, "-m", "usdahd", "preview", str(layer), "-o", str(out), "--atlas"]
    proc = subprocess.run([*base, "--json"], capture_output=True, text=True, env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert len(rep["tiles"]) == 14
    assert list(images.read(out).pixels.shape[1::-1]) == rep["size"]
    out.unlink()
    bad = subprocess.run(
        [*base, "--size", "8", "8"], capture_output=True, text=True, env=env, timeout=900
    )
    assert bad.returncode == 2 and bad.stdout == "" and not out.exists()
    assert bad.stderr.strip().splitlines()[-1] == (
        "usdahd preview: error: --size does not apply to --atlas (a sheet of the textures, not "
        "a view); drop one of them"
    )


# ---------------------------------------------------------------------------------------------
# --model-view: albedo x irradiance at the normal-mapped normal


@pytest.fixture(scope="module")
def wall_bake(tmp_path_factory):
    d = tmp_path_factory.mktemp("wall")
    shutil.copy(SAMPLES / "normal_wall.usda", d)
    shutil.copytree(SAMPLES / "textures", d / "textures")
    argv = ["bake", str(d / "normal_wall.usda"), "--resolution", "32", "--samples", "16"]
    assert cli.main([*argv, "--bounces", "1", "--quiet"]) == 0
    return d


def _model_view(layer, mutate=None, backends=("wgpu", "embree")):
    """{backend: image} of --model-view at the auto camera, plus the flat-normal wgpu image
    ("flat") and the floor's coverage ("floor", normal_wall only)."""
    import dataclasses

    from usdahd.preview import surface
    from usdahd.preview.meshes import draw_items, render_view

    stage, meshes, up = P.baked_meshes(str(layer))
    vp = P.auto_camera(np.concatenate([np.asarray(m.points) for m, *_ in meshes]), up, 96 / 72)
    surf = surface.surfaces(stage, meshes)
    _, dev = P.device()
    out = {}
    for b in backends:
        items = draw_items(meshes, surf)
        out[b] = render_view(stage, meshes, items, vp, SIZE, dev if b == "wgpu" else None, surf)
    flat = [[dataclasses.replace(g, normal_tex=None) for g in s] for s in surf]
    out["flat"] = render_view(stage, meshes, draw_items(meshes, flat), vp, SIZE, dev, flat)
    out["plain"] = render_view(stage, meshes, draw_items(meshes), vp, SIZE, dev)
    if "embree" in backends:
        out["plain_embree"] = render_view(stage, meshes, draw_items(meshes), vp, SIZE, None)
    names = [m.path.rsplit("/", 1)[-1] for m, *_ in meshes]
    if "Floor" in names:
        k = names.index("Floor")
        only = [s if j == k else [] for j, s in enumerate(surf)]
        out["floor"] = render(dev, draw_items(meshes, only), vp)[..., 3] > 0
    return out, surf, meshes


def render(dev, items, vp):
    return P.render(dev, items, vp, SIZE)


def test_model_view_wgpu_matches_embree_on_the_normal_wall(wall_bake):
    """normal_wall: the wall's normal map (a dome grid) and the floor's checker albedo texture,
    through the WGSL functions (wgpu) and their numpy transcription (Embree). Same coverage.
    Pixels without a normal map (the floor) agree as the flat preview does: within 1e-4
    relative (measured max 3.4e-5). On the normal-mapped wall the tail is wider (measured median
    3.3e-4, p99 8.1e-3, max 1.3e-2): the grazing sun makes C_d = I_z (1 - w_a) / d_z
    large and a tilted normal no longer cancels the 1/d_z, so the GPU's fixed-point bilinear
    weights on the direction texture (lavapipe: 8 sub-texel bits) show; a constant tilted map
    gives the same tail (max 1.6e-2), a flat one does not."""
    imgs, surf, _ = _model_view(wall_bake / "normal_wall.lightmaps.usda")
    g, e = imgs["wgpu"], imgs["embree"]
    assert [[x.normal_tex is not None for x in s] for s in surf] == [[True], [False]]
    assert surf[1][0].albedo_tex is not None  # the checker
    cov = g[..., 3] > 0
    assert np.array_equal(cov, e[..., 3] > 0)
    rel = np.abs(e[..., :3] - g[..., :3]).max(-1) / np.maximum(g[..., :3].max(-1), 1e-6)
    floor = imgs["floor"] & cov & np.all(g == imgs["flat"], -1)
    wall = cov & ~imgs["floor"]
    assert floor.sum() > 200 and wall.sum() > 200
    assert rel[floor].max() < 1e-4 and np.median(rel[floor]) < 1e-5
    assert np.median(rel[wall]) < 2e-3 and np.percentile(rel[wall], 99) < 2e-2


def test_model_view_normal_map_changes_the_wall_only(wall_bake):
    """The normal-mapped image differs from the flat-normal one on the wall (the domes turn
    towards and away from the grazing sun: measured ~30 % of the covered pixels beyond 2 %),
    and not at all on the floor, which has no normal map."""
    imgs, _, _ = _model_view(wall_bake / "normal_wall.lightmaps.usda", backends=("wgpu",))
    g, f = imgs["wgpu"], imgs["flat"]
    cov = g[..., 3] > 0
    wall = cov & ~imgs["floor"]
    d = np.abs(g[..., :3] - f[..., :3]).max(-1) / np.maximum(f[..., :3].max(-1), 1e-6)
    assert (d[wall] > 0.02).mean() > 0.3
    lit = g[..., :3].max(-1)[wall] > f[..., :3].max(-1)[wall]
    assert 0.1 < lit.mean() < 0.9  # dome sides both brighter and darker than the flat wall
    assert np.array_equal(g[imgs["floor"] & cov], f[imgs["floor"] & cov])


def test_model_view_is_albedo_times_irradiance_on_constant_albedo(layer):
    """cornell_box: constant diffuseColor everywhere and no normal map, so at every pixel the
    --model-view image divided by the plain preview is exactly one material's diffuseColor
    (both backends), and every wall colour shows."""
    from usdahd.usd.reader import load_scene

    imgs, surf, meshes = _model_view(layer)
    stage, _, _ = P.baked_meshes(str(layer))
    albedos = np.array([m.albedo for m in load_scene(stage).materials], np.float64)
    assert all(g.albedo_tex is None and g.normal_tex is None for s in surf for g in s)
    for b, plain in (("wgpu", imgs["plain"]), ("embree", imgs["plain_embree"])):
        cov = (plain[..., 3] > 0) & (plain[..., :3].min(-1) > 1e-4)
        ratio = imgs[b][..., :3][cov] / plain[..., :3][cov]
        err = np.abs(ratio[:, None, :] - albedos[None]).max(-1).min(-1)
        assert err.max() < 1e-5
        which = np.abs(ratio[:, None, :] - albedos[None]).max(-1).argmin(-1)
        assert len(set(which.tolist())) >= 3  # white, red and green walls


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--atlas"], "--model-view does not apply to --atlas"),
        (["--compare"], "--compare checks the baked irradiance against a path-traced"),
    ],
)
def test_model_view_bad_options(layer, tmp_path, capsys, extra, message):
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(tmp_path / "x.png"), "--model-view", *extra]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "x.png").exists()


def _edited_wall(wall_bake, tmp_path, edit):
    """A copy of the normal_wall bake whose baked layer carries ``edit(stage)``'s opinions."""
    from pxr import Usd

    d = tmp_path / "w"
    shutil.copytree(wall_bake, d)
    layer = d / "normal_wall.lightmaps.usda"
    stage = Usd.Stage.Open(str(layer))
    edit(stage)
    stage.GetRootLayer().Save()
    return layer


@pytest.mark.parametrize(
    "case, message",
    [
        ("no_primvar", "/World/Geometry/Wall: material /World/Looks/BumpyPlaster reads texture "
         "coordinates from primvar 'uv', which the mesh lacks; author it"),
        ("one_channel", "/World/Looks/BumpyPlaster: UsdPreviewSurface inputs:normal is connected "
         "to a one-channel output"),
        ("two_sets", "/World/Looks/BumpyPlaster: diffuseColor reads 'uv' but normal reads 'st'"),
    ],
)  # fmt: skip
def test_model_view_bad_materials(wall_bake, tmp_path, capsys, case, message):
    from pxr import Sdf, UsdShade

    look = "/World/Looks/BumpyPlaster"

    def edit(stage):
        if case == "no_primvar":
            stage.GetPrimAtPath("/World/Geometry/Wall").GetAttribute("primvars:uv").Block()
        elif case == "one_channel":
            tex = UsdShade.Shader(stage.GetPrimAtPath(f"{look}/NormalTexture"))
            tex.CreateOutput("r", Sdf.ValueTypeNames.Float)
            inp = UsdShade.Shader(stage.GetPrimAtPath(f"{look}/PreviewSurface")).GetInput("normal")
            inp.GetAttr().SetConnections([Sdf.Path(f"{look}/NormalTexture.outputs:r")])
        else:
            reader = UsdShade.Shader(stage.GetPrimAtPath(f"{look}/TexCoordReader"))
            reader.GetInput("varname").Set("st")
            inp = UsdShade.Shader(stage.GetPrimAtPath(f"{look}/PreviewSurface")).GetInput(
                "diffuseColor"
            )
            inp.GetAttr().SetConnections(
                [Sdf.Path("/World/Looks/CheckerFloor/DiffuseTexture.outputs:rgb")]
            )

    layer = _edited_wall(wall_bake, tmp_path, edit)
    capsys.readouterr()
    out = tmp_path / "x.png"
    assert cli.main(["preview", str(layer), "-o", str(out), "--size", "32", "24",
                     "--model-view"]) != 0  # fmt: skip
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()
    assert cli.main(["preview", str(layer), "-o", str(out), "--size", "32", "24"]) == 0


# ---------------------------------------------------------------------------------------------
# --ahd-classic: the classic AHD import (usdahd.preview.classic)


def test_ahd_classic_parameters_are_the_bake_at_the_texel_centres(layer):
    """The classic C_a, d, C_d textures decoded from the (hhd) bake give, texel by texel, what
    the model's own decode + evaluate gives at the normal and at tilted normals."""
    from usdahd.preview import classic

    _, meshes, _ = P.baked_meshes(str(layer))
    rng = np.random.default_rng(3)
    for _, res, *_ in meshes[:3]:
        m = models.get(res.model)
        layout = m.layout(res.ratio)
        tex = [schema.read_record_pixels(res, t.role, t.channels) for t in layout]
        ca, d, cd = classic.parameters(res.model, res.ratio, tex, res.factors)
        params = m.decode({t.role: px for t, px in zip(layout, tex)}, ratio=res.ratio,
                          factors=res.factors)  # fmt: skip
        n = rng.normal(size=ca.shape)
        n[..., 2] = np.abs(n[..., 2])
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        got = classic.evaluate(classic.VARIANTS[res.model], classic.filtered(ca, d, cd), n)
        np.testing.assert_allclose(got, m.evaluate(params, n), rtol=1e-5, atol=1e-6)


@pytest.fixture(scope="module")
def pillar_bake(tmp_path_factory):
    """samples/pillar_room.usda baked coarse (ahd, 4 texels per metre, 64 samples, 1 bounce):
    the pillar's shadow edges span few texels, where classic filtering overshoots."""
    d = tmp_path_factory.mktemp("pillar")
    shutil.copy(SAMPLES / "pillar_room.usda", d)
    argv = ["bake", str(d / "pillar_room.usda"), "--model", "ahd", "--texel-density", "4"]
    assert cli.main([*argv, "--samples", "64", "--bounces", "1", "--seed", "1", "--quiet"]) == 0
    return d / "pillar_room.lightmaps.usda"


def _classic_views(layer, backends=("wgpu", "embree")):
    stage, meshes, up = P.baked_meshes(str(layer))
    vp = P.auto_camera(np.concatenate([np.asarray(m.points) for m, *_ in meshes]), up, 96 / 72)
    _, dev = P.device()
    out = {}
    for b in backends:
        for classic in (False, True):
            items = P.draw_items(meshes, ahd_classic=classic)
            out[b, classic] = P.render_view(
                stage, meshes, items, vp, SIZE, dev if b == "wgpu" else None, ahd_classic=classic
            )
    return out


def test_ahd_classic_wgpu_matches_embree_and_overshoots_the_irradz_decode(pillar_bake):
    """Both backends render the classic import alike (float32 C_a, d, C_d filtered by the
    sampler / raytrace.bilinear, d renormalised); it is brighter than the IrradZ decode along
    the pillar's shadow edges (Fig. 1): with the flat normal the classic I_z = C_a + d_z' C_d
    with d_z' >= the interpolated d_z, while the IrradZ decode returns the interpolated I_z.
    (It can also be a little darker where C_d and d_z rise together across a texel.)"""
    v = _classic_views(pillar_bake)
    g, e = v["wgpu", True], v["embree", True]
    cov = g[..., 3] > 0
    assert np.array_equal(cov, e[..., 3] > 0)
    rel = np.abs(e[..., :3] - g[..., :3]).max(-1) / np.maximum(g[..., :3].max(-1), 1e-6)
    assert rel[cov].max() < 2e-4 and np.median(rel[cov]) < 1e-5  # measured max 3.7e-5
    irr = v["wgpu", False][..., :3].mean(-1)
    over = (g[..., :3].mean(-1) - irr)[cov] / np.maximum(irr[cov], 1e-6)
    assert over.max() > 0.2  # the seams (measured: +212 %; 99th percentile +26 %)
    assert over.max() > 4 * -over.min() and over.mean() > 0.0  # measured min -19 %, mean +1.5 %


def test_ahd_classic_refuses_models_that_are_not_ahd_like(tmp_path, capsys):
    shutil.copy(SAMPLES / "open_plane.usda", tmp_path)
    stage = tmp_path / "open_plane.usda"
    argv = ["bake", str(stage), "--model", "sh_l1", "--resolution", "8", "--samples", "16"]
    assert cli.main([*argv, "--quiet"]) == 0
    capsys.readouterr()
    out = tmp_path / "x.png"
    argv = ["preview", str(tmp_path / "open_plane.lightmaps.usda"), "-o", str(out)]
    assert cli.main([*argv, "--ahd-classic", "--backend", "embree"]) == 2
    err = capsys.readouterr().err
    assert "--ahd-classic imports an AHD-like bake as classic AHD textures" in err
    assert "applies to ahd, ahd_classic, hhd bakes, and this prim is baked with sh_l1" in err
    assert "Traceback" not in err and not out.exists()


def test_ahd_classic_does_not_apply_to_the_atlas(layer, tmp_path, capsys):
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(tmp_path / "x.png"), "--atlas", "--ahd-classic"]
    assert cli.main(argv) == 2
    assert "--ahd-classic does not apply to --atlas" in capsys.readouterr().err
