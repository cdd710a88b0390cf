"""UsdLuxSphereLight: a uniformly emitting sphere, or a point light (``treatAsPoint``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usdahd.scene.lights.base import (
    FALLOFF_ISOTROPIC,
    TWO_PI,
    Bound,
    Light,
    LightHits,
    LightSamples,
    cone_dirs,
    lum,
    norm,
)

__all__ = ["PointLight", "SphereLight"]


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
        L = lum(self.radiance)
        r2 = float(self.radius) ** 2
        return Bound(
            FALLOFF_ISOTROPIC, np.pi * r2 * L, r2, np.pi * L, np.asarray(self.center, float)
        )

    def sample(self, p, u):
        w, d2, outside, omc = self._omc(p)
        axis = w / np.sqrt(np.maximum(d2, 1e-300))[:, None]
        dirs = cone_dirs(axis, omc, u)
        t = self._hit_t(p, dirs)
        t = np.where(np.isfinite(t), t, np.sqrt(d2))
        pdf = np.where(outside, 1.0 / (TWO_PI * np.maximum(omc, 1e-300)), 0.0)
        value = np.where(outside[:, None], self.radiance[None, :], 0.0)
        return LightSamples(dirs, t, value, pdf)

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
        return LightHits(hit, t, rad)

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
            FALLOFF_ISOTROPIC, lum(self.radiance), 0.0, np.inf, np.asarray(self.center, float)
        )

    def sample(self, p, u):
        w = self.center - p
        dist = norm(w)
        dirs = w / np.maximum(dist, 1e-300)[:, None]
        value = self.radiance[None, :] / np.maximum(dist * dist, 1e-300)[:, None]
        return LightSamples(dirs, dist, value, np.ones(len(p)))

    def intersect(self, o, d):
        n = len(o)
        return LightHits(np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3)))

    def pdf(self, o, d, t):
        return np.zeros(len(o))
