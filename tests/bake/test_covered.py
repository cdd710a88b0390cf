"""Covered texels (issue 37, the chess pieces' feet): :func:`usdahd.bake.contacts.covered`.

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
from usdahd.bake import contacts as C
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
    np.testing.assert_allclose(C.texel_sizes(tx, scene.meshes[0]), TEXEL, rtol=1e-9)


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


def _contacts(st):
    """The ground's texels after ``push_off_contacts`` (which moves rim texels too)."""
    scene = load_scene(st)
    tracer = Tracer(scene, threads=1)
    mi = next(i for i, m in enumerate(scene.meshes) if m.path == "/ground")
    tx = T.rasterize(scene.meshes[mi], (RES, RES))
    moved, invalid = C.push_off_contacts(tx, scene.meshes[mi], tracer)
    return tx, moved, invalid


def _square_depth(p, lo, hi):
    """Signed distance of points p (n, 3) inside the box's xy footprint [lo, hi]^2 (< 0 out)."""
    return np.minimum(
        np.minimum(p[:, 0] - lo, hi - p[:, 0]), np.minimum(p[:, 1] - lo, hi - p[:, 1])
    )


def test_rim_texels_move_to_the_uncovered_part_of_their_footprint():
    """The ground texels whose centre lies under the floating box but whose square reaches
    beyond its outline (a row on the box's +x and +y sides: the outline lies off the grid)
    get a point outside the box's footprint, still in their own square; texels wholly under
    the box or wholly outside keep their point. Before the rim rule none moved (the probes in the
    ground's plane pass under the box, 1 cm up)."""
    tx, moved, invalid = _contacts(_stage())
    lo, hi = BOX
    c = tx.position.astype(np.float64)  # texel centres (the ground is one quad)
    half = TEXEL / 2
    under = _square_depth(c, lo, hi) > 0
    whole = _square_depth(c, lo + half, hi - half) > 0  # the square inside the outline
    rim = under & ~whole
    new = moved.position.astype(np.float64)
    shifted = np.any(new != c, axis=1)
    assert not invalid.any()
    # centres under the box: x, y in {-0.4375, ..., 0.4375}; the squares at 0.4375 reach past
    # the outline at 0.47, those at -0.4375 end inside -0.53: 8 + 8 - 1 rim texels
    assert rim.sum() == 15
    assert np.array_equal(shifted, rim)
    assert moved.stats["rim_texels"] == rim.sum()
    assert (_square_depth(new[rim], lo, hi) < 0).all()  # out from under the box
    assert (np.abs(new[rim, :2] - c[rim, :2]) <= half).all()  # in the texel's own square
    np.testing.assert_array_equal(new[:, 2], 0.0)  # on the ground


def test_a_cover_higher_than_the_rim_height_moves_nothing():
    """A one-sided table top at 3 cm (0.24 texel, over ``RIM_HEIGHT`` 0.16): its edge's
    texels stay where they are (the ground under it is seen from the side), as does a stage
    with nothing over the ground."""

    def table(st):
        define_quad(st, "/top", [(-1, -1, 0.03), (1, -1, 0.03), (1, 1, 0.03), (-1, 1, 0.03)])

    for st in (_stage(box=False, extra=table), _stage(box=False)):
        tx, moved, _ = _contacts(st)
        assert moved is tx


def _covered_points(st, pos):
    scene = load_scene(st)
    tracer = Tracer(scene, threads=1)
    n = len(pos)
    g = np.tile([0.0, 0.0, 1.0], (n, 1))
    offsets = tracer.offset_scale(np.asarray(pos, np.float64))
    return C.covered(pos, g, offsets, np.full(n, TEXEL), tracer)


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


