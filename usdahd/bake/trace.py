"""Embree ray tracing: one BVH for the whole scene, batched float32 queries.

``Tracer(scene)`` concatenates every mesh (baked meshes, occluders, emissive geometry) into one
Embree triangle geometry, so an Embree primitive id is a global triangle id; per-triangle
tables map it back to mesh, material, geometric/shading normal and texture coordinates.

Conventions: embreex has no tnear (it is 0), so callers offset ray origins along the
geometric normal with :meth:`Tracer.offset` (the native backend keeps the same offsets, tnear
0, so both backends trace identical rays). Batch queries run in two threads over halves of a
batch (Embree releases the GIL); with embreex the first query, which commits the BVH, runs in
the constructor because it is not thread-safe. ``robust=False`` (measured 13-50 % faster).
:meth:`Tracer.run_parallel` spreads numba kernels over the same threads.

Alpha cut-outs (UsdPreviewSurface opacity/opacityThreshold) and stochastic opacity are handled
by re-tracing rays from the transmissive hit, at most ``MAX_TRANSMIT`` times. Path rays pass a
surface of fractional opacity ``op`` (no threshold) with probability ``1 - op``; shadow rays
(:meth:`Tracer.transmittance`) carry the product of ``1 - op`` over the surfaces they cross
instead (the same expectation, without the coin flip's noise: McUsd's rail in the shadow of
its stained-glass block). Both loops run only when the scene has transmissive materials
(plain OCCLUDED otherwise).

Backends (``backend=``): ``"native"`` calls the libembree4 shipped in the embreex wheel directly
(:mod:`usdahd.bake.kernels.embree`; queries from numba without the GIL, and the integrator's
fused kernel in :mod:`usdahd.bake.kernels.integrate`), ``"embreex"`` is the pure-embreex reference
(batched numpy queries). ``"auto"`` (default) picks native when the library binds. Both give
the same hits (same library, same build flags); ``native_tables()`` packs the per-triangle and
material/texture tables for numba.
"""

from __future__ import annotations

import copy
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from usdahd.bake.kernels import embree
from usdahd.bake.kernels.layout import (
    NativeTables,
)
from usdahd.numerics.offsets import FLT_EPS, OFFSET_ULPS, triangle_offset_scale

__all__ = ["MAX_TRANSMIT", "Tracer"]

#: Re-traces through cut-out/transmissive surfaces before a ray is considered blocked.
MAX_TRANSMIT = 8
#: Work items per thread in :meth:`Tracer.run_parallel` (dynamic load balance).
PARTS_PER_THREAD = 4
#: Batches smaller than this run on one thread (thread start-up would dominate).
THREAD_MIN_RAYS = 16384


