"""Atlas rectangles of bake records (docs/schema.md, "Atlas pages"): where a record lives in its
page (``ahdLightmap:atlas:scaleOffset``), and the one reader of a record's pixels. Re-exported by
:mod:`usdahd.usd.schema`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from usdahd.errors import SchemaError

if TYPE_CHECKING:
    from usdahd.usd.schema import BakeResults

__all__ = [
    "NO_ATLAS",
    "crop_record",
    "page_size",
    "read_record_pixels",
    "record_rect",
    "rect_problem",
]


#: ``atlas:scaleOffset`` of a record that is not in an atlas (its textures are its own).
NO_ATLAS = (1.0, 1.0, 0.0, 0.0)


def page_size(results: BakeResults) -> tuple[int, int]:
    """(W, H) of the record's page: its own resolution divided by the scale (exact: pages are
    powers of two and rectangles whole texels)."""
    w, h = (int(r) for r in results.resolution)
    sx, sy = float(results.scale_offset[0]), float(results.scale_offset[1])
    return int(round(w / sx)), int(round(h / sy))


def record_rect(
    results: BakeResults, page: tuple[int, int] | None = None
) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) of the record's rectangle in page pixels (top-left origin, rows down):
    ``x0 = ox W``, ``y0 = (1 - oy - sy) H``, ``w = sx W``, ``h = sy H`` (docs/schema.md,
    "Atlas"). ``page`` (W, H) defaults to :func:`page_size`."""
    sx, sy, ox, oy = (float(v) for v in results.scale_offset)
    W, H = page if page is not None else page_size(results)
    return (
        int(round(ox * W)),
        int(round((1.0 - oy - sy) * H)),
        int(round(sx * W)),
        int(round(sy * H)),
    )


def read_record_pixels(results: BakeResults, role: str, channels=None):
    """(h, w, c) pixels of one record in one texture role (FILE_ROLES): the crop of its atlas
    page (``atlas:scaleOffset``), or the whole file without an atlas. ``channels`` (names) as
    :func:`usdahd.images.read`. The one reader of a record's pixels: validate, preview, export
    and refit go through it. Raises ImageError when the file is unreadable, or SchemaError when
    the page does not hold the record's rectangle."""
    import numpy as np

    from usdahd import images

    px = np.asarray(images.read(results.textures[role], channels=channels).pixels)
    return crop_record(results, px, results.textures[role])


def rect_problem(results: BakeResults, page: tuple[int, int]) -> str | None:
    """Why the record's rectangle does not fit a (W, H) page file, or None. Without an atlas
    the file must be the record's own size."""
    W, H = (int(v) for v in page)
    w, h = (int(r) for r in results.resolution)
    if not results.atlas:
        if (W, H) != (w, h):
            return f"is {W}x{H} but ahdLightmap:baked:resolution is {w}x{h}"
        return None
    if W & (W - 1) or H & (H - 1):
        return f"is an atlas page of {W}x{H}, not a power of two on each side"
    x0, y0, rw, rh = record_rect(results, (W, H))
    so = tuple(results.scale_offset)
    if (rw, rh) != (w, h):
        return (
            f"is a {W}x{H} atlas page where atlas:scaleOffset {so} gives a {rw}x{rh} rectangle, "
            f"not the record's {w}x{h} (ahdLightmap:baked:resolution)"
        )
    if x0 < 0 or y0 < 0 or x0 + w > W or y0 + h > H:
        return f"is a {W}x{H} atlas page that the rectangle ({x0}, {y0}) {w}x{h} leaves"
    return None


def crop_record(results: BakeResults, pixels, what: str = ""):
    """The record's (h, w, ...) region of an already-read page ``pixels`` (H, W, ...), the
    whole array without an atlas. Raises SchemaError (see :func:`rect_problem`)."""
    H, W = pixels.shape[:2]
    why = rect_problem(results, (W, H))
    if why is not None:
        raise SchemaError(f"{what or 'the texture'} {why}; re-bake the prim")
    if not results.atlas:
        return pixels
    x0, y0, w, h = record_rect(results, (W, H))
    return pixels[y0 : y0 + h, x0 : x0 + w]
