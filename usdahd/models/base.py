"""What every lighting model provides, and the texture vocabulary they share.

A model is a plain module in ``usdahd/models/`` registered by name in
``usdahd/models/__init__.py`` (like OpenTimelineIO's adapters). Each module defines:

``NAME``            registry name, e.g. ``"hhd"``.
``RATIOS``          tuple of supported ratio types (``("luminance", "rgb")`` for IrradZ models,
                    ``("none",)`` for models without an ambient ratio).
``SOLVERS``         tuple of solver names; ``DEFAULT_SOLVER`` one of them.
``fit(sh, *, ratio, solver, **options) -> dict[str, ndarray]``
                    sh : (..., 3, 9) tangent-space radiance SH (float32 or float64).
                    returns model parameters, each (..., k) float32 (the names its docstring lists).
``evaluate(params, normals, *, albedo=None) -> ndarray``
                    normalized irradiance (..., 3) in tangent-space normals (..., 3); with
                    ``albedo`` (..., 3) the self-bounce term of 2024 App. A is included.
``layout(ratio) -> list[TextureLayout]``
                    the textures this model writes (see ``ROLES``; 3 or 4 channels each).
``encode(params, *, ratio) -> tuple[dict[str, ndarray], dict[str, float]]``
                    quantized texture channels per role (..., 3|4) in the stored dtype
                    (float16 or uint8) and the scalar decode factors (e.g. ``izScale``).
``decode(channels, *, ratio, factors) -> dict[str, ndarray]``
                    what an engine does: stored channels -> parameters (float32).

IrradZ models (``ahd``, ``hhd``, ``hlsh``) use params ``iz (...,3)``, ``direction (...,3)`` and
``ambient_ratio`` (``(...,1)`` for luminance, ``(...,3)`` for rgb).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from usdahd.errors import ModelError

__all__ = [
    "CHOICE_TEXT",
    "CODES",
    "Fit",
    "MAX_COEFFICIENT_TEXTURES",
    "RESERVED_CODE",
    "ROLES",
    "TextureLayout",
    "check_choice",
    "choice_problem",
    "rgb_layout",
]

#: Texture roles shared by the schema (one asset-valued property per role), the baker and the
#: validator (format version 2). Every texture has 3 or 4 channels (R, G, B[, A]): what engines'
#: importers take (at most 4 channels; no 1- or 2-channel PNGs, which are grey/grey+alpha).
#: Changing this list changes schema/schema.usda.
ROLES = (
    "iz",  # IrradZ irradiance in local z, RGB, float16 EXR, lin_rec709_scene
    "direction",  # hemi-octahedral direction (u, v) + luminance w_a (or reserved), PNG, raw
    "ratio",  # per-channel ambient ratio w_a (ratio "rgb"), RGB PNG, raw
    "ambient",  # classic AHD C_a / hemisphere colour, RGB float16 EXR, lin_rec709_scene
    "directional",  # classic AHD C_d, RGB float16 EXR, lin_rec709_scene
) + tuple(f"coefficients{k}" for k in range(9))  # linear bases: one RGB texture per basis k
#: How many ``coefficients<k>`` roles exist (sh_l2 needs 9).
MAX_COEFFICIENT_TEXTURES = 9

#: Storage formats of textures (the SH sidecar is "float").
FORMATS = ("half", "unorm8")
#: File extension per texture format: EXR for HDR data, PNG for 8-bit data (no TIFF: USD's
#: usdz checks reject it, and engines import neither signed 8-bit TIFF nor > 4 channels).
EXTENSIONS = {"half": ".exr", "unorm8": ".png", "float": ".exr"}
#: File channel names by channel count. EXR stores channels sorted by name, and every EXR
#: reader (OpenEXR's RGBA interface, OpenImageIO, engine importers) maps R, G, B, A by *name*
#: to the texture's red, green, blue, alpha components; PNG has no names, only that order.
CHANNEL_NAMES = {3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}

#: Channel codes: how a stored channel value becomes the quantity it holds. ``q`` is the stored
#: integer code (0..255) of an 8-bit channel, ``t = q / 255`` what a GPU samples from UNORM8.
CODES = {
    "half": "IEEE float16 value h; quantity = h × scale (scale 1 when none is named)",
    "unorm8": "quantity = q / 255 (× scale when named); [0, 1]",
    "snorm8b": "signed value biased into UNORM8: quantity = (q − 128) / 127 (× scale when "
    "named) = (255 t − 128) / 127; q = 128 is 0 exactly; q = 0 decodes as −1 like 1",
    "l0_8bit": "Enlighten's compressed L0: L0 = l0Scale × (q / 255)²",
    "l1_8bit": "Enlighten's compressed L1 component: L1_i = (q − 127) / 127 × L0 (the L0 of the "
    "same texture)",
    "reserved": "unused; written as 128, ignore it",
}
#: Code written into ``reserved`` channels.
RESERVED_CODE = 128


@dataclass(frozen=True)
class TextureLayout:
    """One texture a model writes (format version 2): the single table the writer, the readers,
    the schema's ``packing`` attributes and docs/schema.md are all generated from.

    role : one of ROLES; format : one of FORMATS (the file type follows, EXTENSIONS);
    color_space : a Gf.ColorSpaceNames token (``lin_rec709_scene`` for HDR irradiance, ``raw``
    for data); quantities : what each channel holds, in channel order (R, G, B[, A]), e.g.
    ``("u", "v", "w_a")``; codes : the CODES entry decoding each channel; scales : the decode
    factor (``usdahd.usd.schema.FACTORS``) multiplying each channel, or None.
    """

    role: str
    format: str
    color_space: str
    quantities: tuple[str, ...]
    codes: tuple[str, ...]
    scales: tuple[str | None, ...] = ()

    def __post_init__(self):
        n = len(self.quantities)
        if n not in CHANNEL_NAMES:
            raise ValueError(f"texture {self.role!r}: {n} channels; textures have 3 or 4")
        if self.role not in ROLES or self.format not in FORMATS:
            raise ValueError(f"texture {self.role!r}: unknown role or format {self.format!r}")
        if len(self.codes) != n or any(c not in CODES for c in self.codes):
            raise ValueError(f"texture {self.role!r}: one known code per channel")
        if not self.scales:
            object.__setattr__(self, "scales", (None,) * n)
        if len(self.scales) != n:
            raise ValueError(f"texture {self.role!r}: one scale (or None) per channel")

    @property
    def channels(self) -> tuple[str, ...]:
        """File channel names in order: ("R", "G", "B") or ("R", "G", "B", "A")."""
        return CHANNEL_NAMES[len(self.quantities)]

    @property
    def extension(self) -> str:
        return EXTENSIONS[self.format]

    @property
    def packing(self) -> str:
        """``R=u:snorm8b G=v:snorm8b B=w_a:unorm8`` (``*scale`` appended when scaled): the
        value of the schema's ``ahdLightmap:texture:<role>:packing`` attribute."""
        out = []
        for ch, q, code, s in zip(self.channels, self.quantities, self.codes, self.scales):
            out.append(f"{ch}={q}:{code}" + (f"*{s}" if s else ""))
        return " ".join(out)


