"""UsdLuxDomeLight / DomeLight_1 -> ``DomeLight`` (docs/lights.md)."""

from __future__ import annotations

import numpy as np
from pxr import UsdLux

from usdahd.errors import StageError
from usdahd.scene import lights as L
from usdahd.usd.materials import read_image, sanitize_image, to_rgb
from usdahd.usd.stage import one_line

#: The UsdLux schemas this module reads.
SCHEMAS = (UsdLux.DomeLight, UsdLux.DomeLight_1)
#: Shaping cones at least this wide (degrees) restrict nothing (accepted without a warning).
NEUTRAL_CONE = 90.0


def read(reader, prim, path, rad, m3, c, normalize) -> None:
    """DomeLight / DomeLight_1: radiance L times an optional latlong texture (read with the
    ``auto`` colour space rule), rotated by the light's transform and pole axis."""
    is1 = prim.IsA(UsdLux.DomeLight_1)
    lt = UsdLux.DomeLight_1(prim) if is1 else UsdLux.DomeLight(prim)
    if lt.GetPortalsRel().GetTargets():
        reader.warn(f"{path}: DomeLight portals are not supported (ignored)")
    pole = "Y"
    if is1:
        pa = str(reader.get(lt.GetPoleAxisAttr(), "scene"))
        pole = reader.ctx.up_axis if pa == "scene" else pa
    p = np.eye(3) if pole == "Y" else np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    u, _, vt = np.linalg.svd(m3)
    rot = (u @ vt).T @ p  # world = rot @ local (column vectors)
    image = None
    asset = reader.get(lt.GetTextureFileAttr())
    if asset is not None and (asset.path or ""):
        fmt = str(reader.get(lt.GetTextureFormatAttr(), "automatic"))
        if fmt not in ("automatic", "latlong"):
            reader.warn(f"{path}: DomeLight textureFormat {fmt} not supported; uniform colour")
        else:
            problems = []
            file = asset.resolvedPath or asset.path
            if not asset.resolvedPath:
                problems.append("file not found")
            else:
                ta = lt.GetTextureFileAttr()
                fcs = str(ta.GetColorSpace()) if ta.HasColorSpace() else ""
                image = read_image(file, "auto", problems.append, file_colorspace=fcs)
            if image is None:
                raise StageError(
                    f"{path}: DomeLight texture:file {asset.path} cannot be read "
                    f"({one_line('; '.join(problems), 200)}); the environment would be "
                    "wrong for every prim: fix the path or remove texture:file"
                )
            image = sanitize_image(to_rgb(image), f"{path}: {asset.path}", reader.warn)
    reader.add_light(L.DomeLight(path, rad, image=image, rotation=rot))
