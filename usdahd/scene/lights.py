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

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usdahd.numerics.sampling import (
    SPHERICAL_RECT_MAX_SR,
    SPHERICAL_RECT_MIN_SR,
    concentric_disk,
    cone_local,
    orthonormal_basis,
    sample_discrete,
    spherical_rectangle,
    to_world,
)
from usdahd.numerics.sh import LUMINANCE

TWO_PI = 2.0 * np.pi


def _norm(v):
    return np.sqrt(np.einsum("...i,...i->...", v, v))


# ----------------------------------------------------------------------------- light selection
#: How a light's :class:`Bound` varies with the receiving point: the same everywhere (distant
#: and dome lights), inverse square from ``center`` (spheres, points, cylinders, emissive
#: triangles), or inverse square on the emitting side of ``center``'s plane and 0 behind it
#: (one-sided rect and disk lights).
FALLOFF_CONSTANT, FALLOFF_ISOTROPIC, FALLOFF_FRONT = 0, 1, 2


@dataclass(frozen=True)
class Bound:
    """A cheap estimate of the luminance irradiance a light can deliver at a point p (no
    visibility, no receiver orientation), for choosing which light a path vertex samples:
    ``importance(p) = min(cap, scale / max(|p - center|^2, r2))`` (``cap`` alone for
    FALLOFF_CONSTANT; 0 behind the plane for FALLOFF_FRONT). ``scale`` is luminance x area
    (the far field), ``r2`` a squared radius inside which the light is "close" (its size),
    ``cap`` the irradiance of the light filling the hemisphere (pi L) or, for distant and dome
    lights, their irradiance at normal incidence. center, normal : (3,) float64."""

    falloff: int
    scale: float = 0.0
    r2: float = 0.0
    cap: float = np.inf
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def importance(self, p: np.ndarray) -> np.ndarray:
        """(m,) float64 importance at points ``p`` (m, 3) float64 (the numba twin is
        ``usdahd.bake.kernels.lights.light_importance``)."""
        p = np.asarray(p, np.float64)
        if self.falloff == FALLOFF_CONSTANT:
            return np.full(len(p), float(self.cap))
        w = p - self.center
        d2 = np.maximum(np.maximum(np.einsum("ij,ij->i", w, w), self.r2), 1e-300)
        out = np.minimum(self.cap, self.scale / d2)
        if self.falloff == FALLOFF_FRONT:
            out = np.where(w @ self.normal > 0.0, out, 0.0)
        return out


def selection_pmf(bounds, p: np.ndarray, floor: float) -> np.ndarray:
    """(m, n) float64 probabilities of choosing each light, by the n :class:`Bound` ``bounds``
    of the lights (``Light.bound()``), at points ``p`` (m, 3):
    ``floor / n + (1 - floor) * importance / sum(importance)`` (uniform where every importance
    is 0), so every light keeps at least ``floor / n`` and its sample weight stays bounded.
    The numba twin is ``usdahd.bake.kernels.integrate._nee_pick`` / ``_nee_sel``."""
    n = len(bounds)
    imp = np.stack([b.importance(p) for b in bounds], axis=1)
    tot = imp.sum(axis=1, keepdims=True)
    share = np.where(tot > 0.0, imp / np.where(tot > 0.0, tot, 1.0), 1.0 / n)
    return floor / n + (1.0 - floor) * share


def _lum(rgb) -> float:
    return float(np.asarray(rgb, np.float64)[:3] @ LUMINANCE)


def _cone_dirs(axis, one_minus_cos_max, u):
    """Uniform cone sampling (numerics.sampling.cone_local) around per-query unit ``axis``
    (m, 3)."""
    return to_world(cone_local(u, one_minus_cos_max), orthonormal_basis(axis))


