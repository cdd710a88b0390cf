"""Sample points on contacts (issue 17 item 5): :func:`usdahd.bake.contacts.push_off_contacts`.

Two analytic stages (Z up, a 4 x 4 m ground quad at z = 0 with a 32 x 32 lightmap, so a texel is
0.125 m and its footprint reaches 0.0625 m from the centre):

- a box with vertical walls (no bottom face) on the ground, its footprint off the texel grid:
  the rule must move exactly the ground texels whose centre lies inside the footprint and whose
  footprint square crosses a wall, to a point outside the box inside the texel's square;
- an inverted frustum (sides overhanging outward, normal z = -0.243) standing on the ground,
  under a DistantLight straight down and a uniform DomeLight of radiance 1, every surface black
  (albedo 0, so no interreflection). A side face sees the sky only above the horizon: its
  ``I_z`` is at most ``(1 + n_z) / 2`` (the cosine-weighted share of its hemisphere above the
  ground plane; the ground and the frustum only take away from it; the sun is behind it). The
  bottom row of a side lies on the ground, so its ray origins were ``offset_eps`` *below* the
  ground, where they saw the dome under it: ``(1 - n_z) / 2`` = 0.62 (the bright line).
  The check is on the mean over the bottom-row texels, with the plain Monte Carlo estimator
  (unbiased) and the tolerance :func:`stats.assert_mean` uses: 5 standard errors of the
  estimator, measured from the texels' own spread.
"""

import numpy as np
import pytest
from pxr import Gf, UsdGeom, UsdLux, UsdShade

from tests.scenes import define_mesh, new_stage, preview_material
from tests.stats import SIGMAS, standard_error
from usdahd.bake.contacts import push_off_contacts
from usdahd.bake.integrate import bake_texels
from usdahd.bake.texels import half_texel_vectors, rasterize
from usdahd.bake.trace import Tracer
from usdahd.numerics import raster, sh
from usdahd.usd.reader import load_scene

RES = 32
HALF = 2.0 / RES  # half a ground texel in metres (4 m / 32 / 2)
#: Upper bound of the dome a frustum side sees under the horizon past the skirt's edge (200 m
#: away, seen from at most 0.8 m up: a band 0.0040 rad wide, cosine-weighted share < 0.004/pi).
HORIZON = 2e-3
BOX = (-0.53, 0.61, -0.47, 0.58)  # x0, x1, y0, y1: edges off the 0.125 m texel grid


def _ground(st, material=None):
    pts = [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)]
    uv = [((x + 2) / 4, (y + 2) / 4) for x, y, _ in pts]
    return define_mesh(st, "/ground", pts, [[0, 1, 2, 3]], uv, material)


def _solid(st, path, bottom, top, z1, material=None):
    """Sides and top (no bottom face) of a solid between the rectangles ``bottom`` at z = 0 and
    ``top`` at z1 (x0, x1, y0, y1), normals outward; each face gets its own UV cell."""
    bx0, bx1, by0, by1 = bottom
    tx0, tx1, ty0, ty1 = top
    pts = [(bx0, by0, 0), (bx1, by0, 0), (bx1, by1, 0), (bx0, by1, 0)]
    pts += [(tx0, ty0, z1), (tx1, ty0, z1), (tx1, ty1, z1), (tx0, ty1, z1)]
    faces = [[0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7], [4, 5, 6, 7]]
    cell = [(0.05, 0.05), (0.95 / 3 + 0.05, 0.05), (2 * 0.95 / 3 + 0.05, 0.05), (0.05, 0.5)]
    cell.append((0.95 / 3 + 0.05, 0.5))
    s = 0.95 / 3 - 0.05
    uv = []
    for (u0, v0), _f in zip(cell, faces, strict=True):
        uv += [(u0, v0), (u0 + s, v0), (u0 + s, v0 + s), (u0, v0 + s)]
    return define_mesh(st, path, pts, faces, uv, material)


def _tracer(st):
    scene = load_scene(st)
    return scene, Tracer(scene, threads=1)


def _box_stage():
    st = new_stage()
    _ground(st)
    _solid(st, "/box", BOX, BOX, 1.0)
    UsdLux.DomeLight.Define(st, "/sky")
    return st


