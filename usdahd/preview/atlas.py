"""``usdahd preview --atlas``: a contact sheet of every lightmap texture of a bake (issue 14).

One row per baked prim (sorted by path), one tile per texture of its model's layout (the order of
``models.get(model).layout(ratio)``; the float32 SH sidecar, which engines do not load, is left
out). Each tile is the texture at an integer magnification (nearest texel), so texel boundaries
stay where they are:

- float textures (half/float: I_z, L0, coefficients) are tone-mapped per tile: the 99th
  percentile of the finite covered values maps to 0.9, then sRGB; negative values show black;
- 8-bit textures (direction, ratio codes) show their stored codes as they are;
- one or two channels show grey / red-green, four show the first three;
- **chart outlines**: the prim's lightmap UVs rasterised at the texture's resolution by the
  baker's rasteriser (:func:`usdahd.bake.texels.rasterize`), chart ids per texel
  (:func:`usdahd.bake.texels.chart_ids`); a tile pixel on a boundary between two charts, or
  between a chart and uncovered gutter, is drawn in ``OUTLINE``;
- **flagged texels**: ``usdahd validate``'s findings (errors and warnings) on the prim that name a
  texel (``texel``, ``worst_texel`` in their data) get a square in ``FLAG`` around that texel in
  every tile of the prim.

numpy only here; the USD side (reading the stage, rasterising, validating) is imported when used.
"""

from __future__ import annotations

import numpy as np

__all__ = ["contact_sheet"]

#: Tile pixels aimed at (the larger texture side is magnified by an integer to at most this).
TILE = 192
#: Black pixels between tiles and around the sheet.
GAP = 6
#: Colours (RGB 0..255) of chart outlines and of texels flagged by validate.
OUTLINE = (255, 255, 255)
FLAG = (255, 0, 255)
#: Finding data keys that name one texel (x, y).
TEXEL_KEYS = ("texel", "worst_texel")