@dataclass
class Light:
    """Base: ``path`` (prim path), ``radiance`` (3,) float64 (meaning per subclass).

    The native form: ``KIND`` names the light's kind and ``FIELDS`` ((name, width) pairs) the
    parameters of its row in the baker's light table (``usdahd.bake.kernels.layout
    .LIGHT_PARAMS``: the numba routines read them as ``PAR_<NAME>``); :meth:`pack` writes
    exactly those fields. Light linking (``usdahd.usd.lights.LightReader.link_membership``):
    ``lit_meshes`` / ``shadow_meshes`` (k,) int32 scene mesh indices the light lights / whose
    shadows it casts, None for every mesh."""

    path: str
    radiance: np.ndarray
    delta = False
    infinite = False
    #: False for lights that NEE need not sample (a uniform dome is better covered by
    #: hemisphere sampling alone).
    sampled = True
    lit_meshes = None
    shadow_meshes = None
    KIND = ""
    FIELDS = ()

    def bound(self) -> Bound:
        """The light's :class:`Bound` (which light a path vertex samples)."""
        raise NotImplementedError

    def pack(self, rec, blocks) -> None:
        """Write this light's ``FIELDS`` into ``rec`` (a named row view: ``rec.center = c``);
        ``blocks.add(img (k, 3), pmf (k,), cdf (k,))`` appends per-pixel tables shared by all
        lights and returns their offset."""
        raise NotImplementedError


@dataclass
class SphereLight(Light):
    """Uniformly emitting sphere: ``center`` (3,), ``radius`` (world units)."""

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius: float = 0.5
    KIND = "sphere"
    FIELDS = (("center", 3), ("radius", 1))

    def pack(self, rec, blocks) -> None:
        rec.center = self.center
        rec.radius = self.radius

    def _omc(self, p):
        w = self.center - p
        d2 = np.einsum("ij,ij->i", w, w)
        r2 = self.radius * self.radius
        outside = d2 > r2
        sin2 = np.where(outside, r2 / np.where(outside, d2, 1.0), 1.0)
        cos_max = np.sqrt(np.clip(1.0 - sin2, 0.0, None))
        omc = sin2 / (1.0 + cos_max)  # 1 - cos_max without cancellation
        return w, d2, outside, omc

    def bound(self) -> Bound:
        L = _lum(self.radiance)
        r2 = float(self.radius) ** 2
        return Bound(
            FALLOFF_ISOTROPIC, np.pi * r2 * L, r2, np.pi * L, np.asarray(self.center, float)
        )

    def sample(self, p, u):
        w, d2, outside, omc = self._omc(p)
        axis = w / np.sqrt(np.maximum(d2, 1e-300))[:, None]
        dirs = _cone_dirs(axis, omc, u)
        t = self._hit_t(p, dirs)
        t = np.where(np.isfinite(t), t, np.sqrt(d2))
        pdf = np.where(outside, 1.0 / (TWO_PI * np.maximum(omc, 1e-300)), 0.0)
        value = np.where(outside[:, None], self.radiance[None, :], 0.0)
        return dirs, t, value, pdf

    def _hit_t(self, o, d):
        oc = o - self.center
        b = np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - self.radius * self.radius
        disc = b * b - c
        ok = (disc >= 0) & (c > 0)
        t = -b - np.sqrt(np.where(ok, disc, 0.0))
        return np.where(ok & (t > 0), t, np.inf)

    def intersect(self, o, d):
        t = self._hit_t(o, d)
        hit = np.isfinite(t)
        rad = np.where(hit[:, None], self.radiance[None, :], 0.0)
        return hit, t, rad

    def pdf(self, o, d, t):
        _, _, outside, omc = self._omc(o)
        return np.where(outside, 1.0 / (TWO_PI * np.maximum(omc, 1e-300)), 0.0)


@dataclass
class PointLight(Light):
    """A SphereLight with ``treatAsPoint``: delta light at ``center``.

    ``radiance`` here is the radiant intensity I = L * pi * r^2 (the far field of the sphere it
    replaces, so both give the same irradiance I cos / d^2 outside the sphere).
    """

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    delta = True
    KIND = "point"
    FIELDS = (("center", 3),)

    def pack(self, rec, blocks) -> None:
        rec.center = self.center

    def bound(self) -> Bound:
        return Bound(
            FALLOFF_ISOTROPIC, _lum(self.radiance), 0.0, np.inf, np.asarray(self.center, float)
        )

    def sample(self, p, u):
        w = self.center - p
        dist = _norm(w)
        dirs = w / np.maximum(dist, 1e-300)[:, None]
        value = self.radiance[None, :] / np.maximum(dist * dist, 1e-300)[:, None]
        return dirs, dist, value, np.ones(len(p))

    def intersect(self, o, d):
        n = len(o)
        return np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3))

    def pdf(self, o, d, t):
        return np.zeros(len(o))


