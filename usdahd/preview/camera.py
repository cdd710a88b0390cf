"""Cameras of ``usdahd preview``: a UsdGeomCamera of the stage or the automatic framing.

View-projection matrices (4, 4) float64 for column vectors, to WebGPU clip space (NDC z in
[0, 1], y up); the Embree paths invert the same matrices (:mod:`usdahd.preview.raytrace`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["auto_camera", "usd_camera", "view_projection"]

#: Vertical field of view of the automatic framing (degrees).
AUTO_FOV = 40.0
#: Tangent of the automatic framing's elevation above the horizon (0.5: ~27 degrees).
ELEVATION = 0.5


def look_at(eye, target, up) -> np.ndarray:
    """View matrix (4, 4) float64, column vectors, camera looking down -z (right-handed)."""
    f = np.asarray(target, float) - np.asarray(eye, float)
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, float)
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """Projection (4, 4) float64 to WebGPU clip space (z in [0, 1])."""
    f = 1.0 / math.tan(math.radians(fov_y_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = far / (near - far), near * far / (near - far)
    m[3, 2] = -1.0
    return m


def auto_camera(points: np.ndarray, up_axis: str, aspect: float) -> np.ndarray:
    """View-projection (4, 4) framing the bounding sphere of points (n, 3) from the front
    (+z for a Y-up stage, -y for Z-up) and above; back-face culling opens closed rooms (their
    front wall and ceiling face away from the camera)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    c = 0.5 * (lo + hi)
    r = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
    up = np.array([0.0, 1.0, 0.0]) if up_axis == "Y" else np.array([0.0, 0.0, 1.0])
    front = np.array([0.0, 0.0, 1.0]) if up_axis == "Y" else np.array([0.0, -1.0, 0.0])
    back = front + ELEVATION * up  # from the front and above: floors and planes are not edge-on
    back /= np.linalg.norm(back)
    half = math.radians(AUTO_FOV) / 2.0
    fit = min(half, math.atan(math.tan(half) * aspect))
    dist = r / math.sin(fit)
    eye = c + back * dist
    near, far = max(dist - 1.5 * r, 1e-3 * dist), dist + 1.5 * r
    return perspective(AUTO_FOV, aspect, near, far) @ look_at(eye, c, up)


def usd_camera(stage, path: str, aspect: float) -> np.ndarray:
    """View-projection (4, 4) of a UsdGeomCamera (its vertical aperture kept, the horizontal
    one fitted to the image aspect), WebGPU clip space."""
    from usdahd.usd.camera import read_camera

    view, fov, near, far = read_camera(stage, path)
    return perspective(fov, aspect, near, far) @ view


def view_projection(stage, meshes, up_axis: str, camera: str | None, aspect: float) -> np.ndarray:
    """The preview's view-projection: the UsdGeomCamera at ``camera``, or (None) the automatic
    framing of the points of ``meshes`` (:func:`usdahd.preview.meshes.baked_meshes`)."""
    if camera:
        return usd_camera(stage, camera, aspect)
    pts = np.concatenate([np.asarray(m.points) for m, *_ in meshes])
    return auto_camera(pts, up_axis, aspect)
