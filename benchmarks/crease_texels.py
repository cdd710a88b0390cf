"""Conservative texels on a concave crease, against the analytic irradiance (issue 37).

    python benchmarks/crease_texels.py [--resolution 32] [--json]

A floor ``z = 0``, ``x, y in [0, 1]``, meets a black wall of height ``h`` along ``x = 0``
(infinitely long), under a uniform dome of radiance 1 with black surfaces: the floor's
irradiance at distance ``s`` from the wall is, from the view factor of an infinitely long strip,
``E(s) = pi * (1/2 + s / (2 sqrt(s^2 + h^2)))``: pi / 2 on the crease, rising to pi over a few
``h``. The floor's lightmap UVs are its ``(x, y)`` turned by 7 degrees and shifted, so the chart
border crosses the texels at every phase. Each covered texel of the floor gets ``E`` at its
sample point (:func:`usdahd.numerics.raster.rasterize_uv` at each inset of ``INSETS``,
``raster.CONSERVATIVE_INSET``): a converged bake with no noise. The surface is then read as an
engine reads it, bilinearly (uncovered taps filled from their covered 8-neighbours, as the
bake's dilation does), at 200 x 200 points per texel band ``s in [0, 0.5)``, ``[0.5, 1)``, ``[1,
2)`` texels from the crease, and compared with ``E``: relRMSE and bias per band, for walls of
0.05 to 4 texels. Prints one line per wall height and inset; ``s0-1`` pools the first two bands.

    python benchmarks/crease_texels.py --write crease.usda --resolution 32 --wall 1
    usdahd bake crease.usda --prim /World/Floor --resolution 32 --samples 1024 --no-denoise \
        --atlas off -o out.lightmaps.usda
    python benchmarks/crease_texels.py --baked out.lightmaps.usda --resolution 32 --wall 1

write the stage, bake it (the real integrator) and read the bake's I_z texture the same way.
"""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np

from usdahd.numerics import raster

ANGLE = np.radians(7.0)
#: The sample-point insets compared (raster.CONSERVATIVE_INSET: 0 = the closest point on the
#: triangle's edge, 1 = the centroid of the texel square's part inside the triangle).
INSETS = (0.0, 0.25, 0.5, 0.75, 1.0)


def normalized(s: np.ndarray, h: float) -> np.ndarray:
    """Analytic normalized floor irradiance I_z = E / pi at distance s >= 0 from a black wall
    of height h (1 under the open sky)."""
    s = np.maximum(s, 0.0)
    return 0.5 + s / (2.0 * np.sqrt(s * s + h * h))


def floor_uv(xy: np.ndarray) -> np.ndarray:
    """Floor (x, y) in [0, 1]^2 -> UV: turned by ANGLE, scaled 0.8, shifted inside [0, 1]."""
    c, s = np.cos(ANGLE), np.sin(ANGLE)
    rot = np.array([[c, -s], [s, c]])
    return 0.8 * (xy - 0.5) @ rot.T + 0.5 + 0.013


def measure(res: int, h_texels: float, inset: float) -> dict:
    world_texel = 1.0 / (0.8 * res)  # floor units per texel
    h = h_texels * world_texel
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    uv = floor_uv(corners)[tris]
    old = raster.CONSERVATIVE_INSET
    raster.CONSERVATIVE_INSET = inset
    try:
        r = raster.rasterize_uv(uv, (res, res))
    finally:
        raster.CONSERVATIVE_INSET = old
    xyw = np.einsum("nc,nci->ni", r.barycentrics, corners[tris[r.triangle]])
    img = np.full((res, res), np.nan)
    x, y = r.xy.T
    img[y, x] = normalized(xyw[:, 0], h)
    # one ring of dilation: uncovered texels take the mean of their covered 8-neighbours
    pad = np.pad(img, 1, constant_values=np.nan)
    nb = np.stack(
        [
            pad[1 + dy : 1 + dy + res, 1 + dx : 1 + dx + res]
            for dy in (-1, 0, 1)
            for dx in (-1, 0, 1)
            if dy or dx
        ]
    )
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # texels with no covered neighbour
        ring = np.nanmean(nb, axis=0)
    img = np.where(np.isnan(img), ring, img)
    out = {"resolution": res, "wall_texels": h_texels, "inset": inset}
    cons = ~r.center_inside
    out["conservative_texels"] = int(cons.sum())
    out.update(bilinear_bands(img, res, h))
    s = [out[f"s{b}_relrmse"] for b in ("0-0.5", "0.5-1")]
    out["s0-1_relrmse"] = float(np.sqrt(np.mean(np.square(s))))
    return out


