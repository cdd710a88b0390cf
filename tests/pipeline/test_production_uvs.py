"""Texture UV sets as lightmap UVs on the automatic density (issue 37, production assets such as
the OpenChessSet): a UV set packed edge to edge with no gutter is unwrapped (or, on instance
copies, given a larger map), and unwrapped maps whose charts are a texel wide are raised until
they are CHART_MIN_TEXELS across, within the texel budget (docs/texels.md, "Texture UVs as
lightmap UVs"). The stage is tests/data/production/texture_uvs.usda (make_texture_uvs.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.scenes import SAMPLES
from usdahd import cli
from usdahd.pipeline.plan import (
    CHART_MIN_TEXELS,
    PROP_MAX_RESOLUTION,
    TOUCHING_LIMIT,
    TOUCHING_TARGET,
    narrow_chart_width,
    prop_cap,
)

DATA = Path(__file__).parents[1] / "data" / "production"
STAGE = DATA / "texture_uvs.usda"


def _dry_run(capsys, stage, *args):
    code = cli.main(["bake", str(stage), "--dry-run", "--json", "--quiet", *args])
    out = capsys.readouterr()
    assert code == 0, out.err + out.out
    return json.loads(out.out)


def _prims(report):
    return {p["path"]: p for p in report["prims"]}


def _check_plan(report):
    prims = _prims(report)
    ground, box = prims["/World/Ground"], prims["/World/StripBox"]
    # A one-chart layout is a lightmap layout: kept as authored (the stage is 8 m across, so
    # the floor by stage size leaves the density at 16/m); the props' maps are raised, so the
    # ground steps up to the stage's shared density (docs/texels.md): 8 m at 22.63/m.
    td = report["texel_density"]
    assert td["density"] == 16.0 and td["stage_extent"] == 8.0
    assert td["shared_density"] == 22.63
    assert ground["resolution"] == [184, 184]
    assert not any("gutter" in n for n in ground.get("notes", []) + ground["warnings"])
    # Six strips side by side, 1/500 apart: raised until few texels touch; st is kept.
    note = next(n for n in box.get("notes", []) if "no lightmap gutter" in n)
    assert note.startswith("UV set 'st' packs its charts with no lightmap gutter (at 32x32, ")
    assert "its map is raised to 128x128 (8% of its texels next to another chart's" in note
    assert box["resolution"] == [128, 128]
    share = float(note.split("at 32x32, ")[1].split("%")[0]) / 100
    assert share > TOUCHING_LIMIT > TOUCHING_TARGET
    assert not any("no lightmap gutter" in w for w in box["warnings"])  # a note, not a warning
    # 40 strips a card each: 3 texels wide even at 128x128, so unwrapped (a note says why).
    fence = prims["/World/Fence"]
    note = next(n for n in fence.get("notes", []) if "no lightmap gutter" in n)
    assert note.startswith("UV set 'st' packs its charts with no lightmap gutter (at 32x32, ")
    assert f"also at {PROP_MAX_RESOLUTION}x{PROP_MAX_RESOLUTION} (" in note
    assert "unwrapped with xatlas into a new primvar 'st_lightmap'" in note
    assert not any("gutter" in w for w in fence["warnings"])
    # Under 25 % touching, but its narrowest charts are under 4 texels (all border): raised.
    ribbons = prims["/World/Ribbons"]
    note = next(n for n in ribbons.get("notes", []) if "no lightmap gutter" in n)
    share = float(note.split("at 32x32, ")[1].split("%")[0]) / 100
    assert TOUCHING_TARGET < share < TOUCHING_LIMIT, note
    width = float(note.split("its narrowest charts ")[1].split(" texels")[0])
    assert width < CHART_MIN_TEXELS, note
    assert ribbons["resolution"] == [64, 64] and "its map is raised to 64x64" in note
    # Instance copies: raised like the box (they could not be unwrapped).
    for path in ("/World/Pieces/A/Geom", "/World/Pieces/B/Geom"):
        copy = prims[path]
        assert copy["resolution"] == [128, 128], copy
        assert any("its map is raised to 128x128" in n for n in copy.get("notes", [])), copy
    # 27 separate 1 cm cubes: at the 32x32 minimum their charts are a texel wide.
    sparks = prims["/World/Sparks"]
    widened = next(n for n in sparks.get("notes", []) if "narrowest charts" in n)
    assert sparks["resolution"][0] > 64, sparks
    got = float(widened.split("instead (")[1].split(" texels")[0])
    assert got >= CHART_MIN_TEXELS - 1, widened  # xatlas's own padding rounds
    assert report["texels_total"] <= report["texel_density"]["budget"]


def test_texture_uv_layouts_are_unwrapped_or_raised(capsys, tmp_path):
    report = _dry_run(capsys, STAGE, "-o", str(tmp_path / "out.lightmaps.usda"))
    _check_plan(report)


def test_texture_uv_layouts_subprocess(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(STAGE), "-o", str(tmp_path / "o.usda"),
         "--dry-run", "--json", "--quiet"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    _check_plan(json.loads(proc.stdout))


def test_explicit_settings_keep_the_authored_texture_uvs(capsys, tmp_path):
    """The rule is the automatic density's: --resolution keeps the authored UV set as it is."""
    report = _dry_run(
        capsys,
        STAGE,
        "-o",
        str(tmp_path / "o.usda"),
        "--resolution",
        "32",
        *sum((["--prim", f"/World/{n}"] for n in ("StripBox", "Fence", "Ribbons")), []),
    )
    for path in ("/World/StripBox", "/World/Fence", "/World/Ribbons"):
        box = _prims(report)[path]
        assert box["resolution"] == [32, 32]
        assert not any("gutter" in n for n in box.get("notes", []) + box["warnings"])


