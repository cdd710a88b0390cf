"""``usdahd preview --ahd-classic``: the naive engine import of an AHD bake (2018 Sec. 2, Fig. 2).

An engine that takes classic AHD parameters (ambient colour C_a, unit highlight direction d in
tangent space, highlight colour C_d) into three textures and lets the texture unit filter them
independently overshoots the irradiance wherever d turns quickly between texels (a lit-to-shadowed
transition), even with no normal map: I_z = C_a + d_z' C_d with d' the renormalised interpolated
direction is not the interpolated I_z. The IrradZ parametrisation (I_z, d, ratio; C_d rebuilt as
(I_z - C_a) / d_z *after* the interpolation), which the plain preview decodes, keeps I_z linear.

:func:`parameters` decodes a bake's stored textures at the texel centres into float32 C_a, d, C_d
(numpy; exact there: the model's own decode per texel); the renderers then filter those textures
(the wgpu sampler, :func:`usdahd.preview.raytrace.bilinear`) and shade
``usdahd_ahd_classic_filtered`` + the model's classic evaluate (:func:`filtered`,
:func:`evaluate` are the numpy twins of the WGSL, ``usdahd/shaders/*/ahd_classic.*``).
"""

from __future__ import annotations

import numpy as np

from usdahd.errors import UsageError

__all__ = ["MODEL", "check", "evaluate", "filtered", "item"]

#: Baked models the option applies to -> the shader variant (``usdahd.shaders.FILTERED``):
#: the ones shaded as C_a + max(0, n.d) C_d (AHD; HHD with its (1 + n_z)/2 ambient).
VARIANTS = {"ahd": "filtered", "ahd_classic": "filtered", "hhd": "filtered_hhd"}  # sorted
#: The draw items' model name of the filtered parameters (``usdahd.shaders.calls``).
MODEL = "ahd_classic"


def check(path: str, model: str) -> None:
    """UsageError unless ``model`` (the bake of prim ``path``) is one --ahd-classic applies to."""
    if model not in VARIANTS:
        raise UsageError(
            f"{path}: --ahd-classic imports an AHD-like bake as classic AHD textures "
            f"(C_a, d, C_d); it applies to {', '.join(VARIANTS)} bakes, and this prim is baked "
            f"with {model}: re-bake with --model ahd (or hhd), or preview without --ahd-classic"
        )


def parameters(model: str, ratio: str, textures, factors) -> list[np.ndarray]:
    """[C_a, d, C_d], each (h, w, 3) float32: the stored textures of a ``model`` bake (the
    layout order) decoded at every texel centre with the model's own decode."""
    from usdahd import models
    from usdahd.models import irradz

    m = models.get(model)
    channels = {t.role: px for t, px in zip(m.layout(ratio), textures)}
    p = m.decode(channels, ratio=ratio, factors=dict(factors))
    if model == "ahd_classic":
        ca, d, cd = p["ambient"], p["direction"], p["directional"]
    else:
        ca, cd, d = irradz.colors(p)
    shape = np.asarray(textures[0]).shape[:2] + (3,)
    return [np.ascontiguousarray(np.broadcast_to(x, shape), np.float32) for x in (ca, d, cd)]


def item(model: str, ratio: str, textures, factors) -> tuple:
    """(model, variant, textures, factors) of a draw item shading the filtered classic
    parameters of a ``model``/``ratio`` bake (no decode factors: the textures are float)."""
    return MODEL, VARIANTS[model], parameters(model, ratio, textures, factors), {}


def filtered(ca, d, cd) -> dict:
    """numpy ``usdahd_ahd_classic_filtered``: the filtered samples (m, 3) with d renormalised."""
    d = np.asarray(d, np.float64)
    d = d / np.sqrt(np.maximum(np.sum(d * d, axis=-1, keepdims=True), 1e-30))
    return {"ambient": np.asarray(ca, np.float64), "direction": d,
            "directional": np.asarray(cd, np.float64)}  # fmt: skip


def evaluate(variant: str, params: dict, normals) -> np.ndarray:
    """numpy ``usdahd_ahd_classic_evaluate`` (variant "filtered") or
    ``usdahd_hhd_classic_evaluate`` ("filtered_hhd") at tangent-space normals (m, 3)."""
    n = np.asarray(normals, np.float64)
    ca, d, cd = params["ambient"], params["direction"], params["directional"]
    lobe = np.maximum(np.sum(n * d, axis=-1, keepdims=True), 0.0) * cd
    if variant == "filtered_hhd":
        return 0.5 * (1.0 + n[..., 2:3]) * ca + lobe
    return ca + lobe
