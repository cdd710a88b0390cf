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
        step = tracer.offset_eps / np.maximum(cos, 1e-3)
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


def render(scene, items, viewproj: np.ndarray, size) -> np.ndarray:
    """Embree image (H, W, 4) float32 of ``items`` [(mesh, model, ratio, textures, factors)]:
    linear normalized irradiance, alpha 1 on covered pixels. ``scene`` (a usdahd Scene) supplies
    the materials; only the items' meshes are traced."""
    from usdahd import models
    from usdahd.bake.trace import Tracer

    w, h = size
    sc = copy.copy(scene)
    sc.meshes = [it[0] for it in items]
    tracer = Tracer(sc)
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
            m = models.get(model)
            layout = m.layout(ratio)
            channels = {}
            for t, px in zip(layout, textures):
                channels[t.role] = bilinear(px, uv)  # stored scale: decode divides by 255
            params = m.decode(channels, ratio=ratio, factors=factors)
            n = np.zeros((len(sel), 3))
            n[:, 2] = 1.0
            image[sel, :3] = np.asarray(m.evaluate(params, n), np.float32)[:, :3]
            image[sel, 3] = 1.0
    finally:
        tracer.close()
    return image.reshape(h, w, 4)
