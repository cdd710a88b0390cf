"""Reading a bake: lightmap textures through Ar + OpenImageIO (:func:`read_image`) and the decoded
record (:func:`load_bake`).
"""

from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from usdahd import models, sidecar
from usdahd.usd import schema
from usdahd.validate.findings import RuleFindings, SkipRule
from usdahd.validate.options import DZ_FLOOR, FORMAT_DTYPES

__all__ = [
    "Bake",
    "Image",
    "LOCK",
    "baked_record",
    "clear_caches",
    "decode_factors",
    "file_digest",
    "image_info",
    "load_bake",
    "load_for",
    "read_image",
    "record_encoder",
    "record_image",
]

# ------------------------------------------------------------------------------ image reading


@dataclass
class Image:
    """A texture read through OpenImageIO. data : (h, w, c) in the file's native dtype."""

    path: str
    data: np.ndarray
    format: str  # OIIO format name (half, float, uint8, int8, ...)
    channel_names: tuple[str, ...]
    color_space: str

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    def channels(self, names) -> np.ndarray:
        """(h, w, len(names)) channels looked up by name (EXR stores them sorted)."""
        idx = []
        for n in names:
            if n not in self.channel_names:
                raise KeyError(n)
            idx.append(self.channel_names.index(n))
        return self.data[..., idx]


_IMAGE_CACHE: OrderedDict = OrderedDict()
_IMAGE_CACHE_SIZE = 16
#: The cache also keeps at most this many bytes of pixels (the rules of one prim read its
#: textures several times; a 1024^2 SH sidecar alone is 117 MB, so 16 of them were 1.9 GB).
_IMAGE_CACHE_BYTES = 192 << 20
LOCK = threading.Lock()


def read_image(path: str, cache: bool = True) -> Image:
    """Read a whole image in its native format (cached by path, size and mtime; with
    ``cache=False`` a cached copy is used but a fresh read is not kept).

    Raises OSError with OpenImageIO's message when the file cannot be opened.
    """
    from usdahd.usd import assets

    key = assets.stamp(path)
    if key is None:
        if not assets.exists(path):
            raise FileNotFoundError(f"{path} does not exist")
    with LOCK:
        if key is not None and key in _IMAGE_CACHE:
            _IMAGE_CACHE.move_to_end(key)
            return _IMAGE_CACHE[key]
    with _single_flight(("image", key)):  # UsdValidation runs rules in parallel threads
        with LOCK:
            if key is not None and key in _IMAGE_CACHE:
                return _IMAGE_CACHE[key]
        with assets.local_file(path) as local:  # a file, or an asset in a package (Ar)
            img = _read_local(local, path)
        if cache:
            _cache_image(key, img)
    return img


def _cache_image(key, img) -> None:
    if key is not None:
        with LOCK:
            _IMAGE_CACHE[key] = img
            while len(_IMAGE_CACHE) > 1 and (
                len(_IMAGE_CACHE) > _IMAGE_CACHE_SIZE
                or sum(i.data.nbytes for i in _IMAGE_CACHE.values()) > _IMAGE_CACHE_BYTES
            ):
                _IMAGE_CACHE.popitem(last=False)


_FLIGHTS: dict = {}


@contextlib.contextmanager
def _single_flight(key):
    """One thread at a time reads or decodes ``key``; the others wait and then find it in the
    cache. UsdValidation runs the rules of a prim in parallel threads, and each of them loaded
    the same bake at once (a 1024^2 bake twice in memory: the classroom's peak)."""
    if key is None or (isinstance(key, tuple) and key[-1] is None):
        yield
        return
    with LOCK:
        entry = _FLIGHTS.setdefault(key, [threading.Lock(), 0])
        entry[1] += 1
    try:
        with entry[0]:
            yield
    finally:
        with LOCK:
            entry[1] -= 1
            if entry[1] == 0:
                _FLIGHTS.pop(key, None)


def _read_local(local: str, path: str) -> Image:
    from usdahd import images

    data, fmt, names, color_space = images.read_native(local, path)
    return Image(path=path, data=data, format=fmt, channel_names=names, color_space=color_space)


