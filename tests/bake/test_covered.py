"""Covered texels (issue 37, the chess pieces' feet): :func:`usdahd.bake.texels.covered`.

A 4 x 4 m ground quad at z = 0 with a 32 x 32 lightmap (a texel is 0.125 m; the probe length
``D`` is half a texel, 0.0625 m). A closed box (bottom face included, faces outward) of 1 m
floats ``GAP`` = 1 cm over it, as the OpenChessSet's kings float 0.5 mm over the board (texels
4 mm): ground points under the box see only its bottom face, a *front* face, so the back-face
rule of :func:`usdahd.bake.integrate.inside_geometry` does not flag them, and they baked black.
The analytic share of cosine-weighted directions that hit a flat cover at height h within D
is 1 - (h / D)^2: 0.974 at 1 cm, 0.77 under a table top at 3 cm (stays estimated).
"""

import json

import numpy as np
import pytest
from pxr import UsdLux

from tests.scenes import define_box, define_mesh, define_quad, new_stage
from usdahd.bake import texels as T
from usdahd.bake.integrate import inside_geometry
from usdahd.bake.trace import Tracer
from usdahd.usd.reader import load_scene

RES = 32
TEXEL = 4.0 / RES
GAP = 0.01
BOX = (-0.53, 0.47)  # x and y extent of the box's footprint, off the texel grid


def _ground(st):
    pts = [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)]
    uv = [((x + 2) / 4, (y + 2) / 4) for x, y, _ in pts]
    return define_mesh(st, "/ground", pts, [[0, 1, 2, 3]], uv)


def _stage(box: bool = True, extra=None):
    st = new_stage()
    _ground(st)
    if box:
        lo, hi = BOX
        define_box(st, "/box", (lo, lo, GAP), (hi, hi, GAP + 1.0))
    if extra is not None:
        extra(st)
    UsdLux.DomeLight.Define(st, "/sky")
    return st


def _flagged(st):
    scene = load_scene(st)
    tracer = Tracer(scene, threads=1)
    mi = next(i for i, m in enumerate(scene.meshes) if m.path == "/ground")
    tx = T.rasterize(scene.meshes[mi], (RES, RES))
    offsets = tracer.texel_offsets(tx, mi)
    inside = inside_geometry(tracer, tx, offsets, np.zeros(len(tx)), mesh=mi)
    return tx, inside


def test_texel_sizes_are_the_world_size_of_a_texel():
    scene = load_scene(_stage(box=False))
    tx = T.rasterize(scene.meshes[0], (RES, RES))
    np.testing.assert_allclose(T.texel_sizes(tx, scene.meshes[0]), TEXEL, rtol=1e-9)


def test_ground_under_a_closed_box_is_covered_and_beside_it_is_not():
    tx, inside = _flagged(_stage())
    p = tx.position.astype(np.float64)
    lo, hi = BOX
    depth = np.minimum(
        np.minimum(p[:, 0] - lo, hi - p[:, 0]), np.minimum(p[:, 1] - lo, hi - p[:, 1])
    )
    under = depth > 0
    # every point under the box deeper than 2 gaps is covered (escaping rays need tan > 2)
    assert inside[depth > 2 * GAP].all()
    assert (depth > 2 * GAP).sum() >= 49
    # nothing outside the footprint: the contact row beside the box sees half its sky
    assert not inside[~under].any()
    # without the box nothing is covered
    _, none = _flagged(_stage(box=False))
    assert not none.any()


@pytest.mark.parametrize(
    ("height", "flagged"),
    [(0.03, False), (0.01, True)],
)
def test_a_flat_cover_counts_only_when_low_against_the_texel(height, flagged):
    """A one-sided table top facing up (the ground sees its back) over x, y in [-1, 1]: at 3 cm
    (h / D = 0.48: the share 0.77 < 0.9) its floor stays estimated, at 1 cm (0.974) covered."""

    def table(st):
        define_quad(
            st, "/top", [(-1, -1, height), (1, -1, height), (1, 1, height), (-1, 1, height)]
        )

    tx, inside = _flagged(_stage(box=False, extra=table))
    p = tx.position
    deep = (np.abs(p[:, 0]) < 0.7) & (np.abs(p[:, 1]) < 0.7)
    assert inside[deep].all() == flagged
    assert inside[deep].any() == flagged


