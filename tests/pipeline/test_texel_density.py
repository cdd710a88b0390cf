"""The automatic texel density (issue 39 item 3, docs/texels.md "Texel density and resolution"):
one density per stage from a texel budget spread by area, a minimum map per prim, sides on
4-texel blocks; explicit --texel-density / --resolution / ahdLightmap inputs win."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.scenes import SAMPLES, sample_stages
from usdahd import cli
from usdahd.pipeline.density import (
    SHARED_DENSITY_MAX_RATIO,
    SHARED_DENSITY_SHARE,
    STAGE_MIN_TEXELS,
    auto_texel_density,
    density_ceiling,
    planned_texels,
    shared_density,
)
from usdahd.pipeline.plan import (
    _pad_to_multiple,
)
from usdahd.pipeline.settings import (
    DEFAULT_TEXEL_BUDGET,
    DENSITY_AUTO_MAX,
    DENSITY_LADDER,
    DENSITY_MAX_RESOLUTION,
    MIN_RESOLUTION,
    RESOLUTION_MULTIPLE,
)


def _quad(stage, path, center, size, *, uv=True, up=1):
    """A size x size quad facing +y at ``center`` (UVs filling [0.02, 0.98]^2 when ``uv``)."""
    from pxr import Gf, UsdGeom, Vt

    cx, cy, cz = center
    h = size / 2
    mesh = UsdGeom.Mesh.Define(stage, path)
    pts = [(cx - h, cy, cz + h), (cx + h, cy, cz + h), (cx + h, cy, cz - h), (cx - h, cy, cz - h)]
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(0, up, 0)] * 4))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    if uv:
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", _tc2(), UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray([(0.02, 0.02), (0.98, 0.02), (0.98, 0.98), (0.02, 0.98)]))
    return mesh


def _tc2():
    from pxr import Sdf

    return Sdf.ValueTypeNames.TexCoord2fArray


def _cube(stage, path, center, size):
    """A closed box mesh without UVs (the bake unwraps it)."""
    from pxr import Gf, UsdGeom, Vt

    c, h = np.asarray(center, float), size / 2
    corners = [c + h * np.array([x, y, z]) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in corners]))
    faces = [0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3]
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr(faces)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return mesh


def _stage(path, build, mpu=1.0):
    from pxr import Usd, UsdGeom, UsdLux

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    build(stage)
    stage.GetRootLayer().Save()
    return path


def _dry_run(capsys, stage, *args):
    code = cli.main(["bake", str(stage), "--dry-run", "--json", "--quiet", *args])
    out = capsys.readouterr()
    assert code == 0, out.err + out.out
    return json.loads(out.out)


def _resolutions(report):
    return {p["path"]: tuple(p["resolution"]) for p in report["prims"]}


def _props(stage):
    """Prop-scale meshes: a 10 cm card with UVs, a 20 cm box and a 5 cm box without UVs, 8 m
    apart end to end (so the floor by stage size leaves the density at its 16/m ceiling)."""
    _quad(stage, "/World/Card", (0, 0, 0), 0.1)
    _cube(stage, "/World/Box", (1, 0.1, 0), 0.2)
    _cube(stage, "/World/Dice", (7.95, 0.025, 0), 0.05)


def test_prop_scale_stage_gets_the_minimum_map_on_4_texel_blocks(tmp_path, capsys):
    stage = _stage(tmp_path / "props.usda", _props)
    report = _dry_run(capsys, stage)
    res = _resolutions(report)
    assert set(res) == {"/World/Card", "/World/Box", "/World/Dice"}
    for path, (w, h) in res.items():
        assert min(w, h) >= MIN_RESOLUTION, (path, w, h)
        assert w % RESOLUTION_MULTIPLE == 0 and h % RESOLUTION_MULTIPLE == 0, (path, w, h)
    # Far below the budget: the densest step; the stage is 8 m across (-5 cm to 7.975 m + ...).
    td = report["texel_density"]
    assert td["stage_extent"] >= STAGE_MIN_TEXELS / DENSITY_AUTO_MAX
    assert td["density"] == td["ceiling"] == DENSITY_AUTO_MAX
    prims = {p["path"]: p for p in report["prims"]}
    for path in res:
        assert not any("gives only" in w for w in prims[path]["warnings"]), prims[path]
        assert any("minimum" in n for n in prims[path].get("notes", [])), prims[path]
    # The same stage at an explicit density: 16/m on a 10 cm card is the tiny map it asked for,
    # and the warning says so (explicit settings win over the minimum).
    explicit = _dry_run(capsys, stage, "--texel-density", "16")
    card = next(p for p in explicit["prims"] if p["path"] == "/World/Card")
    assert card["resolution"] == [2, 2]  # ceil(16 * 0.1 / 0.96): exact, not on 4-texel blocks
    assert any("gives only" in w for w in card["warnings"])
    assert "texel_density" not in explicit


def _level(stage):
    """A level: a 300 m ground quad, 24 building walls 20-40 m, and small props."""
    _quad(stage, "/World/Ground", (0, 0, 0), 300.0)
    rng = np.random.default_rng(7)
    for i in range(24):
        x, z = rng.uniform(-120, 120, 2)
        _quad(stage, f"/World/Roof{i}", (float(x), 10.0, float(z)), float(rng.uniform(20, 40)))
    for i in range(6):
        _quad(stage, f"/World/Sign{i}", (float(i), 0.5, 0.0), 0.3)


def test_level_scale_stage_stays_within_the_texel_budget(tmp_path, capsys):
    stage = _stage(tmp_path / "level.usda", _level)
    report = _dry_run(capsys, stage)
    info = report["texel_density"]
    assert info["budget"] == DEFAULT_TEXEL_BUDGET and info["prims"] == 31
    assert report["texels_total"] <= DEFAULT_TEXEL_BUDGET
    assert report["texels_total"] == info["estimated_texels"]  # authored UVs: exact estimate
    # The densest ladder step that fits: one step denser would not.
    d = info["density"]
    k = round(np.log(d / DENSITY_AUTO_MAX) / np.log(DENSITY_LADDER))
    assert d == pytest.approx(DENSITY_AUTO_MAX * DENSITY_LADDER**k, rel=1e-3) and k >= 1
    res = _resolutions(report)
    assert all(w % RESOLUTION_MULTIPLE == 0 and w >= MIN_RESOLUTION for w, _ in res.values())
    ground = res["/World/Ground"][0]
    assert ground == min(DENSITY_MAX_RESOLUTION, int(np.ceil(d * 300 / 0.96 / 4) * 4))
    denser = DENSITY_AUTO_MAX * DENSITY_LADDER ** (k - 1)
    sides = [np.ceil(denser * 300 / 0.96)] + [np.ceil(denser * s / 0.96) for s in _level_sizes()]
    sides = [min(DENSITY_MAX_RESOLUTION, max(MIN_RESOLUTION, -(-int(n) // 4) * 4)) for n in sides]
    assert sum(s * s for s in sides) > DEFAULT_TEXEL_BUDGET
    # A smaller budget gives a lower density, still within it; one prim on an authored
    # resolution keeps it and is left out of the budget.
    small = _dry_run(capsys, stage, "--texel-budget", "200000")
    assert small["texel_density"]["density"] < d
    assert small["texels_total"] <= 200000


def _level_sizes():
    rng = np.random.default_rng(7)
    sizes = []
    for _ in range(24):
        rng.uniform(-120, 120, 2)
        sizes.append(float(rng.uniform(20, 40)))
    return sizes + [0.3] * 6


def test_explicit_settings_win_over_the_automatic_density(tmp_path, capsys):
    from pxr import Usd

    from usdahd.usd import plugin, schema

    plugin.register()
    path = _stage(tmp_path / "mixed.usda", _props)
    stage = Usd.Stage.Open(str(path))
    card = stage.GetPrimAtPath("/World/Card")
    schema.apply(card)
    schema.write_inputs(card, resolution=12)
    box_prim = stage.GetPrimAtPath("/World/Box")
    schema.apply(box_prim)
    schema.write_inputs(box_prim, texel_density=40.0)
    dice = stage.GetPrimAtPath("/World/Dice")
    schema.apply(dice)
    stage.GetRootLayer().Save()
    report = _dry_run(capsys, path)
    res = _resolutions(report)
    assert res["/World/Card"] == (12, 12)  # an authored resolution is kept as it is
    assert report["texel_density"]["prims"] == 1  # only the dice is on the automatic density
    assert min(res["/World/Dice"]) >= MIN_RESOLUTION
    # 40 texels/m on a 20 cm box: 8 texels per face side (xatlas packs 36x24), not raised to
    # the minimum.
    w, h = res["/World/Box"]
    assert w * h < MIN_RESOLUTION**2
    box = next(p for p in report["prims"] if p["path"] == "/World/Box")
    assert not any("minimum" in n for n in box.get("notes", []))
    flag = _resolutions(_dry_run(capsys, path, "--resolution", "20"))
    assert flag["/World/Dice"] == (20, 20) and flag["/World/Card"] == (12, 12)
    dense = _dry_run(capsys, path, "--texel-density", "400")
    assert "texel_density" not in dense
    assert _resolutions(dense)["/World/Card"] == (12, 12)


def test_the_density_does_not_depend_on_the_prim_selection(tmp_path, capsys):
    stage = _stage(tmp_path / "level.usda", _level)
    full = _dry_run(capsys, stage, "--texel-budget", "300000")
    one = _dry_run(capsys, stage, "--texel-budget", "300000", "--prim", "/World/Roof3")
    assert one["texel_density"] == full["texel_density"]
    assert _resolutions(one)["/World/Roof3"] == _resolutions(full)["/World/Roof3"]


@pytest.mark.parametrize("name", sample_stages())
def test_no_sample_gets_a_tiny_map_warning(name, capsys, tmp_path):
    out = tmp_path / "out.lightmaps.usda"
    report = _dry_run(capsys, SAMPLES / name, "-o", str(out))
    for p in report["prims"]:
        assert min(p["resolution"]) >= MIN_RESOLUTION, p
        assert p["resolution"][0] % RESOLUTION_MULTIPLE == 0, p
        assert not any("gives only" in w for w in p["warnings"]), p
    assert report["texels_total"] <= DEFAULT_TEXEL_BUDGET


def test_auto_texel_density_steps_down_the_ladder_until_the_budget_fits():
    ext = [100.0, 10.0, 1.0, 0.01]  # metres of map side at 1 texel/m
    # at 16/m: 1600 -> clamped to 1024, 160, 16 -> the minimum 32, 0.16 -> 32
    d, total, fits = auto_texel_density(ext, 2 << 20)
    assert (d, total, fits) == (DENSITY_AUTO_MAX, 1024**2 + 160**2 + 2 * 32**2, True)
    # 1024^2 alone nearly fills 1 << 20: 3 steps down, where the 100 m map is 952^2
    d1, total1, fits1 = auto_texel_density(ext, 1 << 20)
    assert fits1 and total1 <= 1 << 20
    assert d1 == pytest.approx(DENSITY_AUTO_MAX * DENSITY_LADDER**3, rel=1e-3)
    d2, total2, fits2 = auto_texel_density(ext, 100_000)
    assert fits2 and total2 <= 100_000 and d2 < d
    d3, _, _ = auto_texel_density(ext, int(total2 * 1.3))
    assert d3 >= d2  # monotone in the budget
    # Minimum maps above the budget: not fitting, reported as such.
    d4, total4, fits4 = auto_texel_density([0.01] * 10, 5 * MIN_RESOLUTION**2)
    assert not fits4 and total4 == 10 * MIN_RESOLUTION**2
    assert auto_texel_density([], 1000)[2]


def test_the_density_ceiling_puts_the_floor_across_a_small_stage():
    """A stage smaller than STAGE_MIN_TEXELS / 16 m starts the ladder higher: the first step
    of the same ladder (16 * 2^(j/4)) that puts STAGE_MIN_TEXELS texels across it."""
    assert density_ceiling(0.0) == DENSITY_AUTO_MAX
    assert density_ceiling(STAGE_MIN_TEXELS / DENSITY_AUTO_MAX) == DENSITY_AUTO_MAX  # 8 m
    assert density_ceiling(300.0) == DENSITY_AUTO_MAX
    for extent in (0.056, 0.705, 1.0, 2.0, 3.0, 7.9):
        d = density_ceiling(extent)
        assert d * extent >= STAGE_MIN_TEXELS - 1e-9, extent
        j = np.log(d / DENSITY_AUTO_MAX) / -np.log(DENSITY_LADDER)
        assert j == pytest.approx(round(j), abs=0.01) and round(j) >= 1, (extent, d)  # a step
        below = DENSITY_AUTO_MAX * DENSITY_LADDER ** (1 - round(j))  # the step below it
        assert below * extent < STAGE_MIN_TEXELS, (extent, d)  # the first step that does
    assert density_ceiling(1.0, texels=128) == 128.0
    assert density_ceiling(2.0, texels=128) == 64.0
    # The ladder from a raised ceiling: the same steps, so a budget brings it down to 16/m.
    ext = [1.0, 0.1]
    d, total, fits = auto_texel_density(ext, 1 << 20, ceiling=128.0)
    assert (d, total, fits) == (128.0, 128**2 + 32**2, True)
    d2, total2, fits2 = auto_texel_density(ext, 2 * 32**2, ceiling=128.0)
    assert fits2 and total2 == 2 * 32**2 and d2 <= 32.0
    assert d2 == auto_texel_density(ext, 2 * 32**2)[0] or d2 > DENSITY_AUTO_MAX


TABLETOP = SAMPLES.parent / "tests" / "data" / "production" / "tabletop.usda"


def _check_tabletop(report):
    td = report["texel_density"]
    assert td["stage_extent"] == pytest.approx(1.0)  # 100 cm at metersPerUnit 0.01
    assert td["ceiling"] == density_ceiling(1.0) == td["density"] > DENSITY_AUTO_MAX
    note = next(n for n in report["notes"] if n.startswith("texel density "))
    assert (
        f"the densest step up to {td['ceiling']:g}/m (raised from {DENSITY_AUTO_MAX:g}/m so "
        f"that the stage's largest side, 1 m, gets at least {STAGE_MIN_TEXELS} texels)"
    ) in note, note
    table = next(p for p in report["prims"] if p["path"] == "/World/Table")
    side = int(np.ceil(td["density"] * 1.0 / RESOLUTION_MULTIPLE - 1e-9)) * RESOLUTION_MULTIPLE
    assert table["resolution"] == [side, side]
    assert side >= STAGE_MIN_TEXELS  # at 16/m the 1 m table top was 16 -> the 32^2 minimum


def test_a_tabletop_stage_gets_the_density_floor(capsys, tmp_path):
    report = _dry_run(capsys, TABLETOP, "-o", str(tmp_path / "o.lightmaps.usda"))
    _check_tabletop(report)
    # The budget still wins: a small one brings the density back down the ladder.
    small = _dry_run(capsys, TABLETOP, "-o", str(tmp_path / "o.usda"), "--texel-budget", "4000")
    assert small["texel_density"]["density"] < report["texel_density"]["density"]
    assert small["texel_density"]["estimated_texels"] <= 4000
    assert "raised from" in next(n for n in small["notes"] if n.startswith("texel density "))
    # --prim does not move the floor (the density is the whole stage's).
    one = _dry_run(capsys, TABLETOP, "-o", str(tmp_path / "o.usda"), "--prim", "/World/Block")
    assert one["texel_density"] == report["texel_density"]


def test_a_tabletop_stage_gets_the_density_floor_subprocess(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(TABLETOP), "-o", str(tmp_path / "o.usda"),
         "--dry-run", "--json", "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    _check_tabletop(json.loads(proc.stdout))


def test_padding_an_unwrap_to_4_texel_blocks_keeps_every_texel_in_place():
    rng = np.random.default_rng(3)
    w, h = 13, 6
    uv = rng.uniform(0, 1, (50, 3, 2)).astype(np.float32)
    out, (big_w, big_h) = _pad_to_multiple(uv, (w, h), 4)
    assert (big_w, big_h) == (16, 8)
    px_old = np.stack([uv[..., 0] * w, (1 - uv[..., 1]) * h], -1)
    px_new = np.stack([out[..., 0] * big_w, (1 - out[..., 1]) * big_h], -1)
    np.testing.assert_allclose(px_new, px_old, atol=1e-5)
    same, res = _pad_to_multiple(uv, (16, 8), 4)
    assert res == (16, 8) and same is uv


def test_a_bad_texel_budget_is_a_usage_error(tmp_path, capsys):
    stage = SAMPLES / "open_plane.usda"
    code = cli.main(["bake", str(stage), "--dry-run", "--json", "--texel-budget", "10"])
    out = capsys.readouterr()
    assert code == 2
    assert "--texel-budget must be at least 1024" in json.loads(out.out)["error"]
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), "--dry-run", "--texel-budget", "0"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2 and "--texel-budget must be at least" in proc.stderr
    argv = ["bake", str(stage), "--dry-run", "--texel-budget", "5000", "--resolution", "8"]
    assert cli.main(argv) == 2
    assert "--texel-budget sets the automatic texel density, which --resolution replaces" in (
        capsys.readouterr().err
    )


def test_an_unchanged_rebake_on_the_automatic_density_is_skipped(tmp_path, capsys):
    from tests.scenes import copy_sample

    stage = copy_sample(tmp_path, "open_plane.usda")
    argv = ["bake", str(stage), "--samples", "4", "--bounces", "0", "--json", "--quiet"]
    assert cli.main(argv) == 0
    first = json.loads(capsys.readouterr().out)
    top = density_ceiling(4.0)  # the 4 m plane: STAGE_MIN_TEXELS across
    side = int(np.ceil(top * 4.0 / 0.96 / RESOLUTION_MULTIPLE)) * RESOLUTION_MULTIPLE
    assert first["prims"][0]["status"] == "baked" and first["prims"][0]["resolution"] == [side] * 2
    from pxr import Usd

    from usdahd.usd import schema

    layer = Usd.Stage.Open(str(tmp_path / "open_plane.lightmaps.usda"))
    res = schema.read_results(layer.GetPrimAtPath("/World/Geometry/Plane"))
    assert res.settings["texel_density"] == top
    assert "texel_budget" not in res.settings  # only the density it gives is a setting
    assert res.settings["min_resolution"] == MIN_RESOLUTION
    assert res.settings["resolution_multiple"] == RESOLUTION_MULTIPLE
    assert cli.main(argv) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["prims"][0]["status"] == "skipped"
    # A different budget giving the same density re-bakes nothing; one giving another does.
    assert cli.main([*argv, "--texel-budget", "500000"]) == 0
    assert json.loads(capsys.readouterr().out)["prims"][0]["status"] == "skipped"
    assert cli.main([*argv, "--texel-budget", "4000"]) == 0
    third = json.loads(capsys.readouterr().out)
    assert third["texel_density"]["density"] < top
    assert third["prims"][0]["status"] == "baked" and third["texels_total"] <= 4000


# -- prims on one stage share one density (issue 37: the chess board under its pieces)


def _slab_and_props(path, slab=8.0, props=3):
    """A ``slab`` m ground quad (one-chart st: a lightmap layout) and ``props`` 20 cm boxes
    whose st is six strips side by side 1/500 apart (a texture layout the prop rule raises,
    tests/data/production/make_texture_uvs.py), as a usda file."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_texture_uvs", Path(__file__).parents[1] / "data/production/make_texture_uvs.py"
    )
    mk = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mk)
    h = slab / 2
    boxes = "".join(
        f'    def Mesh "Box{k}"\n    {{\n{mk._box(0.2, (0.5 * k, 0.1, 0.0), True)}\n    }}\n'
        for k in range(props)
    )
    path.write_text(
        f"""#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{{
    def DomeLight "Sky"
    {{
        float inputs:intensity = 1
    }}

    def Mesh "Slab"
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-{h}, 0, {h}), ({h}, 0, {h}), ({h}, 0, -{h}), (-{h}, 0, -{h})]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "vertex"
        )
        uniform token subdivisionScheme = "none"
    }}

{boxes}}}
"""
    )
    return path


