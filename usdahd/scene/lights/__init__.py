"""Light sources in UsdLux units, with the sampling routines the integrator needs (numpy only).

Pure scene description (no Embree, no pxr): :mod:`usdahd.usd.lights` builds these objects and
the baker packs them for its numba kernels (:mod:`usdahd.bake.kernels.lights`, the numba twins
of the ``sample``/``intersect``/``pdf`` methods below).

Units (UsdLux "light units", applied in :mod:`usdahd.usd.lights`, docs/lights.md):
``L = intensity * 2^exposure * color (* blackbody(colorTemperature)) * diffuse``;
``normalize`` divides L by the world-space emitting area of sphere/disk/rect/cylinder lights and
makes a DistantLight's intensity its illuminance at normal incidence. Every class below stores
the final world-space emitted radiance ``radiance`` (3,) (or, for delta lights, the quantity
documented on the class), so the integrator never sees UsdLux attributes.

Common vectorized interface (``m`` query points / rays, float64):

- ``sample(p, u) -> (dirs (m,3), dist (m,), value (m,3), pdf (m,))``: a direction from ``p``
  towards the light. For area/infinite lights ``value`` is the radiance arriving along it (zero
  for back faces) and ``pdf`` its solid-angle density (0 when invalid). For delta lights
  (``delta = True``) ``pdf`` is 1 and ``value`` is the integral of radiance over the
  (vanishing) solid angle, i.e. the irradiance at normal incidence.
- ``intersect(o, d) -> (hit (m,) bool, t (m,), radiance (m,3))``: does a ray see the emitter,
  at which distance (inf for distant/dome), with which radiance (front faces only).
- ``pdf(o, d, t) -> (m,)``: the solid-angle pdf ``sample`` would have produced that direction
  with (only called where ``intersect`` hit).

Lights do not occlude each other or geometry (they are not in the BVH), the usual convention.
"""

from usdahd.scene.lights.base import (
    FALLOFF_CONSTANT,
    FALLOFF_FRONT,
    FALLOFF_ISOTROPIC,
    TWO_PI,
    Bound,
    Light,
    LightHits,
    LightSamples,
    cone_dirs,
    lum,
    norm,
    selection_pmf,
)
from usdahd.scene.lights.cylinder import CylinderLight
from usdahd.scene.lights.distant import DistantLight
from usdahd.scene.lights.dome import DomeLight
from usdahd.scene.lights.emissive import EmissiveTriangles
from usdahd.scene.lights.planar import DiskLight, PlanarLight, RectLight
from usdahd.scene.lights.sphere import PointLight, SphereLight

__all__ = [
    "FALLOFF_CONSTANT",
    "FALLOFF_FRONT",
    "FALLOFF_ISOTROPIC",
    "LIGHT_TYPES",
    "PACKED_LIGHTS",
    "TWO_PI",
    "Bound",
    "CylinderLight",
    "DiskLight",
    "DistantLight",
    "DomeLight",
    "EmissiveTriangles",
    "Light",
    "LightHits",
    "LightSamples",
    "PlanarLight",
    "PointLight",
    "RectLight",
    "SphereLight",
    "cone_dirs",
    "lum",
    "norm",
    "selection_pmf",
]

LIGHT_TYPES = (
    SphereLight,
    PointLight,
    RectLight,
    DiskLight,
    CylinderLight,
    DistantLight,
    DomeLight,
)
#: Every light with a native form, in the order of the baker's ``KIND_*`` numbers.
PACKED_LIGHTS = LIGHT_TYPES + (EmissiveTriangles,)
