"""Embree fallback of ``usdahd preview``: primary rays + the numpy decoders (no Vulkan adapter).

Per pixel centre one ray through the inverse view-projection (wgpu clip space: NDC z in [0, 1],
y up); at the closest hit the lightmap UV is interpolated, every texture of the mesh is sampled
bilinearly (texel centres at (i + 0.5) / W, clamp to edge, like the wgpu sampler) in its stored
scale, the model's Python ``decode`` turns the samples into parameters and ``evaluate`` gives the
irradiance at the tangent-space shading normal (0, 0, 1) (no normal map). Output matches
``render`` of the wgpu path: (H, W, 4) float32, alpha 1 where a baked mesh is hit.

Back faces are culled as the wgpu pipeline culls them (``cull_mode="back"``, counter-clockwise
front): a ray passes through a triangle whose geometric normal (the winding's, as the rasteriser
sees it) does not face the ray, so a closed room viewed from outside opens the same way (the
auto framing looks down through the ceiling's back face).
"""

from __future__ import annotations

import copy

import numpy as np

__all__ = ["front_hits", "primary_rays", "render", "subset_scene"]


def primary_rays(viewproj: np.ndarray, size) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions (H*W, 3) float64 of the rays through the pixel centres."""
    w, h = size
    inv = np.linalg.inv(np.asarray(viewproj, np.float64))
    x = (np.arange(w) + 0.5) / w * 2.0 - 1.0
    y = 1.0 - (np.arange(h) + 0.5) / h * 2.0
    xx, yy = np.meshgrid(x, y)
    ones = np.ones_like(xx)
    near = np.stack([xx, yy, 0.0 * ones, ones], -1).reshape(-1, 4) @ inv.T
    far = np.stack([xx, yy, ones, ones], -1).reshape(-1, 4) @ inv.T
    near = near[:, :3] / near[:, 3:]
    far = far[:, :3] / far[:, 3:]
    d = far - near
    return near, d / np.linalg.norm(d, axis=1, keepdims=True)


#: Back faces a primary ray may pass through before it is taken as a miss.
MAX_BACK_FACES = 16


def front_hits(tracer, o: np.ndarray, d: np.ndarray) -> dict:
    """Closest front-facing hits of rays o, d (m, 3): ``tracer.intersect``'s dict (``tri`` -1 on
    a miss, ``u``, ``v`` barycentrics), with back-facing and edge-on triangles (geometric normal
    . d >= 0) passed through, as the rasteriser's back-face culling drops them."""
    o = np.asarray(o, np.float64)
    d = np.asarray(d, np.float64)
    hit = tracer.intersect(o, d)
    tri, u, v = hit["tri"].copy(), hit["u"].copy(), hit["v"].copy()
    for _ in range(MAX_BACK_FACES):
        idx = np.nonzero(tri >= 0)[0]
        ng = tracer.geom_normal[tri[idx]].astype(np.float64)
        cos = np.einsum("ij,ij->i", ng, d[idx])
        back = cos >= 0.0
        idx, cos = idx[back], cos[back]
        if not idx.size:
            break
        # Continue the same ray: step past the plane along d (not along the normal, which
        # would shift the ray sideways by the offset and move the hit behind by as much).
        step = tracer.tri_offset[tri[idx]] / np.maximum(cos, 1e-3)
        p = tracer.hit_points(tri[idx], u[idx], v[idx]) + step[:, None] * d[idx]
        again = tracer.intersect(p, d[idx])
        tri[idx], u[idx], v[idx] = again["tri"], again["u"], again["v"]
    else:
        idx = np.nonzero(tri >= 0)[0]
        ng = tracer.geom_normal[tri[idx]].astype(np.float64)
        tri[idx[np.einsum("ij,ij->i", ng, d[idx]) >= 0.0]] = -1
    return {"tri": tri, "u": u, "v": v}


