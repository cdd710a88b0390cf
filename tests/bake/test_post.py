"""Post-processing: dilation, invalid-texel filling, SH frame rotation, seams."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd.bake import post
from usdahd.bake import texels as tx
from usdahd.errors import InputError, UsageError
from usdahd.numerics import sh

RNG = np.random.default_rng(5)
QUAD_PTS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)


def two_chart_plane(res=(40, 40)):
    """A flat 2 x 1 plane cut into two UV charts along x = 1; the right chart is rotated 90
    degrees in UV (so the two sides' tangent frames differ)."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    tri = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    p = pts[tri]
    uv = np.zeros((4, 3, 2))
    uv[:2] = np.stack([0.05 + 0.4 * p[:2, ..., 0], 0.1 + 0.4 * p[:2, ..., 1]], -1)
    uv[2:] = np.stack([0.55 + 0.4 * p[2:, ..., 1], 0.1 + 0.4 * (2 - p[2:, ..., 0])], -1)
    mesh = tx.mesh_from_arrays(pts, tri, uv=uv)
    return mesh, tx.rasterize(mesh, res)


# ------------------------------------------------------------------------------ dilation


def test_dilate_fills_gutter_without_changing_valid_texels():
    mesh = tx.mesh_from_arrays(QUAD_PTS, [[0, 1, 2], [0, 2, 3]], uv=QUAD_PTS[:, :2] * 0.5 + 0.25)
    t = tx.rasterize(mesh, (16, 16))
    values = RNG.uniform(1, 2, (len(t), 3)).astype(np.float32)
    img = post.to_image(t, values)
    mask = post.coverage_mask(t)
    out, grown = post.dilate(img, mask, 2, return_mask=True)
    assert np.array_equal(out[mask], img[mask])
    # exactly the texels within Chebyshev distance 2 of the chart are filled
    ys, xs = np.nonzero(mask)
    Y, X = np.mgrid[:16, :16]
    dist = np.full((16, 16), 99)
    for y, x in zip(ys, xs):
        dist = np.minimum(dist, np.maximum(abs(Y - y), abs(X - x)))
    assert np.array_equal(grown, dist <= 2)
    assert (out[grown].min(axis=-1) >= 1.0).all() and (out[~grown] == 0).all()
    # filled values are means of neighbours, so stay within the valid range
    assert out[grown].max() <= values.max()
    # first ring: a texel with exactly one valid neighbour copies it
    full = post.dilate(img, mask, None)
    assert (full.min(axis=-1) >= 1.0).all()
    assert np.array_equal(post.from_image(t, full), values)


def test_dilate_respects_labels_and_integer_dtypes():
    img = np.zeros((1, 6), np.uint8)
    img[0, 0], img[0, 5] = 10, 200
    mask = np.array([[True, False, False, False, False, True]])
    labels = np.array([[0, 0, 0, 1, 1, 1]])
    out = post.dilate(img, mask, None, labels=labels)
    assert out.dtype == np.uint8
    assert list(out[0]) == [10, 10, 10, 200, 200, 200]
    with pytest.raises(UsageError, match="width"):
        post.dilate(img, mask, -1)


# ------------------------------------------------------------------------------ invalid fill


def test_fill_invalid_stays_in_chart():
    mesh, t = two_chart_plane()
    charts = tx.chart_ids(mesh)[t.triangle]
    values = np.where(charts[:, None, None] == 0, 1.0, 5.0) * np.ones((len(t), 3, 9))
    invalid = RNG.random(len(t)) < 0.4
    filled, unfilled = post.fill_invalid(values, t, invalid, charts=charts)
    assert not unfilled.any()
    assert np.array_equal(filled[~invalid], values[~invalid])
    np.testing.assert_array_equal(filled, values)  # each chart only sees its own constant
    # a fully invalid chart cannot be reached across the gutter: flagged, values kept
    invalid = charts == 1
    filled, unfilled = post.fill_invalid(values, t, invalid, charts=charts)
    assert np.array_equal(unfilled, invalid) and np.array_equal(filled, values)


def test_fill_invalid_reports_unreachable():
    mesh, t = two_chart_plane()
    charts = tx.chart_ids(mesh)[t.triangle]
    values = np.ones((len(t), 2))
    filled, unfilled = post.fill_invalid(values * 0, t, np.ones(len(t), bool), charts=charts)
    assert unfilled.all()
    with pytest.raises(InputError):
        post.fill_invalid(values, t, np.ones(3, bool))


# ------------------------------------------------------------------------------ SH frames


def test_sh_frame_matrices_rotate_functions_exactly():
    frames = np.linalg.qr(RNG.standard_normal((6, 3, 3)))[0]  # proper and improper
    local = RNG.standard_normal((6, 3, 9))
    m = post.sh_frame_matrices(frames)
    world = np.einsum("nab,ncb->nca", m, local)
    dirs, _ = sh.sphere_quadrature(8)
    for i in range(6):
        np.testing.assert_allclose(
            sh.basis(dirs) @ world[i].T, sh.basis(dirs @ frames[i].T) @ local[i].T, atol=1e-12
        )
    np.testing.assert_allclose(
        np.einsum("nab,nac->nbc", m, m), np.broadcast_to(np.eye(9), m.shape), atol=1e-12
    )


# ------------------------------------------------------------------------------ seams


def test_seam_on_split_plane_found_and_stitched():
    mesh, t = two_chart_plane()
    seams = post.find_seams(mesh, t.resolution)
    assert seams.edges == 1  # the cut at x = 1 (both triangles' edge)
    assert len(seams) == 2 * 16  # 16 texels long, 2 samples per texel
    np.testing.assert_allclose(seams.position[:, 0], 1.0, atol=1e-12)
    # a world-space-constant radiance expressed in each texel's own frame agrees already
    world = RNG.standard_normal((3, 9))
    m = post.sh_frame_matrices(t.frame)
    consistent = np.einsum("nba,cb->nca", m, world)  # M^T: world -> tangent
    assert np.abs(post.seam_mismatch(consistent, t, seams)).max() < 1e-5
    # random values disagree; stitching makes them agree and touches only seam texels
    values = RNG.standard_normal((len(t), 3, 9)).astype(np.float32)
    before = np.sqrt((post.seam_mismatch(values, t, seams) ** 2).mean())
    out = post.stitch(values, t, seams)
    after = np.sqrt((post.seam_mismatch(out, t, seams) ** 2).mean())
    assert before > 0.5 and after < 0.01 * before
    changed = np.abs(out - values).max(axis=(1, 2)) > 0
    cols = post.texel_index(t, seams.taps.reshape(-1, 2))
    assert set(np.nonzero(changed)[0]) <= set(cols[cols >= 0])
    # stitching twice changes little more (already consistent)
    again = post.stitch(out, t, seams)
    assert np.abs(again - out).max() < 0.05


def test_stitch_is_the_least_squares_minimiser():
    """stitch solves min sum_s (A_s x - B_s x)^2 + w sum (x - x0)^2 exactly: checked against
    numpy's dense least squares on the stacked system, built here from the seam taps."""
    mesh, t = two_chart_plane((24, 24))
    seams = post.find_seams(mesh, t.resolution)
    values = RNG.standard_normal((len(t), 2))
    weight = 0.01
    out = post.stitch(values, t, seams, data_weight=weight)
    idx = post.texel_index(t, seams.taps.reshape(-1, 2)).reshape(len(seams), 2, 4)
    w = np.where(idx >= 0, seams.weights, 0.0)
    w /= w.sum(axis=2, keepdims=True)
    rows = np.zeros((len(seams), len(t)))
    for side, sign in ((0, 1.0), (1, -1.0)):
        for k in range(4):
            np.add.at(rows, (np.arange(len(seams)), np.maximum(idx[:, side, k], 0)),
                      sign * np.where(idx[:, side, k] >= 0, w[:, side, k], 0.0))  # fmt: skip
    a = np.vstack([rows, np.sqrt(weight) * np.eye(len(t))])
    b = np.vstack([np.zeros((len(seams), 2)), np.sqrt(weight) * values])
    want = np.linalg.lstsq(a, b, rcond=None)[0]
    np.testing.assert_allclose(out, want, atol=1e-9)


def _bent_two_chart_strip(res=(48, 48)):
    """A strip bent around a cylinder (radius 1, 2 x 1 units), cut into two UV charts at its
    middle, the second chart rotated 90 degrees in UV; smooth (cylinder) normals."""
    n = 8
    ang = np.linspace(0.0, 2.0, 2 * n + 1)
    pts = np.concatenate(
        [np.stack([np.sin(ang), np.zeros_like(ang), np.cos(ang)], 1),
         np.stack([np.sin(ang), np.ones_like(ang), np.cos(ang)], 1)]
    )  # fmt: skip
    nrm = pts * np.array([1.0, 0.0, 1.0])
    tri, uv = [], []
    for i in range(2 * n):
        a, b, c, d = i, i + 1, 2 * n + 2 + i, 2 * n + 1 + i
        for t in ((a, b, c), (a, c, d)):
            s, h = ang[np.array(t) % (2 * n + 1)], (np.array(t) > 2 * n).astype(float)
            if i < n:
                uv.append(np.stack([0.05 + 0.4 * s, 0.1 + 0.4 * h], 1))
            else:
                uv.append(np.stack([0.55 + 0.4 * h, 0.1 + 0.4 * (2.0 - s)], 1))
            tri.append(t)
    mesh = tx.mesh_from_arrays(pts, np.array(tri), uv=np.array(uv), normals=nrm)
    return mesh, tx.rasterize(mesh, res)


def test_stitched_iz_agrees_as_stored_on_a_curved_seam():
    """A viewer interpolates the stored (tangent-frame) coefficients: across a seam of a
    curved surface the stored Y10 (I_z) and Y20 lookups must agree, not only the world-space
    SH (which agree with each texel's own normal mixed in)."""
    mesh, t = _bent_two_chart_strip()
    seams = post.find_seams(mesh, t.resolution)
    assert seams.edges == 1  # the cut across the strip at its middle
    # one radiance field everywhere (a sky brighter towards +x), in each texel's own frame:
    # world-space lookups agree already, stored I_z lookups do not (the normals turn)
    world = np.zeros((3, 9))
    world[:, 0], world[:, 3], world[:, 8] = 1.0, -0.6, 0.2
    m = post.sh_frame_matrices(t.frame)
    values = np.einsum("nba,cb->nca", m, world)  # M^T: world -> tangent
    assert np.abs(post.seam_mismatch(values, t, seams)).max() < 1e-6
    out = post.stitch(values, t, seams)
    for k in post.LOCAL_COEFFS:
        before = np.abs(post.seam_mismatch(values[:, :, k], t, seams, rotate=False)).mean()
        after = np.abs(post.seam_mismatch(out[:, :, k], t, seams, rotate=False)).mean()
        assert before > 1e-3 and after < 0.1 * before, (k, before, after)
    # what stays world-space (the direction of the light in the tangent plane) stays close
    assert np.abs(post.seam_mismatch(out, t, seams)).mean() < 0.05


def _cube(smooth):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("xatlas")
    from usdahd.bake.unwrap import unwrap

    m = trimesh.creation.box()
    if smooth:
        nrm = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
        mesh = tx.mesh_from_arrays(m.vertices, m.faces, normals=nrm)
    else:
        mesh = tx.mesh_from_arrays(m.vertices, m.faces)
    mesh.uv, res = unwrap(mesh, texels_per_unit=16.0, isolate=False)
    return mesh, res


def test_cube_seams_pairs_and_stitch():
    mesh, res = _cube(smooth=True)
    t = tx.rasterize(mesh, res)
    seams = post.find_seams(mesh, res)
    assert seams.edges == 12  # xatlas cuts the cube at every edge (one chart per face)
    # both sides' bilinear lookups are taken next to the same 3-D point
    for side in range(2):
        idx = post.texel_index(t, seams.taps[:, side])
        w = np.where(idx >= 0, seams.weights[:, side], 0.0)
        w /= w.sum(axis=1, keepdims=True)
        p = np.einsum("sk,ski->si", w, t.position[np.maximum(idx, 0)])
        assert np.linalg.norm(p - seams.position, axis=1).max() < 1.5 / 16.0
    values = RNG.standard_normal((len(t), 3, 9)).astype(np.float32)
    before = np.abs(post.seam_mismatch(values, t, seams)).mean()
    out = post.stitch(values, t, seams)
    after = np.abs(post.seam_mismatch(out, t, seams)).mean()
    assert after < 0.05 * before


def test_hard_creases_are_not_seams_unless_asked():
    mesh, res = _cube(smooth=False)
    assert post.find_seams(mesh, res).edges == 0
    assert post.find_seams(mesh, res, max_normal_angle=180.0).edges == 12


def test_seams_across_meshes():
    mesh, _ = two_chart_plane()
    left = tx.mesh_from_arrays(mesh.points, mesh.triangles[:2], uv=mesh.uv[:2], path="/L")
    right = tx.mesh_from_arrays(mesh.points, mesh.triangles[2:], uv=mesh.uv[2:], path="/R")
    res = [(40, 40), (24, 24)]
    ts = [tx.rasterize(left, res[0]), tx.rasterize(right, res[1])]
    seams = post.find_seams([left, right], res)
    assert seams.edges == 1 and set(map(tuple, seams.mesh)) == {(0, 1)}
    values = [RNG.standard_normal((len(t), 3, 9)) for t in ts]
    before = np.abs(post.seam_mismatch(values, ts, seams)).mean()
    out = post.stitch(values, ts, seams)
    assert isinstance(out, list) and len(out) == 2
    assert np.abs(post.seam_mismatch(out, ts, seams)).mean() < 0.02 * before
    with pytest.raises(InputError, match="seams were found for 2 meshes"):
        post.stitch(values[:1], ts[:1], seams)


def test_generic_arrays_stitch_without_rotation():
    mesh, t = two_chart_plane()
    seams = post.find_seams(mesh, t.resolution)
    values = RNG.standard_normal((len(t), 4))
    out = post.stitch(values, t, seams)
    assert out.shape == values.shape
    assert (
        np.abs(post.seam_mismatch(out, t, seams)).mean()
        < 0.02 * np.abs(post.seam_mismatch(values, t, seams)).mean()
    )
    with pytest.raises(InputError, match="rotate=True"):
        post.stitch(values, t, seams, rotate=True)


# Denoising (usdahd.bake.denoise) is tested in tests/bake/test_denoise.py.
