"""usdahd.numerics.raster: fan triangulation, UV -> pixel mapping, the UV rasteriser's outputs.

The rasteriser's coverage, winners and sample points are tested through the baker in
tests/bake/test_texels.py (both backends, brute-force coverage); here the pieces other callers (the
validator) use directly.
"""

import numpy as np
import pytest

from usdahd.errors import UsageError
from usdahd.numerics import raster


def test_fan_triangulate_polygons_in_face_vertex_slots():
    face, corners = raster.fan_triangulate([3, 4, 2, 5])
    assert face.dtype == np.int64 and corners.dtype == np.int64
    np.testing.assert_array_equal(face, [0, 1, 1, 3, 3, 3])
    # triangle 0..2, quad 3..6, a 2-gon (none), pentagon 9..13
    np.testing.assert_array_equal(
        corners,
        [[0, 1, 2], [3, 4, 5], [3, 5, 6], [9, 10, 11], [9, 11, 12], [9, 12, 13]],
    )
    face, corners = raster.fan_triangulate(np.zeros(0, np.int32))
    assert face.shape == (0,) and corners.shape == (0, 3)


def test_uv_to_pixel_flips_v_and_scales():
    px = raster.uv_to_pixel([[0.0, 0.0], [1.0, 1.0], [0.25, 0.75]], (8, 4))
    np.testing.assert_array_equal(px, [[0.0, 4.0], [8.0, 0.0], [2.0, 1.0]])