@dataclass
class _PlanarLight(Light):
    """Rect or disk: ``center`` (3,), half-axes ``ex``, ``ey`` (3,) world vectors,
    emission direction ``normal`` (3,) unit (the light's -Z in world space)."""

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ex: np.ndarray = field(default_factory=lambda: np.array([0.5, 0, 0]))
    ey: np.ndarray = field(default_factory=lambda: np.array([0, 0.5, 0]))
    normal: np.ndarray = field(default_factory=lambda: np.array([0, 0, -1.0]))
    #: half-extent edges, emitting side, world area, inverse Gram of (ex, ey) row major, unit
    #: plane normal of the hit test
    FIELDS = (
        ("center", 3),
        ("ex", 3),
        ("ey", 3),
        ("normal", 3),
        ("area", 1),
        ("ginv", 4),
        ("plane_n", 3),
    )

    def pack(self, rec, blocks) -> None:
        rec.center, rec.ex, rec.ey, rec.normal = self.center, self.ex, self.ey, self.normal
        rec.area = self.area
        rec.ginv = self._ginv
        rec.plane_n = self._pn

    def __post_init__(self):
        g = np.array(
            [[self.ex @ self.ex, self.ex @ self.ey], [self.ey @ self.ex, self.ey @ self.ey]]
        )
        self._ginv = np.linalg.inv(g)
        n = np.cross(self.ex, self.ey)
        self._pn = n / np.linalg.norm(n)

    @property
    def area(self) -> float:
        raise NotImplementedError

    def _unit(self, u):
        raise NotImplementedError

    def _inside(self, a, b):
        raise NotImplementedError

    def bound(self) -> Bound:
        L, a = _lum(self.radiance), self.area
        c, n = np.asarray(self.center, float), np.asarray(self.normal, float)
        return Bound(FALLOFF_FRONT, L * a, a / np.pi, np.pi * L, c, n)

    def sample(self, p, u):
        ab = self._unit(u)
        q = self.center + ab[:, :1] * self.ex + ab[:, 1:2] * self.ey
        w = q - p
        dist = _norm(w)
        dirs = w / np.maximum(dist, 1e-300)[:, None]
        cos_l = -(dirs @ self.normal)
        front = cos_l > 0
        pdf = np.where(front, dist * dist / (self.area * np.where(front, cos_l, 1.0)), 0.0)
        value = np.where(front[:, None], self.radiance[None, :], 0.0)
        return dirs, dist, value, pdf

    def intersect(self, o, d):
        den = d @ self._pn
        ok = np.abs(den) > 1e-12
        t = np.where(ok, ((self.center - o) @ self._pn) / np.where(ok, den, 1.0), -1.0)
        q = o + t[:, None] * d - self.center
        rhs = np.stack([q @ self.ex, q @ self.ey], axis=-1)
        ab = rhs @ self._ginv.T
        front = -(d @ self.normal) > 0
        hit = ok & (t > 0) & front & self._inside(ab[:, 0], ab[:, 1])
        t = np.where(hit, t, np.inf)
        return hit, t, np.where(hit[:, None], self.radiance[None, :], 0.0)

    def pdf(self, o, d, t):
        cos_l = -(d @ self.normal)
        ok = (cos_l > 0) & np.isfinite(t)
        return np.where(ok, t * t / (self.area * np.where(ok, cos_l, 1.0)), 0.0)