def record_image(results: schema.BakeResults, img: Image) -> Image:
    """A record's region of a (cached, whole) page image (:func:`usdahd.usd.schema.crop_record`,
    the one place that knows the atlas layout); the image itself without an atlas."""
    if not results.atlas:
        return img
    data = schema.crop_record(results, img.data, img.path)
    return Image(img.path, data, img.format, img.channel_names, img.color_space)


# ---------------------------------------------------------------------------- bake loading


@dataclass
class Bake:
    """A prim's bake, decoded once for the texel rules.

    results : the schema record; mod : model module; layout : role -> TextureLayout;
    xy : (n, 2) int32 texel column/row of the texels considered (covered ones, or every texel
    without a sidecar); channels : role -> (n, c) stored values in the layout's dtype;
    params : decoded model parameters for those texels; sh : (n, 3, 9) sidecar SH as stored
    (float32; rules widen the texels they use to float64) or None; valid : (n,) bool texels
    whose decoded values pass TexelValues.
    """

    results: schema.BakeResults
    mod: object
    layout: dict
    resolution: tuple[int, int]
    xy: np.ndarray
    channels: dict
    params: dict
    sh: np.ndarray | None
    factors: dict
    valid: np.ndarray


def decode_factors(results: schema.BakeResults) -> dict:
    """Factors for a model's ``decode``: every schema factor (authored value or fallback)."""
    return {name: results.factor(name) for name in schema.FACTORS}


_BAKE_CACHE: OrderedDict = OrderedDict()
#: Decoded bakes kept: UsdValidation runs a prim's rules one after another, so the current and
#: the previous prim suffice (a decoded 1024^2 bake is ~0.3 GB: float64 SH, channels, params).
_BAKE_CACHE_SIZE = 1


def _bake_key(prim, results) -> tuple:
    stamps = []
    from usdahd.usd import assets

    for role, path in sorted(results.textures.items()):
        stamps.append((role, path, assets.stamp(path)))
    rec = (results.model, results.ratio, results.resolution, tuple(sorted(results.factors.items())))
    return (str(prim.GetPath()), rec, tuple(stamps))


def baked_record(prim):
    """The prim's bake record (schema.BakeResults), or None when it has none or it cannot be
    read (SchemaValues reports that; the other rules have nothing to check)."""
    try:
        return schema.read_results(prim, validate=False)
    except Exception:
        return None


def load_bake(prim) -> Bake:
    """Read and decode a prim's textures; raises SkipRule when another rule reports the cause."""
    try:
        results = schema.read_results(prim, validate=False)
    except Exception as exc:
        raise SkipRule(f"bake record unreadable ({exc}); see SchemaValues") from None
    if results is None:
        raise SkipRule("the prim is not baked; see SchemaValues")
    if schema.result_problems(results):
        raise SkipRule("invalid bake record; see SchemaValues")
    key = _bake_key(prim, results)
    with LOCK:
        if key in _BAKE_CACHE:
            _BAKE_CACHE.move_to_end(key)
            return _BAKE_CACHE[key]
    with _single_flight(("bake", key)):
        with LOCK:
            if key in _BAKE_CACHE:
                return _BAKE_CACHE[key]
        bake = _load_bake(results)
        with LOCK:
            _BAKE_CACHE[key] = bake
            while len(_BAKE_CACHE) > _BAKE_CACHE_SIZE:
                _BAKE_CACHE.popitem(last=False)
    return bake


def load_for(r: RuleFindings, prim, *, sidecar: str | None = None) -> Bake | None:
    """The prim's bake for rule ``r``, or None after the finding "<rule> did not run: why"
    (:func:`load_bake` raised SkipRule; with ``sidecar``, also when the SH sidecar is unreadable,
    ``sidecar`` completing "no readable SH sidecar")."""
    try:
        bake = load_bake(prim)
    except SkipRule as why:
        r.skipped(why)
        return None
    if sidecar is not None and bake.sh is None:
        r.skipped("no readable SH sidecar" + sidecar)
        return None
    return bake


