"""UsdLuxRectLight and UsdLuxDiskLight: one-sided planar emitters."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usdahd.numerics.sampling import (
    SPHERICAL_RECT_MAX_SR,
    SPHERICAL_RECT_MIN_SR,
    concentric_disk,
    spherical_rectangle,
)
from usdahd.scene.lights.base import FALLOFF_FRONT, Bound, Light, LightHits, LightSamples, lum, norm

__all__ = ["DiskLight", "PlanarLight", "RectLight"]


@dataclass
class PlanarLight(Light):
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
        L, a = lum(self.radiance), self.area
        c, n = np.asarray(self.center, float), np.asarray(self.normal, float)
        return Bound(FALLOFF_FRONT, L * a, a / np.pi, np.pi * L, c, n)

    def sample(self, p, u):
        ab = self._unit(u)
        q = self.center + ab[:, :1] * self.ex + ab[:, 1:2] * self.ey
        w = q - p
        dist = norm(w)
        dirs = w / np.maximum(dist, 1e-300)[:, None]
        cos_l = -(dirs @ self.normal)
        front = cos_l > 0
        pdf = np.where(front, dist * dist / (self.area * np.where(front, cos_l, 1.0)), 0.0)
        value = np.where(front[:, None], self.radiance[None, :], 0.0)
        return LightSamples(dirs, dist, value, pdf)

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
        return LightHits(hit, t, np.where(hit[:, None], self.radiance[None, :], 0.0))

    def pdf(self, o, d, t):
        cos_l = -(d @ self.normal)
        ok = (cos_l > 0) & np.isfinite(t)
        return np.where(ok, t * t / (self.area * np.where(ok, cos_l, 1.0)), 0.0)


@dataclass
class RectLight(PlanarLight):
    """UsdLuxRectLight: width along ``2*ex``, height along ``2*ey``, emits towards ``normal``.

    Sampled uniformly in the solid angle it subtends (spherical rectangle, Urena et al. 2013)
    when that solid angle lies in [SPHERICAL_RECT_MIN_SR, SPHERICAL_RECT_MAX_SR] and the edges
    are orthogonal (no shear); by area otherwise. The pdf follows the same rule, so MIS weights
    agree with the sampler.
    """

    KIND = "rect"
    #: rect_ortho: 1 when the edges are orthogonal (solid-angle sampling applies)
    FIELDS = PlanarLight.FIELDS + (("rect_ortho", 1),)

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
        base = super().sample(p, u)
        dirs, dist, value, pdf = base.dirs, base.dist, base.value, base.pdf
        sr = self._solid(p)
        use = sr > 0
        if np.any(use):
            q, _ = spherical_rectangle(
                p[use], self.center - self.ex - self.ey, 2 * self.ex, 2 * self.ey, u[use]
            )
            w = q - p[use]
            dd = norm(w)
            d = w / np.maximum(dd, 1e-300)[:, None]
            front = -(d @ self.normal) > 0
            dirs[use], dist[use] = d, dd
            value[use] = np.where(front[:, None], self.radiance[None, :], 0.0)
            pdf[use] = np.where(front, 1.0 / sr[use], 0.0)
        return LightSamples(dirs, dist, value, pdf)

    def pdf(self, o, d, t):
        base = super().pdf(o, d, t)
        sr = self._solid(o)
        return np.where((sr > 0) & (base > 0), 1.0 / np.where(sr > 0, sr, 1.0), base)

    def _unit(self, u):
        return 2.0 * u - 1.0

    def _inside(self, a, b):
        return (np.abs(a) <= 1.0) & (np.abs(b) <= 1.0)


@dataclass
class DiskLight(PlanarLight):
    """UsdLuxDiskLight: ellipse ``center + a ex + b ey``, a^2 + b^2 <= 1, emits to ``normal``."""

    KIND = "disk"

    @property
    def area(self) -> float:
        return float(np.pi * np.linalg.norm(np.cross(self.ex, self.ey)))

    def _unit(self, u):
        return concentric_disk(u)

    def _inside(self, a, b):
        return a * a + b * b <= 1.0
