"""IrradZ AHD: I(n) = C_a + max(0, n.d) C_d (Sloan & Silvennoinen 2018).

C_a = I_z w_a, C_d = I_z (1 - w_a) / d_z, so I(z) = I_z exactly. Parameters, solvers, stability
measures and texture layout: see :mod:`usdahd.models._irradz` and docs/models.md.
"""

from __future__ import annotations

from usdahd.models import _irradz

NAME = "ahd"
RATIOS = ("luminance", "rgb")
SOLVERS = _irradz.SOLVERS[NAME]
DEFAULT_SOLVER = "golden"
PARAMS = ("iz", "direction", "ambient_ratio", "invalid")


def fit(sh, *, ratio="luminance", solver=DEFAULT_SOLVER, **options):
    """sh : (..., 3, 9) radiance SH -> float32 params iz (...,3), direction (...,3),
    ambient_ratio (...,1|3), invalid (...,1)."""
    return _irradz.fit(sh, NAME, ratio=ratio, solver=solver, **options)


def evaluate(params, normals, *, albedo=None):
    """Normalized irradiance (..., 3) at tangent-space unit normals (..., 3)."""
    return _irradz.evaluate(NAME, params, normals, albedo=albedo)


def layout(ratio="luminance"):
    return _irradz.layout(NAME, ratio)


def encode(params, *, ratio="luminance"):
    return _irradz.encode(NAME, params, ratio=ratio)


def decode(channels, *, ratio="luminance", factors=None):
    return _irradz.decode(NAME, channels, ratio=ratio, factors=factors or {})