def record_region(results, size) -> tuple[int, int, int, int] | None:
    """(x0, y0, w, h) of a record's texels in a texture of ``size`` (W, H): the whole file
    without an atlas, the record's rectangle of its atlas page (``schema.record_rect``) with
    one; None when the file cannot hold them (Textures reports it)."""
    W, H = (int(v) for v in size)
    w, h = (int(v) for v in results.resolution)
    if getattr(results, "atlas", False):  # issue 39's atlas records
        if schema.rect_problem(results, (W, H)) is not None:
            return None
        return tuple(int(v) for v in schema.record_rect(results, (W, H)))
    return (0, 0, w, h) if (W, H) == (w, h) else None


@dataclass
class Sidecar:
    """An SH sidecar file kept sparse: rows (H, W) int32, the row of each covered texel
    (alpha > 0.5) in sh, -1 elsewhere; sh (m, 3, 9) float32 as stored. An atlas page's
    sidecar is read once for all its records: only its covered texels stay in memory
    (a 1024^2 page at 21% fill: 28 MB instead of 117 MB)."""

    rows: np.ndarray
    sh: np.ndarray

    @property
    def width(self) -> int:
        return int(self.rows.shape[1])

    @property
    def height(self) -> int:
        return int(self.rows.shape[0])

    @property
    def nbytes(self) -> int:
        return int(self.rows.nbytes + self.sh.nbytes)


_SIDECARS: OrderedDict = OrderedDict()
#: Sparse sidecars kept (bytes): every page of a classroom-sized atlas bake.
_SIDECAR_BYTES = 256 << 20


def read_sidecar(path: str) -> Sidecar:
    """The SH sidecar at ``path``, sparse (cached by path, size and mtime; read once per
    file). Raises OSError (unreadable), ValueError (a channel of sidecar.CHANNELS missing)."""
    from usdahd.usd import assets

    key = assets.stamp(path)
    with LOCK:
        if key is not None and key in _SIDECARS:
            _SIDECARS.move_to_end(key)
            return _SIDECARS[key]
    with _single_flight(("sidecar", key)):
        with LOCK:
            if key is not None and key in _SIDECARS:
                return _SIDECARS[key]
        img = read_image(path)  # cached: Textures (image_info) reads the same file
        names = sidecar.CHANNELS
        idx = [img.channel_names.index(n) for n in names]  # ValueError: Textures reports it
        ys, xs = np.nonzero(img.data[..., idx[sidecar.COVERAGE]] > 0.5)
        rows = np.full((img.height, img.width), -1, np.int32)
        rows[ys, xs] = np.arange(len(ys), dtype=np.int32)
        sh = _gather(img.data, ys, xs, idx[: sidecar.COVERAGE]).astype(np.float32, copy=False)
        side = Sidecar(rows, sh.reshape(-1, 3, 9))
        info = ImageInfo(img.width, img.height, img.channel_names, img.format, img.color_space)
        del img
        if key is not None:
            with LOCK:
                # Textures needs only the file's metadata now, and the pixels are in ``side``:
                # the whole image (117 MB for a 1024^2 page) leaves the image cache
                _INFOS[key] = info
                _IMAGE_CACHE.pop(key, None)
                _SIDECARS[key] = side
                while len(_SIDECARS) > 1 and (
                    sum(v.nbytes for v in _SIDECARS.values()) > _SIDECAR_BYTES
                ):
                    _SIDECARS.popitem(last=False)
    return side


@dataclass(frozen=True)
class ImageInfo:
    """What the Textures rule checks of a file that decodes: size, channels, format, colour
    space (no pixels)."""

    width: int
    height: int
    channel_names: tuple
    format: str
    color_space: str


_INFOS: OrderedDict = OrderedDict()


