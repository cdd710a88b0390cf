"""usdahd.usd.geometry: fan triangulation (Topology), the transform / precision / degenerate
checks, and the tessellation of implicit gprims, against independent formulas (shoelace areas,
prism and cone volumes, the divergence theorem); GeometryReader through the stage reader."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, UsdGeom

from tests.scenes import define_mesh, new_stage
from usdahd.usd.geometry import (
    MeshFailure,
    Topology,
    check_precision,
    check_transform,
    drop_degenerate,
    tessellate,
)
from usdahd.usd.reader import load_scene


def _polygon(n, r=1.0, z=0.0):
    phi = 2 * np.pi * np.arange(n) / n
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, z)], 1)


def test_topology_fans_each_polygon_and_keeps_its_area():
    """A triangle, a quad and a convex pentagon: n - 2 triangles each, in face order, whose
    areas add up to each polygon's shoelace area."""
    pts = np.concatenate([_polygon(3), _polygon(4, z=1.0), _polygon(5, 2.0, 2.0)])
    counts = np.array([3, 4, 5])
    idx = np.arange(12)
    topo = Topology(counts, idx)
    assert topo.face.tolist() == [0, 1, 1, 2, 2, 2]
    assert topo.corners.tolist()[:3] == [[0, 1, 2], [3, 4, 5], [3, 5, 6]]
    tri = pts[idx[topo.corners]]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    start = 0
    for k, n in enumerate(counts):
        x, y = pts[start : start + n, 0], pts[start : start + n, 1]
        shoelace = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
        assert area[topo.face == k].sum() == pytest.approx(shoelace, rel=1e-12)
        start += n


def test_topology_selection_per_interpolation():
    counts, idx = np.array([4, 3]), np.array([0, 1, 2, 3, 2, 1, 4])
    topo = Topology(counts, idx)
    need, sel = topo.selection("faceVarying")
    assert need == 7 and sel.tolist() == list(range(7))
    for interp in ("vertex", "varying"):
        need, sel = topo.selection(interp)
        assert need == 5 and sel.tolist() == idx.tolist()
    need, sel = topo.selection("uniform")
    assert need == 2 and sel.tolist() == [0, 0, 0, 0, 1, 1, 1]
    assert topo.selection("constant")[0] == 1
    # an unknown token reads as the fallback
    assert topo.selection("bogus")[0] == 1
    assert topo.selection("bogus", fallback="vertex")[0] == 5


def test_check_transform_rejects_nan_and_singular_matrices():
    check_transform(np.diag([2.0, 3.0, -1.0, 1.0]), "/ok")  # a mirror is invertible
    bad = {
        "NaN/Inf": np.diag([1.0, np.nan, 1.0, 1.0]),
        "a zero scale": np.diag([1.0, 0.0, 1.0, 1.0]),
        "rank < 3": np.array(
            [[1, 0, 0, 0], [0, 1, 0, 0], [1, 1, 0, 0], [0, 0, 0, 1]], float
        ),  # z folded onto x + y
    }
    for what, m in bad.items():
        with pytest.raises(MeshFailure) as exc:
            check_transform(m, "/World/Flat")
        assert str(exc.value).startswith("/World/Flat: world transform")
        assert what in str(exc.value) and "fix the xformOps" in str(exc.value)


def test_check_precision_follows_the_float32_spacing():
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float) * 0.01
    check_precision(quad, "/near")
    check_precision(quad + [1000.0, 0, 0], "/km")  # ulp 6e-5: 160 ulps across
    far = 1e6  # ulp 0.0625 > the 1.4 cm diagonal
    assert np.spacing(np.float32(far)) == 0.0625
    with pytest.raises(MeshFailure, match=r"^/far: 0.0141 units across at coordinate 1e\+06"):
        check_precision(quad + [far, 0, 0], "/far")


def test_drop_degenerate_drops_zero_area_triangles_and_says_how_many():
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], float)
    # a quad, then a triangle with a repeated point, then a collinear one
    counts, idx = np.array([4, 3, 3]), np.array([0, 1, 2, 3, 1, 1, 2, 0, 1, 4])
    topo = Topology(counts, idx)
    said = []
    corners, keep = drop_degenerate(pts, topo, topo.corners, "/m", said.append)
    assert keep.tolist() == [True, True, False, False]
    assert corners.tolist() == topo.corners[:2].tolist()
    assert said == ["/m: 2 degenerate (zero-area) triangles in 2 faces dropped "
                    "(repeated or collinear points)"]  # fmt: skip


