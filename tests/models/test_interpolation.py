"""The 2018 paper's Figure 2: bilinear filtering of stored channels between two texels.

Left texel: a unit directional light tilted towards -x; right texel: a zero-intensity light
tilted towards +x. Irradiance in local z should vary linearly between them. Interpolating
classic AHD (C_a, d, C_d) overshoots, because the interpolated direction swings back to z and
the colour does not shrink with it; IrradZ (I_z, d, w_a) interpolates I_z itself, so I(z) is
linear by construction. Filtering is done as a GPU does it: on the stored channel values
(normalized to floats), then decoded.
"""

import numpy as np
import pytest

from usdahd import models

TILT = np.radians(60.0)
D_LEFT = np.array([-np.sin(TILT), 0.0, np.cos(TILT)])
D_RIGHT = np.array([np.sin(TILT), 0.0, np.cos(TILT)])
T = np.linspace(0.0, 1.0, 11)
Z = np.array([0.0, 0.0, 1.0])


def _lerp_channels(channels):
    """Texture filtering between texel 0 and texel 1 at each t, on the stored values."""
    out = {}
    for role, v in channels.items():
        v = np.asarray(v)
        f = v.astype(np.float64)
        mixed = (1 - T)[:, None] * f[0] + T[:, None] * f[1]
        out[role] = mixed.astype(np.float32) if v.dtype.kind == "f" else mixed
    return out


def _iz_along(model, params, ratio):
    mod = models.get(model)
    channels, factors = mod.encode(params, ratio=ratio)
    dec = mod.decode(_lerp_channels(channels), ratio=ratio, factors=factors)
    return mod.evaluate(dec, np.broadcast_to(Z, (len(T), 3)))[:, 0]


def test_classic_ahd_overshoots_between_opposite_tilted_texels():
    params = {
        "ambient": np.zeros((2, 3), np.float32),
        "direction": np.stack([D_LEFT, D_RIGHT]).astype(np.float32),
        "directional": np.array([[1, 1, 1], [0, 0, 0]], np.float32),
        "invalid": np.zeros((2, 1), np.float32),
    }
    got = _iz_along("ahd_classic", params, "none")
    linear = (1 - T) * np.cos(TILT)  # the true irradiance in z, linear in t
    # At texel centres classic AHD is off only by its 8-bit direction (~1 % at 60 degrees).
    np.testing.assert_allclose(got[[0, -1]], linear[[0, -1]], rtol=2e-2, atol=1e-6)
    # Half-way the direction has swung back to z: I(z) ~ 0.5 instead of 0.25.
    assert got[5] > 1.6 * linear[5]
    assert (got[1:-1] > linear[1:-1] + 1e-3).all()


@pytest.mark.parametrize("model", ["ahd", "hhd"])
def test_irradz_is_linear_in_iz_between_the_same_texels(model):
    iz = np.array([[1, 1, 1], [0, 0, 0]], np.float32) * np.float32(np.cos(TILT))
    params = {
        "iz": iz,
        "direction": np.stack([D_LEFT, D_RIGHT]).astype(np.float32),
        "ambient_ratio": np.zeros((2, 1), np.float32),
        "invalid": np.zeros((2, 1), np.float32),
    }
    got = _iz_along(model, params, "luminance")
    linear = (1 - T) * np.cos(TILT)
    # float16 storage of I_z is the only error: 2^-11 relative.
    np.testing.assert_allclose(got, linear, rtol=1e-3, atol=1e-6)
