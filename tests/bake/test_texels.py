"""Texel rasterisation: coverage, sample points, normals, tangent frames, statistics."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import crease_texels as crease
from usdahd.bake import texels as tx
from usdahd.errors import InputError, UsageError
from usdahd.numerics import raster

QUAD_PTS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
QUAD_TRI = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)


def quad(uv_vertex=None, points=QUAD_PTS, normals=None):
    """Unit quad in z = 0 (front +z); per-vertex UVs default to (x, y)."""
    uv = QUAD_PTS[:, :2] if uv_vertex is None else uv_vertex
    return tx.mesh_from_arrays(points, QUAD_TRI, uv=uv, normals=normals)


def texel_centres_uv(xy, res):
    w, h = res
    return np.stack([(xy[:, 0] + 0.5) / w, 1.0 - (xy[:, 1] + 0.5) / h], axis=1)


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def interval_counts(lo, hi):
    """(texels overlapping (lo, hi), texels whose centre is in [lo, hi]) along one axis."""
    touched = sum(1 for i in range(-2, 64) if i < hi and i + 1 > lo)
    centres = sum(1 for i in range(-2, 64) if lo <= i + 0.5 <= hi)
    return touched, centres


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_full_quad_exact_coverage_positions_and_frames(backend):
    res = (4, 4)
    t = tx.rasterize(quad(), res, backend=backend)
    assert len(t) == 16 and t.center_inside.all()
    assert t.stats["covered"] == 16 and t.stats["overlap_texels"] == 0
    # row-major order
    ids = t.xy[:, 1] * 4 + t.xy[:, 0]
    assert np.array_equal(ids, np.arange(16))
    # UV = (x, y) on this quad, so the world position is the texel centre's UV
    uvc = texel_centres_uv(t.xy, res)
    np.testing.assert_allclose(t.position[:, :2], uvc, atol=1e-6)
    np.testing.assert_allclose(t.position[:, 2], 0.0, atol=1e-7)
    np.testing.assert_allclose(t.frame, np.broadcast_to(np.eye(3), (16, 3, 3)), atol=1e-6)
    np.testing.assert_allclose(t.geom_normal, np.broadcast_to([0, 0, 1], (16, 3)), atol=1e-7)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize(
    ("u", "v", "res"),
    [
        ((0.23, 0.71), (0.23, 0.71), (10, 8)),
        ((0.25, 0.75), (0.0, 0.5), (8, 8)),
        ((0.1, 0.9), (0.3, 0.8), (13, 7)),
    ],
)
def test_axis_aligned_rect_exact_counts(backend, u, v, res):
    w, h = res
    uvv = np.array([[u[0], v[0]], [u[1], v[0]], [u[1], v[1]], [u[0], v[1]]])
    t = tx.rasterize(quad(uvv), res, backend=backend)
    tx_c, cx = interval_counts(u[0] * w, u[1] * w)
    ty_c, cy = interval_counts((1 - v[1]) * h, (1 - v[0]) * h)
    assert t.stats["covered"] == tx_c * ty_c
    assert t.stats["center_inside"] == cx * cy
    t0 = tx.rasterize(quad(uvv), res, conservative=False, backend=backend)
    assert len(t0) == cx * cy and t0.center_inside.all()
    # centre-inside samples sit exactly at the texel centre (UV -> position is affine here)
    inside = t.center_inside
    uvc = texel_centres_uv(t.xy[inside], res)
    expect_x = (uvc[:, 0] - u[0]) / (u[1] - u[0])
    expect_y = (uvc[:, 1] - v[0]) / (v[1] - v[0])
    np.testing.assert_allclose(t.position[inside, 0], expect_x, atol=1e-5)
    np.testing.assert_allclose(t.position[inside, 1], expect_y, atol=1e-5)


def test_analytic_tangent_frame_on_rotated_plane():
    R = rotation([0.3, -0.5, 0.8], 1.1)
    pts = QUAD_PTS @ R.T * 2.0 + np.array([1.0, -2.0, 0.5])
    # UV = A (x, y) + b with A a rotation by 0.4 rad and anisotropic scale, det > 0
    c, s = np.cos(0.4), np.sin(0.4)
    A = np.array([[c, -s], [s, c]]) @ np.diag([0.5, 0.3])
    uvv = QUAD_PTS[:, :2] @ A.T + np.array([0.3, 0.2])
    t = tx.rasterize(quad(uvv, points=pts), (32, 32))
    assert len(t) > 20
    # dp/du: p = 2 R [x, y, 0] + o, (x, y) = A^-1 (uv - b)
    dxy_du = np.linalg.inv(A)[:, 0]
    dp_du = 2.0 * R[:, :2] @ dxy_du
    n = R[:, 2]
    tan = dp_du / np.linalg.norm(dp_du)
    bit = np.cross(n, tan)
    expect = np.stack([tan, bit, n])
    np.testing.assert_allclose(t.frame, np.broadcast_to(expect, t.frame.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(t.frame.astype(np.float64)), 1.0, atol=1e-5)
    # dp/dv is in the (t, b) plane with a positive b component (right-handed, not mirrored)
    dp_dv = 2.0 * R[:, :2] @ np.linalg.inv(A)[:, 1]
    assert dp_dv @ bit > 0


def test_mirrored_uv_flips_bitangent_sign():
    plain = tx.rasterize(quad(), (8, 8))
    mirrored_uv = QUAD_PTS[:, :2].copy()
    mirrored_uv[:, 0] = 1.0 - mirrored_uv[:, 0]
    mirrored = tx.rasterize(quad(mirrored_uv), (8, 8))
    assert mirrored.stats["mirrored_texels"] == len(mirrored) == 64
    assert plain.stats["mirrored_texels"] == 0
    f = mirrored.frame.astype(np.float64)
    n, t, b = f[:, 2], f[:, 0], f[:, 1]
    np.testing.assert_allclose(t, np.broadcast_to([-1, 0, 0], t.shape), atol=1e-6)
    np.testing.assert_allclose(b, -np.cross(n, t), atol=1e-6)  # sign = -1
    np.testing.assert_allclose(np.linalg.det(f), -1.0, atol=1e-6)
    # the bitangent still follows dp/dv (+y), as MikkTSpace's sign intends
    np.testing.assert_allclose(b, np.broadcast_to([0, 1, 0], b.shape), atol=1e-6)


def test_frames_orthonormal_on_curved_mesh():
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.uv_sphere(radius=1.0, count=[16, 16])
    # spherical UV (per vertex): u = longitude, v = latitude; seams are fine for this check
    p = m.vertices
    uvv = np.stack(
        [
            (np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi)) % 1.0,
            0.5 + np.arcsin(np.clip(p[:, 2], -1, 1)) / np.pi,
        ],
        axis=1,
    )
    mesh = tx.mesh_from_arrays(p, m.faces, uv=uvv, normals=m.vertex_normals)
    t = tx.rasterize(mesh, (64, 64))
    f = t.frame.astype(np.float64)
    np.testing.assert_allclose(
        np.einsum("nij,nkj->nik", f, f), np.broadcast_to(np.eye(3), f.shape), atol=1e-5
    )
    det = np.linalg.det(f)
    np.testing.assert_allclose(np.abs(det), 1.0, atol=1e-5)
    assert ((det < 0).sum()) == t.stats["mirrored_texels"]


def test_smooth_normal_is_interpolated():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    nrm = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], float)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    mesh = tx.mesh_from_arrays(pts, [[0, 1, 2]], uv=pts[:, :2], normals=nrm)
    t = tx.rasterize(mesh, (16, 16), conservative=False)
    lam = tx.barycentrics(t, mesh)
    expect = lam @ nrm
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(t.frame[:, 2], expect, atol=1e-5)
    np.testing.assert_allclose(t.geom_normal, np.broadcast_to([0, 0, 1], (len(t), 3)), atol=1e-7)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_conservative_texels_lie_on_triangle_and_coverage_is_complete(backend):
    rng = np.random.default_rng(7)
    res = (23, 17)
    for _ in range(5):
        uvt = rng.uniform(0.05, 0.95, (3, 2))
        pts = np.concatenate([uvt * [3.0, 2.0], rng.uniform(-1, 1, (3, 1))], axis=1)
        mesh = tx.mesh_from_arrays(pts, [[0, 1, 2]], uv=uvt)
        t = tx.rasterize(mesh, res, backend=backend)
        lam = tx.barycentrics(t, mesh)
        assert (lam > -1e-5).all() and np.allclose(lam.sum(axis=1), 1.0, atol=1e-5)
        cons = ~t.center_inside
        assert cons.any()
        # closest point in UV is within half a texel diagonal of the centre
        uvq = np.einsum("nc,ci->ni", lam, uvt)
        w, h = res
        dq = (uvq - texel_centres_uv(t.xy, res)) * [w, h]
        assert (np.linalg.norm(dq[cons], axis=1) <= np.sqrt(0.5) + 1e-4).all()
        np.testing.assert_allclose(np.linalg.norm(dq[~cons], axis=1), 0.0, atol=1e-4)
        # brute force: every texel with a 16x16 subsample inside the triangle is covered
        sub = (np.arange(16) + 0.5) / 16
        X, Y = np.meshgrid(np.arange(w), np.arange(h))
        px = raster.uv_to_pixel(uvt, res)
        sx = (X[..., None, None] + sub[None, None, :, None]).reshape(h, w, -1)
        sy = (Y[..., None, None] + sub[None, None, None, :]).reshape(h, w, -1)
        a2 = raster.cross2(px[1] - px[0], px[2] - px[0])
        inside = np.ones_like(sx, dtype=bool)
        for i in range(3):
            a, b = px[(i + 1) % 3], px[(i + 2) % 3]
            e = (b[0] - a[0]) * (sy - a[1]) - (b[1] - a[1]) * (sx - a[0])
            inside &= e * np.sign(a2) > 0
        touched = inside.any(axis=-1)
        got = np.zeros((h, w), bool)
        got[t.xy[:, 1], t.xy[:, 0]] = True
        assert not (touched & ~got).any()
        # and nothing far away is covered
        assert (np.linalg.norm(dq, axis=1) <= np.sqrt(0.5) + 1e-4).all()


def test_backends_agree_on_unwrapped_mesh():
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(2)
    rng = np.random.default_rng(3)
    uv = rng.uniform(0, 1, (len(m.faces), 3, 2))  # random overlapping triangles
    mesh = tx.mesh_from_arrays(m.vertices, m.faces, uv=uv)
    a = tx.rasterize(mesh, (40, 30), backend="numba")
    b = tx.rasterize(mesh, (40, 30), backend="numpy")
    for f in ("xy", "triangle", "center_inside", "position", "frame"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert a.stats == b.stats and a.stats["overlap_texels"] > 0


def test_overlap_detection():
    # both triangles of the quad mapped onto the same UV triangle
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 0], [1, 1]]], float)
    mesh = tx.mesh_from_arrays(QUAD_PTS, QUAD_TRI, uv=uv)
    t = tx.rasterize(mesh, (8, 8))
    # centres strictly inside the lower-right triangle (x + 0.5 > 7.5 - y - ... ) of an 8x8 grid
    xs, ys = np.meshgrid(np.arange(8) + 0.5, np.arange(8) + 0.5)
    u, v = xs / 8, 1 - ys / 8
    expect = int(((v < u - 1e-9) & (v > 0) & (u < 1)).sum())
    assert t.stats["overlap_texels"] == expect > 0
    # a proper quad: centres on the shared diagonal are not overlap
    assert tx.rasterize(quad(), (8, 8)).stats["overlap_texels"] == 0


def test_stats_outside_and_degenerate():
    uvv = QUAD_PTS[:, :2] + [0.5, 0.0]  # corners 1 and 2 at u = 1.5
    t = tx.rasterize(quad(uvv), (8, 8))
    # corners outside [0, 1]: tri 0 has corners 1, 2 outside; tri 1 has corner 2 -> 3 of 6
    assert t.stats["uv_outside_fraction"] == pytest.approx(3 / 6)
    assert (t.xy[:, 0] >= 4).all() and len(t) == 32
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0.2, 0.2], [0.2, 0.2], [0.5, 0.5]]], float)
    t = tx.rasterize(tx.mesh_from_arrays(QUAD_PTS, QUAD_TRI, uv=uv), (8, 8))
    assert t.stats["degenerate_uv_triangles"] == 1
    assert (t.triangle == 0).all()


def test_chart_ids():
    assert np.array_equal(tx.chart_ids(quad()), [0, 0])
    uv = np.array([[[0, 0], [0.4, 0], [0.4, 0.4]], [[0.5, 0.5], [0.9, 0.9], [0.5, 0.9]]], float)
    assert np.array_equal(tx.chart_ids(tx.mesh_from_arrays(QUAD_PTS, QUAD_TRI, uv=uv)), [0, 1])


def test_density_helpers():
    big = quad(points=QUAD_PTS * 2.0)  # 2 x 2 units on UV [0, 1]^2
    assert tx.resolution_for_density(big, 10.0) == (20, 20)
    assert tx.texel_density(big, (20, 20)) == pytest.approx(10.0)
    with pytest.raises(UsageError, match="above the maximum 8192"):
        tx.resolution_for_density(big, 5000.0)
    with pytest.raises(UsageError, match="positive"):
        tx.resolution_for_density(big, -1.0)


def test_bad_inputs_raise_clear_errors():
    mesh = quad()
    mesh.uv = None
    with pytest.raises(InputError, match="no lightmap UV set 'st'"):
        tx.rasterize(mesh, (8, 8))
    mesh = quad()
    mesh.uv = mesh.uv.copy()
    mesh.uv[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        tx.rasterize(mesh, (8, 8))
    with pytest.raises(UsageError, match="exceeds the maximum"):
        tx.rasterize(quad(), (9000, 16))
    with pytest.raises(UsageError, match="positive"):
        tx.rasterize(quad(), (0, 16))
    with pytest.raises(UsageError, match="backend"):
        tx.rasterize(quad(), (4, 4), backend="cuda")


def test_crease_border_texels_read_the_surface_not_the_crease_line():
    """Issue 37: a conservative texel on a concave crease used to be sampled on the crease
    line itself (the triangle's closest point), whose irradiance a step a twentieth of a texel
    high halves; bilinear filtering then spread that dark line over the half texel along the
    chart's border (-13 %). Sampled inside the covered part, the border band reads the
    analytic irradiance (benchmarks/crease_texels.py: a black floor meeting a black wall under
    a uniform sky, I_z(s) = 1/2 + s / (2 sqrt(s^2 + h^2)); each texel holds the exact value at
    its sample point, so only the sample points differ)."""
    new = crease.measure(32, 0.05, raster.CONSERVATIVE_INSET)
    old = crease.measure(32, 0.05, 0.0)
    assert old["s0-0.5_bias"] < -0.12 and old["s0-1_relrmse"] > 0.15  # the dark line
    assert abs(new["s0-0.5_bias"]) < 0.02 and new["s0-1_relrmse"] < 0.105
    # a wall a few texels high (a room's floor and wall): the closest point was right there;
    # the inset costs at most a few thousandths
    for wall in (1.0, 4.0):
        new = crease.measure(32, wall, raster.CONSERVATIVE_INSET)
        old = crease.measure(32, wall, 0.0)
        assert new["s0-1_relrmse"] < old["s0-1_relrmse"] + 0.008
        assert abs(new["s0-0.5_bias"]) < 0.06


@pytest.mark.slow
def test_crease_bake_border_band_against_analytic(tmp_path):
    """The same crease baked by the real integrator (``usdahd bake``, 32^2, no denoising):
    the bilinear read of its I_z texture along the crease matches the analytic irradiance,
    where the old sample points read 13 % dark (the same bake at CONSERVATIVE_INSET = 0,
    measured: bias -0.13 in the first half texel)."""
    from usdahd import cli

    stage = tmp_path / "crease.usda"
    h = crease.write_stage(stage, 32, 0.05)
    layer = tmp_path / "out.lightmaps.usda"
    argv = [str(stage), "-o", str(layer), "--prim", "/World/Floor", "--resolution", "32"]
    argv += ["--samples", "256", "--no-denoise", "--atlas", "off", "--quiet"]
    assert cli.main(["bake", *argv]) == 0
    got = crease.baked(str(layer), 32, h)
    assert abs(got["s0-0.5_bias"]) < 0.03, got
    assert abs(got["s1-2_bias"]) < 0.02, got  # away from the border: the surface itself
