"""Lighting-model registry: one module per encoding, looked up by name.

``get(name)`` returns the model (a module, or a ``"module:attribute"`` object such as the
IrradZ rows) (see ``usdahd.models.base`` for what it defines);
``names()`` lists them; ``fit(sh, model=...)`` is the public entry point.
"""

from __future__ import annotations

import importlib

import numpy as np

from usdahd.errors import InputError, ModelError
from usdahd.models.base import (  # noqa: F401  (re-exported)
    CHOICE_TEXT,
    Fit,
    TextureLayout,
    check_choice,
    choice_problem,
)

__all__ = [
    "Fit",
    "REGISTRY",
    "check_choice",
    "choice_problem",
    "fit",
    "get",
    "names",
    "representable",
]

#: name -> module path, or "module:attribute" for a model object in a module. Add a model by
#: adding a line here.
REGISTRY = {
    "ahd": "usdahd.models.irradz:AHD",
    "hhd": "usdahd.models.irradz:HHD",
    "hlsh": "usdahd.models.irradz:HLSH",
    "ahd_classic": "usdahd.models.ahd_classic",
    "hemisphere": "usdahd.models.hemisphere",
    "sh_l1": "usdahd.models.sh_l1",
    "sh_l2": "usdahd.models.sh_l2",
    "ambient_cube": "usdahd.models.ambient_cube",
    "hl2": "usdahd.models.hl2",
}


def names() -> list[str]:
    """Registered model names whose module is importable, in registry order."""
    out = []
    for name in REGISTRY:
        try:
            get(name)
        except ModelError:
            continue
        out.append(name)
    return out


def get(name: str):
    """The model registered as ``name`` (module or ``module:attribute``); ModelError if unknown."""
    try:
        path = REGISTRY[name]
    except KeyError:
        raise ModelError(f"unknown model {name!r}; choose one of: {', '.join(REGISTRY)}") from None
    path, _, attr = path.partition(":")
    try:
        mod = importlib.import_module(path)
    except ModuleNotFoundError as exc:
        if exc.name == path:
            raise ModelError(f"model {name!r} is registered but not implemented yet") from None
        raise
    if not attr:
        return mod
    try:
        return getattr(mod, attr)
    except AttributeError:
        raise ModelError(f"model {name!r} is registered but not implemented yet") from None


def fit(sh, model: str = "hhd", *, ratio: str | None = None, solver: str | None = None, **options):
    """Fit a lighting model to tangent-space incident radiance SH.

    sh : (..., 3, 9) float32/float64 radiance SH, z = surface normal, zero below the horizon.
    model : a registry name (``names()``); ratio : ``"luminance"`` or ``"rgb"`` for IrradZ
    models (default luminance); solver : one of the model's ``SOLVERS`` (default its
    ``DEFAULT_SOLVER``).
    returns : :class:`usdahd.models.base.Fit`.
    """
    mod = get(model)
    sh = np.asarray(sh)
    if sh.ndim < 2 or sh.shape[-2:] != (3, 9):
        raise InputError(f"SH must have shape (..., 3, 9) (RGB x 9 coefficients), got {sh.shape}")
    if not (np.issubdtype(sh.dtype, np.floating) or np.issubdtype(sh.dtype, np.integer)):
        raise InputError(f"SH must be real numbers, got dtype {sh.dtype}")
    if not np.issubdtype(sh.dtype, np.floating):
        sh = sh.astype(np.float64)
    ratio = ratio or mod.RATIOS[0]
    check_choice(model, "ratio", ratio, mod.RATIOS)
    solver = solver or mod.DEFAULT_SOLVER
    check_choice(model, "solver", solver, mod.SOLVERS)
    params = mod.fit(sh, ratio=ratio, solver=solver, **options)
    return Fit(model=model, ratio=ratio, solver=solver, params=params)


def representable(fitted: Fit, mod=None) -> dict:
    """A fit's params clamped to what the model's textures can store (before rounding to
    codes), via the model's optional ``representable(params, *, ratio)``; else unchanged.
    What the decoded textures are compared against (validate's IzCheck, the bake log)."""
    mod = mod or get(fitted.model)
    rep = getattr(mod, "representable", None)
    return rep(fitted.params, ratio=fitted.ratio) if rep is not None else fitted.params
