"""USD inputs of ``usdahd preview --model-view`` (:mod:`usdahd.preview.surface`): a float2 primvar
at a mesh's triangle corners and UsdPreviewSurface ``inputs:normal``, read with pxr here so the
preview package stays pxr-free (tests/test_layers.py)."""

from __future__ import annotations

import numpy as np

from usdahd.errors import StageError

__all__ = ["corner_primvar", "normal_input"]


def corner_primvar(prim, name: str, mesh, time) -> np.ndarray | None:
    """(t, 3, 2) float32 values of a float2 primvar at the mesh's triangle corners, or None."""
    from pxr import UsdGeom

    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasValue():
        return None
    vals = pv.ComputeFlattened(time)
    if vals is None or len(vals) == 0:
        return None
    vals = np.asarray(vals, np.float64).reshape(len(vals), -1)[:, :2]
    interp = pv.GetInterpolation()
    corner = np.asarray(mesh.corner, np.int64)
    if interp == UsdGeom.Tokens.faceVarying:
        idx = corner
    elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        fvi = np.asarray(UsdGeom.Mesh(prim).GetFaceVertexIndicesAttr().Get(time), np.int64)
        idx = fvi[corner]
    elif interp == UsdGeom.Tokens.uniform:
        idx = np.repeat(np.asarray(mesh.face, np.int64)[:, None], 3, axis=1)
    else:
        idx = np.zeros_like(corner)
    if idx.max(initial=0) >= len(vals):
        return None
    return vals[idx].astype(np.float32)


def normal_input(reader, stage, material: str):
    """(constant (3,), Texture or None, texcoord name) of UsdPreviewSurface ``inputs:normal``
    of the material prim ``material`` (None, None, None: no such shader input)."""
    from pxr import UsdShade

    prim = stage.GetPrimAtPath(material) if material.startswith("/") else None
    if prim is None or not prim.IsValid():
        return None, None, None  # displayColor pseudo-material
    shader = UsdShade.Material(prim).ComputeSurfaceSource()[0]
    if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
        return None, None, None
    names: list[str] = []
    const, tex = reader.surface_input(shader, "normal", (0.0, 0.0, 1.0), material, names)
    if tex is not None and len(tex.channels) != 3:
        raise StageError(
            f"{material}: UsdPreviewSurface inputs:normal is connected to a one-channel output "
            f"of {tex.path}; connect the UsdUVTexture's outputs:rgb"
        )
    return np.asarray(const, np.float32).reshape(-1)[:3], tex, (names[0] if names else None)
