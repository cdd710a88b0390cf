"""Texture files through OpenImageIO: the only module that reads or writes images.

Formats (chosen from the array dtype, see ``FORMAT_DTYPES``):

========  ==========  ===============================  ====================================
format    dtype       files                            use
========  ==========  ===============================  ====================================
half      float16     .exr (zip compression)           HDR irradiance, SH coefficients
float     float32     .exr (zip), .tif                 debug / sidecar images
unorm8    uint8       .png, .tif                       every 8-bit lightmap texture
snorm8    int8        .tif (SampleFormat = signed)     not used by lightmaps (not usdz-legal)
========  ==========  ===============================  ====================================

Pixels are ``(height, width, channels)`` numpy arrays, row 0 = top of the image (the
``usdahd.bake.types`` convention). Values are stored bit-exactly: no colour conversion, no
alpha (un)premultiplication, no dithering.

Colour space: written as ``oiio:ColorSpace`` (EXR ``colorInteropID``; for PNG an sRGB chunk
when it is sRGB, else a gAMA chunk of 1.0, i.e. linear/raw data) and, because PNG and TIFF
keep no "raw" tag for data textures, also as the
``usdahd:ColorSpace`` attribute and in ``ImageDescription`` (``usdahd {"colorSpace": "raw",
"channels": [...], "attributes": {...}}``, JSON, which also carries channel names and extra
attributes through TIFF/PNG); :func:`read` takes the first of these it finds. Names are
Gf.ColorSpaceNames tokens (``lin_rec709_scene``, ``srgb_rec709_scene``, ``raw``, ...).

Writes are atomic (temp file + rename, :func:`usdahd.io_util.atomic_path`).

Material and DomeLight textures are read by :func:`read_texels` (float32, as OpenImageIO
converts them) and colour-converted by :func:`convert_color`; the USD rules (asset resolver,
``sourceColorSpace``) around them are :func:`usdahd.usd.materials.read_image`.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from usdahd.errors import ImageError, UsageError
from usdahd.io_util import atomic_path

__all__ = ["convert_color", "convert_color_8bit", "read", "read_native", "read_texels", "write"]

FORMAT_DTYPES = {
    "half": np.float16,
    "float": np.float32,
    "unorm8": np.uint8,
    "snorm8": np.int8,
}
_OIIO_TYPES = {"half": "half", "float": "float", "unorm8": "uint8", "snorm8": "int8"}
#: Which formats each file extension can hold bit-exactly.
EXTENSION_FORMATS = {
    ".exr": ("half", "float"),
    ".png": ("unorm8",),
    ".tif": ("unorm8", "snorm8", "half", "float"),
    ".tiff": ("unorm8", "snorm8", "half", "float"),
}
DEFAULT_COMPRESSION = {".exr": "zip", ".tif": "zip", ".tiff": "zip", ".png": None}
_DESCRIPTION_PREFIX = "usdahd"


@dataclass
class Image:
    """A decoded image. pixels : (h, w, c) in the stored dtype (see FORMAT_DTYPES)."""

    pixels: np.ndarray
    channels: tuple[str, ...]
    color_space: str | None
    format: str
    attributes: dict = field(default_factory=dict)

    def channel(self, name: str) -> np.ndarray:
        """One channel (h, w) by name."""
        try:
            return self.pixels[..., self.channels.index(name)]
        except ValueError:
            raise ImageError(f"image has no channel {name!r}; it has {self.channels}") from None


def _oiio():
    import OpenImageIO as oiio

    return oiio


def format_of(pixels: np.ndarray) -> str:
    """The format name of an array's dtype (ImageError if it is not one we store)."""
    for name, dt in FORMAT_DTYPES.items():
        if pixels.dtype == dt:
            return name
    raise ImageError(
        f"cannot store {pixels.dtype} pixels; use one of float16 (half), float32, uint8, int8"
    )