@dataclass
class RectLight(_PlanarLight):
    """UsdLuxRectLight: width along ``2*ex``, height along ``2*ey``, emits towards ``normal``.

    Sampled uniformly in the solid angle it subtends (spherical rectangle, Urena et al. 2013)
    when that solid angle lies in [SPHERICAL_RECT_MIN_SR, SPHERICAL_RECT_MAX_SR] and the edges
    are orthogonal (no shear); by area otherwise. The pdf follows the same rule, so MIS weights
    agree with the sampler.
    """

    KIND = "rect"
    #: rect_ortho: 1 when the edges are orthogonal (solid-angle sampling applies)
    FIELDS = _PlanarLight.FIELDS + (("rect_ortho", 1),)

    def __post_init__(self):
        super().__post_init__()
        ne, ny = np.linalg.norm(self.ex), np.linalg.norm(self.ey)
        self.orthogonal = bool(abs(self.ex @ self.ey) <= 1e-9 * ne * ny)

    def pack(self, rec, blocks) -> None:
        super().pack(rec, blocks)
        rec.rect_ortho = 1.0 if self.orthogonal else 0.0

    @property
    def area(self) -> float:
        return float(4.0 * np.linalg.norm(np.cross(self.ex, self.ey)))

    def _solid(self, p):
        """(m,) solid angle when the solid-angle sampler applies at ``p``, else 0 (the rule of
        SPHERICAL_RECT_MIN_SR: an estimate from the centre first, the exact set-up only where
        that estimate is large)."""
        out = np.zeros(len(p))
        if not self.orthogonal:
            return out
        w = p - self.center
        d2 = np.einsum("ij,ij->i", w, w)
        cos_l = (w @ self.normal) / np.sqrt(np.maximum(d2, 1e-300))
        cand = np.nonzero(self.area * np.maximum(cos_l, 0.0) >= SPHERICAL_RECT_MIN_SR * d2)[0]
        if len(cand):
            _, sr = spherical_rectangle(
                p[cand], self.center - self.ex - self.ey, 2 * self.ex, 2 * self.ey, None
            )
            out[cand] = np.where((sr > 0) & (sr <= SPHERICAL_RECT_MAX_SR), sr, 0.0)
        return out

    def sample(self, p, u):
        dirs, dist, value, pdf = super().sample(p, u)
        sr = self._solid(p)
        use = sr > 0
        if np.any(use):
            q, _ = spherical_rectangle(
                p[use], self.center - self.ex - self.ey, 2 * self.ex, 2 * self.ey, u[use]
            )
            w = q - p[use]
            dd = _norm(w)
            d = w / np.maximum(dd, 1e-300)[:, None]
            front = -(d @ self.normal) > 0
            dirs[use], dist[use] = d, dd
            value[use] = np.where(front[:, None], self.radiance[None, :], 0.0)
            pdf[use] = np.where(front, 1.0 / sr[use], 0.0)
        return dirs, dist, value, pdf

    def pdf(self, o, d, t):
        base = super().pdf(o, d, t)
        sr = self._solid(o)
        return np.where((sr > 0) & (base > 0), 1.0 / np.where(sr > 0, sr, 1.0), base)

    def _unit(self, u):
        return 2.0 * u - 1.0

    def _inside(self, a, b):
        return (np.abs(a) <= 1.0) & (np.abs(b) <= 1.0)


@dataclass
class DiskLight(_PlanarLight):
    """UsdLuxDiskLight: ellipse ``center + a ex + b ey``, a^2 + b^2 <= 1, emits to ``normal``."""

    KIND = "disk"

    @property
    def area(self) -> float:
        return float(np.pi * np.linalg.norm(np.cross(self.ex, self.ey)))

    def _unit(self, u):
        return concentric_disk(u)

    def _inside(self, a, b):
        return a * a + b * b <= 1.0


