"""What every lighting model provides, and the texture vocabulary they share.

A model is a plain module in ``usdahd/models/`` registered by name in
``usdahd/models/__init__.py`` (like OpenTimelineIO's adapters). Each module defines:

``NAME``            registry name, e.g. ``"hhd"``.
``RATIOS``          tuple of supported ratio types (``("luminance", "rgb")`` for IrradZ models,
                    ``("none",)`` for models without an ambient ratio).
``SOLVERS``         tuple of solver names; ``DEFAULT_SOLVER`` one of them.
``fit(sh, *, ratio, solver, **options) -> dict[str, ndarray]``
                    sh : (..., 3, 9) tangent-space radiance SH (float32 or float64).
                    returns model parameters, each (..., k) float32 (named as in PARAMS).
``evaluate(params, normals, *, albedo=None) -> ndarray``
                    normalized irradiance (..., 3) in tangent-space normals (..., 3); with
                    ``albedo`` (..., 3) the self-bounce term of 2024 App. A is included.
``layout(ratio) -> list[TextureLayout]``
                    the textures this model writes (see ``ROLES``).
``encode(params, *, ratio) -> tuple[dict[str, ndarray], dict[str, float]]``
                    quantized texture channels per role (..., channels) in the stored dtype
                    (float16, uint8 or int8) and the scalar decode factors (e.g. ``izScale``).
``decode(channels, *, ratio, factors) -> dict[str, ndarray]``
                    what an engine does: stored channels -> parameters (float32).

IrradZ models (``ahd``, ``hhd``, ``hlsh``) use params ``iz (...,3)``, ``direction (...,3)`` and
``ambient_ratio`` (``(...,1)`` for luminance, ``(...,3)`` for rgb).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Texture roles shared by the schema (one asset-valued property per role), the baker and the
#: validator. Changing this list changes schema/schema.usda.
ROLES = (
    "iz",  # IrradZ irradiance in local z, RGB, float16 HDR, lin_rec709_scene
    "direction",  # hemi-octahedral tangent-space direction, 2 x SNORM8, raw
    "ratio",  # ambient ratio w_a: 1 or 3 x UNORM8 (SNORM8 with range for hlsh), raw
    "ambient",  # classic AHD C_a / hemisphere colour, RGB float16, lin_rec709_scene
    "directional",  # classic AHD C_d, RGB float16, lin_rec709_scene
    "coefficients",  # linear bases (sh_l1, sh_l2, ambient_cube, hl2): N x 3 float16, raw
    "coefficientsL1",  # 8-bit compressed L1 directional part (sh_l1 "8bit"), raw
)

FORMATS = ("half", "float", "unorm8", "snorm8")


@dataclass(frozen=True)
class TextureLayout:
    """One texture a model writes.

    role : one of ROLES; channels : channel names in file order (e.g. ("R", "G", "B"));
    format : one of FORMATS; color_space : a Gf.ColorSpaceNames token
    (``lin_rec709_scene`` for HDR irradiance, ``raw`` for coefficients).
    """

    role: str
    channels: tuple[str, ...]
    format: str
    color_space: str


@dataclass
class Fit:
    """Result of :func:`usdahd.fit`: model parameters plus evaluation.

    ``params`` maps names to float32 arrays with the input's leading shape.
    For IrradZ models ``fit.iz``, ``fit.direction`` and ``fit.ambient_ratio`` are shortcuts.
    """

    model: str
    ratio: str
    solver: str
    params: dict

    def __getattr__(self, name):
        params = self.__dict__.get("params", {})
        if name in params:
            return params[name]
        raise AttributeError(name)

    def evaluate(self, normals: np.ndarray, *, albedo: np.ndarray | None = None) -> np.ndarray:
        """Normalized irradiance (..., 3) for tangent-space unit normals (..., 3)."""
        from usdahd.models import get

        return get(self.model).evaluate(self.params, normals, albedo=albedo)

    def encode(self):
        """Quantized texture channels and decode factors, see the model's ``encode``."""
        from usdahd.models import get

        return get(self.model).encode(self.params, ratio=self.ratio)
