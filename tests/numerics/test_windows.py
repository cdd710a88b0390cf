"""usdahd/numerics/windows.py and the second-difference kernel of usdahd/numerics/noise.py:
each numba kernel returns its numpy reference's numbers bit for bit (the same arithmetic in
the same order), on chart-like masks with holes, borders, one-texel rows and NaN outside."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd.numerics import noise, windows

SHAPES = [(1, 1, 1), (1, 9, 3), (7, 1, 2), (5, 6, 27), (23, 31, 6), (40, 17, 3)]


def _chart(shape, seed):
    """A random (h, w, c) image (heavy-tailed, as Monte Carlo radiance) and a mask with holes;
    NaN outside the mask (what a canvas holds there)."""
    rng = np.random.default_rng(seed)
    img = rng.standard_normal(shape) * rng.exponential(size=shape)
    mask = rng.random(shape[:2]) < 0.75
    mask.flat[0] = True
    img[~mask] = np.nan
    return img, mask


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("radius", [0, 1, 2, 5])
def test_box_mean_kernel_is_the_reference_bit_for_bit(shape, radius):
    img, mask = _chart(shape, seed=shape[0] * 31 + shape[1] + radius)
    fast = windows.box_mean(img, mask, radius)
    ref = windows.box_mean(img, mask, radius, backend="numpy")
    assert fast.shape == ref.shape == shape and fast.dtype == np.float64
    np.testing.assert_array_equal(fast, ref)


def test_box_mean_is_the_mean_of_the_mask_texels_in_each_window():
    """The definition, texel by texel (a brute-force loop), to summed-area-table rounding."""
    img, mask = _chart((9, 12, 2), seed=3)
    r = 2
    out = windows.box_mean(img, mask, r)
    for y in range(9):
        for x in range(12):
            win = mask[max(y - r, 0) : y + r + 1, max(x - r, 0) : x + r + 1]
            vals = img[max(y - r, 0) : y + r + 1, max(x - r, 0) : x + r + 1][win]
            want = vals.mean(axis=0) if len(vals) else np.zeros(2)
            np.testing.assert_allclose(out[y, x], want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("shape", SHAPES)
def test_neighbour_mean_kernel_is_the_reference_bit_for_bit(shape):
    rng = np.random.default_rng(shape[0] + 7 * shape[1])
    tiles = rng.exponential(size=shape)
    valid = rng.random(shape) < 0.6
    tiles[~valid] = np.nan  # the medians of empty tiles
    fallback = rng.exponential(size=shape[-1])
    fast = windows.neighbour_mean(tiles, valid, fallback)
    ref = windows.neighbour_mean(tiles, valid, fallback, backend="numpy")
    np.testing.assert_array_equal(fast, ref)
    # a tile with no valid neighbour takes the fallback
    none = windows.neighbour_mean(tiles, np.zeros(shape, bool), fallback)
    np.testing.assert_array_equal(none, np.broadcast_to(fallback, shape))


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("directions, fill", [(4, np.nan), (2, 0.0), (1, -1.0)])
def test_second_differences_kernel_is_the_reference_bit_for_bit(shape, directions, fill):
    img, mask = _chart(shape, seed=shape[0] * 13 + shape[1])
    support = mask & (np.random.default_rng(1).random(shape[:2]) < 0.9)
    fast = noise.second_differences(img, support, directions, fill)
    ref = noise.second_differences(img, support, directions, fill, backend="numpy")
    assert fast.shape == (*shape[:2], directions, shape[2])
    np.testing.assert_array_equal(fast, ref)


def test_second_differences_read_non_finite_values_as_nan_to_num():
    img = np.zeros((1, 3, 1))
    img[0, 1, 0] = np.nan  # read as 0
    assert noise.second_differences(img, np.ones((1, 3), bool), 1)[0, 1, 0, 0] == 0.0
    img[0, 1, 0] = np.inf  # read as the largest float: its square overflows, as the reference
    fast = noise.second_differences(img, np.ones((1, 3), bool), 1)
    with np.errstate(over="ignore"):
        ref = noise.second_differences(img, np.ones((1, 3), bool), 1, backend="numpy")
    np.testing.assert_array_equal(fast, ref)


@pytest.mark.parametrize(
    "call",
    [
        lambda: windows.box_mean(np.zeros((2, 2, 1)), np.ones((2, 2), bool), 1, backend="cuda"),
        lambda: windows.neighbour_mean(
            np.zeros((1, 1, 1)), np.ones((1, 1, 1), bool), np.zeros(1), backend="cuda"
        ),  # fmt: skip
        lambda: noise.second_differences(
            np.zeros((2, 2, 1)), np.ones((2, 2), bool), backend="cuda"
        ),  # fmt: skip
    ],
)
def test_an_unknown_backend_is_refused(call):
    with pytest.raises(ValueError, match="backend"):
        call()


@pytest.mark.parametrize("shape, channels", [((1, 1), 1), ((5, 6), 21), ((23, 31), 3)])
@pytest.mark.parametrize("radius", [1, 2])
def test_box_mean_texels_is_the_canvas_box_mean_bit_for_bit(shape, channels, radius, monkeypatch):
    """Per-texel values in, per-texel means out: the same numbers as the canvas route
    (float32 canvas, ``box_mean``, gathered), in one block of channels or in several."""
    rng = np.random.default_rng(shape[0] + channels + radius)
    mask = rng.random(shape) < 0.7
    mask.flat[0] = True
    ly, lx = np.nonzero(mask)
    values = rng.exponential(size=(len(ly), channels)) * 1e3  # not float32-exact
    ref = windows.box_mean_texels(values, ly, lx, shape, radius, backend="numpy")
    canvas = np.full((*shape, channels), np.nan, np.float32)
    canvas[ly, lx] = values
    direct = windows.box_mean(np.nan_to_num(canvas.astype(np.float64)), mask, radius)[ly, lx]
    np.testing.assert_array_equal(ref, direct)
    np.testing.assert_array_equal(windows.box_mean_texels(values, ly, lx, shape, radius), ref)
    monkeypatch.setattr(windows, "_WORK_ELEMENTS", 1)  # one channel per block
    np.testing.assert_array_equal(windows.box_mean_texels(values, ly, lx, shape, radius), ref)


@pytest.mark.parametrize("shape, channels", [((1, 1), 1), ((2, 9), 6), ((23, 31), 6)])
def test_bends_kernel_is_the_canvas_route_bit_for_bit(shape, channels):
    """``noise.bends`` (the denoiser's curvature test): a texel bends where some channel's
    squared second difference in any direction exceeds factor x its variance; the kernel
    equals the canvas route (float32 canvases, 4-direction second differences, maxima)."""
    rng = np.random.default_rng(shape[1] + channels)
    mask = rng.random(shape) < 0.8
    mask.flat[0] = True
    ly, lx = np.nonzero(mask)
    values = rng.exponential(size=(len(ly), channels)) * 1e3
    variance = rng.exponential(1e4, size=(len(ly), channels))
    variance[rng.random(variance.shape) < 0.1] = 0.0  # noise free: any curvature bends
    ref = noise.bends(values, variance, ly, lx, shape, 24.0, backend="numpy")
    fast = noise.bends(values, variance, ly, lx, shape, 24.0)
    assert fast.dtype == bool and fast.shape == shape
    np.testing.assert_array_equal(fast, ref)
    assert not fast[~mask].any()
    if shape == (23, 31):
        assert 0 < fast.sum() < mask.sum()  # the case is not trivial
    with pytest.raises(ValueError, match="backend"):
        noise.bends(values, variance, ly, lx, shape, 24.0, backend="cuda")
