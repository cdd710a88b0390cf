"""Rule ``Atlas``: a record's ``ahdLightmap:atlas:scaleOffset`` / ``atlas:page`` (issue 39)
give a whole-texel, block-aligned rectangle inside its page; the rectangles of one page are
disjoint and padded; the records of one page name the same page files.

A record's rectangle in page pixels (top-left origin, rows down; docs/schema.md):
``x0 = ox W``, ``y0 = (1 - oy - sy) H``, ``w = sx W``, ``h = sy H`` for the page file's
(W, H). A page is its files: records sharing a file are on one page and must agree on its
index and on every file (page indices are per output layer). The per-stage index of records
(:func:`page_index`) is built once per stage state
(cached by the layers' file stamps, like Staleness' scene) and shared by every prim's run.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

from usdahd.usd import inspect, schema
from usdahd.validate.findings import Finding, RuleFindings
from usdahd.validate.loading import baked_record, image_info

__all__ = ["check_atlas"]

#: Rectangle offsets are multiples of this (block-compressed formats code 4 x 4 blocks).
ALIGN = 4
#: Fewest texels between two rectangles of a page (bilinear taps and the gutter's dilation
#: need one texel on each side; the packer's minimum, ``--atlas-padding``).
MIN_PADDING = 2
#: A rectangle edge within this many texels of an integer is whole (float32 scale/offset of a
#: power-of-two page is exact; this only absorbs a hand-typed decimal).
TEXEL_EPSILON = 1e-3


@dataclass(frozen=True)
class Entry:
    """One atlas record of the stage: prim path, page key (layer, index), scale/offset,
    texture role -> file, page (W, H) from its first readable texture (None if none reads),
    and its rectangle (x0, y0, w, h) in page texels (None without a page size or a valid
    scale/offset)."""

    path: str
    layer: str
    page: int
    scale_offset: tuple
    files: tuple
    page_size: tuple | None
    rect: tuple | None


def _valid_scale_offset(so) -> bool:
    return (
        isinstance(so, tuple)
        and len(so) == 4
        and all(isinstance(v, float) and math.isfinite(v) for v in so)
    )


def _in_range(so) -> bool:
    sx, sy, ox, oy = so
    eps = 1e-6
    return (
        0 < sx <= 1 + eps
        and 0 < sy <= 1 + eps
        and ox >= 0
        and oy >= 0
        and (sx + ox <= 1 + eps and sy + oy <= 1 + eps)
    )


def _page_size(results) -> tuple | None:
    """(W, H) of the record's page: the size of its first texture that reads (Textures
    reports the others)."""
    for role in sorted(results.textures):
        try:
            img = image_info(results.textures[role])
        except Exception:  # noqa: BLE001 - unreadable files are Textures' findings
            continue
        return (img.width, img.height)
    return None


def rectangle(so, page) -> tuple:
    """(x0, y0, w, h) in page texels (floats) of scale/offset ``so`` in a (W, H) page."""
    sx, sy, ox, oy = so
    W, H = page
    return (ox * W, (1.0 - oy - sy) * H, sx * W, sy * H)


def _entry(prim, results, props) -> Entry:
    so = props["scale_offset"] if props["scale_offset"] is not None else (1.0, 1.0, 0.0, 0.0)
    page = props["page"] if props["page"] is not None else 0
    size = _page_size(results)
    rect = None
    if size is not None and _valid_scale_offset(so) and _in_range(so):
        rect = tuple(int(round(v)) for v in rectangle(so, size))
    return Entry(
        str(prim.GetPath()),
        props["layer"] or "",
        page,
        so,
        tuple(sorted(results.textures.items())),
        size,
        rect,
    )


class PageIndex(dict):
    """{prim path: Entry}, plus the entries grouped by file (``by_file``: file -> paths): the
    records that share a file are on one page (a page is its files: page indices are per
    output layer, and the validation's view of instance entries authors them in the session
    layer), so a prim meets only its page's records, not every record of the stage."""

    def __init__(self, entries: dict):
        super().__init__(entries)
        self.by_file: dict = {}
        for path, e in entries.items():
            for _, f in e.files:
                self.by_file.setdefault(f, []).append(path)

    def neighbours(self, path: str) -> list:
        """Entries other than ``path``'s sharing one of its files, by path."""
        me = self[path]
        near = set()
        for _, f in me.files:
            near.update(self.by_file.get(f, ()))
        near.discard(path)
        return [self[p] for p in sorted(near)]


_INDEX: OrderedDict = OrderedDict()
_INDEX_LOCK = threading.Lock()


def _seen_through_a_copy(prim) -> bool:
    """A prototype's record seen through an instance proxy or a PointInstancer prototype: not
    a record of its own (the copies' own entries are; docs/schema.md, Instances)."""
    from usdahd.usd.instances import in_point_instancer_prototype

    return bool(prim.IsInstanceProxy() or in_point_instancer_prototype(prim))


def page_index(stage) -> PageIndex:
    """{prim path: Entry} of every baked prim of the stage with atlas properties (cached per
    stage while its layers are unchanged on disk; rebuilt for unsaved or anonymous layers)."""
    key = inspect.layers_stamp(stage)
    if key is not None:
        key = (id(stage), key)
        with _INDEX_LOCK:
            if key in _INDEX:
                return _INDEX[key]
    index = {}
    for prim in schema.prims_with_api(stage):
        if _seen_through_a_copy(prim):
            continue
        props = inspect.atlas_properties(prim)
        if props is None:
            continue
        results = baked_record(prim)
        if results is None:
            continue
        index[str(prim.GetPath())] = _entry(prim, results, props)
    index = PageIndex(index)
    if key is not None:
        with _INDEX_LOCK:
            _INDEX[key] = index
            while len(_INDEX) > 4:
                _INDEX.popitem(last=False)
    return index