def _frustum_stage():
    st = new_stage()
    black = preview_material(st, "/black", (0, 0, 0), emission=None)
    _ground(st, black)
    # a black skirt out to 200 m: the frustum's sides see no dome below the horizon past the
    # ground's edge (what is left is within 0.23 degrees of the horizon: < HORIZON of I_z)
    far, g = 200.0, 2.0
    pts = [(-far, -far, 0), (far, -far, 0), (far, far, 0), (-far, far, 0)]
    pts += [(-g, -g, 0), (g, -g, 0), (g, g, 0), (-g, g, 0)]
    skirt = UsdGeom.Mesh.Define(st, "/skirt")
    skirt.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    skirt.CreateFaceVertexCountsAttr([4, 4, 4, 4])
    skirt.CreateFaceVertexIndicesAttr([0, 1, 5, 4, 1, 2, 6, 5, 2, 3, 7, 6, 3, 0, 4, 7])
    UsdShade.MaterialBindingAPI.Apply(skirt.GetPrim()).Bind(black)
    _solid(st, "/frustum", (-0.4, 0.4, -0.4, 0.4), (-0.6, 0.6, -0.6, 0.6), 0.8, black)
    sun = UsdLux.DistantLight.Define(st, "/sun")  # shines along -Z: straight down
    sun.CreateAngleAttr(0.0)
    sun.CreateIntensityAttr(float(np.pi))  # illuminance pi: I_z = 1 on the open ground
    sun.CreateNormalizeAttr(True)
    UsdLux.DomeLight.Define(st, "/sky")  # radiance 1
    return st


def _mesh_of(scene, path):
    return next(m for m in scene.meshes if m.path == path)


def test_push_fires_exactly_on_texels_whose_footprint_crosses_a_wall():
    scene, tracer = _tracer(_box_stage())
    ground = _mesh_of(scene, "/ground")
    texels = rasterize(ground, (RES, RES))
    np.testing.assert_allclose(
        np.abs(half_texel_vectors(ground, (RES, RES))).max(axis=2), HALF, rtol=1e-6
    )
    pushed, invalid = push_off_contacts(texels, ground, tracer)
    p0 = texels.position.astype(np.float64)
    x0, x1, y0, y1 = BOX
    inside = (p0[:, 0] > x0) & (p0[:, 0] < x1) & (p0[:, 1] > y0) & (p0[:, 1] < y1)
    square_in = (
        (p0[:, 0] - HALF > x0)
        & (p0[:, 0] + HALF < x1)
        & (p0[:, 1] - HALF > y0)
        & (p0[:, 1] + HALF < y1)
    )
    expected = inside & ~square_in
    moved = np.any(pushed.position != texels.position, axis=1)
    # 9 x 9 centres inside; the squares of the right column and the top and bottom rows cross
    # a wall (the left wall is 0.0925 m from the nearest centres, beyond half a texel)
    assert expected.sum() == 9 + 9 + 9 - 2
    np.testing.assert_array_equal(moved, expected)
    assert not invalid.any()
    assert pushed.stats["contact_texels"] == int(expected.sum())
    q = pushed.position[moved].astype(np.float64)
    out = (q[:, 0] < x0) | (q[:, 0] > x1) | (q[:, 1] < y0) | (q[:, 1] > y1)
    assert out.all()  # in front of the wall it crossed
    np.testing.assert_array_equal(q[:, 2], 0.0)  # still on the ground's plane
    assert (np.abs(q[:, :2] - p0[moved, :2]) <= HALF + 1e-6).all()  # inside its own footprint
    # frame and normal are the rasterised ones
    np.testing.assert_array_equal(pushed.frame, texels.frame)