def test_bake_samples_rim_texels_in_the_light(tmp_path, capsys):
    """End to end: the box's +x edge at 0.4425 puts the rim column's centres (x = 0.4375) 5 mm
    (half a gap) inside the outline, where they see out sideways (not covered) and were
    estimated under the box, in its shadow: I_z 0.09 against 1.15 for their outside
    neighbours (x = 0.5625) in the sun straight down (and the texels under the box were
    filled from them). Now they are sampled outside the outline (x = 0.46875, 2.6 cm out),
    sunlit like the neighbours; the sky's part differs by the box's view factor, 1/2 (1 - s /
    sqrt(s^2 + 1)) at s = 2.6 and 12 cm: 0.49 and 0.44 of the dome's 0.3, 1.3 % of I_z."""
    from usdahd import cli
    from usdahd.preview.meshes import baked_meshes
    from usdahd.usd import schema

    st = new_stage()
    _ground(st)
    define_box(st, "/box", (-0.53, -0.53, GAP), (0.4425, 0.47, GAP + 1.0))
    UsdLux.DomeLight.Define(st, "/sky").CreateIntensityAttr(0.3)
    sun = UsdLux.DistantLight.Define(st, "/sun")
    sun.CreateIntensityAttr(3.0)
    sun.CreateNormalizeAttr(True)
    path = tmp_path / "box.usda"
    st.GetRootLayer().Export(str(path))
    out = tmp_path / "out.lightmaps.usda"
    argv = ["bake", str(path), "-o", str(out), "--json", "--resolution", str(RES)]
    assert cli.main([*argv, "--samples", "32", "--quiet", "--no-denoise"]) == 0
    _, meshes, _ = baked_meshes(str(out))
    mesh, res, *_ = next(m for m in meshes if m[0].path == "/ground")
    iz = np.asarray(schema.read_record_pixels(res, "iz"), np.float64)[..., :3].mean(axis=-1)
    tx = T.rasterize(mesh, (RES, RES))
    p = tx.position
    mid = np.abs(p[:, 1]) < 0.3
    rim = mid & (np.abs(p[:, 0] - 0.4375) < 1e-6)
    out_ = mid & (np.abs(p[:, 0] - 0.5625) < 1e-6)
    rim_iz = iz[tx.xy[rim, 1], tx.xy[rim, 0]]
    out_iz = iz[tx.xy[out_, 1], tx.xy[out_, 0]]
    assert len(rim_iz) == len(out_iz) == 4
    np.testing.assert_allclose(rim_iz, out_iz, rtol=0.1)  # 10 %: 32 samples, the view factor


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


def test_a_sliver_face_under_a_cover_moves_to_its_open_edge():
    """The chess board's playing-field plate meets the frame along a vertical face 1 mm tall
    that the asset's UVs map to a sliver a sixth of a texel high; its lower part is buried
    behind the frame's inner wall, 15 um in front of it, and the texel centres lie there
    (covered, dark: the preview read them along the field's front edge at 0.5 of the
    reference). Here: a wall at y = 0 facing -y, 3 cm tall (z in [-2, 1] cm), in 64 strips,
    mapped to v in [0.5106, 0.5256] of a 32 x 32 map (0.48 texel of row 15, whose centre v =
    0.5156 lies at z = -1 cm); a closed box in front of it up to z = 0 with its face 0.2 mm
    from the wall. None of the texel's 4 x 4 grid points is on the open part (z > 0: v >
    0.5223), so the grid points are taken to their closest points on the texel's triangle;
    the points move above the box, on the wall, in their own texel column."""
    n = 64
    xs = np.linspace(-1.0, 1.0, n + 1)
    v0, v1 = 0.510625, 0.525625
    pts = [(x, 0.0, z) for z in (-0.02, 0.01) for x in xs]
    uv = [((x + 1) / 2, v) for v in (v0, v1) for x in xs]
    faces = [(i, i + 1, n + 2 + i, n + 1 + i) for i in range(n)]  # facing -y

    def scene(st):
        define_mesh(st, "/wall", pts, faces, uv, uv_interpolation="vertex")
        define_box(st, "/frame", (-2.0, -1.0, -1.0), (2.0, -0.0002, 0.0))

    st = new_stage()
    scene(st)
    UsdLux.DomeLight.Define(st, "/sky")
    sc = load_scene(st)
    tracer = Tracer(sc, threads=1)
    mi = next(i for i, m in enumerate(sc.meshes) if m.path == "/wall")
    mesh = sc.meshes[mi]
    tx = T.rasterize(mesh, (RES, RES))
    row = (tx.xy[:, 1] == 15) & (tx.xy[:, 0] > 0) & (tx.xy[:, 0] < RES - 1)
    assert row.sum() == RES - 2
    c = tx.position.astype(np.float64)
    assert (c[row, 2] < 0).all()  # the centres lie behind the box
    moved, invalid = C.push_off_contacts(tx, mesh, tracer)
    new = moved.position.astype(np.float64)
    assert not invalid[row].any()
    assert (new[row, 2] > 0).all()  # above the box: open to the sky
    np.testing.assert_allclose(new[row, 1], 0.0, atol=1e-6)  # on the wall
    col = tx.xy[row, 0]
    assert (np.abs((new[row, 0] + 1) / 2 * RES - (col + 0.5)) <= 0.5).all()  # own column