def magnification(resolution, tile: int = TILE) -> int:
    """Integer magnification of a (w, h) texture into a tile (at least 1)."""
    return max(1, int(tile) // max(int(resolution[0]), int(resolution[1])))


def display(pixels: np.ndarray, covered: np.ndarray | None = None) -> np.ndarray:
    """(h, w, 3) uint8 of a stored texture (h, w, c): see the module doc."""
    px = np.asarray(pixels)
    h, w, c = px.shape
    if px.dtype == np.uint8:
        x = px.astype(np.float64) / 255.0
        srgb = False
    else:
        x = px.astype(np.float64)
        x = np.where(np.isfinite(x), x, 0.0)
        sel = x[covered] if covered is not None and covered.any() else x.reshape(-1, c)
        ref = float(np.percentile(sel, 99)) if sel.size else 0.0
        x = np.clip(x * (0.9 / ref if ref > 0 else 1.0), 0.0, 1.0)
        srgb = True
    rgb = np.zeros((h, w, 3))
    if c == 1:
        rgb[:] = x
    else:
        rgb[..., : min(c, 3)] = x[..., :3]
    if srgb:
        rgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    return np.rint(255.0 * rgb).astype(np.uint8)


def chart_image(mesh, resolution) -> np.ndarray:
    """(h, w) int64: the chart id of each covered texel of the mesh's lightmap UVs, -1 elsewhere."""
    from usdahd.bake.texels import chart_ids, rasterize

    w, h = resolution
    t = rasterize(mesh, (w, h))
    img = np.full((h, w), -1, np.int64)
    img[t.xy[:, 1], t.xy[:, 0]] = chart_ids(mesh)[t.triangle]
    return img


def tile(
    pixels: np.ndarray, charts: np.ndarray, flagged, scale: int
) -> tuple[np.ndarray, np.ndarray]:
    """One tile: (H, W, 3) uint8 at ``scale`` with chart outlines and flagged texels, and the
    (H, W) bool outline mask. flagged : [(x, y)] texel positions."""
    img = display(pixels, charts >= 0)
    big = np.repeat(np.repeat(img, scale, 0), scale, 1)
    ids = np.repeat(np.repeat(charts, scale, 0), scale, 1)
    edge = np.zeros(ids.shape, bool)
    dx = ids[:, 1:] != ids[:, :-1]
    dy = ids[1:, :] != ids[:-1, :]
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    if scale < 2:  # one pixel per texel: outline the chart's own border texels only
        edge &= ids >= 0
    big[edge] = OUTLINE
    h, w = charts.shape
    for x, y in flagged:
        if not (0 <= x < w and 0 <= y < h):
            continue
        x0, y0 = max(x * scale - 1, 0), max(y * scale - 1, 0)
        x1, y1 = min((x + 1) * scale, w * scale - 1), min((y + 1) * scale, h * scale - 1)
        big[y0, x0 : x1 + 1] = FLAG
        big[y1, x0 : x1 + 1] = FLAG
        big[y0 : y1 + 1, x0] = FLAG
        big[y0 : y1 + 1, x1] = FLAG
    return big, edge


def flagged_texels(findings) -> dict[str, list[tuple[int, int, str]]]:
    """{prim: [(x, y, "rule/code")]} of the errors and warnings that name a texel."""
    out: dict[str, list[tuple[int, int, str]]] = {}
    for f in findings:
        if f.severity not in ("error", "warning"):
            continue
        data = f.data or {}
        for key in TEXEL_KEYS:
            xy = data.get(key)
            if xy is not None and len(xy) == 2:
                out.setdefault(f.prim, []).append((int(xy[0]), int(xy[1]), f"{f.rule}/{f.code}"))
    return out


def sheet(rows) -> tuple[np.ndarray, list[dict]]:
    """Lay out rows [(prim, [(role, file, tile (H, W, 3))])] left to right, top to bottom.
    returns (the sheet (H, W, 3) uint8, [{prim, role, file, x, y, width, height}])."""
    cell_h = [max(t.shape[0] for _, _, t in tiles) for _, tiles in rows]
    cell_w = max(t.shape[1] for _, tiles in rows for _, _, t in tiles)
    ncol = max(len(tiles) for _, tiles in rows)
    width = GAP + ncol * (cell_w + GAP)
    height = GAP + sum(h + GAP for h in cell_h)
    out = np.zeros((height, width, 3), np.uint8)
    placed = []
    y = GAP
    for (prim, tiles), ch in zip(rows, cell_h):
        x = GAP
        for role, file, t in tiles:
            out[y : y + t.shape[0], x : x + t.shape[1]] = t
            placed.append(dict(prim=prim, role=role, file=file, x=x, y=y,
                               width=int(t.shape[1]), height=int(t.shape[0])))  # fmt: skip
            x += cell_w + GAP
        y += ch + GAP
    return out, placed


def contact_sheet(meshes, findings, tile_size: int = TILE) -> tuple[np.ndarray, dict]:
    """The ``--atlas`` sheet of ``meshes`` (:func:`usdahd.preview.meshes.baked_meshes`'s
    list) with ``findings`` (usdahd.validate Findings of the stage, or [] to mark none).
    returns (sheet (H, W, 3) uint8, report dict: tiles, flagged, outline_pixels)."""
    from usdahd import models
    from usdahd.usd import schema

    marks = flagged_texels(findings)
    rows, flagged, outline = [], [], 0
    for mesh, res, *_ in sorted(meshes, key=lambda m: m[0].path):
        scale = magnification(res.resolution, tile_size)
        charts = chart_image(mesh, res.resolution)
        here = marks.get(mesh.path, [])
        tiles = []
        for lay in models.get(res.model).layout(res.ratio):
            px = schema.read_record_pixels(res, lay.role, lay.channels)
            if px.shape[:2] != charts.shape:
                ch = chart_image(mesh, (px.shape[1], px.shape[0]))
            else:
                ch = charts
            t, edge = tile(px, ch, [(x, y) for x, y, _ in here], scale)
            outline += int(edge.sum())
            tiles.append((lay.role, str(res.textures[lay.role]), t))
        flagged += [dict(prim=mesh.path, texel=[x, y], finding=what) for x, y, what in here]
        rows.append((mesh.path, tiles))
    img, placed = sheet(rows)
    return img, {"tiles": placed, "flagged": flagged, "outline_pixels": outline}
