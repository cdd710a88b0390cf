"""usdahd.models.irradz.kernel.fit, the numba IrradZ fitter: a uniform sky against its closed-
form SH, round trips through the numpy forward model (reference.model_sh), bad texels, shapes
and the usage errors it raises before any work."""

from __future__ import annotations

import math

import numpy as np
import pytest

from usdahd.errors import InputError, UsageError
from usdahd.models.irradz import reference
from usdahd.models.irradz.kernel import fit
from usdahd.numerics import sh as shm

KINDS = ("ahd", "hhd", "hlsh")


def _uniform_sky(level):
    """Radiance SH (3, 9) of a constant radiance ``level`` (RGB) over the upper hemisphere,
    in closed form: the hemisphere integrals of Y_0^0 = 1 / (2 sqrt(pi)) and
    Y_1^0 = sqrt(3 / (4 pi)) z are sqrt(pi) and sqrt(3 pi) / 2; every other band-2 function
    integrates to 0 over it (odd in x or y, or 3 z^2 - 1 with mean 0)."""
    out = np.zeros((3, 9))
    out[:, 0] = np.asarray(level) * math.sqrt(math.pi)
    out[:, 2] = np.asarray(level) * math.sqrt(3 * math.pi) / 2
    return out


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("ratio", ["luminance", "rgb"])
def test_uniform_sky_gives_its_radiance_as_iz_and_a_vertical_direction(kind, ratio):
    """A constant radiance L over the hemisphere has normalised irradiance I_z = L exactly
    (E_z = pi L), and by symmetry no azimuth: the direction is +z."""
    level = np.array([0.3, 0.6, 1.2])
    out = fit(_uniform_sky(level), kind, ratio=ratio, solver=reference.SOLVERS[kind][0])
    np.testing.assert_allclose(out["iz"], level, rtol=1e-6)
    np.testing.assert_allclose(out["direction"], [0, 0, 1], atol=1e-5)
    assert out["invalid"].tolist() == [0.0]
    assert out["ambient_ratio"].shape == ((3,) if ratio == "rgb" else (1,))


def _params(n, rng):
    """Representable IrradZ parameters: I_z > 0, directions well above the horizon, w_a in
    (0.1, 0.9), one w_a for all channels (luminance ratio)."""
    phi = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(0.5, 0.95, n)
    s = np.sqrt(1 - z * z)
    d = np.stack([s * np.cos(phi), s * np.sin(phi), z], 1)
    return {
        "iz": rng.uniform(0.2, 2.0, (n, 3)),
        "direction": d,
        "ambient_ratio": rng.uniform(0.1, 0.9, (n, 1)),
    }


@pytest.mark.parametrize("solver", ["golden", "golden_phi", "direct"])
def test_round_trip_through_the_numpy_forward_model(solver):
    """HHD (hemispherical ambient: its model radiance is zero below the horizon, as the fit
    assumes): SH made by the numpy twin's forward model (reference.model_sh: irradiance SH;
    radiance = irradiance / the cosine lobe's band factors) is fitted back to its own
    parameters, with an SH-domain error at float32 level."""
    kind = "hhd"
    rng = np.random.default_rng(38)
    p = _params(64, rng)
    radiance = reference.model_sh(kind, p) / shm.COSINE_FACTORS
    out = fit(radiance, kind, solver=solver)
    np.testing.assert_allclose(out["iz"], p["iz"], rtol=1e-5)
    np.testing.assert_allclose(out["direction"], p["direction"], atol=2e-3)
    np.testing.assert_allclose(out["ambient_ratio"], p["ambient_ratio"], atol=2e-3)
    err = reference.sh_error(kind, radiance, out)
    scale = reference.sh_error(kind, radiance, {**out, "iz": np.zeros_like(out["iz"])})
    assert (err <= 1e-6 * scale).all()


def test_bad_texels_are_flagged_and_output_black():
    sh = np.stack([_uniform_sky([1, 1, 1])] * 3)
    sh[1, 0, 4] = np.nan
    sh[2, 2, 0] = np.inf
    out = fit(sh, "hhd")
    assert out["invalid"][:, 0].tolist() == [0.0, 1.0, 1.0]
    np.testing.assert_array_equal(out["iz"][1:], 0.0)
    np.testing.assert_array_equal(out["ambient_ratio"][1:], 1.0)
    np.testing.assert_array_equal(out["direction"][1:], [[0, 0, 1]] * 2)


def test_leading_dimensions_and_dtypes():
    sh = np.broadcast_to(_uniform_sky([0.5, 0.5, 0.5]), (2, 5, 3, 9))
    out = fit(sh.astype(np.float32), "ahd", ratio="rgb")
    assert out["iz"].shape == (2, 5, 3) and out["direction"].shape == (2, 5, 3)
    assert out["ambient_ratio"].shape == (2, 5, 3) and out["invalid"].shape == (2, 5, 1)
    assert all(v.dtype == np.float32 for v in out.values())
    empty = fit(np.zeros((0, 3, 9)), "hhd")
    assert empty["iz"].shape == (0, 3)


@pytest.mark.parametrize(
    "args, kwargs, error, message",
    [
        (("hhx",), {}, UsageError, "unknown IrradZ model 'hhx'; choose one of ahd, hhd, hlsh"),
        (("hhd",), {"ratio": "rgbx"}, UsageError, "ratio must be 'luminance' or 'rgb'"),
        (("hhd",), {"solver": "newton"}, UsageError, "newton"),
        (("hhd",), {"tolerance": 1e-3}, UsageError, "unknown fit option(s) for hhd: tolerance"),
        (("hhd",), {"objective": "chroma"}, UsageError, "objective must be"),
        (("hhd",), {"ratio": "rgb", "objective": "luminance"}, UsageError, "always 'rgb'"),
        (("hlsh",), {"solver": "direct", "objective": "rgb"}, UsageError, "needs solver golden"),
        (("hlsh",), {"solver": "golden"}, UsageError, "model 'hlsh' has solvers direct"),
    ],
)
def test_usage_errors(args, kwargs, error, message):
    with pytest.raises(error) as exc:
        fit(np.zeros((1, 3, 9)), *args, **kwargs)
    assert message in str(exc.value)


def test_input_errors_name_the_shape_or_dtype():
    with pytest.raises(InputError, match=r"shape \(\.\.\., 3, 9\).*got \(4, 9\)"):
        fit(np.zeros((4, 9)), "hhd")
    with pytest.raises(InputError, match="real floating-point array, got dtype complex128"):
        fit(np.zeros((1, 3, 9), complex), "hhd")