class Tracer:
    """One BVH over ``scene.meshes``.

    Attributes (T = total triangles): ``tri_mesh`` (T,) int32, ``tri_local`` (T,) int32,
    ``tri_material`` (T,) int32, ``tri_one_sided`` (T,) bool (False on ``doubleSided``
    meshes, whose back faces are surfaces, not the inside of geometry: :meth:`back_face`),
    ``geom_normal`` (T,3) float32 unit, ``corner_normal``
    (T,3,3) float32, ``verts`` (T,3,3) float64, ``tri_offset`` (T,) float64 the ray-origin
    offset of points on each triangle (:func:`triangle_offset_scale`), ``offset_eps`` float the
    largest of them (for points whose triangle is not known), ``build_time`` s,
    ``rays_traced`` int (a running count).
    """

    def __init__(self, scene, threads: int = 2, backend: str = "auto"):
        t0 = time.perf_counter()
        if backend not in ("auto", "native", "embreex"):
            from usdahd.errors import UsageError

            raise UsageError(f"unknown tracer backend {backend!r} (auto, native or embreex)")
        if backend == "auto":
            backend = "native" if embree.available() else "embreex"
        self.backend = backend
        self.scene = scene
        self.threads = max(1, int(threads))
        pts, tris, mesh_id, local, mats, normals, tex, one = [], [], [], [], [], [], [], []
        base = 0
        for i, m in enumerate(scene.meshes):
            pts.append(m.points)
            tris.append(m.triangles.astype(np.int64) + base)
            base += len(m.points)
            n = len(m.triangles)
            mesh_id.append(np.full(n, i, np.int32))
            local.append(np.arange(n, dtype=np.int32))
            mats.append(m.material.astype(np.int32))
            one.append(np.full(n, not m.double_sided))
            normals.append(m.normals.astype(np.float32))
            tc = np.zeros((n, 3, 2), np.float32)
            tcs = scene.texcoords[i] if i < len(scene.texcoords) else {}
            for mi in np.unique(m.material):
                name = scene.materials[mi].texcoord
                if name in tcs:
                    sel = m.material == mi
                    tc[sel] = tcs[name][sel]
            tex.append(tc)
        points = np.concatenate(pts).astype(np.float64)
        self.triangles = np.concatenate(tris)
        self.tri_mesh = np.concatenate(mesh_id)
        self.tri_local = np.concatenate(local)
        self.tri_material = np.concatenate(mats)
        self.tri_one_sided = np.concatenate(one).astype(bool)
        self.corner_normal = np.concatenate(normals)
        self.tri_texcoord = np.concatenate(tex)
        self.verts = points[self.triangles]  # (T,3,3) float64
        e1 = self.verts[:, 1] - self.verts[:, 0]
        e2 = self.verts[:, 2] - self.verts[:, 0]
        gn = np.cross(e1, e2)
        ln = np.linalg.norm(gn, axis=1, keepdims=True)
        self.geom_normal = np.where(ln > 0, gn / np.where(ln > 0, ln, 1), [0, 0, 1.0]).astype(
            np.float32
        )
        lo, hi = points.min(axis=0), points.max(axis=0)
        self.extent = float(np.linalg.norm(hi - lo))
        self.tri_offset = triangle_offset_scale(self.verts)
        self.mesh_first = np.r_[0, np.cumsum([len(m.triangles) for m in scene.meshes])]
        self.offset_eps = float(self.tri_offset.max(initial=OFFSET_ULPS * FLT_EPS))
        self._embree = self._native = None
        if backend == "native":
            self._native = embree.NativeScene(points, self.triangles)
        else:
            self._embree = rtcore_scene.EmbreeScene(robust=False)
            TriangleMesh(
                self._embree,
                np.ascontiguousarray(points, dtype=np.float32),
                np.ascontiguousarray(self.triangles, dtype=np.int32),
            )
        # Material tables.
        mt = scene.materials
        self.albedo = np.array([m.albedo for m in mt], np.float32).reshape(-1, 3)
        self.emission = np.array([m.emission for m in mt], np.float32).reshape(-1, 3)
        self.emissive_materials = np.array([m.emissive for m in mt], bool)
        self.transmissive_materials = np.array([m.transmissive for m in mt], bool)
        self.has_transmission = bool(np.any(self.transmissive_materials[self.tri_material]))
        self.has_emission = bool(np.any(self.emissive_materials[self.tri_material]))
        self.rays_traced = 0
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        self._tables = None
        if self._embree is not None:
            # Commit the BVH now (first run is not thread-safe).
            self._embree.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self.build_time = time.perf_counter() - t0

    # ------------------------------------------------------------------ raw queries
    def _split(self, fn, n, *arrays):
        if self._pool is None or n < THREAD_MIN_RAYS:
            return [fn(*arrays)]
        k = self.threads
        bounds = np.linspace(0, n, k + 1).astype(int)
        futs = [
            self._pool.submit(fn, *[a[bounds[i] : bounds[i + 1]] for a in arrays]) for i in range(k)
        ]
        return [f.result() for f in futs]

    def run_parallel(self, fn, ids):
        """Run ``fn(part)`` on the tracer's threads over contiguous parts of ``ids`` (m,) int64
        (contiguous, so threads never write neighbouring texels' accumulators - no false
        sharing; several parts per thread balance texels of different cost and threads slowed
        down by other processes); returns the list of results in part order."""
        if self._pool is None or len(ids) < 2:
            return [fn(ids)]
        k = max(1, min(PARTS_PER_THREAD * self.threads, len(ids)))
        futs = [self._pool.submit(fn, np.ascontiguousarray(p)) for p in np.array_split(ids, k)]
        return [f.result() for f in futs]

    def _raw_intersect(self, o, d, tfar):
        if self._native is not None:

            def run(o_, d_, t_):
                m = len(o_)
                out = (
                    np.empty(m, np.float32),
                    np.empty(m, np.int64),
                    np.empty(m, np.float32),
                    np.empty(m, np.float32),
                )
                embree.intersect_batch(self._native.handle, o_, d_, t_, *out)
                return out[0], out[1].astype(np.int32), out[2], out[3]

        else:

            def run(o_, d_, t_):
                r = self._embree.run(o_, d_, dists=t_, output=1)
                return r["tfar"], r["primID"], r["u"], r["v"]

        parts = self._split(run, len(o), o, d, tfar)
        self.rays_traced += len(o)
        return tuple(np.concatenate([p[i] for p in parts]) for i in range(4))

    def _raw_occluded(self, o, d, tfar):
        if self._native is not None:

            def run(o_, d_, t_):
                out = np.empty(len(o_), bool)
                embree.occluded_batch(self._native.handle, o_, d_, t_, out)
                return out

        else:

            def run(o_, d_, t_):
                return self._embree.run(o_, d_, dists=t_, query="OCCLUDED") != -1

        parts = self._split(run, len(o), o, d, tfar)
        self.rays_traced += len(o)
        return np.concatenate(parts)

    # ------------------------------------------------------------------ public batch API
    def offset(self, p: np.ndarray, ng: np.ndarray, d: np.ndarray, scale=None) -> np.ndarray:
        """Ray origins: ``p`` moved along ``ng`` to the side ``d`` points to, by ``scale``
        (m,) (the offset of the point's triangle: ``tri_offset[tri]``, or
        :func:`texel_offsets`), at least ``OFFSET_ULPS`` ulps of the point's own largest
        coordinate; without ``scale`` by ``offset_eps`` (the largest of the scene).

        p, ng, d : (m,3).  returns : (m,3) float64.
        """
        s = np.sign(np.einsum("ij,ij->i", ng, d))
        s = np.where(s == 0, 1.0, s)
        return p + (s * self.offset_scale(p, scale))[:, None] * ng

    def offset_scale(self, p: np.ndarray, scale=None) -> np.ndarray:
        """(m,) the distance :meth:`offset` moves points ``p`` (m, 3) by: ``scale`` (m,)
        (``offset_eps`` when None), at least ``OFFSET_ULPS`` ulps of each point's largest
        coordinate."""
        own = OFFSET_ULPS * FLT_EPS * np.abs(p).max(axis=1)
        return np.maximum(self.offset_eps if scale is None else scale, own)

    def texel_offsets(self, texels, mesh) -> np.ndarray:
        """Ray-origin offsets (n,) float64 of ``texels`` of the scene mesh ``mesh`` (its index
        or its MeshData): the ``tri_offset`` of each texel's triangle, at least ``OFFSET_ULPS``
        ulps of its point's largest coordinate. ``mesh`` None (texels not of one scene mesh):
        ``offset_eps``, the scene's largest."""
        n = len(texels)
        if mesh is not None and not isinstance(mesh, (int, np.integer)):
            mesh = next((i for i, m in enumerate(self.scene.meshes) if m is mesh), None)
        if mesh is None:
            scale = np.full(n, self.offset_eps)
        else:
            tri = self.mesh_first[int(mesh)] + np.asarray(texels.triangle, np.int64)
            scale = self.tri_offset[tri]
        p = np.asarray(texels.position, np.float64)
        return np.maximum(scale, OFFSET_ULPS * FLT_EPS * np.abs(p).max(axis=1, initial=0.0))

    def intersect(self, o, d, tfar=None, rng=None):
        """Closest hits. o, d : (m,3) (d unit); tfar : (m,) or None (inf).

        returns dict: ``t`` (m,) float32 (inf on miss), ``tri`` (m,) int32 global triangle id
        (-1 on miss), ``u``, ``v`` (m,) float32 barycentrics (of vertices 1 and 2).
        Transmissive surfaces (cut-outs) are passed through.
        """
        o32 = np.ascontiguousarray(o, np.float32)
        d32 = np.ascontiguousarray(d, np.float32)
        m = len(o32)
        tf = (
            np.full(m, np.inf, np.float32)
            if tfar is None
            else np.ascontiguousarray(tfar, np.float32).copy()
        )
        t, tri, u, v = self._raw_intersect(o32, d32, tf.copy())
        t = np.where(tri >= 0, t, np.inf).astype(np.float32)
        if self.has_transmission:
            travelled = np.zeros(m, np.float64)
            idx = np.nonzero(tri >= 0)[0]  # rays still moving: each surface is decided once
            for _ in range(MAX_TRANSMIT):
                if len(idx) == 0:
                    break
                passes = self._transmits(tri[idx], u[idx], v[idx], rng)
                idx = idx[passes]
                if len(idx) == 0:
                    break
                idx = self._pass_through(idx, d, d32, tf, t, tri, u, v, travelled)
            t = np.where(tri >= 0, travelled + t, np.inf).astype(np.float32)
        return {"t": t, "tri": tri, "u": u, "v": v}

    def _pass_through(self, idx, d, d32, tf, t, tri, u, v, travelled):
        """Continue rays ``idx`` past their current hits (t, tri, u, v updated in place, the
        distance before them added to ``travelled``); returns the rays that hit again."""
        p = self.hit_points(tri[idx], u[idx], v[idx])
        ng = self.geom_normal[tri[idx]].astype(np.float64)
        no = self.offset(p, ng, d[idx], self.tri_offset[tri[idx]])
        done = travelled[idx] + t[idx]
        rem = tf[idx] - done
        t2, tri2, u2, v2 = self._raw_intersect(
            np.ascontiguousarray(no, np.float32), d32[idx], rem.astype(np.float32)
        )
        travelled[idx] = done
        tri[idx], u[idx], v[idx] = tri2, u2, v2
        t[idx] = np.where(tri2 >= 0, t2, np.inf)
        return idx[tri2 >= 0]

    def transmittance(self, o, d, tfar):
        """Shadow rays: (m,) float64 fraction of light that passes between ``o`` and ``o + tfar
        d``: 0 behind an opaque surface (or a cut-out texel at or above its threshold, or
        beyond ``MAX_TRANSMIT`` crossings), else the product of ``1 - opacity`` over the
        fractional-opacity surfaces crossed (1 through cut-out holes). Deterministic: the
        expectation of :meth:`occluded`'s stochastic pass-through.
        o, d : (m, 3); tfar : (m,) distance to the light (inf for distant/dome)."""
        o32 = np.ascontiguousarray(o, np.float32)
        d32 = np.ascontiguousarray(d, np.float32)
        tf = np.ascontiguousarray(tfar, np.float32).copy()
        if not self.has_transmission:
            return np.where(self._raw_occluded(o32, d32, tf.copy()), 0.0, 1.0)
        m = len(o32)
        T = np.ones(m)
        t, tri, u, v = self._raw_intersect(o32, d32, tf.copy())
        travelled = np.zeros(m)
        todo = np.nonzero(tri >= 0)[0]
        for _ in range(MAX_TRANSMIT):
            if len(todo) == 0:
                break
            T[todo] *= self._transmission(tri[todo], u[todo], v[todo])
            todo = todo[T[todo] > 0.0]
            if len(todo) == 0:
                break
            todo = self._pass_through(todo, d, d32, tf, t, tri, u, v, travelled)
        T[todo] = 0.0  # still blocked after MAX_TRANSMIT crossings
        return T

    def occluded(self, o, d, tfar, rng=None):
        """Shadow rays. tfar : (m,) distance to the light (inf for distant/dome).

        returns : (m,) bool, True when something opaque lies in (0, tfar).
        """
        if self.has_transmission:
            return self.intersect(o, d, tfar, rng)["tri"] >= 0
        return self._raw_occluded(
            np.ascontiguousarray(o, np.float32),
            np.ascontiguousarray(d, np.float32),
            np.ascontiguousarray(tfar, np.float32).copy(),
        )

    # ------------------------------------------------------------------ surface data
    def hit_points(self, tri, u, v):
        """World positions at barycentrics. returns (m,3) float64."""
        w = self.verts[tri]
        u = u.astype(np.float64)[:, None]
        v = v.astype(np.float64)[:, None]
        return (1.0 - u - v) * w[:, 0] + u * w[:, 1] + v * w[:, 2]

    def shading_normals(self, tri, u, v):
        """Interpolated unit shading normals (m,3) float64."""
        cn = self.corner_normal[tri].astype(np.float64)
        u = u.astype(np.float64)[:, None]
        v = v.astype(np.float64)[:, None]
        n = (1.0 - u - v) * cn[:, 0] + u * cn[:, 1] + v * cn[:, 2]
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        gn = self.geom_normal[tri].astype(np.float64)
        return np.where(ln > 1e-12, n / np.where(ln > 1e-12, ln, 1.0), gn)

    def texcoords(self, tri, u, v):
        tc = self.tri_texcoord[tri]
        u = u[:, None]
        v = v[:, None]
        return (1.0 - u - v) * tc[:, 0] + u * tc[:, 1] + v * tc[:, 2]

    def _per_material(self, tri, u, v, attr, const):
        mat = self.tri_material[tri]
        out = const[mat].copy()
        for mi, m in enumerate(self.scene.materials):
            tex = getattr(m, attr)
            if tex is None:
                continue
            sel = mat == mi
            if np.any(sel):
                val = tex.sample(self.texcoords(tri[sel], u[sel], v[sel]))
                v2 = val.reshape(len(val), -1)
                out[sel] = v2[:, 0] if out.ndim == 1 else v2[:, : out.shape[1]]
        return out

    def albedo_at(self, tri, u, v):
        """(m,3) float32 diffuse albedo at hits (texture sampled at the material's texcoord)."""
        return np.clip(self._per_material(tri, u, v, "albedo_tex", self.albedo), 0.0, 1.0)

    def emission_at(self, tri, u, v):
        """(m,3) float32 emitted radiance at hits (front faces, both on doubleSided meshes; caller
        checks facing)."""
        return self._per_material(tri, u, v, "emission_tex", self.emission)

    def _opacity(self, tri, u, v):
        """(op, threshold) (k,) float32 of the transmissive-material hits among ``tri`` (m,),
        and their indices (k,) into it (other hits are opaque)."""
        mat = self.tri_material[tri]
        idx = np.nonzero(self.transmissive_materials[mat])[0]
        ops = np.array([m.opacity for m in self.scene.materials], np.float32)
        thr = np.array([m.opacity_threshold for m in self.scene.materials], np.float32)
        op = self._per_material(tri[idx], u[idx], v[idx], "opacity_tex", ops)
        op = np.asarray(op, np.float32).reshape(len(idx))
        return op, thr[mat[idx]], idx

    def _transmits(self, tri, u, v, rng):
        out = np.zeros(len(tri), bool)
        op, th, idx = self._opacity(tri, u, v)
        if len(idx) == 0:
            return out
        cut = th > 0
        res = np.where(cut, op < th, False)
        stoch = ~cut & (op < 1.0)
        if np.any(stoch):
            r = (rng or np.random.default_rng(0)).random(int(stoch.sum()))
            res[stoch] = r >= op[stoch]
        out[idx] = res
        return out

    def _transmission(self, tri, u, v):
        """(m,) float64 fraction of light passing each hit: 1 - opacity (fractional opacity),
        1 / 0 below / at or above a cut-out threshold, 0 on opaque materials."""
        out = np.zeros(len(tri))
        op, th, idx = self._opacity(tri, u, v)
        frac = np.clip(1.0 - op.astype(np.float64), 0.0, 1.0)
        out[idx] = np.where(th > 0, np.where(op < th, 1.0, 0.0), frac)
        return out

    # ------------------------------------------------------------------ native tables
    def native_tables(self):
        """Per-triangle, material and texture tables for the numba kernels (cached).

        returns a :class:`usdahd.bake.kernels.layout.NativeTables` (read by
        :mod:`usdahd.bake.kernels.trace`; fields and shapes there).
        """
        if self._tables is not None:
            return self._tables
        mats = self.scene.materials
        nm = max(1, len(mats))
        mat_const = np.zeros((nm, 8))
        mat_tex = np.full((nm, 3), -1, np.int64)
        textures = []
        for i, m in enumerate(mats):
            mat_const[i, 0:3] = m.albedo
            mat_const[i, 3:6] = m.emission
            mat_const[i, 6] = m.opacity
            mat_const[i, 7] = m.opacity_threshold
            for j, tex in enumerate((m.albedo_tex, m.emission_tex, m.opacity_tex)):
                if tex is not None:
                    mat_tex[i, j] = len(textures)
                    textures.append(tex)
        self._tables = NativeTables(
            np.ascontiguousarray(self.verts, np.float64),
            self.geom_normal.astype(np.float64),
            np.ascontiguousarray(self.corner_normal, np.float32),
            self.tri_material.astype(np.int32),
            self.tri_one_sided.astype(np.uint8),
            np.ascontiguousarray(self.tri_offset, np.float64),
            self.tri_texcoord.astype(np.float64),
            mat_const,
            mat_tex,
            *pack_textures(textures),
            tri_mesh=np.ascontiguousarray(self.tri_mesh, np.int32),
        )
        return self._tables

    def back_face(self, tri: np.ndarray, d: np.ndarray, ng: np.ndarray) -> np.ndarray:
        """(n,) bool: hits on the back of a one-sided triangle, the sign that a ray's origin
        is inside geometry (``dot(d, ng) > 0``; misses and ``doubleSided`` meshes: False).

        tri : (n,) int triangle ids (-1: miss); d : (n, 3) ray directions; ng : (n, 3) the
        hit triangles' geometric normals."""
        tri = np.asarray(tri)
        hit = tri >= 0
        one = self.tri_one_sided[np.where(hit, tri, 0)]
        return hit & one & (np.einsum("ij,ij->i", d, ng) > 0)

    def fork(self) -> Tracer:
        """A tracer sharing this one's BVH, tables and threads, with its own ``rays_traced``
        (from 0): one per prim traced at once (:func:`usdahd.pipeline.stages._trace_jobs`), so
        each counts its own rays. Queries are thread-safe (a committed Embree scene; the
        cached tables are built here, before any sharing). Close only the original."""
        if self.backend == "native":
            self.native_tables()
        twin = copy.copy(self)
        twin.rays_traced = 0
        return twin

    @property
    def native_handle(self) -> int:
        """RTCScene address for :mod:`usdahd.bake.kernels.embree` (native backend only)."""
        return self._native.handle if self._native is not None else 0

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