def _gap(a: tuple, b: tuple) -> tuple[int, int]:
    """Texels between rectangles a and b along x and along y (negative: they overlap along that
    axis by that many)."""
    ax, ay, aw, ah = a
    bx, by, bw, bh = b
    return max(bx - (ax + aw), ax - (bx + bw)), max(by - (ay + ah), ay - (by + bh))


def _show(rect) -> str:
    x0, y0, w, h = rect
    return f"({x0}, {y0}) {w}x{h}"


def check_atlas(prim) -> list[Finding]:
    """Rule Atlas (see RULES)."""
    r = RuleFindings("Atlas", prim)
    results = baked_record(prim)
    if results is None:
        return r.out
    props = inspect.atlas_properties(prim)
    if props is None or _seen_through_a_copy(prim):
        return r.out  # no atlas (the record's textures are its own), or not its own record
    path = str(prim.GetPath())
    so, page = props["scale_offset"], props["page"]
    so = so if so is not None else (1.0, 1.0, 0.0, 0.0)
    page = page if page is not None else 0
    # Range: SchemaValues reports it when the schema knows the atlas properties (one finding).
    reported = any(p.startswith("atlas:") for p in schema.result_problems(results))
    if not isinstance(page, int) or isinstance(page, bool) or page < 0:
        if not reported:
            r.error(
                "PageIndex",
                f"{inspect.ATLAS_PAGE} is {page!r}, not a page index (an integer >= 0)",
                "re-bake the prim",
                page=str(page),
            )
        return r.out
    if not _valid_scale_offset(so) or not _in_range(so):
        if not reported:
            r.error(
                "ScaleOffsetRange",
                f"{inspect.ATLAS_SCALE_OFFSET} {so!r} does not put the record inside its page "
                "(need four finite numbers with 0 < sx, sy <= 1, ox, oy >= 0, sx + ox <= 1 "
                "and sy + oy <= 1)",
                "re-bake the prim",
                scale_offset=str(so),
            )
        return r.out
    index = page_index(prim.GetStage())
    me = index.get(path)
    if me is None or me.page_size is None:
        return r.out  # no readable page file: Textures reports it
    W, H = me.page_size
    exact = rectangle(so, (W, H))
    frac = max(abs(v - round(v)) for v in exact)
    if frac > TEXEL_EPSILON:
        r.error(
            "FractionalRect",
            f"{inspect.ATLAS_SCALE_OFFSET} {so} gives the rectangle x0 {exact[0]:g}, y0 "
            f"{exact[1]:g}, {exact[2]:g} x {exact[3]:g} texels in the {W}x{H} page {page}: not "
            "whole texels, so the record's texels straddle page texels",
            "re-bake the prim (scale and offset are whole texels over the page size)",
            page=page,
            page_size=(W, H),
            rect=exact,
        )
        return r.out
    rect = me.rect
    if rect[0] % ALIGN or rect[1] % ALIGN:
        r.error(
            "Unaligned",
            f"the rectangle {_show(rect)} in page {page} ({W}x{H}) starts off the {ALIGN}x"
            f"{ALIGN} block grid (x0 and y0 must be multiples of {ALIGN}), so block-compressed "
            "pages mix its texels with a neighbour's in one block",
            "re-bake the prim",
            page=page,
            rect=rect,
        )
    for other in index.neighbours(path):  # the records sharing a file with this one
        shared = {f for _, f in other.files} & {f for _, f in me.files}
        if other.page != me.page:
            r.error(
                "PageFiles",
                f"{path} (page {page}) and {other.path} (page {other.page}) name the same file "
                f"{sorted(shared)[0]} under different page indices",
                "re-bake both prims (a page file belongs to one page index)",
                other=other.path,
            )
        elif other.files != me.files:
            mine, theirs = dict(me.files), dict(other.files)
            roles = [k for k in sorted(set(mine) | set(theirs)) if mine.get(k) != theirs.get(k)]
            r.error(
                "PageFiles",
                f"{path} and {other.path} share page {page}'s {sorted(shared)[0]} but name "
                f"different files for {', '.join(roles)} (e.g. {mine.get(roles[0])} and "
                f"{theirs.get(roles[0])})",
                "re-bake both prims (every record of a page names the page's files)",
                other=other.path,
                roles=roles,
            )
            continue
        if other.rect is None:
            continue
        gx, gy = _gap(rect, other.rect)
        if gx < 0 and gy < 0:
            r.error(
                "Overlap",
                f"the rectangle {_show(rect)} of {path} overlaps {other.path}'s "
                f"{_show(other.rect)} in page {page} ({W}x{H}) by {-gx}x{-gy} texels: both "
                "prims' lightmaps are read from the same texels",
                "re-bake both prims",
                other=other.path,
                rect=rect,
                other_rect=other.rect,
                page=page,
            )
        elif max(gx, gy) < MIN_PADDING:
            r.error(
                "Padding",
                f"the rectangle {_show(rect)} of {path} is {max(gx, gy)} texel(s) from "
                f"{other.path}'s {_show(other.rect)} in page {page} ({W}x{H}), below the "
                f"{MIN_PADDING}-texel padding, so bilinear filtering and mips blend the two",
                "re-bake both prims (--atlas-padding 2 or more)",
                other=other.path,
                rect=rect,
                other_rect=other.rect,
                gap=max(gx, gy),
                page=page,
            )
    return r.out
