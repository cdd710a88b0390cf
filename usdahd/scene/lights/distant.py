"""UsdLuxDistantLight: a sun disc of a given angle, or a delta direction."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usdahd.scene.lights.base import (
    FALLOFF_CONSTANT,
    TWO_PI,
    Bound,
    Light,
    LightHits,
    LightSamples,
    cone_dirs,
    lum,
)

__all__ = ["DistantLight"]


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
        L = lum(self.radiance)  # delta: already the illuminance at normal incidence
        if not self.delta:
            L *= np.pi * (1.0 - self._cos_max**2)  # a disc of radiance L: pi sin^2(half angle)
        return Bound(FALLOFF_CONSTANT, cap=L)

    def sample(self, p, u):
        n = len(p)
        if self.delta:
            dirs = np.broadcast_to(self.direction, (n, 3)).copy()
            rad = np.broadcast_to(self.radiance, (n, 3))
            return LightSamples(dirs, np.full(n, np.inf), rad, np.ones(n))
        axis = np.broadcast_to(self.direction, (n, 3))
        dirs = cone_dirs(axis, self._omc, u)
        pdf = np.full(n, 1.0 / (TWO_PI * self._omc))
        return LightSamples(dirs, np.full(n, np.inf), np.broadcast_to(self.radiance, (n, 3)), pdf)

    def intersect(self, o, d):
        n = len(o)
        if self.delta:
            return LightHits(np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3)))
        hit = d @ self.direction >= self._cos_max
        rad = np.where(hit[:, None], self.radiance[None, :], 0.0)
        return LightHits(hit, np.full(n, np.inf), rad)

    def pdf(self, o, d, t):
        if self.delta:
            return np.zeros(len(o))
        hit = d @ self.direction >= self._cos_max
        return np.where(hit, 1.0 / (TWO_PI * self._omc), 0.0)