def test_a_slab_under_raised_props_steps_up_to_their_density(tmp_path, capsys):
    stage = _slab_and_props(tmp_path / "slab.usda")
    report = _dry_run(capsys, stage, "-o", str(tmp_path / "o.usda"))
    td, res = report["texel_density"], _resolutions(report)
    # The 8 m stage is held at the 16/m ceiling; the prop rule raises each box 32 -> 128
    # (64/m), so the slab steps up to the first step at SHARED_DENSITY_SHARE x 64/m.
    assert td["density"] == DENSITY_AUTO_MAX and td["raised_prims"] == 3
    assert td["raised_median_density"] == pytest.approx(DENSITY_AUTO_MAX * 128 / 32, abs=0.1)
    want = td["shared_density"]
    assert want >= SHARED_DENSITY_SHARE * td["raised_median_density"] > want * DENSITY_LADDER
    assert want == 26.91  # 16 * 2^(3/4)
    assert res["/World/Slab"] == (216, 216)  # ceil(8 m x 26.91/m) on 4-texel blocks
    for k in range(3):
        assert res[f"/World/Box{k}"] == (128, 128)
    slab = next(p for p in report["prims"] if p["path"] == "/World/Slab")
    assert not slab["warnings"]
    assert any("prims on one stage share one density" in n for n in report["notes"])
    assert report["texels_total"] == 216**2 + 3 * 128**2