@pytest.mark.parametrize(
    "name,total", [("cornell_box.usda", 138128), ("exterior_sun_sky.usda", 39504),
                   ("stretched_boxes.usda", 35664)],
)  # fmt: skip
def test_the_samples_lightmap_layouts_are_kept(name, total, capsys, tmp_path):
    """The samples' UV sets (validated against Cycles) have gutters of about a texel at 16/m
    (at most 16 % of the texels next to another chart's, on the Cornell box's short box) and
    more at the density floor of their 2-6 m stages (64, 22.63 and 32/m): no raise and no
    unwrap, each map exactly its density's (docs/texels.md's table)."""
    report = _dry_run(capsys, SAMPLES / name, "-o", str(tmp_path / "o.usda"))
    assert report["texels_total"] == total
    for p in report["prims"]:
        assert not any("gutter" in n or "narrowest" in n for n in p.get("notes", [])), p


def test_narrow_chart_width_is_a_strips_width():
    """2 x area / perimeter of a w x L strip is wL / (w + L); of a disc its radius."""

    def rect(x0, y0, w, h):
        a, b, c, d = (x0, y0), (x0 + w, y0), (x0 + w, y0 + h), (x0, y0 + h)
        return [[a, b, c], [a, c, d]]

    strip = np.asarray(rect(0.0, 0.0, 0.05, 0.8), np.float64)
    assert narrow_chart_width(strip) == pytest.approx(0.05 * 0.8 / 0.85)
    # a big square and nine small ones of 12 % of the area in all: the narrow 10 % are small
    tris = rect(0.0, 0.0, 0.6, 0.6)
    side = np.sqrt(0.05 / 9)
    for k in range(9):
        tris += rect(0.65 + (k % 3) * 0.1, 0.65 + (k // 3) * 0.1, side, side)
    width = narrow_chart_width(np.asarray(tris, np.float64))
    assert width == pytest.approx(side / 2, rel=1e-6)
    t = np.linspace(0, 2 * np.pi, 257)[:-1]
    ring = np.stack([np.cos(t), np.sin(t)], 1) * 0.3 + 0.5
    disc = np.asarray([[(0.5, 0.5), ring[i], ring[(i + 1) % 256]] for i in range(256)])
    assert narrow_chart_width(disc) == pytest.approx(0.3, rel=1e-3)


def test_prop_cap_keeps_every_raised_map_within_the_budget_left():
    assert prop_cap((1 << 20) - 50_176, 49) == PROP_MAX_RESOLUTION  # the chess set
    assert prop_cap(-3000, 79) == 0  # a plan already over the budget: no raise
    assert prop_cap(1 << 20, 1000) == 32  # sqrt(1048.576) = 32.4 -> 32
    for budget, prims in ((1 << 20, 1000), (300_000, 77), (4096, 3)):
        side = prop_cap(budget, prims)
        assert side % 4 == 0 and prims * side * side <= budget


def test_one_prim_unwrapped_by_an_authored_uv_primvar(capsys, tmp_path):
    """docs/texels.md, "Unwrapping one prim whose texture UVs the plan keeps": a layer over the
    stage applies AhdLightmapAPI to the meshes to bake (the API selects: the others are only
    traced) and names a primvar the asset lacks on one of them, which is unwrapped into it while
    the other keeps its authored ``st``."""
    layer = tmp_path / "one_unwrapped.usda"
    layer.write_text(
        f"""#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
    subLayers = [@{STAGE.as_posix()}@]
)

over "World"
{{
    over "Ground" (prepend apiSchemas = ["AhdLightmapAPI"])
    {{
    }}
    over "Ribbons" (prepend apiSchemas = ["AhdLightmapAPI"])
    {{
        string ahdLightmap:uvPrimvar = "st_lightmap"
    }}
}}
"""
    )
    report = _dry_run(capsys, layer, "-o", str(tmp_path / "o.lightmaps.usda"))
    prims = _prims(report)
    assert set(prims) == {"/World/Ground", "/World/Ribbons"}, sorted(prims)
    ground, ribbons = prims["/World/Ground"], prims["/World/Ribbons"]
    assert ground["resolution"] == [128, 128]
    assert not any("xatlas" in m for m in ground["warnings"] + ground.get("notes", []))
    assert any(
        "no UV set 'st_lightmap': unwrapped with xatlas" in w for w in ribbons["warnings"]
    ), ribbons
    # Without the layer the same mesh keeps its st, raised to 64x64 (the stage's plan, above).
    alone = _prims(_dry_run(capsys, STAGE, "-o", str(tmp_path / "s.lightmaps.usda")))
    assert alone["/World/Ribbons"]["resolution"] == [64, 64]
    assert not any("xatlas" in m for m in alone["/World/Ribbons"].get("notes", []))
