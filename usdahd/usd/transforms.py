"""Local-to-world transforms of prims (for ``usdahd export gltf``'s node transforms)."""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom

__all__ = ["camera_paths", "point_instancer_transforms", "world_matrices"]


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


def point_instancer_transforms(stage, path: str, time=None) -> list[np.ndarray] | None:
    """The per-instance transforms of the PointInstancer at ``path`` (USD's row-vector
    convention, one (4, 4) float64 matrix per ``positions`` entry, relative to the
    PointInstancer: ``UsdGeomPointInstancer.ComputeInstanceTransformsAtTime``, as the scene
    reader places a copy: ``[p, 1] @ proto_local @ M_i @ world(PointInstancer)``), or None
    when ``path`` is not a PointInstancer or its transforms cannot be computed."""
    t = Usd.TimeCode.Default() if time is None else Usd.TimeCode(float(time))
    prim = stage.GetPrimAtPath(Sdf.Path(path)) if Sdf.Path.IsValidPathString(path) else None
    if not prim or not prim.IsA(UsdGeom.PointInstancer):
        return None
    xfs = UsdGeom.PointInstancer(prim).ComputeInstanceTransformsAtTime(t, t)
    if not xfs:
        return None
    return [np.array(m, dtype=np.float64) for m in xfs]


def camera_paths(stage) -> list[str]:
    """Paths of the stage's UsdGeomCameras (active, defined, not in instances), sorted."""
    return sorted(str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera))
