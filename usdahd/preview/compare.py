"""``usdahd preview --compare``: a path-traced reference of the preview's view (issue 14).

Visible points: one primary ray per pixel centre of the image it is given (the CLI gives the
sub-pixel grid of the footprint, below) through the preview's view-projection, the closest
*front-facing* hit on a baked mesh (:func:`usdahd.preview.raytrace.front_hits`, the faces the
rasteriser keeps), so the reference is traced at the surface point each preview (sub-)pixel
shows. At each point the frame is built as the baker builds a texel's
(:func:`usdahd.bake.texels.rasterize`): n the normalized interpolated corner normal, t the
interpolated corner tangent (:func:`usdahd.bake.texels.tangent_frames`, the one the preview's
vertices carry) Gram-Schmidt against
n, b = sign * cross(n, t).

Reference: the baker's own integrator (:func:`usdahd.bake.integrate.bake_texels`, as
``usdahd validate --retrace`` calls it) over the *whole* stage (unbaked meshes occlude and
reflect), plain Monte Carlo (``estimator="mc"``, unbiased), the bake's own bounce cap (from its
recorded settings; ``--compare-bounces`` overrides), ``samples`` per point in K independent
batches (streams 1..K of a seed hashed from ``--seed``). The pixel value is I_z of the traced SH
(irradiance about the shading normal over pi, the quantity the preview's decoders return at the
unperturbed normal), so the two images are the same quantity.

Pixel footprint (``--compare-footprint S``, default :data:`FOOTPRINT`): both images are
shaded at the same S x S sub-pixel points (the pixel centres of an image S times the size, one
visible point each) and each pixel is the box average of its sub-pixel points that both images
cover (alpha: their share). The preview and the reference thus see the same geometry at every
point and the same footprint per pixel, as an anti-aliased render shows them: a pixel that
straddles a silhouette or a shadow boundary finer than a pixel compares its average, not
whichever side its centre happens to fall on. The samples per pixel are split over the S^2
points (``samples // S^2`` each, at least 2). S = 1 is one point at each pixel centre. The
point-by-point error at the sub-pixel points is reported too (``relrmse_subsamples``), and the
pixels are split into *edge* pixels (the 3 x 3 pixels around hold sub-pixel points of more than
one mesh or the background) and *interior* pixels, each with its own relRMSE, and the edge
pixels' share of the squared error (:func:`footprint_stats`).

Statistics over the pixels both images cover (RGB, linear):

- ``relrmse`` = sqrt(sum (b - r)^2 / sum r^2), b the preview, r the reference;
- ``bias`` = sum (b - r) / sum r (the relative mean difference);
- ``reference_noise`` = sqrt(sum Var(r) / sum r^2), Var(r) the variance of each pixel's
  reference mean from the scatter of its K batch means (K - 1 degrees of freedom);
- ``relrmse_denoised`` = sqrt(max(relrmse^2 - reference_noise^2, 0)): the reference's noise is
  independent of the bake, so it adds its variance to E[(b - r)^2]; subtracting it estimates the
  preview's error against the noiseless reference.

The error heat map shows |b - r| per pixel relative to max(r, 0.1 mean r) (luminance), on a
black-blue-green-yellow-red ramp from 0 to ``HEAT_RANGE``.

numpy only here; the tracer and integrator are imported when a reference is traced.
"""

from __future__ import annotations

import hashlib
import math
from typing import NamedTuple

import numpy as np

from usdahd.errors import UsageError
from usdahd.numerics.triangles import edge_cross, texel_frame

__all__ = [
    "FOOTPRINT",
    "Reference",
    "downsample",
    "edge_pixels",
    "error_stats",
    "footprint_stats",
    "heat_map",
    "points_per_pixel",
    "reference",
    "side_by_side",
]

