"""UsdLuxDistantLight -> ``DistantLight`` (docs/lights.md)."""

from __future__ import annotations

import math

import numpy as np
from pxr import UsdLux

from usdahd.errors import StageError
from usdahd.scene import lights as L

#: The UsdLux schemas this module reads.
SCHEMAS = (UsdLux.DistantLight,)
#: Shaping cones at least this wide (degrees) restrict nothing (accepted without a warning).
NEUTRAL_CONE = 90.0


def read(reader, prim, path, rad, m3, c, normalize) -> None:
    """DistantLight towards its +Z: a disc of half angle angle/2; normalize makes the
    intensity the illuminance at normal incidence (divides by pi sin^2(angle/2)); angle 0
    is a delta light whose L is taken as that illuminance."""
    lt = UsdLux.DistantLight(prim)
    angle = float(reader.get(lt.GetAngleAttr(), 0.53))
    if not np.isfinite(angle) or angle < 0:
        raise StageError(f"{path}: DistantLight angle {angle} must be >= 0")
    half = math.radians(min(angle, 180.0)) / 2.0
    d = np.array([0, 0, 1.0]) @ m3
    d /= np.linalg.norm(d)
    if half > 0:
        if normalize:  # intensity is the illuminance at normal incidence
            rad = rad / (np.pi * math.sin(half) ** 2)
    elif not normalize:
        reader.warn(
            f"{path}: DistantLight angle 0 without normalize: intensity taken "
            "as illuminance at normal incidence"
        )
    reader.add_light(L.DistantLight(path, rad, direction=d, half_angle=half))