def test_a_slab_under_raised_props_subprocess(tmp_path):
    stage = _slab_and_props(tmp_path / "slab.usda")
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), "-o", str(tmp_path / "o.usda"),
         "--dry-run", "--json"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["texel_density"]["shared_density"] == 26.91
    assert _resolutions(report)["/World/Slab"] == (216, 216)
    assert any("texel density 26.91/m (not 16/m)" in n for n in report["notes"])


def test_the_shared_density_does_not_depend_on_the_prim_selection(tmp_path, capsys):
    stage = _slab_and_props(tmp_path / "slab.usda")
    full = _dry_run(capsys, stage, "-o", str(tmp_path / "o.usda"))
    one = _dry_run(capsys, stage, "-o", str(tmp_path / "o.usda"), "--prim", "/World/Slab")
    assert one["texel_density"] == full["texel_density"]
    assert [p["path"] for p in one["prims"]] == ["/World/Slab"]
    assert _resolutions(one)["/World/Slab"] == _resolutions(full)["/World/Slab"] == (216, 216)
    box = _dry_run(capsys, stage, "-o", str(tmp_path / "o.usda"), "--prim", "/World/Box1")
    assert box["texel_density"] == full["texel_density"]
    assert _resolutions(box)["/World/Box1"] == (128, 128)


