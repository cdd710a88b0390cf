"""UsdLux lights -> light objects in physical units: the one home of the light-unit rules.

This package reads what every light shares (emission, unsupported inputs, linking); each
light type has its own reader module (:data:`LIGHT_READERS`: ``sphere``, ``planar``,
``cylinder``, ``distant``, ``dome``) beside its class in :mod:`usdahd.scene.lights`.

docs/lights.md is the user's page for these rules (what is honoured, what is warned); this
module implements them, and :mod:`usdahd.scene.lights` holds the light classes it builds (each
stores its final world-space ``radiance`` (3,) float64, so the integrator never sees a UsdLux
attribute).

Emission, every light type (:meth:`LightReader.read`)::

    L = intensity * 2^exposure * color * diffuse  (* blackbody(colorTemperature) when
                                                   enableColorTemperature)

NaN/Inf or negative intensity, color or diffuse (and a NaN/Inf exposure) raise StageError
naming the prim; a light with no positive component is ignored (warned); ``L`` above
:data:`usdahd.scene.types.MAX_RADIANCE` raises. ``inputs:intensity`` unauthored uses the
UsdLux fallback 1 (one warning per stage). Then per type, at the light's world transform
(scale included; a non-invertible transform ignores the light, warned):

==================  =====================================  ===================================
type                ``normalize`` = 1 divides L by          built as
==================  =====================================  ===================================
SphereLight         4 pi r^2 (world radius: mean scale)     SphereLight(radiance L)
SphereLight,        (same, before the switch)               PointLight of radiant intensity
treatAsPoint or                                             L pi r^2 (r = 0: intensity L,
radius 0                                                    warned)
RectLight           width x height (world area)             RectLight(L), emits along -Z
DiskLight           pi r^2 (world area)                     DiskLight(L), emits along -Z
CylinderLight       2 pi r x length (world area)            CylinderLight(L) along local X
DistantLight        pi sin^2(angle / 2): intensity is the   DistantLight(L, half angle); angle
                    illuminance at normal incidence         0: delta light of illuminance L
DomeLight(_1)       nothing (no area)                       DomeLight(L x latlong texture)
==================  =====================================  ===================================

Not supported, each a warning: shaping cone/focus (cones at least 90 degrees wide for
planar, distant and dome lights, 180 for the others, restrict nothing and are accepted), IES
profiles, light filters, RectLight textures, DomeLight portals and non-latlong formats,
CylinderLight ``treatAsLine``, ``shadow:enable = false``, ``shadow:color``, ``shadow:distance``,
``shadow:falloff``; PortalLight and PluginLight prims. Light and shadow linking collections
are read as mesh indices (:meth:`LightReader.link_membership`).
"""

from __future__ import annotations

import math

import numpy as np
from pxr import Sdf, UsdLux

from usdahd.errors import StageError
from usdahd.scene import lights as L
from usdahd.scene.types import MAX_RADIANCE
from usdahd.usd.geometry import SINGULAR_DET_REL
from usdahd.usd.lights import cylinder, distant, dome, planar, sphere
from usdahd.usd.stage import fmt_values

__all__ = ["LIGHT_READERS", "LightReader", "light_module"]

#: The reader module of every supported light type (one module per light: ``SCHEMAS`` it
#: reads, ``NEUTRAL_CONE``, ``read(reader, prim, path, L, m3, center, normalize)``).
LIGHT_READERS = (sphere, planar, cylinder, distant, dome)


def light_module(prim):
    """The reader module of ``prim``'s light type (:data:`LIGHT_READERS`), or None."""
    for module in LIGHT_READERS:
        if any(prim.IsA(schema) for schema in module.SCHEMAS):
            return module
    return None