def image_info(path: str) -> ImageInfo:
    """The ImageInfo of a texture that OpenImageIO opens and decodes whole (cached by path,
    size and mtime, so an atlas page shared by many records is decoded once, not per record).
    Raises OSError like :func:`read_image`."""
    from usdahd.usd import assets

    key = assets.stamp(path)
    with LOCK:
        if key is not None and key in _INFOS:
            return _INFOS[key]
    img = read_image(path)
    info = ImageInfo(img.width, img.height, img.channel_names, img.format, img.color_space)
    if key is not None:
        with LOCK:
            _INFOS[key] = info
            while len(_INFOS) > 4096:
                _INFOS.popitem(last=False)
    return info


_DIGESTS: OrderedDict = OrderedDict()


def file_digest(path: str) -> str:
    """``schema.file_digest`` cached by path, size and mtime (an atlas page's files are
    hashed once, not once per record)."""
    from usdahd.usd import assets

    key = assets.stamp(path)
    with LOCK:
        if key is not None and key in _DIGESTS:
            return _DIGESTS[key]
    digest = schema.file_digest(path)
    if key is not None:
        with LOCK:
            _DIGESTS[key] = digest
            while len(_DIGESTS) > 4096:
                _DIGESTS.popitem(last=False)
    return digest


def clear_caches() -> None:
    """Forget every cached read (images, sparse sidecars, image metadata, digests, decoded
    bakes): for callers that rewrite files in place within a file system's mtime resolution."""
    with LOCK:
        for cache in (_IMAGE_CACHE, _SIDECARS, _INFOS, _DIGESTS, _BAKE_CACHE):
            cache.clear()


def _gather(data: np.ndarray, ys: np.ndarray, xs: np.ndarray, channels) -> np.ndarray:
    """(n, len(channels)) values of ``data`` (h, w, c) at texels (xs, ys), channels by index,
    in one gather (no copy of the whole image's channels first; ``data`` may be a view, e.g.
    a record's crop of an atlas page)."""
    ch = np.asarray(channels, np.intp)[None, :]
    return data[np.asarray(ys, np.intp)[:, None], np.asarray(xs, np.intp)[:, None], ch]


def _load_bake(results) -> Bake:
    try:
        mod = models.get(results.model)
        layout = {t.role: t for t in mod.layout(results.ratio)}
    except Exception as exc:
        raise SkipRule(f"model settings unusable ({exc}); see SchemaValues") from None
    w, h = results.resolution
    images, origin = {}, {}
    for role, lay in layout.items():
        path = results.textures.get(role)
        if path is None or "<UDIM>" in results.asset_paths.get(role, ""):
            raise SkipRule(f"texture {role!r} missing or a UDIM set; see Textures")
        try:
            img = read_image(path)
        except OSError:
            raise SkipRule(f"texture {role!r} unreadable; see Textures") from None
        region = record_region(results, (img.width, img.height))
        if region is None or set(img.channel_names) != set(lay.channels):
            raise SkipRule(f"texture {role!r} has the wrong shape or channels; see Textures")
        images[role], origin[role] = img, region[:2]
    sh = None
    sc = results.textures.get(schema.SIDECAR_ROLE)
    if sc is not None:
        try:
            side = read_sidecar(sc)
            region = record_region(results, (side.width, side.height))
            if region is not None:
                x0, y0 = region[:2]
                rows = side.rows[y0 : y0 + h, x0 : x0 + w]
                ys, xs = np.nonzero(rows >= 0)
                # the covered texels' SH as stored (float32 holds a float16 or float32
                # sidecar exactly; the rules widen the texels they use to float64): a view
                # of the sidecar's when they are its rows a..b in order (a whole file)
                r = rows[ys, xs]
                if len(r) and int(r[-1]) - int(r[0]) == len(r) - 1 and (np.diff(r) == 1).all():
                    sh = side.sh[int(r[0]) : int(r[-1]) + 1]
                else:
                    sh = side.sh[r]
        except (OSError, KeyError, ValueError):
            sh = None  # Textures reports it
    if sh is None:
        ys, xs = np.mgrid[0:h, 0:w]
        xy = np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(np.int32)
    else:
        xy = np.stack([xs, ys], axis=-1).astype(np.int32)
    # Channels by name, in the layout's order (EXR stores them sorted, so never by position).
    channels = {
        role: _gather(
            images[role].data,
            xy[:, 1] + origin[role][1],
            xy[:, 0] + origin[role][0],
            [images[role].channel_names.index(c) for c in lay.channels],
        ).astype(FORMAT_DTYPES[lay.format], copy=False)
        for role, lay in layout.items()
    }
    factors = decode_factors(results)
    try:
        with np.errstate(all="ignore"):
            params = mod.decode(channels, ratio=results.ratio, factors=factors)
    except Exception as exc:
        raise SkipRule(f"the textures do not decode ({exc}); see Textures") from None
    params = {k: np.asarray(v) for k, v in params.items()}
    valid = np.ones(len(xy), bool)
    for k, v in params.items():
        if k != "invalid" and v.dtype.kind == "f":
            valid &= np.isfinite(v.reshape(len(xy), -1)).all(axis=1)
    if "direction" in params:
        valid &= params["direction"][:, 2] >= DZ_FLOOR
    return Bake(results, mod, layout, (w, h), xy, channels, params, sh, factors, valid)


