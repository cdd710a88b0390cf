"""usdahd.numerics.charts: the hull, rectangle and layout helpers of the unwrap's candidate
loop, and their per-chart cache (ChartRects), against independent numpy formulations."""

from __future__ import annotations

import numpy as np

from usdahd.numerics.charts import (
    ChartRects,
    convex_hull,
    layout,
    min_area_rect,
    split_rings,
    widen_thin,
)


def _charts(seed=0, count=40):
    """Random charts: each a fan of 1-6 triangles around its own centre, some slivers
    (a tenth of a texel across), on a grid so no two overlap. (uv (t, 3, 2), labels (t,),
    polygon of each triangle (t,))."""
    rng = np.random.default_rng(seed)
    uv, labels, face = [], [], []
    for c in range(count):
        n = int(rng.integers(1, 7))
        centre = np.array([c % 8, c // 8], float) * 30.0 + 15.0
        angles = np.sort(rng.uniform(0, 2 * np.pi, n + 1))
        radius = rng.uniform(2.0, 10.0, n + 1)
        squash = 0.01 if c % 5 == 0 else 1.0
        ring = np.stack([np.cos(angles) * radius, np.sin(angles) * radius * squash], axis=1)
        for i in range(n):
            uv.append([centre, centre + ring[i], centre + ring[i + 1]])
            labels.append(c)
            face.append(len(face))
    return np.array(uv), np.array(labels, np.int64), np.array(face, np.int64)


def test_convex_hull_holds_every_point_on_its_inner_side_and_drops_duplicates():
    rng = np.random.default_rng(1)
    for _ in range(50):
        pts = rng.normal(size=(int(rng.integers(3, 40)), 2)).round(1)  # rounding: duplicates
        pts = np.concatenate([pts, pts[:3]])
        hull = convex_hull(pts)
        assert len(np.unique(hull, axis=0)) == len(hull)
        assert all((hull[i] == pts).all(axis=1).any() for i in range(len(hull)))
        edges = np.roll(hull, -1, axis=0) - hull
        rel = pts[:, None, :] - hull[None, :, :]
        cross = edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0]
        assert (cross >= -1e-12).all()  # counter-clockwise: every point left of every edge


def test_layout_matches_numpy_unique_rows():
    """layout's own sort gives the vertices and indices np.unique(rows, axis=0) gives."""
    uv, labels, _ = _charts(2)
    verts, idx = layout(uv, labels)
    flat_v = verts[idx.astype(np.int64)]  # (t, 3, 2) as laid out
    lab = np.repeat(np.unique(labels, return_inverse=True)[1], 3)
    rows = np.concatenate([lab[:, None].astype(np.float64), flat_v.reshape(-1, 2)], axis=1)
    unique, inverse = np.unique(rows, axis=0, return_inverse=True)
    assert np.array_equal(verts, unique[:, 1:].astype(np.float32))
    assert np.array_equal(idx.reshape(-1), inverse.reshape(-1))
    for c in np.unique(labels):  # each chart keeps its shape, moved as a whole
        a, b = uv[labels == c].reshape(-1, 2), flat_v[labels == c].reshape(-1, 2)
        assert np.allclose(a - a.min(axis=0), b - b.min(axis=0), atol=1e-4)


def test_chart_rects_are_the_rectangles_of_each_chart_and_computed_once():
    uv, labels, face = _charts(3)
    rects = ChartRects(uv)
    for c in np.unique(labels):
        tris = np.flatnonzero(labels == c)
        rot, lo, hi = rects(tris)
        want = min_area_rect(convex_hull(uv[tris].reshape(-1, 2)))
        assert np.array_equal(rot, want[0]) and np.array_equal(lo, want[1])
        assert rects(tris)[0] is rot  # cached
    assert len(rects._rects) == len(np.unique(labels))


def test_shared_chart_rects_change_no_result():
    """widen_thin and split_rings with one ChartRects for every floor, density and cut give
    what each gives on its own (the unwrap's candidates share one per pass-1 layout)."""
    uv, labels, face = _charts(4)
    rects = ChartRects(uv)
    for solidity in (0.5, 0.8, 0.95):
        alone = split_rings(uv, labels, face, solidity)
        assert np.array_equal(split_rings(uv, labels, face, solidity, rects), alone)
        for scale in (0.5, 1.0, 3.0):
            for floor in (2.0, 4.0):
                a, na = widen_thin(uv, alone, scale, floor)
                b, nb = widen_thin(uv, alone, scale, floor, rects)
                assert na == nb and np.array_equal(a, b)
    # slivers were widened somewhere, else the comparison above is empty
    assert widen_thin(uv, labels, 1.0, 2.0, rects)[1] > 0


def test_chart_rects_refuse_another_layout():
    import pytest

    uv, labels, _ = _charts(5)
    with pytest.raises(ValueError, match="another UV layout"):
        widen_thin(uv[:-1], labels[:-1], 1.0, 2.0, ChartRects(uv))
