"""UsdLuxCylinderLight -> ``CylinderLight`` (docs/lights.md)."""

from __future__ import annotations

import numpy as np
from pxr import UsdLux

from usdahd.scene import lights as L

#: The UsdLux schemas this module reads.
SCHEMAS = (UsdLux.CylinderLight,)
#: Shaping cones at least this wide (degrees) restrict nothing (accepted without a warning).
NEUTRAL_CONE = 180.0


def read(reader, prim, path, rad, m3, c, normalize) -> None:
    """CylinderLight along its local X axis: normalize divides by the side area
    2 pi r x length (world; the radius scaled by the mean of the Y and Z scales)."""
    g = reader.get
    lt = UsdLux.CylinderLight(prim)
    r = float(g(lt.GetRadiusAttr(), 0.5))
    ln = float(g(lt.GetLengthAttr(), 1.0))
    ax = m3[0]
    hl = 0.5 * ln * np.linalg.norm(ax)
    rw = r * 0.5 * (np.linalg.norm(m3[1]) + np.linalg.norm(m3[2]))
    if g(lt.GetTreatAsLineAttr(), False):
        reader.warn(f"{path}: CylinderLight treatAsLine ignored (traced as a cylinder)")
    area = 2 * np.pi * rw * 2 * hl
    if area <= 0:
        reader.warn(f"{path}: zero-area light ignored")
        return
    if normalize:
        rad = rad / area
    reader.add_light(
        L.CylinderLight(
            path, rad, center=c, axis=ax / np.linalg.norm(ax), half_length=hl, radius=rw
        )
    )