def test_the_shared_density_stays_within_the_texel_budget(tmp_path, capsys):
    stage = _slab_and_props(tmp_path / "slab.usda")
    budget = 62000  # the 16/m plan (128^2 + 3 x 32^2) fits with room for the raises
    report = _dry_run(capsys, stage, "-o", str(tmp_path / "o.usda"), "--texel-budget", str(budget))
    td, res = report["texel_density"], _resolutions(report)
    boxes = sum(res[f"/World/Box{k}"][0] * res[f"/World/Box{k}"][1] for k in range(3))
    d = td.get("shared_density", td["density"])
    assert d > td["density"]  # it did step up
    assert report["texels_total"] == res["/World/Slab"][0] ** 2 + boxes <= budget
    nxt = float(f"{d / DENSITY_LADDER:.4g}")  # the next step would not fit
    assert boxes + planned_texels(nxt, [8.0]) > budget


def test_a_stage_with_no_raised_prim_keeps_its_density(tmp_path, capsys):
    stage = _slab_and_props(tmp_path / "slab.usda", props=0)
    report = _dry_run(capsys, stage, "-o", str(tmp_path / "o.usda"))
    assert "shared_density" not in report["texel_density"]
    assert _resolutions(report)["/World/Slab"] == (128, 128)


def test_shared_density_rule():
    d = 215.3
    # nothing raised, nothing left alone, or every map left alone at its minimum: unchanged
    assert shared_density(d, [], [1.3], 0, 1 << 20) == d
    assert shared_density(d, [800.0], [], 0, 1 << 20) == d
    assert shared_density(d, [800.0], [0.1], 0, 1 << 20) == d  # 21.5 texels: at the minimum 32
    # the chess set: a board of extent 1.3 m under 32 pieces raised to a median 813/m
    raised = [430.5] * 4 + [626.3] * 4 + [689.0] * 4 + [765.5] * 4 + [861.2] * 16
    got = shared_density(d, raised, [1.3], 0, 1 << 20)
    assert got == 362.0 and got >= SHARED_DENSITY_SHARE * np.median(raised) > got * DENSITY_LADDER
    # the texel budget stops the steps: 400^2 fits, the next (472^2) does not
    assert shared_density(d, [861.2], [1.3], 900_000, 900_000 + 400**2) == 304.4
    assert shared_density(d, [861.2], [1.3], 1 << 20, 1 << 20) == d  # no room at all
    # already dense enough: unchanged
    assert shared_density(d, [400.0], [1.3], 0, 1 << 20) == d
    # one very dense raised prop over a large stage with room in the budget: at most
    # SHARED_DENSITY_MAX_RATIO x the density (the step at or under it), not the budget's limit
    big = shared_density(16.0, [2000.0], [8.0], 0, 1 << 24)
    assert big == 32.0 == SHARED_DENSITY_MAX_RATIO * 16.0
    assert shared_density(16.0, [2000.0], [8.0], 0, 1 << 24, max_ratio=8.0) == 128.0


