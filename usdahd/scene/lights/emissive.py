"""Emissive triangles (UsdPreviewSurface ``emissiveColor``) as one sampled light."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from usdahd.numerics.sampling import sample_discrete
from usdahd.numerics.sh import LUMINANCE
from usdahd.numerics.triangles import edge_cross
from usdahd.scene.lights.base import FALLOFF_ISOTROPIC, Bound, Light, LightHits, LightSamples, norm

__all__ = ["EmissiveTriangles"]


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
        cr = edge_cross(v)
        area = 0.5 * norm(cr)
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
        dist = norm(w)
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
        return LightSamples(dirs, dist, value, pdf)

    def pdf_hit(self, tri, t, cos_abs):
        """Solid-angle pdf of hitting global triangle ``tri`` (m,) at distance ``t`` with
        |cos| ``cos_abs`` at the emitter (0 for triangles not in the light)."""
        return self.pdf_area[tri] * t * t / np.maximum(cos_abs, 1e-300)

    def intersect(self, o, d):  # emitters are geometry: hits are found by the tracer
        n = len(o)
        return LightHits(np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3)))

    def pdf(self, o, d, t):  # pragma: no cover - MIS at emitters uses pdf_hit
        return np.zeros(len(o))
