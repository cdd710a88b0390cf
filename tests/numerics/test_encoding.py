"""Quantizers of usdahd.numerics.encoding: hemi-octahedral directions, UNORM8/SNORM8, float16
scale."""

import numpy as np
import pytest

from usdahd.errors import InputError
from usdahd.numerics import encoding, sh


def _all_codes():
    c = np.arange(-128, 128, dtype=np.int16)
    return np.stack(np.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2).astype(np.int8)


def test_hemioct_roundtrip_unquantized_is_exact():
    d = sh.fibonacci_sphere(2000, hemisphere=True)
    back = encoding.hemioct_decode(encoding.hemioct_encode(d))
    np.testing.assert_allclose(back, d, atol=1e-6)  # float32 decode


def test_hemioct_z_is_exact_with_snorm():
    codes = encoding.encode_direction(np.array([0.0, 0.0, 1.0]))
    assert codes.tolist() == [0, 0]
    assert encoding.decode_direction(codes).tolist() == [0.0, 0.0, 1.0]


def test_hemioct_8bit_angular_error_bound():
    # Half a code step (1/127 in u and v) moves the octahedral point by <= 1/127 (L1); the
    # worst angle is near the horizon corners; bound measured ~0.56 deg, assert 1 deg.
    d = sh.fibonacci_sphere(20000, hemisphere=True)
    d = d[d[:, 2] > 1.0 / 127.0]
    back = encoding.decode_direction(encoding.encode_direction(d)).astype(np.float64)
    ang = np.degrees(np.arccos(np.clip(np.sum(back * d, -1), -1, 1)))
    assert ang.max() < 1.0


def test_every_clamped_code_decodes_dz_at_least_1_over_127():
    codes = _all_codes()
    # Codes are clamped at encode; simulate the encoder's clamp on all raw codes.
    clamped = np.clip(codes, -encoding.OCT_CODE_MAX, encoding.OCT_CODE_MAX)
    d = encoding.decode_direction(clamped)
    assert d[:, 2].min() >= 1.0 / 127.0
    # and the encoder never emits anything outside the clamp, even for horizon directions
    phi = np.linspace(0, 2 * np.pi, 721)
    horizon = np.stack([np.cos(phi), np.sin(phi), 0 * phi], -1)
    enc = encoding.encode_direction(horizon)
    assert np.abs(enc.astype(int)).max() <= encoding.OCT_CODE_MAX
    assert encoding.decode_direction(enc)[:, 2].min() >= 1.0 / 127.0


def test_unclamped_extreme_code_would_give_dz_zero():
    # why the clamp exists: code 127 decodes to d_z = 0 -> C_d = I_z (1 - w_a) / d_z = Inf
    d = encoding.decode_direction(np.array([127, 0], np.int8))
    assert d[2] == 0.0


def test_unorm8_and_snorm8_roundtrip_half_step():
    x = np.linspace(0, 1, 1001)
    err = np.abs(encoding.dequantize_unorm8(encoding.quantize_unorm8(x)) - x)
    assert err.max() <= 0.5 / 255 + 1e-7
    assert encoding.dequantize_unorm8(encoding.quantize_unorm8(np.array([0.0, 1.0]))).tolist() == [
        0.0,
        1.0,
    ]
    y = np.linspace(-1, 1, 1001)
    err = np.abs(encoding.dequantize_snorm8(encoding.quantize_snorm8(y)) - y)
    assert err.max() <= 0.5 / 127 + 1e-7
    assert encoding.dequantize_snorm8(np.array([-128, -127, 0, 127], np.int8)).tolist() == [
        -1.0,
        -1.0,
        0.0,
        1.0,
    ]


def test_half_prescale_above_float16_range():
    x = np.array([[1.0, 2.0, 3.0], [1e6, 5e5, 7e7]])
    h, s = encoding.encode_half(x)
    assert s > 1.0 and np.log2(s) == int(np.log2(s))  # power of two
    assert np.all(np.isfinite(h.astype(np.float32)))
    np.testing.assert_allclose(encoding.decode_half(h, s), x, rtol=1e-3)  # float16: 2^-11
    h1, s1 = encoding.encode_half(np.array([1.0, 60000.0]) * 0.5)
    assert s1 == 1.0
    # without the scale float16 overflows to inf
    with np.errstate(over="ignore"):
        assert np.isinf(np.float16(7e7))


def test_quantizers_reject_nan():
    with pytest.raises(InputError, match="NaN"):
        encoding.quantize_unorm8(np.array([np.nan]))
    with pytest.raises(InputError, match="NaN"):
        encoding.encode_direction(np.array([[np.inf, 0, 1]]))
    with pytest.raises(InputError, match="NaN"):
        encoding.encode_half(np.array([np.nan]))


def test_biased_snorm8_is_snorm8_plus_128_and_zero_is_exact():
    """Format version 2 stores signed codes biased in UNORM8: q = snorm + 128 (exhaustive)."""
    codes = np.arange(-128, 128).astype(np.int8)
    q = encoding.bias_snorm8(codes)
    assert q.dtype == np.uint8 and q.min() == 1 and q.max() == 255  # -128 is treated as -127
    np.testing.assert_array_equal(
        encoding.dequantize_snorm8_biased(q), encoding.dequantize_snorm8(codes)
    )
    assert encoding.dequantize_snorm8_biased(np.uint8(128)) == 0.0
    assert encoding.dequantize_snorm8_biased(np.uint8(0)) == -1.0
    x = np.linspace(-1, 1, 20001)
    err = np.abs(encoding.dequantize_snorm8_biased(encoding.quantize_snorm8_biased(x)) - x)
    assert err.max() <= 0.5 / 127 + 1e-7
    # directions: the same quantization as int8 codes, d = z exact, d_z >= 1/127 everywhere
    u, v = np.meshgrid(np.arange(256), np.arange(256))
    d = encoding.decode_direction_u8(np.stack([u, v], -1).astype(np.uint8).reshape(-1, 2))
    assert np.isfinite(d).all()
    z = encoding.encode_direction_u8(np.array([[0.0, 0.0, 1.0]]))
    assert z.tolist() == [[128, 128]]
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(5000, 3))
    dirs[:, 2] = np.abs(dirs[:, 2])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    q = encoding.encode_direction_u8(dirs)
    assert q.min() >= 2 and q.max() <= 254
    np.testing.assert_array_equal(q, encoding.bias_snorm8(encoding.encode_direction(dirs)))
    assert encoding.decode_direction_u8(q)[:, 2].min() >= 1 / 127