def test_a_crevice_open_above_stays_estimated():
    """Two boxes standing on the ground 2 cm apart (a crevice a sixth of a texel wide, 1 m
    deep): the ground between them sees walls within D in 80 % of its directions, but nothing
    lies over it, so it is estimated (dark), not filled."""

    def walls(st):
        define_box(st, "/a", (-1.0, -1.0, 0.0), (-0.01, 1.0, 1.0))
        define_box(st, "/b", (0.01, -1.0, 0.0), (1.0, 1.0, 1.0))

    pos = np.c_[np.zeros(8), np.linspace(-0.8, 0.8, 8), np.zeros(8)]
    assert not _covered_points(_stage(box=False, extra=walls), pos).any()

    def lidded(st):  # the same crevice under a lid 1 cm over the ground: covered
        walls(st)
        define_quad(
            st, "/lid", [(-0.01, -1, 0.01), (0.01, -1, 0.01), (0.01, 1, 0.01), (-0.01, 1, 0.01)]
        )

    assert _covered_points(_stage(box=False, extra=lidded), pos).all()


def _covered_points(st, pos):
    scene = load_scene(st)
    tracer = Tracer(scene, threads=1)
    n = len(pos)
    g = np.tile([0.0, 0.0, 1.0], (n, 1))
    offsets = tracer.offset_scale(np.asarray(pos, np.float64))
    return T.covered(pos, g, offsets, np.full(n, TEXEL), tracer)


def test_bake_fills_the_ground_under_the_box(tmp_path, capsys):
    """End to end: ``usdahd bake`` flags the covered ground texels invalid and fills them from
    their lit neighbours; before, they were baked black (I_z 0 under a front face)."""
    from usdahd import cli
    from usdahd.preview.meshes import baked_meshes
    from usdahd.usd import schema

    st = _stage()
    sun = UsdLux.DistantLight.Define(st, "/sun")
    sun.CreateIntensityAttr(2.0)
    path = tmp_path / "box.usda"
    st.GetRootLayer().Export(str(path))
    out = tmp_path / "out.lightmaps.usda"
    argv = ["bake", str(path), "-o", str(out), "--json", "--resolution", str(RES)]
    assert cli.main([*argv, "--samples", "32", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    prims = {p["path"]: p for p in report["prims"]}
    assert prims["/ground"]["invalid_texels"] >= 49
    # the box's bottom face lies 1 cm over the ground: its inner texels are covered too, but a
    # covered texel is not "inside geometry?" (no such warning)
    assert prims["/box"]["invalid_texels"] > 0
    assert not any("inside geometry" in w for p in prims.values() for w in p["warnings"])
    _, meshes, _ = baked_meshes(str(out))
    mesh, res, *_ = next(m for m in meshes if m[0].path == "/ground")
    iz = np.asarray(schema.read_record_pixels(res, "iz"), np.float64)[..., :3].mean(axis=-1)
    tx = T.rasterize(mesh, (RES, RES))
    p = tx.position
    lo, hi = BOX
    deep = (p[:, 0] > lo + 0.1) & (p[:, 0] < hi - 0.1) & (p[:, 1] > lo + 0.1) & (p[:, 1] < hi - 0.1)
    values = iz[tx.xy[deep, 1], tx.xy[deep, 0]]
    assert values.min() > 0.05  # filled from neighbours (the old bake: 0 exactly)


def test_a_wholly_covered_chart_keeps_its_estimate_without_a_warning(tmp_path, capsys):
    """A box 2 mm over the ground at 64 x 64: every texel of its bottom face is covered by the
    ground, so its chart has no valid texel to fill from. The texels keep their estimate (no
    view sees them); the warning for unfilled texels inside geometry ("flipped normals?") is
    not given for them (it was, before covered texels were told apart)."""
    from usdahd import cli

    st = new_stage()
    _ground(st)
    lo, hi = BOX
    define_box(st, "/box", (lo, lo, 0.002), (hi, hi, 1.002))
    UsdLux.DomeLight.Define(st, "/sky")
    path = tmp_path / "box.usda"
    st.GetRootLayer().Export(str(path))
    out = tmp_path / "out.lightmaps.usda"
    argv = ["bake", str(path), "-o", str(out), "--json", "--resolution", "64"]
    assert cli.main([*argv, "--samples", "16", "--quiet"]) == 0
    prims = {p["path"]: p for p in json.loads(capsys.readouterr().out)["prims"]}
    assert prims["/box"]["invalid_texels"] > 0
    assert not any("inside geometry" in w for w in prims["/box"]["warnings"])