#: Sub-pixel points per side of a compared pixel (``--compare-footprint`` default): 2 x 2.
FOOTPRINT = 2
#: Largest ``--compare-footprint``.
MAX_FOOTPRINT = 8
#: A pixel whose points' paths leave through back faces more often than this is reported in
#: ``inside_geometry`` (the baker's inside-geometry threshold).
INSIDE = 0.25
#: Batches K of the reference (per-pixel noise estimate with K - 1 degrees of freedom).
BATCHES = 8
#: Relative error mapped to the top of the heat map's ramp.
HEAT_RANGE = 0.2
#: Per-pixel relative errors are taken against max(r, DARK_FLOOR * mean r).
DARK_FLOOR = 0.1
#: Rec. 709 luminance.
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: The heat map's ramp: (position, RGB 0..255).
RAMP = np.array(
    [
        (0.0, 0, 0, 0),
        (0.25, 30, 60, 220),
        (0.5, 30, 200, 80),
        (0.75, 240, 220, 40),
        (1.0, 230, 30, 30),
    ],
    np.float64,
)


def reference_seed(seed: int) -> int:
    """The 32-bit seed of the reference's random stream (its own: hashed ``preview:{seed}``)."""
    return int.from_bytes(hashlib.sha256(f"preview:{seed}".encode()).digest()[:4], "little")


def points_per_pixel(samples: int, footprint: int) -> int:
    """Samples per sub-pixel point when ``samples`` per pixel are split over footprint^2 points
    (UsageError when a point would get fewer than 2: its noise estimate needs 2 batches)."""
    if footprint < 1 or footprint > MAX_FOOTPRINT:
        raise UsageError(
            f"--compare-footprint {footprint}: sub-pixel points per side must be 1..{MAX_FOOTPRINT}"
        )
    per = int(samples) // (footprint * footprint)
    if per < 2:
        raise UsageError(
            f"--compare-samples {samples}: with --compare-footprint {footprint} each of the "
            f"{footprint * footprint} sub-pixel points needs at least 2 samples; give "
            f"--compare-samples {2 * footprint * footprint} or more, or a smaller footprint"
        )
    return per


def batch_plan(samples: int) -> tuple[int, int]:
    """(K batches, samples per batch) for ``samples`` >= 2 samples per point."""
    if samples < 2:
        raise UsageError(f"--compare-samples {samples}: the reference needs at least 2 samples")
    k = min(BATCHES, samples)
    return k, samples // k