def _signed_volume(p, t):
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _get(attr, default):
    return attr.Get() if attr.HasAuthoredValue() else default


def test_tessellate_closed_gprims_enclose_their_volume_outward():
    """Positive signed volume (divergence theorem) = CCW outward faces; a cube exactly, a
    cylinder/cone as the 24-gon prism/pyramid they are, sphere and capsule below and within 5 %
    of the smooth solid (inscribed)."""
    st = new_stage()
    UsdGeom.Cube.Define(st, "/cube").CreateSizeAttr(3.0)
    UsdGeom.Cylinder.Define(st, "/cyl").CreateHeightAttr(4.0)
    UsdGeom.Cone.Define(st, "/cone")
    UsdGeom.Sphere.Define(st, "/sphere").CreateRadiusAttr(2.0)
    cap = UsdGeom.Capsule.Define(st, "/capsule")
    cap.CreateAxisAttr("X")
    poly = 24 / 2 * math.sin(2 * math.pi / 24)  # area of the unit-radius 24-gon
    caps = math.pi * 0.5**2 * 1.0 + 4 / 3 * math.pi * 0.5**3
    want = {
        "/cube": (27.0, 1e-12),
        "/cyl": (poly * 4.0, 1e-12),
        "/cone": (poly * 2.0 / 3.0, 1e-12),
        "/sphere": (4 / 3 * math.pi * 8, 0.05),
        "/capsule": (caps, 0.05),
    }
    for path, (volume, rel) in want.items():
        p, t = tessellate(st.GetPrimAtPath(path), _get)
        got = _signed_volume(p, t)
        assert got > 0, path
        if rel < 1e-6:
            assert got == pytest.approx(volume, rel=rel), path
        else:
            assert volume * (1 - rel) < got <= volume, path
    # the capsule lies along X: its extent is 1 + 2 r along x, 2 r across
    p, _ = tessellate(st.GetPrimAtPath("/capsule"), _get)
    np.testing.assert_allclose(np.ptp(p, axis=0), [2.0, 1.0, 1.0], atol=1e-12)


def test_tessellate_plane_and_non_gprims():
    st = new_stage()
    pl = UsdGeom.Plane.Define(st, "/plane")
    pl.CreateWidthAttr(4.0)
    pl.CreateLengthAttr(1.0)
    pl.CreateAxisAttr("Y")
    p, t = tessellate(st.GetPrimAtPath("/plane"), _get)
    n = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
    assert 0.5 * np.linalg.norm(n, axis=1).sum() == pytest.approx(4.0)
    np.testing.assert_allclose(n / np.linalg.norm(n, axis=1)[:, None], [[0, 1, 0]] * 2)
    define_mesh(st, "/mesh", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])
    assert tessellate(st.GetPrimAtPath("/mesh"), _get) == (None, None)


def test_geometry_reader_applies_the_world_transform_and_keeps_faces_front():
    """Through the stage reader: world-space points are the authored ones under the xform
    (Gf's matrix as the reference), and a mirroring scale keeps the triangle's front side
    facing the side the authored winding faces (+z mirrored in x still faces +z)."""
    st = new_stage()
    m = define_mesh(st, "/World/Tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])
    m.AddTranslateOp().Set(Gf.Vec3d(5, 0, 1))
    m.AddScaleOp().Set(Gf.Vec3f(-2, 1, 1))
    sc = load_scene(st)
    assert not sc.failed
    (md,) = sc.meshes
    xf = UsdGeom.Xformable(m).ComputeLocalToWorldTransform(0)
    want = [xf.Transform(Gf.Vec3d(*p)) for p in [(0, 0, 0), (1, 0, 0), (0, 1, 0)]]
    tri = md.points[md.triangles[0]]
    assert sorted(map(tuple, np.round(tri, 12))) == sorted(tuple(w) for w in want)
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    assert normal[2] > 0