def pack_textures(textures):
    """Concatenate :class:`usdahd.scene.types.Texture` objects for ``kernels.trace.nb_texture``.

    returns (data (D,) f32, info (K,8) i64 = offset, h, w, c, wrap s, wrap t, channel count, 0;
    chan (K,4) i64 selected channels; sb (K,8) f64 scale then bias); wrap codes 0 repeat,
    1 clamp/black (clamped, as ``Texture.sample``), 2 mirror.
    """
    data, info, chan, sb = [np.zeros(1, np.float32)], [], [], []
    off = 1
    wrap_code = {"repeat": 0, "clamp": 1, "black": 1, "mirror": 2}
    for tex in textures:
        h, w, c = tex.data.shape
        wraps = [wrap_code.get(tex.wrap[0], 0), wrap_code.get(tex.wrap[1], 0)]
        info.append([off, h, w, c] + wraps + [len(tex.channels), 0])
        ch = list(tex.channels)[:4]
        chan.append(ch + [0] * (4 - len(ch)))
        sb.append(np.r_[np.asarray(tex.scale, float)[:4], np.asarray(tex.bias, float)[:4]])
        data.append(np.ascontiguousarray(tex.data, np.float32).reshape(-1))
        off += tex.data.size
    return (
        np.concatenate(data),
        np.array(info, np.int64).reshape(-1, 8),
        np.array(chan, np.int64).reshape(-1, 4),
        np.array(sb, np.float64).reshape(-1, 8),
    )
