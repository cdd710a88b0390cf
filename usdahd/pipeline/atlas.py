"""Atlas pages (``usdahd bake --atlas on``, the default; docs/schema.md "Atlas"): the per-prim
stages (trace or refit, fill, denoise, stitch) run as before; then the records are grouped by
encoding (model, ratio, solver, container), each group's rectangles are packed into pages
(:mod:`usdahd.numerics.atlas`), and per page: every record is fitted, the page is encoded once
over the concatenated fits (decode factors per page, copied into every record on it), each
record's texels are scattered at its offset and dilated inside its rectangle (exactly as a
one-map-per-prim bake dilates its own texture), the rectangle's edge texels are then repeated
into its half of the gutter (``--atlas-padding // 2`` texels on every side: bilinear taps at the
rectangle's border read the record's own values, like clamp-to-edge on its own texture, and
nothing bleeds across rectangles), and the page textures plus the page's SH sidecar are written
(staged, then committed with content-addressed names like every texture).

Incremental: a record that is not re-baked keeps its page while nothing else in its group
changes; when a group changes, its pages are rebuilt from the kept records' SH (their region of
the page's SH sidecar: refit and re-encode, 0 rays) plus the new records, and every record on a
rebuilt page is re-authored with its content hash unchanged.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from usdahd import models
from usdahd.errors import BakeError, UsdAhdError
from usdahd.numerics import atlas as packer
from usdahd.pipeline.outputs import texture_path, write_role_texture
from usdahd.pipeline.plan import PrimJob
from usdahd.pipeline.settings import BakeOptions

__all__ = [
    "group_key",
    "item_from_job",
    "item_from_record",
    "max_size",
    "padding",
    "plan_pages",
    "summary",
    "write_pages",
]

#: Settings that decide which records can share a page (one encode per page).
GROUP_KEYS = ("model", "ratio", "solver", "container")


def group_key(settings: dict) -> tuple:
    """The encoding a record's textures use: records of one page share it."""
    return tuple(str(settings.get(k) or "") for k in GROUP_KEYS)


def padding(opts: BakeOptions) -> int:
    """``--atlas-padding`` (default: the bake's ``--padding``, else 4; at least 2)."""
    if opts.atlas_padding is not None:
        return int(opts.atlas_padding)
    return max(packer.MIN_PADDING, int(opts.padding if opts.padding is not None else 4))


def max_size(opts: BakeOptions) -> int:
    return int(opts.atlas_size or packer.DEFAULT_SIZE)


@dataclass
class Item:
    """One record to place on a page: its texels (xy in its own grid) and their SH."""

    job: PrimJob
    resolution: tuple[int, int]
    xy: np.ndarray  #: (n, 2) int column, row
    sh: np.ndarray  #: (n, 3, 9) float32
    charts: np.ndarray | None  #: (n,) chart id per texel (None: one chart)
    settings: dict
    old: object = None  #: the previous BakeResults of a re-authored (not re-baked) record


def item_from_job(job: PrimJob) -> Item:
    """A record traced or refitted in this bake."""
    charts = job.charts
    if charts is None and job.mesh is not None:
        from usdahd.bake.texels import chart_ids

        charts = chart_ids(job.mesh)[job.texels.triangle]
    return Item(
        job,
        tuple(int(r) for r in job.texels.resolution),
        np.asarray(job.texels.xy),
        np.asarray(job.sh, np.float32),
        None if charts is None else np.asarray(charts),
        job.settings,
    )


def item_from_record(job: PrimJob, res, pages: dict | None = None) -> Item:
    """A record kept from the previous bake: its SH from its region of the SH sidecar (what
    it was fitted from, so the refit reproduces it exactly). ``pages``: a dict caching the page
    sidecars read (a page is read once for all its records). Raises BakeError when the sidecar
    is unusable (the caller re-bakes nothing and keeps the old page for it)."""
    from usdahd import images
    from usdahd.usd import schema

    side = res.textures.get(schema.SIDECAR_ROLE, "")
    try:
        if pages is None or not res.atlas:
            px = schema.read_record_pixels(res, schema.SIDECAR_ROLE, schema.SH_SIDECAR_CHANNELS)
        else:
            if side not in pages:
                pages.clear()  # records come sorted by page: keep one page in memory
                img = images.read(side, channels=schema.SH_SIDECAR_CHANNELS)
                pages[side] = img.pixels
            px = schema.crop_record(res, pages[side], side)
    except (UsdAhdError, OSError, KeyError) as exc:
        raise BakeError(f"{job.path}: SH sidecar unusable: {exc}") from None
    cov = px[..., 27] > 0.5
    ys, xs = np.nonzero(cov)
    sh = np.ascontiguousarray(px[ys, xs, :27].astype(np.float32).reshape(-1, 3, 9))
    xy = np.stack([xs, ys], axis=-1).astype(np.int32)
    return Item(job, tuple(int(r) for r in res.resolution), xy, sh, None, res.settings, old=res)


