"""UsdLuxRectLight and UsdLuxDiskLight -> ``RectLight`` / ``DiskLight`` (docs/lights.md)."""

from __future__ import annotations

import numpy as np
from pxr import UsdLux

from usdahd.scene import lights as L

#: The UsdLux schemas this module reads.
SCHEMAS = (UsdLux.RectLight, UsdLux.DiskLight)
#: Shaping cones at least this wide (degrees) restrict nothing (accepted without a warning).
NEUTRAL_CONE = 90.0


def read(reader, prim, path, rad, m3, c, normalize) -> None:
    """RectLight (width x height) and DiskLight (pi r^2): one-sided, emitting along their
    -Z axis; normalize divides by the world-space area."""
    g = reader.get
    inv_t = np.linalg.inv(m3).T
    is_rect = prim.IsA(UsdLux.RectLight)
    n = -(np.array([0, 0, 1.0]) @ inv_t)
    n /= np.linalg.norm(n)
    if is_rect:
        lt = UsdLux.RectLight(prim)
        w = float(g(lt.GetWidthAttr(), 1.0))
        h = float(g(lt.GetHeightAttr(), 1.0))
        ex, ey = 0.5 * w * m3[0], 0.5 * h * m3[1]
        area = 4.0 * np.linalg.norm(np.cross(ex, ey))
        tf = lt.GetTextureFileAttr()
        if tf and tf.HasAuthoredValue() and reader.get(tf):
            reader.warn(f"{path}: RectLight texture is not supported (uniform emission)")
    else:
        lt = UsdLux.DiskLight(prim)
        r = float(g(lt.GetRadiusAttr(), 0.5))
        ex, ey = r * m3[0], r * m3[1]
        area = np.pi * np.linalg.norm(np.cross(ex, ey))
    if area <= 0:
        reader.warn(f"{path}: zero-area light ignored")
        return
    if normalize:
        rad = rad / area
    cls = L.RectLight if is_rect else L.DiskLight
    reader.add_light(cls(path, rad, center=c, ex=ex, ey=ey, normal=n))