def test_push_leaves_texels_outside_a_single_sided_shell_alone():
    """The same box with its faces wound inward (a room modelled from the inside, like the
    shared classroom's walls): from the ground around it the probes hit back faces too, but
    those points are outside, in front of nothing, and the points inside see front faces only.
    Nothing may move (before the rule asked which side is inside, the outside texels whose
    footprint crosses a wall were moved into the room: on the classroom 4.2 m, black where
    Cycles has them sunlit)."""
    st = new_stage()
    _ground(st)
    room = _solid(st, "/room", BOX, BOX, 1.0)
    room.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)  # normals inward
    UsdLux.DomeLight.Define(st, "/sky")
    scene, tracer = _tracer(st)
    ground = _mesh_of(scene, "/ground")
    texels = rasterize(ground, (RES, RES))
    # the probes do see back faces from outside: the situation the rule must tell apart
    p0 = texels.position.astype(np.float64)
    x0, x1, y0, y1 = BOX
    outside = (p0[:, 0] < x0) | (p0[:, 0] > x1) | (p0[:, 1] < y0) | (p0[:, 1] > y1)
    near = outside & (p0[:, 0] > x0 - HALF) & (p0[:, 0] < x1 + HALF)
    near &= (p0[:, 1] > y0 - HALF) & (p0[:, 1] < y1 + HALF)
    assert near.sum() >= 8
    o = tracer.offset(p0[near], texels.geom_normal[near], texels.geom_normal[near])
    backs = 0
    for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)):
        dd = np.tile(np.array(d, np.float64), (len(o), 1))
        hit = tracer.intersect(o, dd, np.full(len(o), HALF))
        hn = tracer.geom_normal[np.maximum(hit["tri"], 0)]
        backs += int(((hit["tri"] >= 0) & (np.einsum("ij,ij->i", dd, hn) > 0)).sum())
    assert backs >= near.sum()  # every near texel's footprint crosses a wall seen from behind
    pushed, invalid = push_off_contacts(texels, ground, tracer)
    assert pushed is texels and not invalid.any()


def test_push_in_chunks_gives_the_same_points(monkeypatch):
    """push_off_contacts probes its texels in chunks of CONTACT_CHUNK (bounded memory): chunks
    of 7 texels (boundaries through the moved rows) give exactly the result of one chunk."""
    import usdahd.bake.contacts as tx

    scene, tracer = _tracer(_box_stage())
    ground = _mesh_of(scene, "/ground")
    texels = rasterize(ground, (RES, RES))
    whole, inv_whole = push_off_contacts(texels, ground, tracer)
    monkeypatch.setattr(tx, "CONTACT_CHUNK", 7)
    chunked, inv_chunked = push_off_contacts(texels, ground, tracer)
    assert whole.stats["contact_texels"] > 0 and len(texels) > 7 * 10
    np.testing.assert_array_equal(chunked.position, whole.position)
    np.testing.assert_array_equal(inv_chunked, inv_whole)
    assert chunked.stats == whole.stats


def test_push_leaves_texels_without_contacts_alone():
    """The box's own texels touch the ground only with front faces (or not at all), and a ground
    without anything on it has no contact: the same object comes back."""
    scene, tracer = _tracer(_box_stage())
    box = _mesh_of(scene, "/box")
    texels = rasterize(box, (RES, RES))
    pushed, invalid = push_off_contacts(texels, box, tracer)
    assert pushed is texels and not invalid.any()
    st = new_stage()
    _ground(st)
    UsdLux.DomeLight.Define(st, "/sky")
    scene, tracer = _tracer(st)
    ground = _mesh_of(scene, "/ground")
    texels = rasterize(ground, (RES, RES))
    assert push_off_contacts(texels, ground, tracer)[0] is texels


def test_push_leaves_texels_next_to_double_sided_walls_alone():
    """The box of the first test with ``doubleSided`` walls: both sides are surfaces, so a
    ground footprint crossing a wall is not behind anything and no texel moves (the same walls
    one-sided move texels: test_push_fires_exactly_on_texels_whose_footprint_crosses_a_wall)."""
    st = _box_stage()
    UsdGeom.Mesh(st.GetPrimAtPath("/box")).CreateDoubleSidedAttr(True)
    scene, tracer = _tracer(st)
    ground = _mesh_of(scene, "/ground")
    texels = rasterize(ground, (RES, RES))
    pushed, invalid = push_off_contacts(texels, ground, tracer)
    assert pushed is texels and not invalid.any()
    one_sided = push_off_contacts(texels, ground, _tracer(_box_stage())[1])[0]
    assert one_sided is not texels  # the control: one-sided walls do move texels


def _side_row(texels, mesh):
    """Texels of the frustum's first side (triangles of face 0) whose sample point lies on
    the ground (the contact row) and the side's unit normal."""
    face0 = mesh.face[texels.triangle] == 0
    row = face0 & (texels.position[:, 2] <= 1e-6)
    return row, texels.geom_normal[face0][0].astype(np.float64)