def plan_pages(todo: list[PrimJob], rebuild: list[PrimJob], opts: BakeOptions) -> dict:
    """``--dry-run``: the pages a bake would write (rectangles only: no texel is traced, so
    no coverage and no file yet): {"max_size", "padding", "planned": True, "pages": [{"size",
    "records", "rect_fill"}]}. ``rebuild``: kept records that would be re-packed."""
    sized = [(j.path, j.settings, tuple(int(r) for r in j.resolution)) for j in todo]
    sized += [(j.path, j.previous.settings, tuple(j.previous.resolution)) for j in rebuild]
    groups: dict[tuple, list] = {}
    for entry in sized:
        groups.setdefault(group_key(entry[1]), []).append(entry)
    pages = []
    for key in sorted(groups):
        members = sorted(groups[key], key=lambda e: e[0])
        packing = packer.pack(
            [e[2] for e in members], [e[0] for e in members], max_size=max_size(opts),
            padding=padding(opts),
        )  # fmt: skip
        for k, (W, H) in enumerate(packing.pages):
            on = [e for e, p in zip(members, packing.placements, strict=True) if p.page == k]
            pages.append(
                {
                    "size": [W, H],
                    "records": [e[0] for e in on],
                    "rect_fill": sum(e[2][0] * e[2][1] for e in on) / (W * H),
                }
            )
    return {"max_size": max_size(opts), "padding": padding(opts), "planned": True, "pages": pages}


def _status(opts: BakeOptions, msg: str) -> None:
    import sys

    if not opts.quiet:
        print(msg, file=sys.stderr)


def write_pages(
    items: list[Item], out: Path, opts: BakeOptions, used_pages: set[int]
) -> list[dict]:
    """Pack, encode and write the pages of ``items`` (see the module doc); sets each item's
    ``job.results``. ``used_pages``: page indices of records that keep their page (new pages
    take other indices). returns the page entries of the bake report."""
    groups: dict[tuple, list[Item]] = {}
    for it in items:
        groups.setdefault(group_key(it.settings), []).append(it)
    pad = padding(opts)
    entries = []
    free = (k for k in range(10**9) if k not in used_pages)
    for key in sorted(groups):
        members = sorted(groups[key], key=lambda it: it.job.path)
        packing = packer.pack(
            [it.resolution for it in members],
            [it.job.path for it in members],
            max_size=max_size(opts),
            padding=pad,
        )
        for k_local, size in enumerate(packing.pages):
            on_page = [
                (it, p)
                for it, p in zip(members, packing.placements, strict=True)
                if p.page == k_local
            ]
            index = next(free)
            t0 = time.perf_counter()
            try:
                entry = _write_page(index, size, on_page, out, pad)
            except UsdAhdError as exc:
                for it, _ in on_page:
                    it.job.results = None
                    it.job.report.update(
                        status="failed", error=f"{it.job.path}: page {index}: {exc}"
                    )
                continue
            entry["seconds"] = round(time.perf_counter() - t0, 3)
            entries.append(entry)
    return entries


def summary(entry: dict, opts: BakeOptions) -> None:
    """One stderr line per page (after the commit, with the files' sizes)."""
    for page in entry["pages"]:
        W, H = page["size"]
        size = sum(page.get("bytes", {}).values())
        _status(
            opts,
            f"atlas page {page['page']}: {W}x{H}, {len(page['records'])} record(s), fill "
            f"{100 * page['fill']:.1f}% ({page['covered_texels']} covered texels), "
            f"{size / 2**20:.2f} MiB in {len(page.get('bytes', {}))} file(s)",
        )


