"""The IrradZ lighting models (AHD, HHD, HLSH): fit, evaluate, encode, decode.

Registry rows (``usdahd.models.REGISTRY``): :data:`AHD`, :data:`HHD`, :data:`HLSH`, each an
:class:`IrradZModel` with the model-module interface of :mod:`usdahd.models.base`.
Code: :mod:`.reference` (numpy constants, formulas, direct solves, evaluate),
:mod:`.kernel` (numba fit kernels with named rows, and :func:`fit`), :mod:`.codec` (texture
layout, encode, **decode**).

IrradZ parameters per texel (Sloan & Silvennoinen 2018; Roughton et al. 2024 §2.2):
``iz`` (n, 3) irradiance in local z, ``direction`` d (n, 3) unit with d_z >= 1/127, and the
ambient ratio ``ambient_ratio`` w_a, (n, 1) (``ratio="luminance"``) or (n, 3) (``"rgb"``).
The model colours are ``C_a = I_z w_a`` and ``C_d = I_z (1 - w_a) / d_z`` so that
``I(z) = I_z`` exactly for every w_a, in every channel.

- AHD:  I(n) = C_a + max(0, n.d) C_d
- HHD:  I(n) = (n_z + 1)/2 C_a + max(0, n.d) C_d        (2024 Eq 6)
- HLSH: I(n) = C_a + (n.d) C_d, w_a unconstrained       (2024 Eq 12)

Solvers (each documented with cost and error in docs/models.md):

``golden``       2024 §4.2: golden-section search for d_z along the optimal-linear phi, with the
                 closed-form ratio (Eq 33) at every step, hemispherical Gram error; a final
                 parabolic step; texels searched in lockstep blocks (see _search_block).
``golden_phi``   the same with an outer golden-section search on phi.
``2018_sphere``  2018 Eq 9-12: optimal linear direction, colours on the null-space line of the
                 I_z constraint, t clamped to [t_min, t_max]; E(t) is quadratic, so closed form;
                 spherical (identity Gram) error.
``2018_hemi``    the same with the hemispherical Gram error.
``direct``       HHD from linear SH (2024 Eq 7-11 with the corrected Eq 10 and 56), HLSH by the
                 IrradZ-constrained least squares (Eq 19-22, corrected G_BY signs, Eq 20 over
                 Omega+).

ratio="luminance" takes the option objective="luminance" (default: d and the one w_a fit the
luminance signal) or "rgb" (they minimise the summed RGB error; golden, golden_phi, direct).

Numerical safeguards (each tested): per-texel normalisation by max |coefficient|; the ratio is
solved as C_d (equivalently c = C_d / I_z, bounded by 1/d_z) rather than in the literal Eq 31-33
form whose terms grow like 1/d_z^2; non-finite input -> black output and ``invalid = 1``;
I_z <= IZ_TINY (relative) -> w_a = 1, d = z; I_z < 0 -> 0; d_z >= DZ_FLOOR;
w_a >= WA_ONE -> d = z.

The fitted parameters are float32 ``iz``, ``direction``, ``ambient_ratio`` and ``invalid``
((n, 1), 1.0 where the input texel held NaN/Inf and was output black).
"""

from __future__ import annotations

from usdahd.models.irradz.codec import HLSH_RATIO_SCALE_MAX, decode, encode, layout
from usdahd.models.irradz.kernel import (  # noqa: F401  (tests reach the kernels here)
    BLK_ROWS,
    BLOCK,
    dir_error,
    fit,
    line_coeffs,
    line_error,
)
from usdahd.models.irradz.reference import (  # noqa: F401  (public constants and formulas)
    AMB_AHD,
    AMB_HHD,
    B_Z,
    DZ_FLOOR,
    G_B_SCALE,
    G_BY,
    GRAM_I,
    GRAM_J,
    GRAM_PAIRS,
    IZ_FROM_L10,
    IZ_TINY,
    KINDS,
    SOLVERS,
    WA_ONE,
    ambient_sh,
    c_bounded,
    colors,
    directional_sh,
    evaluate,
    expand,
    gram_hemi,
    hhd_direct_linear,
    hlsh_direct,
    linear_sh,
    model_sh,
    nullspace_bounds,
    nullspace_colors,
    sh_error,
    sparse_gram,
    wa_bounded,
    wa_literal,
)

__all__ = ["RATIO_RANGE", "SOLVERS", "colors", "expand", "fit"]

#: The ambient ratio range w_a of each model: [0, 1], except HLSH whose stored w_a is
#: clamped to +-HLSH_RATIO_SCALE_MAX (usdahd.validate's RatioRange).
RATIO_RANGE = {
    "ahd": (0.0, 1.0),
    "hhd": (0.0, 1.0),
    "hlsh": (-HLSH_RATIO_SCALE_MAX, HLSH_RATIO_SCALE_MAX),
}


class IrradZModel:
    """One IrradZ model as a registry row: the interface of :mod:`usdahd.models.base`
    (NAME, RATIOS, SOLVERS, DEFAULT_SOLVER, fit, evaluate, layout, encode, decode)."""

    RATIOS = ("luminance", "rgb")

    def __init__(self, name: str, default_solver: str, doc: str):
        self.NAME = name
        self.SOLVERS = SOLVERS[name]
        self.DEFAULT_SOLVER = default_solver
        self.__doc__ = doc

    def __repr__(self) -> str:
        return f"<IrradZ model {self.NAME!r}>"

    def fit(self, sh, *, ratio="luminance", solver=None, **options):
        """sh : (..., 3, 9) radiance SH -> float32 params iz (...,3), direction (...,3),
        ambient_ratio (...,1|3), invalid (...,1)."""
        return fit(sh, self.NAME, ratio=ratio, solver=solver or self.DEFAULT_SOLVER, **options)

    def evaluate(self, params, normals, *, albedo=None):
        """Normalized irradiance (..., 3) at tangent-space unit normals (..., 3)."""
        return evaluate(self.NAME, params, normals, albedo=albedo)

    def layout(self, ratio="luminance"):
        return layout(self.NAME, ratio)

    def encode(self, params, *, ratio="luminance"):
        return encode(self.NAME, params, ratio=ratio)

    def decode(self, channels, *, ratio="luminance", factors=None):
        return decode(self.NAME, channels, ratio=ratio, factors=factors or {})


AHD = IrradZModel(
    "ahd", "golden", "IrradZ AHD: I(n) = C_a + max(0, n.d) C_d (Sloan & Silvennoinen 2018)."
)
HHD = IrradZModel(
    "hhd",
    "golden",
    "IrradZ HHD: I(n) = (n_z + 1)/2 C_a + max(0, n.d) C_d (Roughton et al. 2024 Eq 6).",
)
HLSH = IrradZModel(
    "hlsh",
    "direct",
    "IrradZ HLSH: I(n) = C_a + (n.d) C_d, linear; w_a unbounded (Roughton et al. 2024 Eq 12-18).",
)
