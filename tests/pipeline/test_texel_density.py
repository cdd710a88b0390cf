"""The automatic texel density (issue 39 item 3, docs/texels.md "Texel density and resolution"):
one density per stage from a texel budget spread by area, a minimum map per prim, sides on
4-texel blocks; explicit --texel-density / --resolution / ahdLightmap inputs win."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.scenes import SAMPLES, sample_stages
from usdahd import cli
from usdahd.pipeline.plan import (
    STAGE_MIN_TEXELS,
    _pad_to_multiple,
    auto_texel_density,
    density_ceiling,
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