def _write_page(index: int, size, on_page, out: Path, pad: int) -> dict:
    """Fit, encode (once), scatter, dilate and write one page; set every record's results."""
    from usdahd import images
    from usdahd.bake import post
    from usdahd.usd import schema
    from usdahd.version import __version__

    s0 = on_page[0][0].settings
    model, ratio, solver = s0["model"], s0["ratio"], s0["solver"]
    mod = models.get(model)
    W, H = size
    fits = [models.fit(it.sh, model, ratio=ratio, solver=solver) for it, _ in on_page]
    counts = [len(it.xy) for it, _ in on_page]
    starts = np.concatenate([[0], np.cumsum(counts)])
    params = {k: np.concatenate([f.params[k] for f in fits]) for k in fits[0].params}
    channels, factors = mod.encode(params, ratio=ratio)
    decoded = mod.decode(channels, ratio=ratio, factors=factors)
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0], np.float32), (int(starts[-1]), 3))
    got = mod.evaluate(decoded, z)
    want = np.concatenate(
        [
            mod.evaluate(models.representable(f, mod), z[: len(it.xy)])
            for f, (it, _) in zip(fits, on_page)
        ]  # fmt: skip
    ).astype(np.float64)
    if not np.isfinite(got).all():
        raise BakeError("decoded lightmap contains NaN/Inf (please report a bug)")
    err = np.abs(got - want) / np.maximum(np.abs(want).max(axis=-1, keepdims=True), 1e-6)
    for i, (it, _) in enumerate(on_page):
        if it.old is None:
            e = err[starts[i] : starts[i + 1]]
            it.job.report["iz_max_rel_error"] = float(e.max()) if e.size else 0.0

    rects = []
    page_mask = np.zeros((H, W), bool)
    page_charts = np.full((H, W), -1, np.int64)
    base = 0
    for it, p in on_page:
        w, h = it.resolution
        mask = np.zeros((h, w), bool)
        mask[it.xy[:, 1], it.xy[:, 0]] = True
        page_mask[p.y : p.y + h, p.x : p.x + w] = mask
        ch = np.zeros(len(it.xy), np.int64) if it.charts is None else it.charts.astype(np.int64)
        cimg = np.full((h, w), -1, np.int64)
        cimg[it.xy[:, 1], it.xy[:, 0]] = ch + base
        page_charts[p.y : p.y + h, p.x : p.x + w] = cimg
        base += int(ch.max()) + 1 if len(ch) else 1
        rects.append((mask, packer.territory(p, size, pad)))

    container = s0.get("container")
    textures, digests, ktx = {}, {}, {}
    stem = f"page{index}"
    for lay in mod.layout(ratio):
        values = np.asarray(channels[lay.role])
        values = values.reshape(int(starts[-1]), -1)
        page = np.zeros((H, W, values.shape[1]), values.dtype)
        for i, ((it, p), (mask, terr)) in enumerate(zip(on_page, rects)):
            w, h = it.resolution
            img = np.zeros((h, w, values.shape[1]), values.dtype)
            img[it.xy[:, 1], it.xy[:, 0]] = values[starts[i] : starts[i + 1]]
            img = post.dilate(img, mask, int(it.settings.get("padding", 4)))
            img = img.astype(values.dtype, copy=False)
            x0, y0, x1, y1 = terr
            grown = np.pad(
                img, ((p.y - y0, y1 - p.y - h), (p.x - x0, x1 - p.x - w), (0, 0)), mode="edge"
            )
            page[y0:y1, x0:x1] = grown
        path, digests[lay.role] = write_role_texture(out, stem, lay, page, factors)
        textures[lay.role] = path
        path = Path(path)
        if container in ("ktx2", "ktx2-bc"):
            from usdahd import ktx2

            kv = {"usdahd:packing": lay.packing, "usdahd:role": lay.role}
            kv.update({f"usdahd:{k}": repr(float(v)) for k, v in factors.items()})
            comp = "bc" if container == "ktx2-bc" else "none"
            info = ktx2.write(
                path.with_suffix(".ktx2"),
                page,
                page_mask,
                page_charts,
                lay.format,
                compression=comp,
                attributes=kv,
            )
            ktx[lay.role] = {"path": str(path.with_suffix(".ktx2")), **info}
    side = np.zeros((H, W, 28), np.float32)
    for it, p in on_page:
        side[p.y + it.xy[:, 1], p.x + it.xy[:, 0], :27] = it.sh.reshape(-1, 27)
        side[p.y + it.xy[:, 1], p.x + it.xy[:, 0], 27] = 1.0
    side_path = texture_path(out, stem, schema.SIDECAR_ROLE, ".exr")
    images.write(
        side_path, side, format="float", color_space="raw", channels=schema.SH_SIDECAR_CHANNELS
    )
    textures[schema.SIDECAR_ROLE] = str(side_path)
    digests[schema.SIDECAR_ROLE] = schema.file_digest(side_path)

    fac = {k: float(v) for k, v in factors.items()}
    covered = 0
    for it, p in on_page:
        so = packer.scale_offset(p, size)
        covered += len(it.xy)
        common = dict(
            textures=dict(textures),
            factors=dict(fac),
            digests=dict(digests),
            page=index,
            scale_offset=so,
            atlas=True,
        )
        if it.old is not None:  # re-authored: same record, new page files
            it.job.results = dataclasses.replace(it.old, **common)
            it.job.report["repacked"] = True
            continue
        job = it.job
        job.results = schema.BakeResults(
            model=model,
            ratio=ratio,
            solver=solver,
            uv_primvar=it.settings["uv"],
            resolution=it.resolution,
            content_hash=job.content_hash,
            part_hashes=job.parts,
            settings=it.settings,
            generator=f"usdahd {__version__}",
            **common,
        )
        if ktx:
            job.report["ktx2"] = {r: dict(v) for r, v in ktx.items()}
        job.report["status"] = "baked"
        job.report["page"] = index
        job.report["seconds"] = job.report.get("trace_seconds", 0.0)
    return {
        "page": index,
        "size": [W, H],
        "records": [it.job.path for it, _ in on_page],
        "covered_texels": int(covered),
        "fill": covered / float(W * H),
        "rect_fill": sum(it.resolution[0] * it.resolution[1] for it, _ in on_page) / (W * H),
        "model": model,
        "ratio": ratio,
        "files": dict(textures),
        **({"ktx2": ktx} if ktx else {}),
    }