class LightReader:
    """The lights of one stage read at ``ctx.time`` (see the module docstring).

    ctx : usdahd.usd.reader.ReadContext. ``lights`` : usdahd.scene.lights objects, in the
    traversal's order.
    """

    def __init__(self, ctx):
        self.ctx = ctx
        self.warn = ctx.warn
        self.get = ctx.get
        self.lights: list = []
        self.unauthored_intensity: list[str] = []
        self._link_queries: list = []
        self._current_light = None  # the prim whose light objects are being added
        self._emission = (float("nan"), float("nan"))  # (intensity, exposure) of that prim

    # --------------------------------------------------------------------- one light
    def read(self, prim) -> None:
        """Add the light of a prim with UsdLuxLightAPI (or warn why it is ignored)."""
        path = str(prim.GetPath())
        api = UsdLux.LightAPI(prim)
        rad, normalize = self._emission_rule(prim, path, api)
        if rad is None:
            return
        self._unsupported_warnings(prim, path, api)
        self._current_light = prim
        m = np.array(self.ctx.xf.GetLocalToWorldTransform(prim))
        if not np.all(np.isfinite(m)):
            raise StageError(
                f"{path}: light world transform contains NaN/Inf; fix the xformOps of the light "
                "or its ancestors"
            )
        m3, c = m[:3, :3], m[3, :3].copy()
        rows = np.linalg.norm(m3, axis=1)
        if rows.min() == 0.0 or abs(np.linalg.det(m3)) <= SINGULAR_DET_REL * np.prod(rows):
            self.warn(
                f"{path}: light transform is not invertible (zero scale): the light has no "
                "size or direction and is ignored"
            )
            return
        module = light_module(prim)
        if module is None:
            self.warn(
                f"{path}: light type {prim.GetTypeName()} is not supported (ignored)",
                key=f"lt:{prim.GetTypeName()}",
            )
            return
        module.read(self, prim, path, rad, m3, c, normalize)

    def _emission_rule(self, prim, path, api):
        """(L, normalize): L = intensity x 2^exposure x color x diffuse (x blackbody), (3,)
        float64, or None when the light emits nothing (warned); normalize : inputs:normalize.
        Raises StageError for broken values."""
        g = self.get
        intensity = g(api.GetIntensityAttr(), 1.0)
        if not api.GetIntensityAttr().HasAuthoredValue():
            self.unauthored_intensity.append(path)
        exposure = g(api.GetExposureAttr(), 0.0)
        color = np.array(g(api.GetColorAttr(), (1, 1, 1)), np.float64)
        diffuse = g(api.GetDiffuseAttr(), 1.0)
        normalize = bool(g(api.GetNormalizeAttr(), False))
        named = {
            "inputs:intensity": np.array([intensity], np.float64),
            "inputs:exposure": np.array([exposure], np.float64),
            "inputs:color": color,
            "inputs:diffuse": np.array([diffuse], np.float64),
        }
        for name, v in named.items():
            if v.shape[-1:] != (3,) and name == "inputs:color":
                raise StageError(f"{path}: {name} must be a color3f, got {tuple(v.tolist())}")
            if not np.all(np.isfinite(v)):
                kind = "NaN" if np.isnan(v).any() else "Inf"
                raise StageError(
                    f"{path}: light {name} is {kind} ({fmt_values(v)}); a broken light spoils "
                    "every prim's bake: fix it or deactivate the light"
                )
            if name != "inputs:exposure" and np.any(v < 0):
                raise StageError(
                    f"{path}: light {name} is negative ({fmt_values(v)}); lights cannot emit "
                    "negative energy: fix it or deactivate the light"
                )
        with np.errstate(over="ignore"):
            gain = np.exp2(np.float64(exposure))
        rad = intensity * gain * color * diffuse
        self._emission = (float(intensity), float(exposure))
        if not np.any(rad > 0):
            self.warn(
                f"{path}: light emits nothing (inputs:intensity {float(intensity):g}, "
                f"color {fmt_values(color)}, diffuse {float(diffuse):g}): ignored"
            )
            return None, normalize
        if not np.all(np.isfinite(rad)) or rad.max() > MAX_RADIANCE:
            raise StageError(
                f"{path}: inputs:intensity {float(intensity):g} x 2^inputs:exposure "
                f"{float(exposure):g} = {float(np.max(rad)):.3g} overflows the baker's range "
                f"(max {MAX_RADIANCE:.0e}); lower the exposure or intensity"
            )
        if g(api.GetEnableColorTemperatureAttr(), False):
            t = g(api.GetColorTemperatureAttr(), 6500.0)
            if not (math.isfinite(t) and t > 0):
                raise StageError(
                    f"{path}: light inputs:colorTemperature {t:g} must be a positive finite "
                    "temperature in kelvin: fix it or disable enableColorTemperature"
                )
            rad = rad * np.array(UsdLux.BlackbodyTemperatureAsRgb(float(t)), np.float64)
        return rad, normalize

    def _unsupported_warnings(self, prim, path, api) -> None:
        """Filters, shaping (cone/focus, IES) and ShadowAPI inputs: ignored, each warned."""
        g = self.get
        if api.GetFiltersRel().GetTargets():
            self.warn(f"{path}: light filters are not supported (ignored)")
        if prim.HasAPI(UsdLux.ShapingAPI):
            sh = UsdLux.ShapingAPI(prim)
            cone = g(sh.GetShapingConeAngleAttr(), 90.0)
            focus = g(sh.GetShapingFocusAttr(), 0.0)
            ies = g(sh.GetShapingIesFileAttr())
            module = light_module(prim)
            # cones at least this wide restrict nothing
            limit = module.NEUTRAL_CONE if module is not None else 180.0
            if cone < limit or focus != 0.0:
                self.warn(f"{path}: shaping (cone/focus) not supported (ignored)")
            if ies is not None and (ies.path or ""):
                self.warn(f"{path}: IES profiles not supported (ignored)")
        sa = prim.GetAttribute("inputs:shadow:enable")
        if sa and sa.HasAuthoredValue() and not self.get(sa, True):
            self.warn(f"{path}: shadow:enable = false is not supported (shadows are cast)")
        self._shadow_warnings(prim, path)

    def _shadow_warnings(self, prim, path) -> None:
        """ShadowAPI inputs that change what a renderer shows and that the baker ignores."""
        col = prim.GetAttribute("inputs:shadow:color")
        if col and col.HasAuthoredValue():
            c = np.asarray(self.get(col, (0, 0, 0)), np.float64)
            if np.any(c != 0):
                self.warn(
                    f"{path}: inputs:shadow:color {fmt_values(c)} is not supported: shadows are "
                    "black (physically correct); remove it or bake with a fill light"
                )
        for name, neutral in (("inputs:shadow:distance", -1.0), ("inputs:shadow:falloff", -1.0)):
            a = prim.GetAttribute(name)
            if a and a.HasAuthoredValue() and float(self.get(a, neutral)) != neutral:
                self.warn(f"{path}: {name} is not supported (shadows reach any distance)")

    def add_light(self, light):
        """Append a light after checking its final (area-normalized) emission."""
        peak = float(np.max(light.radiance))
        img = getattr(light, "image", None)
        if img is not None and img.size:
            peak *= float(np.max(img))
        if not np.isfinite(peak) or peak > MAX_RADIANCE:
            i, e = self._emission
            raise StageError(
                f"{light.path}: emitted radiance {peak:.3g} (inputs:intensity {i:g}, exposure "
                f"{e:g}, after normalize/area) overflows the baker's range (max "
                f"{MAX_RADIANCE:.0e}); lower the exposure or intensity, or enlarge the light"
            )
        prim = self._current_light
        if prim is not None and str(prim.GetPath()) == light.path:
            self._link_queries.append((light, prim))
        self.lights.append(light)

    # --------------------------------------------------------------------- whole stage
    def link_membership(self, link_paths) -> None:
        """Per light, the baked-scene mesh indices its ``collection:lightLink`` includes
        (``light.lit_meshes``) and whose shadows its ``collection:shadowLink`` includes
        (``light.shadow_meshes``): (k,) int32 sorted, or None when the collection includes
        every mesh (the default). Read through Usd.CollectionAPI membership queries.

        link_paths : per mesh of the scene, the prim path it is queried by (copies of a
        PointInstancer: the instancer's path; see docs/lights.md)."""
        if not self._link_queries:
            return
        paths = list(link_paths)
        for light, prim in self._link_queries:
            api = UsdLux.LightAPI(prim)
            for attr, coll in (
                ("lit_meshes", api.GetLightLinkCollectionAPI()),
                ("shadow_meshes", api.GetShadowLinkCollectionAPI()),
            ):
                query = coll.ComputeMembershipQuery()
                inc = np.array([bool(query.IsPathIncluded(Sdf.Path(p))) for p in paths], bool)
                setattr(light, attr, None if inc.all() else np.flatnonzero(inc).astype(np.int32))

    def light_warnings(self, meshes) -> None:
        """Stage-level light warnings: unauthored intensities (the schema fallback 1 is used)
        and DistantLights too dim to contribute next to the other light sources.

        meshes : the scene's MeshData (their centre is where illuminance is estimated)."""
        if self.unauthored_intensity:
            p = sorted(self.unauthored_intensity)
            more = f" and {len(p) - 3} more" if len(p) > 3 else ""
            self.warn(
                f"{len(p)} lights do not author inputs:intensity ({', '.join(p[:3])}{more}): "
                "the UsdLux fallback 1 is used (very dim in physical units); author the "
                "intensity you mean",
                key="lights:intensity",
            )
        if not self.lights:
            return
        # Rough illuminance each light delivers at the scene's centre (a warning only; emissive
        # surfaces are left out: their extent is unknown here, and overrating them would flag
        # a sun as dim).
        pts = [m.points for m in meshes]
        centre = np.mean([p.mean(axis=0) for p in pts], axis=0) if pts else np.zeros(3)
        scale = {}
        for light in self.lights:
            rad = float(np.max(light.radiance))
            if isinstance(light, L.DistantLight):
                h = light.half_angle
                scale[light.path] = rad * (np.pi * math.sin(h) ** 2 if h > 0 else 1.0)
            elif isinstance(light, L.DomeLight):
                img = getattr(light, "image", None)
                scale[light.path] = np.pi * rad * (float(np.mean(img)) if img is not None else 1)
            else:
                c = np.asarray(getattr(light, "center", centre), np.float64)
                size = float(getattr(light, "radius", 0.0) or 0.0)
                for k in ("ex", "ey"):
                    if getattr(light, k, None) is not None:
                        size = max(size, float(np.linalg.norm(getattr(light, k))))
                d2 = max(float(np.sum((c - centre) ** 2)), size * size, 1e-12)
                solid = min(np.pi * size * size / d2, np.pi) if size > 0 else 1.0 / d2
                scale[light.path] = rad * solid
        for light in self.lights:
            if not isinstance(light, L.DistantLight):
                continue
            others = [v for k, v in scale.items() if k != light.path]
            if others and scale[light.path] < 1e-3 * max(others):
                ratio = scale[light.path] / max(others)
                hint = ""
                if light.half_angle > 0:
                    solid = np.pi * math.sin(light.half_angle) ** 2
                    hint = (
                        "; with inputs:normalize off, intensity is the radiance of the sun "
                        f"disc (illuminance = intensity x {solid:.2g}): set inputs:normalize "
                        "= 1 to make it the illuminance"
                    )
                self.warn(
                    f"{light.path}: this DistantLight delivers about {ratio:.1e} of the "
                    f"brightest other light's illuminance, so it contributes nothing "
                    f"visible{hint}"
                )