@pytest.mark.parametrize("backend", ["native", "embreex"])
def test_contact_row_is_not_brighter_than_its_open_sky(backend, monkeypatch):
    """The frustum's sides overhang and rest on the ground: texels sampled on their bottom edge
    (the contact line) have their ray origin under the ground and see the dome there, until
    push_off_contacts moves them. Since issue 37 conservative texels are sampled inside their
    covered part, above the contact line (checked last); the rule is tested on the sample
    points on the line (``CONSERVATIVE_INSET = 0``), as a texel centre on a contact gives."""
    st = _frustum_stage()
    scene = load_scene(st)
    tracer = Tracer(scene, threads=1, backend=backend)
    mi, frustum = next((i, m) for i, m in enumerate(scene.meshes) if m.path == "/frustum")
    with monkeypatch.context() as m:
        m.setattr(raster, "CONSERVATIVE_INSET", 0.0)
        texels = rasterize(frustum, (RES, RES))
    row, n = _side_row(texels, frustum)
    assert tracer.offset_eps < 0.01  # well inside half a texel of the sides (~0.05 m)
    assert row.sum() >= 8 and n[2] == pytest.approx(-0.2425, abs=1e-3)
    bound = (1.0 + n[2]) / 2.0  # sky above the horizon, nothing else
    leak = (1.0 - n[2]) / 2.0  # the dome under the ground, seen from below it

    def row_iz(tx):
        out, stats = bake_texels(
            scene, tracer, tx, samples=1024, bounces=0, estimator="mc", seed=3, mesh=mi
        )
        return sh.iz(out.astype(np.float64))[row].mean(axis=1), stats

    # without the rule the row sees the dome under the ground (what the test guards against)
    before, _ = row_iz(texels)
    assert before.mean() > bound + 0.5 * (leak - bound)
    pushed, invalid = push_off_contacts(texels, frustum, tracer)
    assert not invalid.any()
    moved = np.any(pushed.position != texels.position, axis=1)
    assert moved[row].all()
    after, stats = row_iz(pushed)
    assert after.mean() < bound + SIGMAS * standard_error(after) + HORIZON
    assert not stats["invalid"][row].any()
    # and the whole of each side, higher up, too (per texel: 5 sigma of one texel's estimate,
    # a mean of 1024 samples of 2 V cos(theta) <= 2: sd <= sqrt(4/3 / 1024) = 0.036)
    full, _ = bake_texels(
        scene, tracer, pushed, samples=1024, bounces=0, estimator="mc", seed=5, mesh=mi
    )
    side = pushed.geom_normal[:, 2] < -0.2
    fiz = sh.iz(full.astype(np.float64)).mean(axis=1)[side]
    assert fiz.max() < bound + SIGMAS * 0.036 + HORIZON

    # the ground around it: never above the open-sky value, sun (1) plus dome (1)
    ground = _mesh_of(scene, "/ground")
    gt, _ = push_off_contacts(rasterize(ground, (RES, RES)), ground, tracer)
    out, _ = bake_texels(scene, tracer, gt, samples=256, bounces=0, estimator="mc", seed=4, mesh=0)
    giz = sh.iz(out.astype(np.float64)).mean(axis=1)
    # the sun is exact (one delta shadow ray); the dome part is a mean of 256 samples of
    # 2 cos(theta) <= 2, whose standard deviation is at most sqrt(4/3 / 256) = 0.072
    assert giz.max() < 2.0 + SIGMAS * 0.072

    # the default sample points of the row lie inside the covered part, above the ground by
    # more than the ray offset: no view under the ground even before the contact rule
    inset = rasterize(frustum, (RES, RES))
    np.testing.assert_array_equal(inset.xy, texels.xy)
    assert (inset.position[row, 2] > 4 * tracer.offset_eps).all()
    own, _ = row_iz(inset)
    assert own.mean() < bound + SIGMAS * standard_error(own) + HORIZON


def test_bake_moves_contact_texels_and_reports_them(tmp_path, capsys):
    """The bake applies the rule before tracing and reports the moved texels per prim."""
    import json

    from usdahd import cli

    st = _box_stage()
    path = tmp_path / "box.usda"
    st.GetRootLayer().Export(str(path))
    argv = ["bake", str(path), "--json", "--resolution", str(RES), "--samples", "64"]
    assert cli.main([*argv, "--bounces", "0", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    prims = {p["path"]: p for p in report["prims"]}
    assert prims["/ground"]["contact_texels"] == 9 + 9 + 9 - 2  # as the test above
    assert prims["/box"]["contact_texels"] == 0
