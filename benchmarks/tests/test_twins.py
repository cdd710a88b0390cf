"""Coincident opposite-facing faces (twins) are found and separated for Cycles
(benchmarks/reference/twins.py), and nothing else moves."""

from __future__ import annotations

import numpy as np
import pytest

from tests.scenes import new_stage

pytest.importorskip("pxr")
from pxr import Sdf, UsdGeom, Vt  # noqa: E402

from benchmarks.reference import export  # noqa: E402
from benchmarks.reference.twins import TWIN_GAP, find_twins, separate_twins  # noqa: E402


def _grid(n, z, up, x0=0.0, size=1.0):
    """(2 n^2, 3, 3) triangles of a size x size square at height z facing +z (up) or -z."""
    xs = np.linspace(x0, x0 + size, n + 1)
    tris = []
    for i in range(n):
        for j in range(n):
            a, b = (xs[i], xs[j], z), (xs[i + 1], xs[j], z)
            c, d = (xs[i + 1], xs[j + 1], z), (xs[i], xs[j + 1], z)
            tris += [(a, b, c), (a, c, d)]
    t = np.array(tris, np.float64)
    return t if up else t[:, [0, 2, 1]]


def test_opposite_coplanar_faces_are_twins_whatever_their_triangulation():
    up = _grid(1, 5.926285, True)  # 2 large triangles facing +z
    down = _grid(4, 5.926285, False)  # 32 small ones facing -z, the same square
    apart = _grid(2, 5.936285, False, x0=2.0)  # facing -z 1 cm higher, elsewhere
    same = _grid(1, 5.926285, True, x0=2.0)  # facing +z under `apart`: not a twin of it
    p = np.concatenate([up, down, apart, same])
    tw = find_twins(p)
    assert tw[: len(up) + len(down)].all()
    assert not tw[len(up) + len(down) :].any()
    # a twin 0.09 mm off the plane is not coplanar (PLANE_TOL 0.01 mm): Cycles handles that
    assert not find_twins(np.concatenate([up, _grid(4, 5.926285 + 9e-5, False)])).any()
    # faces touching only along an edge are not twins
    assert not find_twins(np.concatenate([up, _grid(1, 5.926285, False, x0=1.0)])).any()


def test_separation_moves_each_twin_half_the_gap_toward_its_front():
    up, down = _grid(1, 2.0, True), _grid(3, 2.0, False)
    other = _grid(2, 0.0, True, x0=5.0)
    p = np.concatenate([up, down, other])
    moved, tw = separate_twins(p)
    assert tw.sum() == len(up) + len(down)
    dz = moved[..., 2] - p[..., 2]
    np.testing.assert_allclose(dz[: len(up)], TWIN_GAP / 2, rtol=1e-9)
    np.testing.assert_allclose(dz[len(up) : len(up) + len(down)], -TWIN_GAP / 2, rtol=1e-9)
    np.testing.assert_array_equal(moved[len(up) + len(down) :], other)
    np.testing.assert_array_equal(moved[..., :2], p[..., :2])
    q, none = separate_twins(other)
    assert q is other and not none.any()  # no twin: the very same array, digest unchanged


def _mesh(stage, path, z, flip, st=True):
    m = UsdGeom.Mesh.Define(stage, path)
    pts = [(-1, -1, z), (1, -1, z), (1, 1, z), (-1, 1, z)]
    m.CreatePointsAttr(Vt.Vec3fArray(pts))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 3, 2, 1] if flip else [0, 1, 2, 3]))
    m.CreateSubdivisionSchemeAttr("none")
    if st:
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
        )
        pv.Set(Vt.Vec2fArray([(0, 0), (1, 0), (1, 1), (0, 1)]))
    return m


def test_export_separates_twins_and_says_which_meshes(tmp_path):
    st = new_stage("Z", path=tmp_path / "s.usda")
    _mesh(st, "/World/Outer", 3.0, False)
    _mesh(st, "/World/Inner", 3.0, True, st=False)
    _mesh(st, "/World/Floor", 0.0, False)
    st.GetRootLayer().Save()
    sc = export.export_stage(st.GetRootLayer().realPath, resolution=8)
    msg = [w for w in sc.warnings if "opposite-facing" in w]
    assert len(msg) == 1 and "/World/Outer" in msg[0] and "/World/Inner" in msg[0]
    assert "/World/Floor" not in msg[0] and "4 faces" in msg[0]
    z = {m["path"]: sc.tri_p[sc.tri_mesh == k][..., 2] for k, m in enumerate(sc.meshes)}
    np.testing.assert_allclose(z["/World/Outer"], 3.0 + TWIN_GAP / 2, rtol=1e-6)
    np.testing.assert_allclose(z["/World/Inner"], 3.0 - TWIN_GAP / 2, rtol=1e-6)
    np.testing.assert_array_equal(z["/World/Floor"], 0.0)