DOC = (
    "A 1 x 1 m black floor (z = 0, st turned by 7 degrees) meeting a black wall box {h} m high"
    " along x = 0 (7 m long) under a uniform DomeLight of radiance 1: the floor's normalized"
    " irradiance is I_z(s) = 1/2 + s / (2 sqrt(s^2 + h^2)) at distance s from the wall."
    " Written by benchmarks/crease_texels.py."
)
STAGE = """#usda 1.0
(
    defaultPrim = "World"
    doc = "{doc}"
    metersPerUnit = 1
    upAxis = "Z"
)

def Xform "World"
{{
    def Mesh "Floor" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        rel material:binding = </World/Looks/Black>
        normal3f[] normals = [(0, 0, 1), (0, 0, 1), (0, 0, 1), (0, 0, 1)] (
            interpolation = "vertex"
        )
        point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
        texCoord2f[] primvars:st = [{st}] (
            interpolation = "vertex"
        )
        uniform token subdivisionScheme = "none"
    }}

    def Mesh "Wall" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {{
        int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
        int[] faceVertexIndices = [0, 3, 2, 1, 4, 5, 6, 7, 0, 1, 5, 4, 1, 2, 6, 5, 2, 3, 7, 6,
            3, 0, 4, 7]
        rel material:binding = </World/Looks/Black>
        point3f[] points = [(-0.2, -3, 0), (0, -3, 0), (0, 4, 0), (-0.2, 4, 0), (-0.2, -3, {h}),
            (0, -3, {h}), (0, 4, {h}), (-0.2, 4, {h})]
        uniform token subdivisionScheme = "none"
    }}

    def DomeLight "Sky"
    {{
        color3f inputs:color = (1, 1, 1)
        float inputs:intensity = 1
        bool inputs:normalize = 0
    }}

    def Scope "Looks"
    {{
        def Material "Black"
        {{
            token outputs:surface.connect = </World/Looks/Black/S.outputs:surface>

            def Shader "S"
            {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0, 0, 0)
                float inputs:roughness = 1
                token outputs:surface
            }}
        }}
    }}
}}
"""


def write_stage(path, res: int, h_texels: float) -> float:
    """Write the floor-and-wall stage with a wall of ``h_texels`` texels at ``res``; returns
    the wall's height in metres."""
    h = h_texels / (0.8 * res)
    uv = floor_uv(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float))
    st = ", ".join(f"({u:.9f}, {v:.9f})" for u, v in uv)
    with open(path, "w") as f:
        f.write(STAGE.format(h=repr(h), st=st, doc=DOC.format(h=repr(h))))
    return h


def bilinear_bands(img: np.ndarray, res: int, h: float) -> dict:
    """relRMSE and bias of the bilinear read of ``img`` (res x res, row 0 at the top, every
    texel a tap may read filled) against the analytic irradiance, per band from the crease."""
    world_texel = 1.0 / (0.8 * res)
    out = {}
    for lo, hi in ((0.0, 0.5), (0.5, 1.0), (1.0, 2.0)):
        g = (np.arange(200) + 0.5) / 200
        s = (lo + (hi - lo) * g[:, None]) * world_texel
        yy = 0.1 + 0.8 * g[None, :]
        pts = np.stack(np.broadcast_arrays(s, yy), -1).reshape(-1, 2)
        px = raster.uv_to_pixel(floor_uv(pts), (res, res)) - 0.5
        i0 = np.floor(px).astype(int)
        f = px - i0
        val = 0.0
        for dy in (0, 1):
            for dx in (0, 1):
                wgt = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
                val = val + wgt * img[i0[:, 1] + dy, i0[:, 0] + dx]
        err = val / normalized(pts[:, 0], h) - 1.0
        key = f"s{lo:g}-{hi:g}"
        out[key + "_relrmse"] = float(np.sqrt(np.mean(err**2)))
        out[key + "_bias"] = float(np.mean(err))
    return out


def baked(layer: str, res: int, h: float) -> dict:
    """The bands of a bake of the stage (its I_z texture, luminance)."""
    from usdahd.preview.meshes import baked_meshes
    from usdahd.usd import schema

    _, meshes, _ = baked_meshes(layer)
    _, rec, *_ = [m for m in meshes if m[0].path == "/World/Floor"][0]
    iz = np.asarray(schema.read_record_pixels(rec, "iz"), np.float64)
    lum = iz[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    assert lum.shape == (res, res), lum.shape
    return bilinear_bands(lum, res, h)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--write", metavar="STAGE", help="write the stage (wall --wall texels)")
    ap.add_argument("--baked", metavar="LAYER", help="measure a bake of the written stage")
    ap.add_argument("--wall", type=float, default=2.0)
    a = ap.parse_args(argv)
    if a.write:
        print(write_stage(a.write, a.resolution, a.wall))
        return 0
    if a.baked:
        h = a.wall / (0.8 * a.resolution)
        print(json.dumps(baked(a.baked, a.resolution, h)))
        return 0
    rows = [
        measure(a.resolution, hw, inset)
        for hw in (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
        for inset in INSETS
    ]
    if a.json:
        print(json.dumps(rows, indent=1))
        return 0
    for r in rows:
        bands = "  ".join(
            f"{k[:-8]}: {r[k]:.3f} / {r.get(k[:-8] + '_bias', np.nan):+.3f}"
            for k in r
            if k.endswith("_relrmse")
        )
        print(f"wall {r['wall_texels']:g} texels, inset {r['inset']:g}: relRMSE / bias  {bands}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