def test_instance_copies_of_a_prototype_with_a_resolution_leave_the_density_pool(tmp_path, capsys):
    """A PointInstancer's copies read their inputs from the prototype mesh: one that authors
    ahdLightmap:resolution keeps its copies off the automatic density (they were counted,
    lowering the density of the rest, before)."""
    from pxr import Usd

    from tests.instance_scene import POINTS, write_stage
    from usdahd.usd import plugin, schema

    plugin.register()
    path = write_stage(tmp_path / "inst.usda")
    stage = Usd.Stage.Open(str(path))
    box = stage.GetPrimAtPath("/Proto/Box")
    schema.apply(box)
    schema.write_inputs(box, resolution=16)
    schema.apply(stage.GetPrimAtPath("/World/Ground"))
    stage.GetRootLayer().Save()
    report = _dry_run(capsys, path, "-o", str(tmp_path / "o.usda"))
    copies = [p for p in report["prims"] if p["path"].startswith("/World/Pawns/instance_")]
    assert copies and len(POINTS) > 1
    assert all(p["resolution"] == [16, 16] for p in copies)
    assert report["texel_density"]["prims"] == 1  # the ground alone
    assert report["texel_density"]["density"] == DENSITY_AUTO_MAX  # 60 m ground at 16/m


#: Every sample's dry-run texel total at the defaults: the shared density leaves them as they
#: were (no prop rule raises a map there).
SAMPLE_TOTALS = {
    "cornell_box.usda": 138128,
    "emissive_only.usda": 179984,
    "exterior_sun_sky.usda": 39504,
    "floor_lamp.usda": 41472,
    "indirect_ceiling.usda": 126080,
    "normal_wall.usda": 36992,
    "open_plane.usda": 18496,
    "pillar_room.usda": 88528,
    "stretched_boxes.usda": 35664,
}