# ------------------------------------------------------------------ encoding in a page's context

_ANCHORS: OrderedDict = OrderedDict()


def _page_anchors(results: schema.BakeResults, mod) -> dict | None:
    """The fitted params of a few texels of the record's atlas page: for every parameter, the
    texel with the largest magnitude over the whole page (from the page's SH sidecar, fitted as
    the bake fitted it). A model's decode factors are set by such maxima, so encoding a record's
    params together with these rows gives the page's factors, hence the page's codes. Cached per
    page file; None when the sidecar is unreadable."""
    from usdahd.usd import assets

    side = results.textures.get(schema.SIDECAR_ROLE)
    if side is None:
        return None
    key = (side, assets.stamp(side), results.model, results.ratio, results.solver)
    with LOCK:
        if key in _ANCHORS:
            return _ANCHORS[key]
    with _single_flight(("anchors", key)):
        with LOCK:
            if key in _ANCHORS:
                return _ANCHORS[key]
        try:
            sh = read_sidecar(side).sh  # the page's covered texels, float32, read once
        except (OSError, KeyError, ValueError):
            return None
        from usdahd.validate.irradiance import fit_chunked

        fitted = fit_chunked(results, sh)  # per texel, chunked: no float64 copy of the page
        rows = set()
        for v in fitted.params.values():
            a = np.abs(np.asarray(v, np.float64).reshape(len(sh), -1))
            if a.size:
                rows.add(int(np.argmax(np.where(np.isfinite(a), a, -1.0).max(axis=1))))
        rows = sorted(rows)
        anchors = {k: np.asarray(v)[rows] for k, v in fitted.params.items()}
        with LOCK:
            _ANCHORS[key] = anchors
            while len(_ANCHORS) > 4:
                _ANCHORS.popitem(last=False)
    return anchors


def record_encoder(bake: Bake):
    """``encode(params) -> channels | None``: a record's params quantized as its bake quantized
    them. Without an atlas: the model's encode. In an atlas page the factors are the page's
    (one encode per page): the record's params are encoded together with the page's anchor
    texels (:func:`_page_anchors`) and kept only when the factors come out as the record's
    (``None`` otherwise: the codes cannot be re-derived)."""
    res = bake.results
    if not res.atlas:
        return lambda params: bake.mod.encode(params, ratio=res.ratio)[0]
    anchors = _page_anchors(res, bake.mod)

    def encode(params):
        if anchors is None:
            return None
        n = len(next(iter(params.values())))
        both = {k: np.concatenate([np.asarray(v), anchors[k]]) for k, v in params.items()}
        channels, factors = bake.mod.encode(both, ratio=res.ratio)
        if any(abs(float(v) - res.factor(k)) > 0 for k, v in factors.items()):
            return None
        return {r: np.asarray(c)[:n] for r, c in channels.items()}

    return encode
