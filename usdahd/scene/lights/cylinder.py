"""UsdLuxCylinderLight: a side-emitting cylinder."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usdahd.numerics.sampling import orthonormal_basis
from usdahd.scene.lights.base import (
    FALLOFF_ISOTROPIC,
    TWO_PI,
    Bound,
    Light,
    LightHits,
    LightSamples,
    lum,
    norm,
)

__all__ = ["CylinderLight"]


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
        L = lum(self.radiance)
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
        dist = norm(w)
        dirs = w / np.maximum(dist, 1e-300)[:, None]
        cos_l = -np.einsum("ij,ij->i", dirs, radial)
        front = cos_l > 0
        pdf = np.where(front, dist * dist / (self.area * np.where(front, cos_l, 1.0)), 0.0)
        return LightSamples(dirs, dist, np.where(front[:, None], self.radiance[None, :], 0.0), pdf)

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
        return LightHits(hit, t, np.where(hit[:, None], self.radiance[None, :], 0.0))

    def pdf(self, o, d, t):
        hit, t2, radial = self._hit(o, d)
        cos_l = -np.einsum("ij,ij->i", d, radial) / self.radius
        ok = hit & (cos_l > 0)
        return np.where(ok, t2 * t2 / (self.area * np.where(ok, cos_l, 1.0)), 0.0)