@pytest.mark.parametrize("name", sample_stages())
def test_the_samples_texel_totals_are_unchanged(name, capsys, tmp_path):
    report = _dry_run(capsys, SAMPLES / name, "-o", str(tmp_path / "o.usda"))
    assert report["texels_total"] == SAMPLE_TOTALS[name]
    assert "shared_density" not in report.get("texel_density", {})


def test_an_unchanged_rebake_on_the_shared_density_is_skipped(tmp_path, capsys):
    """The slab's record holds the shared density, and a re-bake (which plans the stage's
    density, then the shared one, again) skips every prim; --prim the slab alone too."""
    stage = _slab_and_props(tmp_path / "slab.usda", props=1)
    argv = ["bake", str(stage), "--samples", "4", "--bounces", "0", "--json", "--quiet"]
    assert cli.main(argv) == 0
    first = json.loads(capsys.readouterr().out)
    shared = first["texel_density"]["shared_density"]
    assert {p["status"] for p in first["prims"]} == {"baked"}
    from pxr import Usd

    from usdahd.usd import schema

    layer = Usd.Stage.Open(str(tmp_path / "slab.lightmaps.usda"))
    assert schema.read_results(layer.GetPrimAtPath("/World/Slab")).settings["texel_density"] == (
        shared
    )
    assert cli.main(argv) == 0
    again = json.loads(capsys.readouterr().out)
    assert {p["status"] for p in again["prims"]} == {"skipped"}, again["prims"]
    assert cli.main([*argv, "--prim", "/World/Slab"]) == 0
    one = json.loads(capsys.readouterr().out)
    assert [(p["path"], p["status"]) for p in one["prims"]] == [("/World/Slab", "skipped")]
