"""Tolerances of the rules (:data:`OPTIONS`, changed by ``usdahd validate --tolerance`` and
friends).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from usdahd.numerics import encoding
from usdahd.numerics.raster import UV_OVERLAP_LIMIT

__all__ = [
    "DZ_FLOOR",
    "FORMAT_DTYPES",
    "FORMAT_RELATIVE_TOLERANCE",
    "HALF_ABSOLUTE_TOLERANCE",
    "IRRADZ",
    "MODEL_RMSE_NOTE",
    "NONNEGATIVE_COLOURS",
    "OIIO_FORMATS",
    "OPTIONS",
    "Options",
    "UNIT_TOLERANCE",
]

# ------------------------------------------------------------------------------- tolerances


@dataclass
class Options:
    """Every tolerance of the rules, with the reason for its default.

    iz_tolerance : relative I(z) tolerance (times the texel's brightest reference channel);
        None (default) derives it per texel from the codes' quantization
        (:func:`quantization_tolerance`).
    rmse_warning : relative hemispherical RMSE (per prim) of the decoded textures against the
        model's own unquantized fit above which EncodingError warns; 0.25 is 4x the largest
        quantization error measured on the samples (hlsh, whose 8-bit w_a spans up to +-16:
        0.061; float16 models ~3e-4) and well below a wrong decode (order 1). The model's own
        fit error is reported, not warned about: it is a choice of model, not a defect.
    model_rmse_warning : relative hemispherical RMSE of the decoded textures against the SH
        irradiance (model fit and quantization together) above which EncodingError warns
        (``HighModelError``): at 1 the error is as large as the irradiance itself, so the
        shading is wrong whatever the cause (light from below the tangent plane, which IrradZ
        models decode black, gives 1.2-1.4; fresh default bakes of the samples measure at most
        0.24).
    model_texel_share : share of a prim's texels whose own relative RMSE exceeds
        model_rmse_warning above which EncodingError warns too: such a texel is shaded worse
        than black; isolated ones occur on fresh bakes (contact shadows, grazing light: at most
        0.64% of a prim of the Cornell box at 16 x 16, hhd), 5% (8x that) is a region.
    model_texel_min : fewest such texels that make a region (with model_texel_share): on an
        8 x 8 map at 16 samples a few noisy grazing texels are over 5% of a box's face
        (the Cornell TallBox, hemisphere model: 0.66 on the prim) without being a region.
    rmse_normals : normals of the hemispherical RMSE (spherical Fibonacci, upper hemisphere).
    rmse_max_texels : a prim with more valid texels is judged on a seeded simple random
        sample of this many (binomial bounds in docs/validate.md, EncodingError: a region of
        >= 6% of the texels is flagged with >= 99.7% probability, one of <= 4% with <= 0.09%;
        a defect on >= 0.17% of the texels is in the sample with >= 99.9%). 4096 keeps the
        64-normal evaluation at ~0.1 s per prim; every texel's codes are IzCheck's.
    uv_epsilon : UVs may leave [0, 1] by this much (float32 rounding of authored 0 and 1).
    uv_overlap : fraction of covered texels whose centre lies in two triangles that still
        passes: the baker's own limit (numerics.raster.UV_OVERLAP_LIMIT), so a UV set the
        baker accepts passes.
    density_spread : area-weighted 90th/10th percentile ratio of texel density that warns.
    """

    iz_tolerance: float | None = None
    rmse_warning: float = 0.25
    model_rmse_warning: float = 1.0
    model_texel_share: float = 0.05
    model_texel_min: int = 8
    rmse_normals: int = 64
    rmse_max_texels: int = 4096
    uv_epsilon: float = 1e-5
    uv_overlap: float = UV_OVERLAP_LIMIT
    density_spread: float = 4.0


OPTIONS = Options()
#: Model fit RMSE above which the EncodingError note says the model fits loosely and names the
#: models measured to fit closer (never the model in use; usdahd.validate.irradiance
#: ADVICE_MODELS): the quantization warning's threshold, so a note never calls a smaller
#: error loose than the one the textures may add.
MODEL_RMSE_NOTE = 0.25

#: Relative rounding bound of a stored value by storage format (documentation and tests; IzCheck
#: derives its tolerance per texel, :func:`quantization_tolerance`): float16 rounds to nearest
#: with a relative error <= 2^-11 = 4.88e-4 (normal range), so 5e-4; float32 2^-24, so 1e-6.
FORMAT_RELATIVE_TOLERANCE = {"half": 5e-4, "float": 1e-6}
#: Absolute tolerance (times the decode scale) for values in float16's subnormal range, where
#: the spacing is 2^-24 (rounding error <= 2^-25).
HALF_ABSOLUTE_TOLERANCE = 2.0**-24
#: The smallest decoded d_z an 8-bit hemi-octahedral code may have (encoding.DZ_MIN = 1/127),
#: minus float32 rounding of the decode.
DZ_FLOOR = encoding.DZ_MIN * (1.0 - 1e-5)
#: Decoded directions must be unit length to this (float32 normalise).
UNIT_TOLERANCE = 1e-4
#: OpenImageIO format name -> schema storage format.
OIIO_FORMATS = {"half": "half", "float": "float", "uint8": "unorm8", "int8": "snorm8"}
FORMAT_DTYPES = {"half": np.float16, "float": np.float32, "unorm8": np.uint8, "snorm8": np.int8}
IRRADZ = ("ahd", "hhd", "hlsh")
#: Models whose colours must be non-negative (HLSH may have C_d < 0; linear bases ring).
NONNEGATIVE_COLOURS = ("ahd", "hhd", "ahd_classic", "hemisphere")
