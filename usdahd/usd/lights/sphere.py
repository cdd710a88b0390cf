"""UsdLuxSphereLight -> ``SphereLight``, or ``PointLight`` with ``treatAsPoint`` (docs/lights.md)"""

from __future__ import annotations

import numpy as np
from pxr import UsdLux

from usdahd.scene import lights as L

#: The UsdLux schemas this module reads.
SCHEMAS = (UsdLux.SphereLight,)
#: Shaping cones at least this wide (degrees) restrict nothing (accepted without a warning).
NEUTRAL_CONE = 180.0


def read(reader, prim, path, rad, m3, c, normalize) -> None:
    """SphereLight: normalize divides by the world area 4 pi r^2; treatAsPoint (or radius
    0) makes a point light of radiant intensity L pi r^2 (L itself for radius 0)."""
    g = reader.get
    lt = UsdLux.SphereLight(prim)
    r = float(g(lt.GetRadiusAttr(), 0.5))
    sc = np.linalg.norm(m3, axis=1)
    if np.ptp(sc) > 1e-4 * sc.max():
        reader.warn(f"{path}: non-uniform scale on a SphereLight; mean scale used")
    rw = r * float(sc.mean())
    if normalize and rw > 0:
        rad = rad / (4.0 * np.pi * rw * rw)
    if g(lt.GetTreatAsPointAttr(), False) or rw <= 0:
        if rw <= 0:
            reader.warn(
                f"{path}: SphereLight radius 0: treated as a point light of "
                "radiant intensity = its radiance"
            )
            inten = rad
        else:
            inten = rad * np.pi * rw * rw
        reader.add_light(L.PointLight(path, inten, center=c))
    else:
        reader.add_light(L.SphereLight(path, rad, center=c, radius=rw))
