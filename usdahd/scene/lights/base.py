"""The light base class, the selection bound every light provides and shared helpers."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from usdahd.numerics.sampling import (
    cone_local,
    orthonormal_basis,
    to_world,
)
from usdahd.numerics.sh import LUMINANCE

__all__ = [
    "Bound",
    "FALLOFF_CONSTANT",
    "FALLOFF_FRONT",
    "FALLOFF_ISOTROPIC",
    "Light",
    "LightHits",
    "LightSamples",
    "TWO_PI",
    "cone_dirs",
    "lum",
    "norm",
    "selection_pmf",
]

TWO_PI = 2.0 * np.pi


class LightSamples(NamedTuple):
    """What ``Light.sample`` returns for m query points (float64): unit directions ``dirs``
    (m, 3) towards the light, distances ``dist`` (m,) (inf: infinite lights), the radiance
    arriving ``value`` (m, 3) (delta lights: the irradiance at normal incidence) and the
    solid-angle ``pdf`` (m,) (1 for delta lights, 0: invalid)."""

    dirs: np.ndarray
    dist: np.ndarray
    value: np.ndarray
    pdf: np.ndarray


class LightHits(NamedTuple):
    """What ``Light.intersect`` returns for m rays: ``hit`` (m,) bool, distance ``t`` (m,)
    (inf for infinite lights and misses), emitted ``radiance`` (m, 3) (0 on misses)."""

    hit: np.ndarray
    t: np.ndarray
    radiance: np.ndarray


def norm(v):
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
    The numba twin is ``usdahd.bake.kernels.shading.nee_pick`` / ``nee_sel``."""
    n = len(bounds)
    imp = np.stack([b.importance(p) for b in bounds], axis=1)
    tot = imp.sum(axis=1, keepdims=True)
    share = np.where(tot > 0.0, imp / np.where(tot > 0.0, tot, 1.0), 1.0 / n)
    return floor / n + (1.0 - floor) * share


def lum(rgb) -> float:
    return float(np.asarray(rgb, np.float64)[:3] @ LUMINANCE)


def cone_dirs(axis, one_minus_cos_max, u):
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