@dataclass
class CylinderLight(Light):
    """UsdLuxCylinderLight: axis ``axis`` (unit, the light's X), ``half_length``, ``radius``.
    Emits outwards from the side only (no end caps), as the schema says."""

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0, 0]))
    half_length: float = 0.5
    radius: float = 0.5
    KIND = "cylinder"
    #: cyl_e1, cyl_e2: unit vectors across the axis
    FIELDS = (
        ("center", 3),
        ("axis", 3),
        ("radius", 1),
        ("area", 1),
        ("half_length", 1),
        ("cyl_e1", 3),
        ("cyl_e2", 3),
    )

    def __post_init__(self):
        f = orthonormal_basis(self.axis[None, :])[0]
        self._e1, self._e2 = f[0], f[1]

    def pack(self, rec, blocks) -> None:
        rec.center, rec.axis = self.center, self.axis
        rec.radius, rec.area, rec.half_length = self.radius, self.area, self.half_length
        rec.cyl_e1, rec.cyl_e2 = self._e1, self._e2

    @property
    def area(self) -> float:
        return float(TWO_PI * self.radius * 2.0 * self.half_length)

    def bound(self) -> Bound:
        # far field of a side-emitting cylinder ~ its power pi * area * L spread over 4 pi
        L = _lum(self.radiance)
        r2 = float(self.radius) ** 2 + float(self.half_length) ** 2
        return Bound(
            FALLOFF_ISOTROPIC, 0.25 * self.area * L, r2, np.pi * L, np.asarray(self.center, float)
        )

    def sample(self, p, u):
        x = (2.0 * u[:, 0] - 1.0) * self.half_length
        phi = TWO_PI * u[:, 1]
        radial = np.cos(phi)[:, None] * self._e1 + np.sin(phi)[:, None] * self._e2
        q = self.center + x[:, None] * self.axis + self.radius * radial
        w = q - p
        dist = _norm(w)
        dirs = w / np.maximum(dist, 1e-300)[:, None]
        cos_l = -np.einsum("ij,ij->i", dirs, radial)
        front = cos_l > 0
        pdf = np.where(front, dist * dist / (self.area * np.where(front, cos_l, 1.0)), 0.0)
        return dirs, dist, np.where(front[:, None], self.radiance[None, :], 0.0), pdf

    def _hit(self, o, d):
        oc = o - self.center
        op = oc - (oc @ self.axis)[:, None] * self.axis
        dp = d - (d @ self.axis)[:, None] * self.axis
        a = np.einsum("ij,ij->i", dp, dp)
        b = np.einsum("ij,ij->i", op, dp)
        c = np.einsum("ij,ij->i", op, op) - self.radius**2
        disc = b * b - a * c
        ok = (a > 1e-18) & (disc >= 0) & (c > 0)
        t = (-b - np.sqrt(np.where(ok, disc, 0.0))) / np.where(ok, a, 1.0)
        x = (oc + t[:, None] * d) @ self.axis
        hit = ok & (t > 0) & (np.abs(x) <= self.half_length)
        return hit, np.where(hit, t, np.inf), oc + t[:, None] * d - x[:, None] * self.axis

    def intersect(self, o, d):
        hit, t, _ = self._hit(o, d)
        return hit, t, np.where(hit[:, None], self.radiance[None, :], 0.0)

    def pdf(self, o, d, t):
        hit, t2, radial = self._hit(o, d)
        cos_l = -np.einsum("ij,ij->i", d, radial) / self.radius
        ok = hit & (cos_l > 0)
        return np.where(ok, t2 * t2 / (self.area * np.where(ok, cos_l, 1.0)), 0.0)


@dataclass
class DistantLight(Light):
    """UsdLuxDistantLight. ``direction`` (3,) unit vector *towards* the light (its +Z).

    ``half_angle`` > 0: a disc of radiance ``radiance`` subtending that half-angle (radians).
    ``half_angle`` == 0: a delta light whose ``radiance`` holds the illuminance at normal
    incidence.
    """

    direction: np.ndarray = field(default_factory=lambda: np.array([0, 0, 1.0]))
    half_angle: float = 0.0
    infinite = True
    KIND = "distant"
    #: direction towards the light; omc, cos_max: 1 - cos(half angle), cos(half angle)
    FIELDS = (("direction", 3), ("omc", 1), ("cos_max", 1))

    def __post_init__(self):
        self.delta = self.half_angle <= 0.0
        s = np.sin(self.half_angle / 2.0)
        self._omc = 2.0 * s * s  # 1 - cos(half_angle)
        self._cos_max = 1.0 - self._omc

    def pack(self, rec, blocks) -> None:
        rec.direction = self.direction
        rec.omc, rec.cos_max = self._omc, self._cos_max

    def bound(self) -> Bound:
        L = _lum(self.radiance)  # delta: already the illuminance at normal incidence
        if not self.delta:
            L *= np.pi * (1.0 - self._cos_max**2)  # a disc of radiance L: pi sin^2(half angle)
        return Bound(FALLOFF_CONSTANT, cap=L)

    def sample(self, p, u):
        n = len(p)
        if self.delta:
            dirs = np.broadcast_to(self.direction, (n, 3)).copy()
            return dirs, np.full(n, np.inf), np.broadcast_to(self.radiance, (n, 3)), np.ones(n)
        axis = np.broadcast_to(self.direction, (n, 3))
        dirs = _cone_dirs(axis, self._omc, u)
        pdf = np.full(n, 1.0 / (TWO_PI * self._omc))
        return dirs, np.full(n, np.inf), np.broadcast_to(self.radiance, (n, 3)), pdf

    def intersect(self, o, d):
        n = len(o)
        if self.delta:
            return np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3))
        hit = d @ self.direction >= self._cos_max
        return hit, np.full(n, np.inf), np.where(hit[:, None], self.radiance[None, :], 0.0)

    def pdf(self, o, d, t):
        if self.delta:
            return np.zeros(len(o))
        hit = d @ self.direction >= self._cos_max
        return np.where(hit, 1.0 / (TWO_PI * self._omc), 0.0)