def rgb_layout(role: str, name: str, format: str, color_space: str, scale: str | None):
    """A 3-channel texture holding one colour ``<name>.R, <name>.G, <name>.B``."""
    code = "half" if format == "half" else "unorm8"
    return TextureLayout(
        role, format, color_space, tuple(f"{name}.{c}" for c in "RGB"), (code,) * 3, (scale,) * 3
    )


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


# ------------------------------------------------------------------ ratio and solver choices

#: The default wording of a ratio / solver a model does not offer, per kind. Callers that name
#: the choice otherwise (a CLI flag, a schema property) pass their own ``text``: a format
#: string with the fields ``model``, ``value`` and ``allowed`` (the choices, comma-separated).
CHOICE_TEXT = {
    "ratio": "model {model!r} supports ratio {allowed}, not {value!r}",
    "solver": "model {model!r} has solvers {allowed}, not {value!r}",
}


def choice_problem(
    model: str, kind: str, value, allowed: tuple[str, ...], text: str | None = None
) -> str | None:
    """None when ``value`` is one of ``allowed`` (the ``RATIOS`` or ``SOLVERS`` of ``model``),
    else the message, in the caller's ``text`` or :data:`CHOICE_TEXT` of ``kind``: the one
    ratio/solver check of the package (models.fit, the linear models, the bake settings, the
    validator)."""
    if value in allowed:
        return None
    return (text or CHOICE_TEXT[kind]).format(model=model, value=value, allowed=", ".join(allowed))


def check_choice(
    model: str,
    kind: str,
    value,
    allowed: tuple[str, ...],
    text: str | None = None,
    error: type[Exception] = ModelError,
) -> None:
    """Raise ``error`` (ModelError by default) with :func:`choice_problem`'s message when
    ``value`` is not one of ``allowed``."""
    problem = choice_problem(model, kind, value, allowed, text)
    if problem is not None:
        raise error(problem)
