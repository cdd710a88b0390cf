"""Packing lightmap rectangles into atlas pages (``usdahd bake --atlas``, docs/schema.md "Atlas").

:func:`pack` takes one rectangle ``(w, h)`` per record (its own texel grid) and returns, per
record, a page index and the top-left pixel offset of its rectangle in that page, plus each
page's size. The rules:

- **pages are powers of two**, at most ``max_size`` on a side; a page shrinks (each side on its
  own) to the smallest power of two that still holds its rectangles, so a Cornell box does not
  get a 2048² page; a rectangle larger than ``max_size`` gets a page of its own (the next powers
  of two of its sides);
- **offsets are multiples of** :data:`ALIGN` (4: block-compressed formats code 4x4 blocks, so
  no block straddles two records);
- **at least ``padding`` texels between two rectangles** (each rectangle's cell is its size plus
  ``padding``, rounded up to :data:`ALIGN`); the gutter is shared by the two neighbours, each
  dilating into its half (:func:`territory`), so nothing bleeds across rectangles;
- **fewest page texels**: page caps of ``max_size``, half of it, ... are tried (:func:`pack`);
- **deterministic**: rectangles are placed in the order (taller first, then wider, then key),
  by a skyline bottom-left rule (each goes where its top edge ends highest, then leftmost), or,
  where that leaves rectangles out that they place, by MaxRects with the best-area or the
  best-long-side fit (:data:`PLACERS`, tried in that order; the first that places the most
  area wins, so the skyline's pages stay as they were wherever it already fitted); then the
  same rules wider first (:data:`ORDERS`). A rectangle on a page's right or bottom edge keeps
  no gutter beyond it.

numpy only (the packing itself is a small pure-Python loop over the skyline).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DEFAULT_SIZE", "MIN_PADDING", "is_power_of_two", "pack", "scale_offset", "territory"]

#: Offsets and cell sizes are multiples of this (the 4x4 block of BC6H / BC7).
ALIGN = 4
#: Smallest padding between two rectangles (bilinear filtering reads one texel beyond a
#: rectangle's edge: each neighbour needs at least one gutter texel of its own).
MIN_PADDING = 2
#: Default largest page side (``--atlas-size``): 2048 is the largest lightmap page Unity's
#: default "Max Lightmap Size" and Godot's LightmapGI "max_texture_size" (16384 max, 2048 per
#: page on mobile) import everywhere, and a 2048² half-float RGBA page is 32 MiB in memory.
DEFAULT_SIZE = 2048


@dataclass(frozen=True)
class Placement:
    """Where one rectangle went: page index and top-left pixel offset (x right, y down)."""

    page: int
    x: int
    y: int
    w: int
    h: int


@dataclass
class Packing:
    """placements : one per input rectangle (input order); pages : (W, H) per page."""

    placements: list[Placement]
    pages: list[tuple[int, int]]

    def fill(self, page: int | None = None) -> float:
        """Rectangle area / page area (of one page, or of all pages)."""
        idx = range(len(self.pages)) if page is None else [page]
        area = sum(self.pages[k][0] * self.pages[k][1] for k in idx)
        used = sum(p.w * p.h for p in self.placements if p.page in idx)
        return used / area if area else 0.0


#: Texels a page counts beyond its own in :func:`pack`'s choice (a 128² page's worth): enough
#: that records sharing a page beat one page each when the gutters cost less than this per page.
PAGE_COST = 128 * 128


def is_power_of_two(n: int) -> bool:
    return isinstance(n, int) and n > 0 and n & (n - 1) == 0


def next_power_of_two(n: int) -> int:
    return 1 << max(0, int(n) - 1).bit_length()


def _align(n: int) -> int:
    return -(-int(n) // ALIGN) * ALIGN


def cell(w: int, h: int, padding: int) -> tuple[int, int]:
    """The space a (w, h) rectangle takes in a page: its size plus ``padding``, aligned."""
    return _align(w + padding), _align(h + padding)


def _skyline(cells: list[tuple[int, int]], width: int, height: int) -> list | None:
    """Top-left offsets of ``cells`` (in order) in a ``width`` x ``height`` page by the skyline
    bottom-left rule, or None for a cell that does not fit (then the whole list is returned
    with None at that cell). A cell may overhang the right/bottom edge by its padding only:
    callers pass cells already clipped to what must fit."""
    sky = [[0, 0, width]]  # segments [x, y, w]: free space starts at row y over [x, x + w)
    out = []
    for cw, ch in cells:
        best = None
        for i in range(len(sky)):
            x = sky[i][0]
            if x + cw > width:
                break
            # the highest skyline under [x, x + cw)
            y, j, span = 0, i, 0
            while span < cw:
                y = max(y, sky[j][1])
                span += sky[j][2]
                j += 1
            if y + ch > height:
                continue
            if best is None or (y + ch, x) < (best[1] + ch, best[0]):
                best = (x, y, i)
        if best is None:
            out.append(None)
            continue
        x, y, i = best
        out.append((x, y))
        # raise the skyline under the new cell
        new = [x, y + ch, cw]
        j, end = i, x + cw
        rest = []
        while j < len(sky) and sky[j][0] < end:
            sx, sy, sw = sky[j]
            if sx + sw > end:
                rest.append([end, sy, sx + sw - end])
            j += 1
        sky[i:j] = [new] + rest
        merged = []
        for seg in sky:
            if merged and merged[-1][1] == seg[1]:
                merged[-1][2] += seg[2]
            else:
                merged.append(seg)
        sky = merged
    return out


def _maxrects(cells: list[tuple[int, int]], width: int, height: int, rule: str) -> list:
    """Top-left offsets of ``cells`` (in order) in a ``width`` x ``height`` page by MaxRects
    (Jylanki, "A Thousand Ways to Pack the Bin", 2010: the free space kept as maximal
    rectangles), each cell in the free rectangle that leaves the least area (``rule`` "baf") or
    the shortest long side ("blsf") free, ties by the other measure then top, left; None for a
    cell that does not fit (the others are still placed). Offsets are sums of cell sizes, so
    aligned cells keep aligned offsets."""
    free = [(0, 0, width, height)]
    out: list = []
    for cw, ch in cells:
        best = None
        for fx, fy, fw, fh in free:
            if cw > fw or ch > fh:
                continue
            short, long_ = sorted((fw - cw, fh - ch))
            if rule == "baf":
                score = (fw * fh - cw * ch, short, fy, fx)
            else:
                score = (long_, short, fy, fx)
            if best is None or score < best[0]:
                best = (score, fx, fy)
        if best is None:
            out.append(None)
            continue
        _, x, y = best
        out.append((x, y))
        split = []
        for fx, fy, fw, fh in free:
            if x >= fx + fw or x + cw <= fx or y >= fy + fh or y + ch <= fy:
                split.append((fx, fy, fw, fh))
                continue
            if x > fx:
                split.append((fx, fy, x - fx, fh))
            if x + cw < fx + fw:
                split.append((x + cw, fy, fx + fw - x - cw, fh))
            if y > fy:
                split.append((fx, fy, fw, y - fy))
            if y + ch < fy + fh:
                split.append((fx, y + ch, fw, fy + fh - y - ch))
        split = sorted(set(split))
        free = [
            a
            for a in split
            if not any(
                b != a
                and b[0] <= a[0]
                and b[1] <= a[1]
                and b[0] + b[2] >= a[0] + a[2]
                and b[1] + b[3] >= a[1] + a[3]
                for b in split
            )
        ]
    return out


#: The placement rules tried, in order (:func:`_place`): skyline bottom-left, then MaxRects
#: best-area fit and best-long-side fit. On Sponza's 37 records after branch i39-fill2's
#: unwraps (961,552 texels of cells with their padding) the skyline needs a 1024² page and a
#: 256² one; MaxRects best-area fit puts them all in the 1024² page (fill 52.9 % -> 56.2 %).
PLACERS = ("skyline", "baf", "blsf")
#: MaxRects keeps a list of free rectangles that grows with the cells (its cost per cell is
#: quadratic in that list): pages of more cells than this are placed by the skyline alone.
MAXRECTS_LIMIT = 256


#: Orders the cells are placed in by each rule of :data:`PLACERS` (:func:`_place`): as given
#: (taller first), then wider first. Sponza's 37 maps after branch i39-fill3's unwraps (999,472
#: texels of cells, 95 % of a 1024² page) fit one page only wider first with MaxRects
#: best-long-side fit.
ORDERS = ("given", "wider")


def _area(cells, got) -> int:
    """Cell area of the cells placed (``got`` not None)."""
    return sum(c[0] * c[1] for c, g in zip(cells, got) if g is not None)


def _place(cells: list[tuple[int, int]], width: int, height: int, ok=None) -> list:
    """Offsets of ``cells`` in a ``width`` x ``height`` page by the first rule of
    :data:`PLACERS`, in the first order of :data:`ORDERS`, that places every cell (and passes
    ``ok(offsets)`` when given), else by the first that places the most cell area (None for
    cells left out)."""
    best = None
    for order in ORDERS:
        if order == "given":
            idx = list(range(len(cells)))
        else:
            idx = sorted(range(len(cells)), key=lambda i: (-cells[i][0], -cells[i][1], i))
        seq = [cells[i] for i in idx]
        for rule in PLACERS:
            if rule == "skyline":
                placed = _skyline(seq, width, height)
            elif len(cells) <= MAXRECTS_LIMIT:
                placed = _maxrects(seq, width, height, rule)
            else:
                continue
            got: list = [None] * len(cells)
            for i, g in zip(idx, placed):
                got[i] = g
            if all(g is not None for g in got) and (ok is None or ok(got)):
                return got
            area = _area(cells, got)
            if best is None or area > best[0]:
                best = (area, got)
    return best[1]


def pack(
    sizes: list[tuple[int, int]],
    keys: list[str] | None = None,
    *,
    max_size: int = DEFAULT_SIZE,
    padding: int = 4,
) -> Packing:
    """Pack rectangles ``sizes`` [(w, h)] into pages (see the module doc); ``keys`` (e.g. prim
    paths, default the index) break ties so the result does not depend on the input order.

    Pages of at most ``max_size``, ``max_size / 2``, ... (down to ``max_size / 8``, at least 64)
    are tried, and the packing with the fewest page texels in total wins, each page counted
    ``PAGE_COST`` texels more (then the fewest pages): one 2048² page holding 2.4 M texels of
    rectangles is 58 % full, where a 1024² page for the largest map and two more for the rest
    fill theirs (the classroom); and 49 maps of 128² (``--resolution 128``) take one 1024²
    page, not 49 pages of their own that save the padding (a page costs an engine a texture
    binding and splits batches)."""
    if not is_power_of_two(max_size):
        raise ValueError(f"the page size must be a power of two, got {max_size}")
    best = None
    size = max_size
    while size >= max(64, max_size // 8) or size == max_size:
        got = _pack(sizes, keys, max_size=size, padding=padding)
        area = sum(w * h for w, h in got.pages) + PAGE_COST * len(got.pages)
        if best is None or (area, len(got.pages)) < best[0]:
            best = ((area, len(got.pages)), got)
        size //= 2
    return best[1]


def _pack(sizes, keys, *, max_size: int, padding: int) -> Packing:
    if not is_power_of_two(max_size):
        raise ValueError(f"the page size must be a power of two, got {max_size}")
    if padding < MIN_PADDING:
        raise ValueError(f"the padding must be >= {MIN_PADDING} texels, got {padding}")
    n = len(sizes)
    keys = [str(i) for i in range(n)] if keys is None else [str(k) for k in keys]
    for w, h in sizes:
        if int(w) <= 0 or int(h) <= 0:
            raise ValueError(f"rectangle sizes must be positive, got {(w, h)}")
    order = sorted(range(n), key=lambda i: (-sizes[i][1], -sizes[i][0], keys[i]))
    placements: list[Placement | None] = [None] * n
    pages: list[tuple[int, int]] = []
    # a rectangle that cannot fit a max_size page (with its padding) gets its own page
    big = [i for i in order if max(cell(*sizes[i], padding)) > max_size]
    todo = [i for i in order if i not in set(big)]
    groups: list[list[int]] = []
    while todo:
        cells = [cell(*sizes[i], padding) for i in todo]

        # a rectangle on the page's right or bottom edge needs no gutter beyond it
        def inside(got, todo=todo):
            return all(
                g is None or (x + sizes[i][0] <= max_size and y + sizes[i][1] <= max_size)
                for i, g in zip(todo, got)
                for x, y in [g or (0, 0)]
            )

        got = _place(cells, max_size, max_size)
        if any(g is None for g in got):
            edge = _place(cells, max_size + padding, max_size + padding, inside)
            if inside(edge) and _area(cells, edge) > _area(cells, got):
                got = edge
        groups.append(
            ([i for i, g in zip(todo, got) if g is not None], [g for g in got if g is not None])
        )
        todo = [i for i, g in zip(todo, got) if g is None]
    for members, placed in groups:
        k = len(pages)
        size, offsets = _smallest(members, sizes, padding, max_size, placed)
        pages.append(size)
        for i, (x, y) in zip(members, offsets):
            placements[i] = Placement(k, x, y, int(sizes[i][0]), int(sizes[i][1]))
    for i in big:
        w, h = int(sizes[i][0]), int(sizes[i][1])
        placements[i] = Placement(len(pages), 0, 0, w, h)
        pages.append((next_power_of_two(w), next_power_of_two(h)))
    return Packing([p for p in placements if p is not None], pages)


def _smallest(members, sizes, padding, max_size, placed):
    """The smallest power-of-two page (area, then squarer) that holds ``members`` (packed in
    order), and their offsets; else the ``max_size`` page with the offsets ``placed``. The
    last cell of a row or column may lose its trailing gutter at the page edge (the rectangle
    itself always fits)."""
    cells = [cell(*sizes[i], padding) for i in members]
    area = sum(sizes[i][0] * sizes[i][1] for i in members)
    candidates = []
    s = 1
    while s <= max_size:
        t = 1
        while t <= max_size:
            if s * t >= area:
                candidates.append((s * t, abs(s - t), s, t))
            t *= 2
        s *= 2
    for _, _, w, h in sorted(candidates):
        # the gutter beyond the page edge is not needed: allow it to overhang
        def inside(got, w=w, h=h):
            return all(
                g is not None and g[0] + sizes[i][0] <= w and g[1] + sizes[i][1] <= h
                for i, g in zip(members, got)
            )

        for extra in (padding + ALIGN, padding):
            got = _place(cells, w + extra, h + extra, inside)
            if inside(got):
                return (w, h), got
    return (max_size, max_size), placed


def scale_offset(p: Placement, page: tuple[int, int]) -> tuple[float, float, float, float]:
    """(sx, sy, ox, oy) with ``uv_page = uv * (sx, sy) + (ox, oy)`` (UV origin bottom-left, as
    USD's st; the pixel rectangle has its origin top-left, rows down)."""
    W, H = page
    return (p.w / W, p.h / H, p.x / W, (H - p.y - p.h) / H)


def rect_of(
    scale_offset: tuple[float, float, float, float], page: tuple[int, int]
) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) pixel rectangle (top-left origin) of a scale/offset in a (W, H) page."""
    sx, sy, ox, oy = (float(v) for v in scale_offset)
    W, H = page
    return (
        int(round(ox * W)),
        int(round((1.0 - oy - sy) * H)),
        int(round(sx * W)),
        int(round(sy * H)),
    )


def territory(p: Placement, page: tuple[int, int], padding: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) the pixels a rectangle may write: itself plus ``padding // 2`` gutter
    texels on every side (clipped to the page). Rectangles are at least ``padding`` apart, so
    territories never overlap."""
    e = padding // 2
    W, H = page
    return max(0, p.x - e), max(0, p.y - e), min(W, p.x + p.w + e), min(H, p.y + p.h + e)