@dataclass
class DomeLight(Light):
    """UsdLuxDomeLight: uniform ``radiance`` (3,), optionally times a latlong ``image``.

    image : (h, w, 3) float32 linear radiance multipliers or None (OpenEXR latlong layout:
        column 0 = longitude +pi, row 0 = latitude +pi/2, longitude 0 = local +Z, pi/2 = +X,
        pole = local +Y).
    rotation : (3, 3) world-from-dome rotation (dome transform and pole alignment).
    Textured domes are importance sampled by a piecewise-constant 2-D CDF over
    luminance * sin(theta); uniform domes are left to hemisphere sampling (``sampled`` False).
    """

    image: np.ndarray | None = None
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    infinite = True
    KIND = "dome"
    #: textured flag; offsets of the image's pmf/cdf and pixels in the shared blocks;
    #: world-from-dome rotation (row major), its inverse; image height, width
    FIELDS = (
        ("dome_textured", 1),
        ("dome_pmf", 1),
        ("dome_pix", 1),
        ("dome_rot", 9),
        ("dome_inv_rot", 9),
        ("dome_h", 1),
        ("dome_w", 1),
    )

    def pack(self, rec, blocks) -> None:
        rec.dome_rot = np.asarray(self.rotation, np.float64)
        if self.image is None:  # uniform: hit by rays only, never sampled
            rec.dome_textured = rec.dome_pmf = rec.dome_pix = rec.dome_h = rec.dome_w = 0.0
            rec.dome_inv_rot = np.zeros(9)
            return
        h, w = self._img.shape[:2]
        rec.dome_textured = 1.0
        rec.dome_pmf = rec.dome_pix = blocks.add(
            self._img[..., :3].reshape(-1, 3), self._pmf, self._cdf
        )
        rec.dome_inv_rot = self._inv_rot
        rec.dome_h, rec.dome_w = h, w

    def __post_init__(self):
        self.sampled = self.image is not None
        if self.image is None:
            return
        img = np.asarray(self.image, dtype=np.float64)
        h, w = img.shape[:2]
        self._img = img
        theta = np.pi * (np.arange(h) + 0.5) / h
        lum = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        wgt = np.maximum(lum, 0.0) * np.sin(theta)[:, None]
        if not np.any(wgt > 0):
            wgt = np.ones_like(wgt) * np.sin(theta)[:, None]
        flat = wgt.reshape(-1)
        self._pmf = flat / flat.sum()
        self._cdf = np.cumsum(self._pmf)
        self._cdf[-1] = 1.0
        self._inv_rot = np.linalg.inv(self.rotation)

    def _lookup(self, d):
        loc = d @ self._inv_rot.T
        loc /= np.maximum(_norm(loc), 1e-300)[:, None]
        h, w = self._img.shape[:2]
        lat = np.arcsin(np.clip(loc[:, 1], -1.0, 1.0))
        lon = np.arctan2(loc[:, 0], loc[:, 2])
        x = np.clip(((np.pi - lon) / TWO_PI * w).astype(np.int64), 0, w - 1)
        y = np.clip(((0.5 * np.pi - lat) / np.pi * h).astype(np.int64), 0, h - 1)
        return x, y

    def eval(self, d):
        """Radiance arriving along world directions ``d`` (m,3) -> (m,3)."""
        if self.image is None:
            return np.broadcast_to(self.radiance, d.shape).copy()
        x, y = self._lookup(d)
        return self._img[y, x, :3] * self.radiance[None, :]

    def bound(self) -> Bound:
        m = 1.0
        if self.image is not None:  # the image's mean luminance over the sphere
            h = self._img.shape[0]
            sin = np.sin(np.pi * (np.arange(h) + 0.5) / h)
            lum = np.maximum(self._img[..., :3] @ LUMINANCE, 0.0).mean(axis=1)
            m = float((lum * sin).sum() / sin.sum())
        return Bound(FALLOFF_CONSTANT, cap=np.pi * _lum(self.radiance) * m)

    def sample(self, p, u):
        n = len(p)
        h, w = self._img.shape[:2]
        # Reuse u[:,0] for the pixel choice and a stratified remainder for the jitter.
        idx = sample_discrete(self._cdf, u[:, 0])
        lo = np.where(idx > 0, self._cdf[np.maximum(idx - 1, 0)], 0.0)
        frac = np.clip((u[:, 0] - lo) / np.maximum(self._pmf[idx], 1e-300), 0.0, 1.0 - 1e-12)
        y, x = np.divmod(idx, w)
        theta = np.pi * (y + frac) / h
        lon = np.pi - TWO_PI * (x + u[:, 1]) / w
        lat = 0.5 * np.pi - theta
        loc = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), np.cos(lat) * np.cos(lon)], axis=-1)
        dirs = loc @ self.rotation.T
        dirs /= _norm(dirs)[:, None]
        pdf = self._pmf[idx] * (h * w) / (2.0 * np.pi * np.pi * np.maximum(np.sin(theta), 1e-12))
        value = self._img[y, x, :3] * self.radiance[None, :]
        return dirs, np.full(n, np.inf), value, pdf

    def intersect(self, o, d):
        n = len(o)
        return np.ones(n, bool), np.full(n, np.inf), self.eval(d)

    def pdf(self, o, d, t):
        if self.image is None:
            return np.zeros(len(o))
        h, w = self._img.shape[:2]
        x, y = self._lookup(d)
        loc = d @ self._inv_rot.T
        sin_t = np.sqrt(np.clip(1.0 - (loc[:, 1] / np.maximum(_norm(loc), 1e-300)) ** 2, 0, 1))
        return self._pmf[y * w + x] * (h * w) / (2.0 * np.pi * np.pi * np.maximum(sin_t, 1e-12))


