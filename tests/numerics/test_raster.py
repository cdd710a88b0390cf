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
