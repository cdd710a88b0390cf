"""UsdGeomCamera -> view matrix and projection parameters (for ``usdahd preview``)."""

from __future__ import annotations

import math

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from usdahd.errors import UsageError

__all__ = ["read_camera"]


def read_camera(stage, path: str):
    """The UsdGeomCamera at ``path``, read at the default time.

    Returns (view (4, 4) float64 world -> camera for column vectors, vertical field of view in
    degrees, near, far). Raises UsageError naming the cameras on the stage when ``path`` is
    not one.
    """
    prim = stage.GetPrimAtPath(Sdf.Path(path)) if Sdf.Path.IsValidPathString(path) else None
    if not prim or not prim.IsA(UsdGeom.Camera):
        cams = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
        have = ", ".join(cams) if cams else "none (omit --camera for an automatic framing)"
        raise UsageError(f"--camera {path}: no UsdGeomCamera there; cameras on the stage: {have}")
    cam = UsdGeom.Camera(prim).GetCamera(Usd.TimeCode.Default())
    view = np.array(cam.transform.GetInverse(), dtype=np.float64).T  # Gf: row vectors
    near, far = cam.clippingRange.min, cam.clippingRange.max
    fov = 2.0 * math.degrees(math.atan(0.5 * cam.verticalAperture / cam.focalLength))
    return view, fov, near, far
