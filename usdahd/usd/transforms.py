"""Local-to-world transforms of prims (for ``usdahd export gltf``'s node transforms)."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom

__all__ = ["camera_paths", "world_matrices"]


def world_matrices(stage, paths, time=None) -> dict[str, np.ndarray]:
    """{path: (4, 4) float64 local-to-world matrix, USD's row-vector convention
    (``[p, 1] @ M``)} of the prims at ``paths`` at ``time`` (a float time code, or None for the
    default time). A path that is not an imageable prim (e.g. a PointInstancer copy) maps to
    None: its points are exported in world space."""
    t = Usd.TimeCode.Default() if time is None else Usd.TimeCode(float(time))
    cache = UsdGeom.XformCache(t)
    out = {}
    for p in paths:
        prim = stage.GetPrimAtPath(Sdf.Path(p)) if Sdf.Path.IsValidPathString(p) else None
        if not prim or not prim.IsA(UsdGeom.Imageable):
            out[p] = None
            continue
        out[p] = np.array(cache.GetLocalToWorldTransform(prim), dtype=np.float64)
    return out


def camera_paths(stage) -> list[str]:
    """Paths of the stage's UsdGeomCameras (active, defined, not in instances), sorted."""
    return sorted(str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera))