@pytest.mark.parametrize("backend", raster.BACKENDS)
def test_rasterize_uv_full_square_and_overlap_ids(backend):
    # two triangles covering [0, 1]^2, then both mapped onto the same lower-right half
    quad = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
    r = raster.rasterize_uv(quad, (4, 4), backend=backend)
    np.testing.assert_array_equal(r.ids, np.arange(16))
    assert r.center_inside.all() and len(r.overlap_ids) == 0
    np.testing.assert_array_equal(r.xy, np.stack([np.arange(16) % 4, np.arange(16) // 4], 1))
    np.testing.assert_allclose(r.barycentrics.sum(axis=1), 1.0)
    same = np.array([quad[0], quad[0]])
    r = raster.rasterize_uv(same, (4, 4), backend=backend)
    # overlap: centres strictly inside the half v < u, i.e. pixel x + y > 3 on a 4 x 4 grid
    # (centres on the diagonal are on an edge, not inside); ties go to the lower triangle
    x, y = r.xy.T
    assert (r.triangle == 0).all()
    np.testing.assert_array_equal(r.overlap_ids, r.ids[x + y > 3])
    assert r.degenerate.tolist() == [False, False]


def test_degenerate_triangles_cover_nothing_and_backend_is_checked():
    uv = np.array([[[0.2, 0.2], [0.2, 0.2], [0.5, 0.5]]], float)
    r = raster.rasterize_uv(uv, (8, 8))
    assert len(r.ids) == 0 and r.degenerate.tolist() == [True]
    with pytest.raises(UsageError, match="backend"):
        raster.rasterize_uv(uv, (8, 8), backend="cuda")


@pytest.mark.parametrize("backend", raster.BACKENDS)
def test_coverage_is_rasterize_uvs_texels(backend):
    """coverage() (the UVSet rule's statistic, without sample points) gives exactly
    rasterize_uv's covered and overlap ids on random, overlapping UV triangles."""
    rng = np.random.default_rng(5)
    uv = rng.random((40, 3, 2))
    r = raster.rasterize_uv(uv, (37, 23), backend=backend)
    ids, overlap = raster.coverage(uv, (37, 23), backend=backend)
    assert len(r.overlap_ids) > 0  # the case exercises overlaps
    np.testing.assert_array_equal(ids, r.ids)
    np.testing.assert_array_equal(overlap, r.overlap_ids)


def _subsample_inside(c, P, n=64):
    """Brute force: n x n sub-points of the unit squares centred at c (m, 2) inside triangles
    P (m, 3, 2): the points (m, n*n, 2) and the mask."""
    sub = (np.arange(n) + 0.5) / n - 0.5
    X, Y = np.meshgrid(sub, sub)
    pts = c[:, None, :] + np.stack([X.ravel(), Y.ravel()], 1)[None]
    a2 = raster.signed_area2(P)
    inside = np.ones(pts.shape[:2], bool)
    for i in range(3):
        a = P[:, (i + 1) % 3]
        e = P[:, (i + 2) % 3] - a
        inside &= raster.cross2(e[:, None, :], pts - a[:, None, :]) * np.sign(a2)[:, None] > 0
    return pts, inside


def test_clip_square_area_and_centroid_match_brute_force():
    rng = np.random.default_rng(11)
    P = rng.uniform(0, 4, (3000, 3, 2))
    c = rng.integers(0, 4, (3000, 2)) + 0.5
    area, cen = raster.clip_square(c, P, raster.signed_area2(P))
    pts, inside = _subsample_inside(c, P)
    share = inside.mean(axis=1)
    # 64 x 64 sub-points: each edge crossing the square miscounts at most ~64 of 4096 cells
    # by half (worst case 0.02), typically far fewer
    np.testing.assert_allclose(area, share, atol=0.02)
    assert np.abs(area - share).mean() < 0.001
    assert (area[share == 0] < 0.006).all() and (share == 0).any() and (share == 1).any()
    ok = share > 0.1  # the sub-point centroid of a sliver is coarse
    mean = (pts * inside[..., None]).sum(axis=1)[ok] / inside.sum(axis=1)[ok, None]
    np.testing.assert_allclose(cen[ok], mean, atol=0.03)
    assert np.abs(cen[ok] - mean).mean() < 0.002
    # an exact case: the edge x = 1.2 crosses the square centred at (1, 0)
    P1 = np.array([[[1.2, -10.0], [11.2, 0.0], [1.2, 10.0]]])
    for tri in (P1, P1[:, ::-1]):  # either winding
        a, g = raster.clip_square(np.array([[1.0, 0.0]]), tri, raster.signed_area2(tri))
        np.testing.assert_allclose(a, [0.3])
        np.testing.assert_allclose(g, [[1.35, 0.0]], atol=1e-12)
        q = raster.conservative_points(np.array([[1.0, 0.0]]), tri, raster.signed_area2(tri), 0.5)
        np.testing.assert_allclose(q, [[1.275, 0.0]], atol=1e-12)  # half way from 1.2 to 1.35


@pytest.mark.parametrize("backend", raster.BACKENDS)
def test_conservative_sample_points_lie_strictly_inside_triangle_and_square(backend):
    """A conservative texel's sample point is inside its triangle (every barycentric > 0, not
    on an edge: on a crease the edge sees the other face) and inside the texel's square, half
    way from the closest point to the centroid of the covered part."""
    rng = np.random.default_rng(3)
    uv = rng.uniform(0.05, 0.95, (30, 3, 2))
    res = (29, 31)
    r = raster.rasterize_uv(uv, res, backend=backend)
    cons = ~r.center_inside
    assert cons.sum() > 50
    px = raster.uv_to_pixel(uv, res)[r.triangle]
    q = np.einsum("nc,nci->ni", r.barycentrics, px)
    centre = r.xy + 0.5
    assert (np.abs(q - centre)[cons] <= 0.5 + 1e-9).all()
    area, cen = raster.clip_square(centre[cons], px[cons], raster.signed_area2(px[cons]))
    closest, _ = raster.closest_point(centre[cons], px[cons])
    ok = area > raster.CENTROID_MIN_AREA
    # where the triangle's closest point lies in the square it is the covered part's closest
    # point too (else that part's is on the square's boundary, still inside the square)
    sq = ok & (np.abs(closest - centre[cons]) <= 0.5).all(axis=1)
    assert sq.mean() > 0.8
    want = closest + raster.CONSERVATIVE_INSET * (cen - closest)
    np.testing.assert_allclose(q[cons][sq], want[sq], atol=1e-9)
    # strictly inside: the point sits off every edge (the old rule put it on one)
    assert (r.barycentrics[cons][ok].min(axis=1) > 1e-9).all() and ok.mean() > 0.9
    np.testing.assert_allclose(q[~cons], centre[~cons], atol=1e-9)  # centres stay centres