def bilinear(pixels: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples (m, C) float64 of an (H, W, C) texture at texture coordinates uv (m, 2)
    (origin top-left), clamp to edge; values in the stored scale (uint8 0..255, float16 as is)."""
    h, w, _ = pixels.shape
    px = np.asarray(pixels, np.float64)
    x = np.clip(uv[:, 0] * w - 0.5, 0.0, w - 1.0)
    y = np.clip(uv[:, 1] * h - 0.5, 0.0, h - 1.0)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    top = px[y0, x0] * (1 - fx) + px[y0, x1] * fx
    bot = px[y1, x0] * (1 - fx) + px[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def subset_scene(scene, meshes):
    """A shallow copy of ``scene`` holding only ``meshes`` (MeshData of that stage, matched by
    prim path), its per-mesh lists (``texcoords``) re-indexed to match: the tracer reads a
    mesh's material texcoords by its index (a textured mesh after an unbaked one would
    otherwise get another mesh's texcoords: IndexError, or silently wrong albedo)."""
    index = {m.path: i for i, m in enumerate(scene.meshes)}
    sc = copy.copy(scene)
    sc.meshes = list(meshes)
    sc.texcoords = [
        scene.texcoords[index[m.path]]
        if m.path in index and index[m.path] < len(scene.texcoords)
        else {}
        for m in meshes
    ]
    return sc


def render(scene, items, viewproj: np.ndarray, size, surfaces=None, frames=None) -> np.ndarray:
    """Embree image (H, W, 4) float32 of ``items`` [(mesh, model, ratio, textures, factors)]:
    linear normalized irradiance, alpha 1 on covered pixels. ``scene`` (a usdahd Scene) supplies
    the materials; only the items' meshes are traced.

    --model-view: ``surfaces`` (per item, its :class:`usdahd.preview.surface.Surface` groups)
    and ``frames`` (per item, the lightmap (tangent (t, 3, 3), sign (t,))): the image is albedo
    x irradiance at the normal-mapped normal, the numpy transcription of the WGSL fragment
    (:mod:`usdahd.preview.surface`).

    --ahd-classic items (:func:`usdahd.preview.classic.item`: model ``ahd_classic``, a
    ``usdahd.shaders.FILTERED`` variant, float C_a, d, C_d textures) are filtered as they are
    and shaded by :func:`usdahd.preview.classic.evaluate`, d renormalised."""
    from usdahd import models, shaders
    from usdahd.bake.trace import Tracer
    from usdahd.preview import classic

    w, h = size
    tracer = Tracer(subset_scene(scene, [it[0] for it in items]))
    try:
        o, d = primary_rays(viewproj, size)
        hit = front_hits(tracer, o, d)
        tri, u, v = hit["tri"], hit["u"], hit["v"]
        image = np.zeros((h * w, 4), np.float32)
        for k, (mesh, model, ratio, textures, factors) in enumerate(items):
            sel = np.nonzero((tri >= 0) & (tracer.tri_mesh[np.maximum(tri, 0)] == k))[0]
            if not sel.size:
                continue
            local = tracer.tri_local[tri[sel]]
            st = np.asarray(mesh.uv, np.float64)[local]  # (m, 3, 2) per-corner lightmap st
            a = u[sel].astype(np.float64)[:, None]
            b = v[sel].astype(np.float64)[:, None]
            st = (1 - a - b) * st[:, 0] + a * st[:, 1] + b * st[:, 2]
            uv = np.stack([st[:, 0], 1.0 - st[:, 1]], -1)
            if model == classic.MODEL and ratio in shaders.FILTERED:  # --ahd-classic
                params = classic.filtered(*(bilinear(px, uv) for px in textures))

                def evaluate(params, n, ratio=ratio):
                    return classic.evaluate(ratio, params, n)
            else:
                m = models.get(model)
                layout = m.layout(ratio)
                channels = {}
                for t, px in zip(layout, textures):
                    channels[t.role] = bilinear(px, uv)  # stored scale: decode divides by 255
                params = m.decode(channels, ratio=ratio, factors=factors)
                evaluate = m.evaluate
            if surfaces is None:
                n = np.zeros((len(sel), 3))
                n[:, 2] = 1.0
                image[sel, :3] = np.asarray(evaluate(params, n), np.float32)[:, :3]
            else:
                lm = _at_hits(mesh, frames[k], local, a, b)
                albedo, n = _model_view(surfaces[k], mesh, local, a, b, lm)
                irr = np.asarray(evaluate(params, n), np.float64)[:, :3]
                image[sel, :3] = (albedo * irr).astype(np.float32)
            image[sel, 3] = 1.0
    finally:
        tracer.close()
    return image.reshape(h, w, 4)


def _at_hits(mesh, frame, local, a, b):
    """The lightmap tangent frame (numpy ``usdahd_tangent_frame``) at the hits: the corner
    normals and tangents interpolated with the barycentrics, as the rasteriser does."""
    from usdahd.preview.surface import tangent_frame

    tangent, sign = frame

    def lerp(x):
        x = np.asarray(x, np.float64)[local]
        return (1 - a - b) * x[:, 0] + a * x[:, 1] + b * x[:, 2]

    return lerp(mesh.normals), tangent_frame(
        lerp(mesh.normals), lerp(tangent), np.asarray(sign)[local]
    )


def _model_view(groups, mesh, local, a, b, lm):
    """(albedo (m, 3), tangent-space shading normal (m, 3)) at the hits on triangles ``local``
    of ``mesh``: each hit's material group samples its albedo and normal map at the material
    texcoord, applies the map in the material frame and expresses it in the lightmap frame."""
    from usdahd.preview.surface import apply_normal_map, sample, tangent_frame, to_tangent

    normal, frame = lm
    albedo = np.ones((len(local), 3))
    n = to_tangent(frame, frame[2])
    for g in groups:
        pos = np.full(len(mesh.triangles), -1, np.int64)
        pos[g.tris] = np.arange(len(g.tris))
        gi = pos[local]
        sel = np.nonzero(gi >= 0)[0]
        if not sel.size:
            continue
        w = (1 - a[sel] - b[sel], a[sel], b[sel])

        def lerp(x, sel=sel, gi=gi, w=w):
            x = np.asarray(x, np.float64)[gi[sel]]
            return w[0] * x[:, 0] + w[1] * x[:, 1] + w[2] * x[:, 2]

        st = lerp(g.st)
        albedo[sel] = g.albedo[None, :].astype(np.float64)
        if g.albedo_tex is not None:
            albedo[sel] *= sample(g.albedo_tex, st, g.albedo_wrap)
        if g.normal_tex is not None:
            mf = tangent_frame(normal[sel], lerp(g.tangent), g.sign[gi[sel]])
            big = apply_normal_map(sample(g.normal_tex, st, g.normal_wrap), mf)
            n[sel] = to_tangent(tuple(f[sel] for f in frame), big)
    return albedo, n