def visible_points(meshes, viewproj: np.ndarray, size, scene):
    """Front-facing surface points of the preview's pixels.

    meshes : [(MeshData, BakeResults, tangent, sign)]
        (:func:`usdahd.preview.meshes.baked_meshes`); scene : the stage's Scene (its materials).
    returns (pixel (m,) int64 row-major pixel index, mesh (m,) int64 index into ``meshes``,
        Texels of the m points).
    """
    from usdahd.bake.trace import Tracer
    from usdahd.bake.types import Texels
    from usdahd.preview.raytrace import front_hits, primary_rays, subset_scene

    tracer = Tracer(subset_scene(scene, [m for m, *_ in meshes]))
    try:
        o, d = primary_rays(viewproj, size)
        hit = front_hits(tracer, o, d)
        pix = np.nonzero(hit["tri"] >= 0)[0]
        tri = hit["tri"][pix]
        which = tracer.tri_mesh[tri].astype(np.int64)
        local = tracer.tri_local[tri].astype(np.int64)
        u = hit["u"][pix].astype(np.float64)
        v = hit["v"][pix].astype(np.float64)
        pos = tracer.hit_points(tri, hit["u"][pix], hit["v"][pix])
    finally:
        tracer.close()
    m = len(pix)
    lam = np.stack([1.0 - u - v, u, v], axis=1)
    geom = np.zeros((m, 3))
    shade = np.zeros((m, 3))
    tan = np.zeros((m, 3))
    sgn = np.ones(m)
    for k, (mesh, _res, tangent, sign) in enumerate(meshes):
        sel = np.nonzero(which == k)[0]
        if not sel.size:
            continue
        t_idx = local[sel]
        pts = np.asarray(mesh.points, np.float64)[np.asarray(mesh.triangles)[t_idx]]
        geom[sel] = edge_cross(pts)
        nrm = np.asarray(mesh.normals, np.float64)[t_idx]
        nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-30)
        shade[sel] = np.einsum("nc,nci->ni", lam[sel], nrm)
        tan[sel] = np.einsum("nc,nci->ni", lam[sel], np.asarray(tangent, np.float64)[t_idx])
        sgn[sel] = np.asarray(sign, np.float64)[t_idx]
    geom = _unit(geom, np.array([0.0, 0.0, 1.0]))
    shade = _unit(shade, geom)
    frame = texel_frame(shade, tan, sgn)
    texels = Texels(
        resolution=tuple(size),
        xy=np.stack([pix % size[0], pix // size[0]], axis=1).astype(np.int32),
        position=pos.astype(np.float32),
        geom_normal=geom.astype(np.float32),
        frame=frame.astype(np.float32),
        triangle=local.astype(np.int32),
        center_inside=np.ones(m, bool),
    )
    return pix, which, texels


def _unit(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = n > 1e-12
    return np.where(ok, v / np.where(ok, n, 1.0), np.broadcast_to(fallback, v.shape))


class Reference(NamedTuple):
    """:func:`reference`'s result, at the size it was traced (one visible point per pixel)."""

    #: (H, W, 4) float32: I_z RGB, alpha 1 on traced pixels.
    image: np.ndarray
    #: (H, W, 3) float64: the variance of each pixel's mean.
    var: np.ndarray
    #: (H, W) int64: the index into ``meshes`` of the mesh each pixel shows, -1 for none.
    owner: np.ndarray
    #: samples, batches, bounces, seed, rays, points, inside_geometry (points).
    info: dict
    #: (H, W) float64: each point's share of paths that left it through a back face.
    backface: np.ndarray | None = None


def reference(stage, meshes, viewproj, size, *, samples: int, seed: int, bounces, progress=None):
    """Path-traced reference of the preview's view, one visible point per pixel of ``size``
    (the CLI passes the sub-pixel grid: ``size`` times the footprint).

    stage : the baked stage; meshes : :func:`usdahd.preview.meshes.baked_meshes`'s list;
    samples : per visible point (split into K batches); bounces : the integrator's cap (None:
    the bake's recorded ``bounces``, else the integrator's default); progress : callable(str)
    or None.
    returns a :class:`Reference`.
    """
    from usdahd.bake import integrate
    from usdahd.bake.trace import Tracer
    from usdahd.preview.meshes import preview_scene
    from usdahd.scene.hashing import is_dark

    w, h = size
    k, s = batch_plan(int(samples))
    if bounces is None:
        recorded = {(r.settings or {}).get("bounces") for _, r, *_ in meshes}
        recorded.discard(None)
        bounces = max(recorded) if recorded else integrate.DEFAULT_BOUNCES
    bounces = int(bounces)
    if bounces < 0:
        raise UsageError(f"--compare-bounces {bounces}: bounces must be >= 0")
    scene = preview_scene(stage, meshes[0][1].uv_primvar)  # refined as the bake traced it
    pix, which, texels = visible_points(meshes, viewproj, size, scene)
    owner = np.full(h * w, -1, np.int64)
    owner[pix] = which
    owner = owner.reshape(h, w)
    image = np.zeros((h * w, 4), np.float32)
    var = np.zeros((h * w, 3))
    info = {
        "samples": k * s,
        "batches": k,
        "bounces": bounces,
        "seed": int(seed),
        "points": int(len(pix)),
        "rays": 0,
        "inside_geometry": 0,
    }
    back = np.zeros(h * w)
    if not len(pix):
        return Reference(image.reshape(h, w, 4), var.reshape(h, w, 3), owner, info,
                         back.reshape(h, w))  # fmt: skip
    image[pix, 3] = 1.0
    if is_dark(scene):  # nothing emits: the exact answer is 0 (the baker traces nothing either)
        return Reference(image.reshape(h, w, 4), var.reshape(h, w, 3), owner, info,
                         back.reshape(h, w))  # fmt: skip
    index = {m.path: i for i, m in enumerate(scene.meshes)}
    rseed = reference_seed(seed)
    batches = np.zeros((k, len(pix), 3))
    backface = np.zeros(len(pix))
    tracer = Tracer(scene)
    try:
        for mk, (mesh, *_rest) in enumerate(meshes):
            sel = np.nonzero(which == mk)[0]
            if not sel.size:
                continue
            if progress:
                progress(f"reference {mesh.path}: {len(sel)} points x {k * s} samples")
            iz, bf, rays = integrate.iz_batches(
                scene,
                tracer,
                texels.take(sel),
                batches=k,
                samples=s,
                bounces=bounces,
                seed=rseed,
                stream=1 + k * mk,
                mesh=index.get(mesh.path),
            )
            batches[:, sel] = iz
            backface[sel] = bf
            info["rays"] += rays
    finally:
        tracer.close()
    info["inside_geometry"] = int((backface > INSIDE).sum())
    image[pix, :3] = batches.mean(axis=0)
    var[pix] = batches.var(axis=0, ddof=1) / k
    back[pix] = backface
    return Reference(image.reshape(h, w, 4), var.reshape(h, w, 3), owner, info,
                     back.reshape(h, w))  # fmt: skip


def downsample(image: np.ndarray, footprint: int, mask: np.ndarray | None = None) -> np.ndarray:
    """(H*S, W*S, C) sub-pixel image -> (H, W, C) float64: the RGB of each pixel the mean of its
    S x S sub-pixel points where ``mask`` (H*S, W*S) bool (default: alpha > 0, C = 4), the
    alpha (C = 4) the share of its points in ``mask``; pixels with none are 0."""
    s = int(footprint)
    hs, ws, c = image.shape
    h, w = hs // s, ws // s
    if mask is None:
        mask = image[..., 3] > 0
    m = mask.astype(np.float64)
    n = m.reshape(h, s, w, s).sum(axis=(1, 3))
    rgb = (image[..., :3].astype(np.float64) * m[..., None]).reshape(h, s, w, s, 3)
    rgb = rgb.sum(axis=(1, 3)) / np.maximum(n, 1.0)[..., None]
    if c == 3:
        return rgb
    return np.concatenate([rgb, (n / (s * s))[..., None]], axis=-1)


def edge_pixels(owner: np.ndarray, footprint: int) -> np.ndarray:
    """(H, W) bool: the pixels whose 3 x 3 neighbourhood (its sub-pixel points, ``owner``
    (H*S, W*S) mesh indices, -1 for none) shows more than one mesh or the background; the
    rest (all points on one mesh) are *interior*."""
    s = int(footprint)
    hs, ws = owner.shape
    h, w = hs // s, ws // s
    blk = owner.reshape(h, s, w, s)
    lo = np.pad(blk.min(axis=(1, 3)), 1, constant_values=-1)
    hi = np.pad(blk.max(axis=(1, 3)), 1, constant_values=-1)
    mn = np.min([lo[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1)
                 for dx in (-1, 0, 1)], axis=0)  # fmt: skip
    mx = np.max([hi[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1)
                 for dx in (-1, 0, 1)], axis=0)  # fmt: skip
    return (mn != mx) | (mn < 0)


def footprint_stats(baked: np.ndarray, ref: Reference, footprint: int):
    """The compared images and statistics at the pixel footprint (module doc).

    baked : the preview (H*S, W*S, 4) at the sub-pixel points; ref : :func:`reference` of the
    same sub-pixel grid. Returns (baked (H, W, 4) float32, reference (H, W, 4) float32, stats):
    each pixel the mean of its sub-pixel points both images cover; stats = :func:`error_stats`
    of the two plus ``footprint``, ``relrmse_subsamples`` (the error point by point at the
    sub-pixel points), ``inside_geometry`` (pixels whose points' paths leave through back
    faces more than INSIDE of the time, all their samples pooled), ``interior_pixels`` /
    ``interior_relrmse`` / ``interior_bias``, ``edge_pixels`` / ``edge_relrmse`` /
    ``edge_bias`` / ``edge_error_share`` (the edge pixels' share of sum (b - r)^2)."""
    s = int(footprint)
    both = (baked[..., 3] > 0) & (ref.image[..., 3] > 0)
    b = downsample(baked, s, both)
    r = downsample(ref.image, s, both)
    h, w = both.shape[0] // s, both.shape[1] // s
    cnt = both.reshape(h, s, w, s).sum(axis=(1, 3)).astype(np.float64)
    vsum = (ref.var * both[..., None]).reshape(h, s, w, s, 3).sum(axis=(1, 3))
    var = vsum / np.maximum(cnt, 1.0)[..., None] ** 2  # the variance of a mean of cnt points
    st = error_stats(b, r, var)
    sub = error_stats(baked, ref.image, ref.var)
    edge = edge_pixels(ref.owner, s)
    out = {"footprint": s, **st, "relrmse_subsamples": sub["relrmse"]}
    if ref.backface is not None:  # the baker's inside-geometry test on each pixel's paths
        bf = (ref.backface * both).reshape(h, s, w, s).sum(axis=(1, 3))
        out["inside_geometry"] = int((bf > INSIDE * np.maximum(cnt, 1.0))[cnt > 0].sum())
    cov = (b[..., 3] > 0) & (r[..., 3] > 0)
    d2 = ((b[..., :3] - r[..., :3]) ** 2).sum(axis=-1)
    total = float(d2[cov].sum())
    for name, sel in (("interior", cov & ~edge), ("edge", cov & edge)):
        part = error_stats(b * sel[..., None], r * sel[..., None], var)
        out[f"{name}_pixels"] = part["pixels"]
        out[f"{name}_relrmse"] = part["relrmse"]
        out[f"{name}_bias"] = part["bias"]
    out["edge_error_share"] = float(d2[cov & edge].sum()) / total if total > 0 else None
    return b.astype(np.float32), r.astype(np.float32), out


def error_stats(baked: np.ndarray, ref: np.ndarray, ref_var: np.ndarray) -> dict:
    """The ``--compare`` statistics (see the module doc) of baked and reference (H, W, 4)
    images over the pixels both cover; ref_var (H, W, 3) the variance of each reference pixel."""
    cov = (baked[..., 3] > 0) & (ref[..., 3] > 0)
    b = baked[..., :3][cov].astype(np.float64)
    r = ref[..., :3][cov].astype(np.float64)
    v = ref_var[cov]
    out = {"pixels": int(cov.sum())}
    r2 = float((r * r).sum())
    if not cov.any() or r2 <= 0.0:
        return {**out, "relrmse": None, "bias": None, "reference_noise": None,
                "relrmse_denoised": None}  # fmt: skip
    rel = math.sqrt(float(((b - r) ** 2).sum()) / r2)
    noise = math.sqrt(float(v.sum()) / r2)
    return {
        **out,
        "relrmse": rel,
        "bias": float((b - r).sum() / r.sum()),
        "reference_noise": noise,
        "relrmse_denoised": math.sqrt(max(rel * rel - noise * noise, 0.0)),
        "reference_mean_rgb": [float(x) for x in r.mean(axis=0)],
    }


def heat_map(baked: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: per-pixel |b - r| / max(r, DARK_FLOOR mean r) in luminance on the RAMP
    from 0 to HEAT_RANGE; pixels not covered by both images are black."""
    cov = (baked[..., 3] > 0) & (ref[..., 3] > 0)
    lb = baked[..., :3].astype(np.float64) @ LUMA
    lr = ref[..., :3].astype(np.float64) @ LUMA
    floor = DARK_FLOOR * float(lr[cov].mean()) if cov.any() else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(lb - lr) / np.maximum(np.maximum(lr, floor), 1e-30)
    x = np.clip(np.where(cov, err, 0.0) / HEAT_RANGE, 0.0, 1.0)
    rgb = np.stack([np.interp(x, RAMP[:, 0], RAMP[:, c]) for c in (1, 2, 3)], axis=-1)
    rgb[~cov] = 0.0
    return np.rint(rgb).astype(np.uint8)


def side_by_side(*panels: np.ndarray, gap: int = 4) -> np.ndarray:
    """Panels (H, W, 3) uint8 left to right, ``gap`` black columns between them."""
    h = panels[0].shape[0]
    sep = np.zeros((h, gap, 3), np.uint8)
    row = []
    for i, p in enumerate(panels):
        row += [sep, p] if i else [p]
    return np.concatenate(row, axis=1)
