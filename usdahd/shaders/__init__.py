"""Reference shader decoders of the lightmap textures (format version 2) in GLSL, HLSL and WGSL.

For every model a *decode* function (texture samples + the ``ahdLightmap:baked:*Scale`` factors
-> model parameters, a struct) and an *evaluate* function (parameters, tangent-space unit
normal -> normalized irradiance RGB), plus, in ``common``, the channel codes, the hemi-octahedral
direction decode, the lightmap tangent frame, normal-map application and the 2024 self-bounce.
The formulas are those of docs/schema.md; ``tests/test_shaders.py`` runs every function on a
Vulkan implementation and compares it with :mod:`usdahd.models`.

Each language has one file per model family (``irradz`` serves ahd, hhd and hlsh) and a shared
``common`` file that must come first: WGSL has no ``#include``, so :func:`source` concatenates
them. Function names are prefixed ``usdahd_``, struct names ``Usdahd``; the files declare no
bindings, entry points or ``#version``, so they paste into any shader.
"""

from __future__ import annotations

from pathlib import Path

from usdahd.errors import UsageError

__all__ = ["COMMON", "FILTERED", "MODEL_FILES", "calls", "path", "source"]

#: Directory holding ``<language>/<name>.<language>``.
ROOT = Path(__file__).resolve().parent
LANGUAGES = ("glsl", "hlsl", "wgsl")
#: Model name -> shader file (without extension) that implements it.
MODEL_FILES = {
    "ahd": "irradz",
    "hhd": "irradz",
    "hlsh": "irradz",
    "ahd_classic": "ahd_classic",
    "hemisphere": "hemisphere",
    "sh_l1": "sh_l1",
    "sh_l2": "sh_l2",
    "ambient_cube": "ambient_cube",
    "hl2": "hl2",
}
COMMON = "common"
#: ``calls("ahd_classic", variant)`` of ``usdahd preview --ahd-classic``: the textures are
#: float C_a, unit d, C_d (decoded at the texel centres), filtered, d renormalised; the variant
#: names the evaluate function (the baked model's: AHD's, or HHD's hemispherical ambient).
FILTERED = {
    "filtered": "usdahd_ahd_classic_evaluate",
    "filtered_hhd": "usdahd_hhd_classic_evaluate",
}


def path(language: str, name: str) -> Path:
    """The file ``<language>/<name>.<language>`` (name: ``common`` or a MODEL_FILES value)."""
    if language not in LANGUAGES:
        raise UsageError(f"unknown shader language {language!r}; choose {', '.join(LANGUAGES)}")
    if name != COMMON and name not in MODEL_FILES.values():
        known = ", ".join(sorted(set(MODEL_FILES.values())))
        raise UsageError(f"no shader file {name!r}; there are {COMMON}, {known}")
    return ROOT / language / f"{name}.{language}"


def source(language: str, model: str) -> str:
    """The source text a shader includes for ``model``: ``common`` followed by the model's file.

    language : ``glsl``, ``hlsl`` or ``wgsl``; model : a name of ``usdahd.models.REGISTRY``.
    """
    if model not in MODEL_FILES:
        raise UsageError(f"no shader for model {model!r}; models: {', '.join(MODEL_FILES)}")
    parts = [path(language, COMMON), path(language, MODEL_FILES[model])]
    return "\n".join(p.read_text(encoding="utf-8") for p in parts)


def calls(model: str, ratio: str) -> tuple[str, str, tuple[str, ...], str]:
    """How a shader calls a model's functions: (struct type, decode call, struct fields,
    evaluate function), the same text in all three languages.

    In the decode call ``s<k>`` is the RGBA sample of the k-th texture of the model's
    ``layout(ratio)`` (``usdahd.models``) and the factor names (``izScale``, ``ratioScale``, ...)
    are variables holding ``ahdLightmap:baked:<factor>``. ``calls("ahd_classic", v)`` with ``v``
    a :data:`FILTERED` variant: the preview's ``--ahd-classic`` (``s0..s2``: float C_a, d, C_d).
    """
    if model not in MODEL_FILES:
        raise UsageError(f"no shader for model {model!r}; models: {', '.join(MODEL_FILES)}")
    rgb = "true" if ratio == "rgb" else "false"
    if model in ("ahd", "hhd", "hlsh"):
        ratio_arg = "s2.rgb" if ratio == "rgb" else "s1.rgb"  # ignored for luminance
        extra = ", ratioScale" if model == "hlsh" else ""
        call = f"usdahd_{model}_decode(s0.rgb, s1.rgb, {ratio_arg}, izScale{extra}, {rgb})"
        return "UsdahdIrradZ", call, ("iz", "d", "wa"), f"usdahd_{model}_evaluate"
    if model == "ahd_classic" and ratio in FILTERED:
        call = "usdahd_ahd_classic_filtered(s0.rgb, s1.rgb, s2.rgb)"
        return "UsdahdAhdClassic", call, ("ca", "d", "cd"), FILTERED[ratio]
    if model == "ahd_classic":
        call = "usdahd_ahd_classic_decode(s0.rgb, s1.rgb, s2.rgb, ambientScale, directionalScale)"
        return "UsdahdAhdClassic", call, ("ca", "d", "cd"), "usdahd_ahd_classic_evaluate"
    if model == "hemisphere":
        call = "usdahd_hemisphere_decode(s0.rgb, ambientScale)"
        return "UsdahdHemisphere", call, ("c",), "usdahd_hemisphere_evaluate"
    if model == "sh_l1" and ratio == "8bit":
        call = "usdahd_sh_l1_decode_8bit(s0, s1, s2, l0Scale)"
        return "UsdahdShL1", call, tuple(f"c[{k}]" for k in range(4)), "usdahd_sh_l1_evaluate"
    n = {"sh_l1": 4, "sh_l2": 9, "ambient_cube": 6, "hl2": 3}[model]
    struct = {"sh_l1": "UsdahdShL1", "sh_l2": "UsdahdShL2", "ambient_cube": "UsdahdAmbientCube"}
    args = ", ".join(f"s{k}.rgb" for k in range(n))
    evaluate = f"usdahd_{model}_evaluate" + ("_nonlinear" if ratio == "nonlinear" else "")
    return (
        struct.get(model, "UsdahdHl2"),
        f"usdahd_{model}_decode({args}, coefficientsScale)",
        tuple(f"c[{k}]" for k in range(n)),
        evaluate,
    )