def default_channels(n: int) -> tuple[str, ...]:
    return {1: ("Y",), 2: ("X", "Y"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}.get(
        n, tuple(f"c{i}" for i in range(n))
    )


def write(
    path: str | os.PathLike,
    pixels: np.ndarray,
    *,
    color_space: str,
    channels: tuple[str, ...] | list[str] | None = None,
    format: str | None = None,
    compression: str | None = None,
    attributes: dict | None = None,
) -> None:
    """Write ``pixels`` (h, w, c) or (h, w) atomically to ``path``.

    format : one of FORMAT_DTYPES; default from the dtype. If given and the dtype differs, float
        arrays are cast to half/float; integer formats must already be quantized (ImageError).
    color_space : Gf.ColorSpaceNames token stored with the file (see module doc).
    channels : channel names (default R,G,B[,A] / X,Y / Y / c0..).
    compression : EXR/TIFF compression (default "zip": lossless).
    attributes : extra metadata (str/int/float values), e.g. decode factors.
    """
    oiio = _oiio()
    path = os.fspath(path)
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3 or min(pixels.shape) < 1:
        raise ImageError(f"{path}: pixels must be (height, width, channels), got {pixels.shape}")
    if format is None:
        format = format_of(pixels)
    if format not in FORMAT_DTYPES:
        raise UsageError(f"unknown image format {format!r}; use one of {tuple(FORMAT_DTYPES)}")
    want = np.dtype(FORMAT_DTYPES[format])
    if pixels.dtype != want:
        if format in ("half", "float") and np.issubdtype(pixels.dtype, np.floating):
            pixels = pixels.astype(want)
        else:
            raise ImageError(
                f"{path}: format {format} needs {want} pixels (quantize first), got {pixels.dtype}"
            )
    if format in ("half", "float") and not np.isfinite(pixels).all():
        raise ImageError(f"{path}: pixels contain NaN or infinity (or overflow float16)")
    ext = os.path.splitext(path)[1].lower()
    if ext not in EXTENSION_FORMATS:
        raise ImageError(f"{path}: unsupported extension {ext!r}; use .exr, .png or .tif")
    if format not in EXTENSION_FORMATS[ext]:
        raise ImageError(
            f"{path}: {ext} files cannot hold {format} data; use one of "
            f"{[e for e, f in EXTENSION_FORMATS.items() if format in f]}"
        )
    h, w, c = pixels.shape
    channels = tuple(channels) if channels is not None else default_channels(c)
    if len(channels) != c:
        raise ImageError(f"{path}: {c} channels but {len(channels)} channel names")

    spec = oiio.ImageSpec(w, h, c, _OIIO_TYPES[format])
    spec.channelnames = channels
    spec.alpha_channel = -1
    spec.attribute("oiio:ColorSpace", color_space)
    spec.attribute("usdahd:ColorSpace", color_space)
    if ext == ".png" and "srgb" not in color_space.lower():
        # PNG's only way to say "not sRGB": a gAMA chunk of 1.0 (OpenImageIO, browsers and
        # engine importers then take the values as linear data instead of sRGB).
        spec.attribute("oiio:Gamma", 1.0)
    extra = dict(attributes or {})
    desc = {"colorSpace": color_space, "channels": list(channels), "attributes": extra}
    spec.attribute("ImageDescription", f"{_DESCRIPTION_PREFIX} {json.dumps(desc)}")
    spec.attribute("oiio:UnassociatedAlpha", 1)  # never premultiply data channels
    spec.attribute("Software", "usdahd")
    # Byte-reproducible files (same pixels, same bytes, same content-addressed name): no write
    # time unless SOURCE_DATE_EPOCH asks for one (the reproducible-builds convention). An empty
    # DateTime stops OpenImageIO's EXR writer from stamping the current time.
    spec.attribute("DateTime", _source_date())
    comp = compression if compression is not None else DEFAULT_COMPRESSION[ext]
    if comp:
        spec.attribute("compression", comp)
    for key, value in extra.items():
        spec.attribute(key, value)

    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise ImageError(f"{path}: OpenImageIO cannot write {ext} files: {oiio.geterror()}")
        errors = []
        try:
            if not out.open(str(tmp), spec):
                raise ImageError(
                    f"{path}: cannot open for writing: {_first_line(out.geterror())}; "
                    + _write_fix(path)
                )
            if not out.write_image(np.ascontiguousarray(pixels)):
                errors.append(out.geterror() or "write_image failed")
            elif out.has_error:  # libpng's writer reports a short write only here
                errors.append(out.geterror())
        finally:
            # close() writes the last blocks (the PNG's end, a TIFF's directory): its result
            # and any error it leaves are the write's too (issue 40).
            if not out.close():
                errors.append("close failed")
            if out.has_error:
                errors.append(out.geterror())
        # OpenImageIO's TIFF writer always reports this when DateTime is empty (as written
        # here, for reproducible files); the image directory itself is written.
        benign = "TIFFWriteCustomDirectory() of the Exif data"
        errors = [e for e in errors if e and e.strip() and e.strip() != f"failed {benign}"]
        if not errors and _disk_full(str(tmp)):
            # OpenImageIO does not report a failed final flush (fclose): a file that ran into
            # a full disk on its last block looks written. No block left = maybe cut short.
            errors.append("no space left on the disk after writing it")
        if errors:
            raise ImageError(
                f"{path}: could not write the image ({_first_line(errors[0])}); " + _write_fix(path)
            )


def _disk_full(path: str) -> bool:
    """No whole block is left on the file system holding ``path`` (for this user)."""
    try:
        st = os.statvfs(os.path.dirname(os.path.abspath(path)))
    except OSError:
        return False
    avail = st.f_bfree if os.geteuid() == 0 else st.f_bavail
    return st.f_blocks > 0 and avail * st.f_frsize < max(st.f_bsize, st.f_frsize)


def _first_line(text: str) -> str:
    lines = (text or "").strip().splitlines()
    return lines[0][:200] if lines else "unknown error"


def _write_fix(path: str) -> str:
    """What to do when ``path`` could not be written: names a full disk when it is one."""
    import shutil

    folder = os.path.dirname(os.path.abspath(path))
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        free = None
    if free is not None and free < 4 * 2**20:
        return f"the disk is full ({free // 1024} KiB free in {folder}): free space and re-run"
    if not os.access(folder, os.W_OK):
        return f"{folder} is not writable: fix its permissions or write elsewhere"
    return "check free space and permissions of the folder and re-run"


def _check_size(path: str, spec, itemsize: int, error: type = ImageError) -> None:
    """``error`` when the pixels the header declares exceed the memory budget
    (:mod:`usdahd.budget`), before they are decoded."""
    from usdahd import budget

    size = int(spec.width) * int(spec.height) * max(1, int(spec.depth)) * int(spec.nchannels)
    budget.check(
        size * itemsize,
        f"{path}: the image ({spec.width} x {spec.height} pixels, {spec.nchannels} channels) "
        "decodes to",
        "resize the image or raise the budget",
        error=error,
    )


def _source_date() -> str:
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not epoch.isdigit():
        return ""
    return time.strftime("%Y:%m:%d %H:%M:%S", time.gmtime(int(epoch)))


def _parse_description(text: str) -> dict:
    if not isinstance(text, str) or not text.startswith(_DESCRIPTION_PREFIX + " "):
        return {}
    try:
        out = json.loads(text[len(_DESCRIPTION_PREFIX) + 1 :])
    except ValueError:
        return {}
    return out if isinstance(out, dict) else {}


def read(path: str | os.PathLike, *, channels: tuple[str, ...] | list[str] | None = None) -> Image:
    """Read an image as stored (half, float, uint8 or int8 pixels (h, w, c)).

    channels : names to return, in this order (ImageError if one is missing). Files written by
    :func:`write` give back their channel names and colour space; other files report
    OpenImageIO's (``color_space`` None if unknown). Other pixel types (uint16, ...) are
    returned as float32.
    """
    oiio = _oiio()
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ImageError(f"{path}: no such image file")
    if not os.path.isfile(path):  # a FIFO would block, a directory has no reader
        raise ImageError(f"{path}: not a regular file (a directory, FIFO or device)")
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(path, config)
    if inp is None:
        raise ImageError(f"{path}: cannot read image: {oiio.geterror()}")
    try:
        spec = inp.spec()
        base = str(spec.format)
        fmt = {v: k for k, v in _OIIO_TYPES.items()}.get(base)
        if fmt is None:
            fmt = "float"
        _check_size(path, spec, np.dtype(FORMAT_DTYPES[fmt]).itemsize)
        pixels = inp.read_image(0, 0, 0, spec.nchannels, _OIIO_TYPES[fmt])
        if pixels is None:
            raise ImageError(f"{path}: cannot decode pixels: {inp.geterror()}")
    finally:
        inp.close()
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    attrs = {p.name: p.value for p in spec.extra_attribs}
    desc = _parse_description(attrs.get("ImageDescription", ""))
    color_space = attrs.get("usdahd:ColorSpace") or desc.get("colorSpace")
    if not color_space:
        color_space = attrs.get("oiio:ColorSpace") or None
    for key, value in (desc.get("attributes") or {}).items():
        attrs.setdefault(key, value)
    names = tuple(spec.channelnames)
    stored = desc.get("channels")
    # EXR keeps channel names but stores them sorted (OpenImageIO reads them in file order), so
    # its own names are the truth; PNG/TIFF lose the names, so take those written in the
    # description, which are in the order the pixels were written.
    if isinstance(stored, list) and len(stored) == len(names) and set(stored) != set(names):
        names = tuple(str(c) for c in stored)
    image = Image(pixels, names, color_space, fmt, attrs)
    if channels is not None:
        missing = [c for c in channels if c not in names]
        if missing:
            raise ImageError(f"{path}: missing channels {missing}; the file has {names}")
        idx = [names.index(c) for c in channels]
        image = Image(pixels[..., idx], tuple(channels), color_space, fmt, attrs)
    return image


def read_native(path: str | os.PathLike, label: str | None = None):
    """Read a whole image exactly as an engine's loader sees it (the validator's view).

    Unlike :func:`read`, nothing is reinterpreted: pixels in the file's own format (OpenImageIO
    ``UNKNOWN``), the file's channel names and OpenImageIO's colour-space tag, not the ones our
    writer records in the description. PNG alpha stays unassociated (it is data).
    path : a local file; label : the name used in messages (e.g. the asset path).
    returns : (data (h, w, c) native dtype, format name as OpenImageIO spells it (half, float,
    uint8, int8, ...), channel names tuple, colour space str ("" if untagged)).
    Raises OSError with OpenImageIO's message when the file cannot be opened or decoded.
    """
    oiio = _oiio()
    label = label or os.fspath(path)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # PNG alpha is data: never premultiply
    inp = oiio.ImageInput.open(os.fspath(path), config)
    if inp is None:
        raise OSError(oiio.geterror() or f"OpenImageIO cannot open {label}")
    try:
        spec = inp.spec()
        _check_size(label, spec, max(1, spec.format.size()), error=OSError)
        data = _read_native_pixels(inp, spec, label)
        return (
            data,
            str(spec.format),
            tuple(spec.channelnames),
            spec.get_string_attribute("oiio:ColorSpace", ""),
        )
    finally:
        inp.close()


#: Scanline images above this many bytes are read in strips of STRIP_ROWS rows into one array:
#: a whole-image read holds OpenImageIO's own buffer beside the array (a 1024^2 28-channel
#: float sidecar: 259 MB peak for 112 MB of pixels; in strips 147 MB).
STRIP_BYTES = 16 << 20
STRIP_ROWS = 64


def _read_native_pixels(inp, spec, label: str) -> np.ndarray:
    """(h, w, c) pixels of an open ImageInput in the file's own format (OpenImageIO UNKNOWN)."""
    oiio = _oiio()
    h, w, c = spec.height, spec.width, spec.nchannels
    size = h * w * c * max(1, spec.format.size())
    if spec.tile_width or size <= STRIP_BYTES or h <= STRIP_ROWS:
        data = inp.read_image(0, 0, 0, c, oiio.UNKNOWN)
        if data is None:
            raise OSError(inp.geterror() or f"OpenImageIO cannot read the pixels of {label}")
        return np.asarray(data).reshape(h, w, c)
    out = None
    for y0 in range(spec.y, spec.y + h, STRIP_ROWS):
        y1 = min(y0 + STRIP_ROWS, spec.y + h)
        strip = inp.read_scanlines(0, 0, y0, y1, 0, 0, c, oiio.UNKNOWN)
        if strip is None:
            raise OSError(inp.geterror() or f"OpenImageIO cannot read the pixels of {label}")
        strip = np.asarray(strip).reshape(y1 - y0, w, c)
        if out is None:
            out = np.empty((h, w, c), strip.dtype)
        out[y0 - spec.y : y1 - spec.y] = strip
    return out


def read_texels(path: str | os.PathLike) -> tuple[np.ndarray | None, str]:
    """Pixels of a material or light texture as float32 (h, w, c), as OpenImageIO converts
    them (8-bit -> [0, 1]; no colour conversion; alpha unassociated: RGB is never multiplied
    by alpha), and the file's pixel format name (``uint8``,
    ``half``, ...). path : a local file (:func:`usdahd.usd.assets.local_file`).

    Returns (None, format) when the pixels cannot be decoded. Raises ImageError with
    OpenImageIO's message (first 200 characters) when the file cannot be opened; OSError
    passes through.
    """
    oiio = _oiio()
    config = oiio.ImageSpec()
    # straight colour, as the file stores it: OpenImageIO would otherwise multiply a PNG's RGB
    # by its alpha, darkening a cut-out's albedo at its edges and zeroing it where alpha is 0
    # (McUsd's fern: the albedo of its opaque texels 12 % low)
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(os.fspath(path), config)
    if inp is None:
        raise ImageError(oiio.geterror()[:200])
    try:
        spec = inp.spec()
        _check_size(os.fspath(path), spec, 4)
        data = inp.read_image(0, 0, 0, spec.nchannels, "float")
        fmt = str(spec.format)
    finally:
        inp.close()
    if data is None:
        return None, fmt
    return np.asarray(data, np.float32).reshape(spec.height, spec.width, spec.nchannels), fmt


def convert_color(data: np.ndarray, src: str, dst: str) -> np.ndarray:
    """The colour channels of (h, w, c) float32 texels converted from colour space ``src`` to
    ``dst`` with OpenImageIO's colour management (``ImageBufAlgo.colorconvert``, its built-in
    OCIO config); alpha and the second channel of grey+alpha stay. Returns a new array.
    Raises ImageError with OpenImageIO's message when it cannot convert (unknown name)."""
    oiio = _oiio()
    h, w, c = data.shape
    rgb = data[..., :3] if c >= 3 else np.repeat(data[..., :1], 3, axis=2)
    buf = oiio.ImageBuf(np.ascontiguousarray(rgb, np.float32))
    out = oiio.ImageBufAlgo.colorconvert(buf, src, dst)
    if out.has_error or not out.initialized:
        raise ImageError(out.geterror())
    conv = np.asarray(out.get_pixels(oiio.FLOAT), np.float32).reshape(h, w, 3)
    data = data.copy()
    if c >= 3:
        data[..., :3] = conv
    else:
        data[..., 0] = conv[..., 0]
    return data


_LUT8: dict[tuple[str, str], np.ndarray | None] = {}


def _lut8(src: str, dst: str) -> np.ndarray | None:
    """(256, 3) float32: OpenImageIO's conversion of every 8-bit code per channel, or None when
    the conversion mixes channels (a matrix, e.g. to another gamut), where a per-channel table
    would be wrong. Checked on ramps that vary one channel at a time."""
    key = (src, dst)
    if key not in _LUT8:
        v = np.arange(256, dtype=np.float32) / 255.0
        z = np.zeros_like(v)
        ramps = np.stack(
            [np.stack(c, axis=1) for c in ((v, v, v), (v, z, z), (z, v, z), (z, z, v))]
        )  # (4, 256, 3): one image row per ramp
        conv = convert_color(ramps, src, dst)
        lut = conv[0]
        zero = lut[0]
        ok = all(
            np.allclose(conv[1 + c][:, c], lut[:, c], rtol=1e-5, atol=1e-7)
            and np.allclose(np.delete(conv[1 + c], c, axis=1), np.delete(zero, c)[None, :])
            for c in range(3)
        )
        _LUT8[key] = lut if ok else None
    return _LUT8[key]


def convert_color_8bit(data: np.ndarray, src: str, dst: str) -> np.ndarray:
    """:func:`convert_color` of texels decoded from an 8-bit file ((h, w, c) float32 = code /
    255) by a table of OpenImageIO's result for each of the 256 codes: the same values, a
    gather instead of a per-pixel colour transform (a 2048^2 texture: ~1.6 s -> ~0.1 s).
    Falls back to :func:`convert_color` when the conversion mixes channels."""
    lut = _lut8(src, dst)
    if lut is None:
        return convert_color(data, src, dst)
    h, w, c = data.shape
    out = data.copy()
    n = 3 if c >= 3 else 1  # grey (+ alpha): the grey channel; alpha is data and stays
    codes = np.rint(data[..., :n] * 255.0).astype(np.uint8)
    for ch in range(n):
        out[..., ch] = lut[codes[..., ch], ch]
    return out