@dataclass
class EmissiveTriangles(Light):
    """Every emissive triangle of the scene as one light (UsdPreviewSurface ``emissiveColor``;
    front faces emit, both faces on ``doubleSided`` meshes). Sampled by power: a triangle with
    probability proportional to its area times the luminance of its emission (textured
    emission: estimated at four points, floored so that no emissive triangle has probability
    0), then a uniform point on it. Built by the
    integrator from its tracer (:meth:`from_tracer`), since emission is looked up at the sample.

    tri : (E,) int64 global triangle ids; verts : (E, 3, 3) float64; normal : (E, 3) float64
    unit front normals; area : (E,) float64; pmf, cdf : (E,) float64; pdf_area : (T,) float64
    probability per unit area of every global triangle (0 where not emissive), for MIS at hits;
    lum : (E,) float64 the emitted luminance estimate each triangle is chosen by (doubled
    for two-sided ones); two_sided : (E,) bool, triangles of ``doubleSided`` meshes, which
    emit from both faces (None: none);
    emission_at : callable(tri (m,), u (m,), v (m,)) -> (m, 3) emitted radiance (Embree
    barycentrics: p = (1-u-v) v0 + u v1 + v v2). ``radiance`` is unused (ones).
    """

    tri: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    verts: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    area: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pmf: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cdf: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pdf_area: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lum: np.ndarray = field(default_factory=lambda: np.zeros(0))
    two_sided: np.ndarray | None = None
    emission_at: object = None
    KIND = "emissive"
    #: offsets in the shared blocks of the per-emitter pmf/cdf (E entries), of the global
    #: triangles' ``pdf_area`` (T entries, in ``pmf``), of the emitters' global triangle ids
    #: (E entries, float64 in ``pmf``); E
    FIELDS = (("em_table", 1), ("em_pdf_area", 1), ("em_tri", 1), ("em_count", 1))

    def pack(self, rec, blocks) -> None:
        ne, nt = len(self.tri), len(self.pdf_area)
        rec.em_table = blocks.add(np.zeros((ne, 3)), self.pmf, self.cdf)
        rec.em_count = ne
        rec.em_pdf_area = blocks.add(np.zeros((nt, 3)), self.pdf_area, np.zeros(nt))
        rec.em_tri = blocks.add(np.zeros((ne, 3)), self.tri.astype(np.float64), np.zeros(ne))

    @classmethod
    def from_tracer(cls, tracer) -> EmissiveTriangles | None:
        """The emissive triangles of ``tracer``'s scene, or None when nothing emits."""
        mat = tracer.tri_material
        tri = np.nonzero(tracer.emissive_materials[mat])[0].astype(np.int64)
        if len(tri) == 0:
            return None
        v = tracer.verts[tri].astype(np.float64)
        cr = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        area = 0.5 * _norm(cr)
        keep = area > 0
        tri, v, cr, area = tri[keep], v[keep], cr[keep], area[keep]
        if len(tri) == 0:
            return None
        # luminance estimate per triangle: centroid and three interior points
        uv = np.array([[1 / 3, 1 / 3], [2 / 3, 1 / 6], [1 / 6, 2 / 3], [1 / 6, 1 / 6]])
        lum = np.zeros(len(tri))
        for a, b in uv:
            e = tracer.emission_at(tri, np.full(len(tri), a), np.full(len(tri), b))
            lum += np.clip(np.asarray(e, np.float64)[:, :3], 0, None) @ LUMINANCE / len(uv)
        if not np.any(lum > 0):
            lum = np.ones(len(tri))
        lum = np.maximum(lum, 1e-3 * lum.max())  # every emissive triangle can be chosen
        two = ~np.asarray(tracer.tri_one_sided, bool)[tri]  # doubleSided: both faces emit
        lum = lum * np.where(two, 2.0, 1.0)  # (its power: both hemispheres)
        power = area * lum
        pmf = power / power.sum()
        cdf = np.cumsum(pmf)
        cdf[-1] = 1.0
        pdf_area = np.zeros(len(tracer.tri_material))
        pdf_area[tri] = pmf / area
        return cls(
            "<emissive triangles>",
            np.ones(3),
            tri=tri,
            verts=v,
            normal=cr / (2.0 * area)[:, None],
            area=area,
            pmf=pmf,
            cdf=cdf,
            pdf_area=pdf_area,
            lum=lum,
            two_sided=two,
            emission_at=tracer.emission_at,
        )

    def _pick(self, u):
        """Triangle index and barycentrics (u, v) from unit-square samples u (m, 2)."""
        k = sample_discrete(self.cdf, u[:, 0])
        lo = np.where(k > 0, self.cdf[np.maximum(k - 1, 0)], 0.0)
        u0 = np.clip((u[:, 0] - lo) / np.maximum(self.pmf[k], 1e-300), 0.0, 1.0)
        su = np.sqrt(u0)
        return k, 1.0 - su, u[:, 1] * su

    def bound(self) -> Bound:
        # every emitter as one isotropic source at their power-weighted centroid, "close"
        # within the sphere around it that holds every emitting vertex
        power = self.area * self.lum
        tot = float(power.sum())
        c = (power @ self.verts.mean(axis=1)) / tot if tot > 0 else self.verts.mean(axis=(0, 1))
        r2 = float(np.max(np.einsum("ijk,ijk->ij", self.verts - c, self.verts - c)))
        return Bound(FALLOFF_ISOTROPIC, tot, r2, np.pi * float(self.lum.max()), c)

    def sample(self, p, u):
        k, bu, bv = self._pick(u)
        v = self.verts[k]
        q = (1.0 - bu - bv)[:, None] * v[:, 0] + bu[:, None] * v[:, 1] + bv[:, None] * v[:, 2]
        w = q - p
        dist = _norm(w)
        dirs = w / np.maximum(dist, 1e-300)[:, None]
        cos_l = -np.einsum("ij,ij->i", dirs, self.normal[k])
        if self.two_sided is not None:
            cos_l = np.where(self.two_sided[k], np.abs(cos_l), cos_l)
        front = cos_l > 0
        pdf = np.where(
            front, self.pmf[k] / self.area[k] * dist * dist / np.where(front, cos_l, 1.0), 0.0
        )
        em = np.asarray(self.emission_at(self.tri[k], bu, bv), np.float64)[:, :3]
        value = np.where(front[:, None], em, 0.0)
        return dirs, dist, value, pdf

    def pdf_hit(self, tri, t, cos_abs):
        """Solid-angle pdf of hitting global triangle ``tri`` (m,) at distance ``t`` with
        |cos| ``cos_abs`` at the emitter (0 for triangles not in the light)."""
        return self.pdf_area[tri] * t * t / np.maximum(cos_abs, 1e-300)

    def intersect(self, o, d):  # emitters are geometry: hits are found by the tracer
        n = len(o)
        return np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3))

    def pdf(self, o, d, t):  # pragma: no cover - MIS at emitters uses pdf_hit
        return np.zeros(len(o))


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
