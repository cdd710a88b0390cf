"""Textures of materials and lights: reading (Ar + OpenImageIO), colour spaces, sanitising,
UsdUVTexture channels, and the product of a diffuse and a metallic texture.

Split out of :mod:`usdahd.usd.materials` (which re-exports these names); no pxr here.
:func:`read_image` applies the colour space rule (:func:`source_color_space`:
``sourceColorSpace``, the file's ``colorSpace`` metadata, else Hydra's 8-bit rule) to the
working space :data:`LINEAR_SPACE`; docs/usd-semantics.md (Colour spaces).
"""

from __future__ import annotations

import numpy as np

from usdahd import images
from usdahd.errors import ImageError
from usdahd.scene.types import Material, Texture
from usdahd.usd import assets
from usdahd.usd.checks import asset_problem  # regular file, size limit (issue 18)
from usdahd.usd.stage import one_line

__all__ = [
    "LINEAR_SPACE",
    "albedo_times_metal",
    "outputs_on_grid",
    "read_image",
    "sanitize_image",
    "source_color_space",
    "texture_channels",
    "to_rgb",
]


def outputs_on_grid(tex: Texture, h: int, w: int) -> np.ndarray:
    """The UsdUVTexture output (``Texture.outputs``) of ``tex`` at the texel centres of an
    h x w grid over [0, 1]^2, (h, w, len(channels)) float32: the texels themselves when the
    texture is h x w, else its bilinear lookup (``Texture.sample``, its wrap modes)."""
    if tex.data.shape[:2] == (h, w):
        return tex.outputs()
    out = np.empty((h, w, len(tex.channels)), np.float32)
    u = (np.arange(w, dtype=np.float64) + 0.5) / w
    rows = max(1, (1 << 20) // w)
    for r0 in range(0, h, rows):
        r = np.arange(r0, min(h, r0 + rows), dtype=np.float64)
        v = 1.0 - (r + 0.5) / h
        uv = np.stack(np.broadcast_arrays(u[None, :], v[:, None]), axis=-1).reshape(-1, 2)
        out[r0 : r0 + len(r)] = tex.sample(uv).reshape(len(r), w, -1)
    return out


def albedo_times_metal(mat: Material, metal: Texture, warn) -> Texture:
    """The albedo texture of a material whose ``inputs:metallic`` is a texture: diffuse
    albedo = diffuseColor x (1 - metallic), on a common texel grid.

    mat : the material, with its diffuseColor constant (``albedo``) or texture
    (``albedo_tex``, reading the same texcoord as ``metal``: :meth:`MaterialReader
    ._metallic_texture`); metal : the metallic UsdUVTexture (one channel selected; its
    scale, bias, wrap modes and colour space already applied as for any texture).

    Returns a texture with scale 1, bias 0, rgb, whose texels are the product. The grid is
    the metallic texture's (constant diffuseColor), else per axis the larger of the two
    resolutions; each texture is evaluated at the grid's texel centres by its own bilinear
    lookup (its texels when it has the grid's resolution). What is exact and what is not:

    - constant diffuseColor: exact everywhere (c x (1 - m) is affine in m, and bilinear
      filtering commutes with it), apart from the clamp of metallic to [0, 1], applied per
      texel rather than after filtering (warned when a texel is outside).
    - diffuseColor texture: exact at the common grid's texel centres. Between them the
      kernel filters the product bilinearly where a renderer multiplies two filtered values;
      the difference is second order (zero where either texture is constant over the
      texel cell). A texture of lower resolution than the grid is resampled bilinearly.
    - wrap modes: the diffuse texture's; when the metallic texture's differ, outside
      [0, 1] metallic follows the diffuse texture's mode (warned).
    """
    name = mat.name
    d = mat.albedo_tex
    if d is None:
        h, w = metal.data.shape[:2]
        wrap = metal.wrap
    else:
        h = max(d.data.shape[0], metal.data.shape[0])
        w = max(d.data.shape[1], metal.data.shape[1])
        wrap = d.wrap
        if tuple(metal.wrap) != tuple(d.wrap):
            warn(
                f"{name}: the metallic texture {metal.path} wraps {tuple(metal.wrap)} but the "
                f"diffuseColor texture {d.path} wraps {tuple(d.wrap)}; the combined albedo "
                "texture uses the diffuse texture's modes (outside [0, 1] metallic follows "
                "them). Fix: author the same wrapS/wrapT on both"
            )
    m = outputs_on_grid(metal, h, w)[..., 0]
    bad = ~((m >= 0.0) & (m <= 1.0))
    if bad.any():
        warn(
            f"{name}: {int(bad.sum())} texels of the metallic texture {metal.path} are outside "
            f"[0, 1] after scale and bias ({float(np.nanmin(m)):g} .. {float(np.nanmax(m)):g}); "
            "clamped. Fix: the texture's values or its inputs:scale / inputs:bias"
        )
        m = np.clip(np.nan_to_num(m, nan=0.0), 0.0, 1.0)
    k = (np.float32(1.0) - m.astype(np.float32))[..., None]
    if d is None:
        data = np.asarray(mat.albedo, np.float32)[None, None, :3] * k
        path = metal.path
    else:
        dv = np.clip(outputs_on_grid(d, h, w), 0.0, 1.0)
        data = np.broadcast_to(dv, (h, w, 3)) * k if dv.shape[2] == 1 else dv[..., :3] * k
        path = d.path
    return Texture(
        path,
        np.ascontiguousarray(data, np.float32),
        np.ones(4, np.float32),
        np.zeros(4, np.float32),
        (0, 1, 2),
        tuple(wrap),
    )


def sanitize_image(data, label, warn):
    """Replace NaN/Inf and negative texels by 0 (with a warning); data : (h, w, c) float32."""
    bad = ~np.isfinite(data)
    neg = np.isfinite(data) & (data < 0)
    if bad.any() or neg.any():
        warn(
            f"{label}: {int(bad.sum())} NaN/Inf and {int(neg.sum())} negative texel values "
            "replaced by 0"
        )
        data = np.where(bad | neg, np.float32(0), data).astype(np.float32)
    return data


def texture_channels(out_name: str) -> tuple[int, ...]:
    """Channel indices a UsdUVTexture output selects (``rgb`` -> (0, 1, 2), ``a`` -> (3,))."""
    return {"rgb": (0, 1, 2), "r": (0,), "g": (1,), "b": (2,), "a": (3,)}.get(out_name, (0, 1, 2))


def to_rgb(img):
    """(h, w, c) -> (h, w, 3): the first three channels, or grey replicated."""
    if img.shape[2] >= 3:
        return img[..., :3]
    return np.repeat(img[..., :1], 3, axis=2)


#: The colour space the baker works in (Gf.ColorSpaceNames / OpenImageIO's built-in config).
LINEAR_SPACE = "lin_rec709_scene"
#: Source colour spaces that need no conversion (data, or already the working space).
_NO_CONVERSION = ("raw", "data", "lin_rec709_scene", "lin_rec709", "linear", "lin_srgb")


def source_color_space(colorspace: str, file_colorspace: str, fmt: str, nchannels: int):
    """The colour space a texture's texels are in, or None for data (no conversion).

    colorspace : UsdUVTexture ``inputs:sourceColorSpace`` (``raw``, ``sRGB`` or ``auto``);
    file_colorspace : ``colorSpace`` metadata authored on ``inputs:file`` (or "");
    fmt : OpenImageIO pixel format of the file; nchannels : its channel count.
    ``raw`` and ``sRGB`` are explicit. ``auto`` takes the file's colorSpace metadata when
    authored, else Hydra's rule (HioImage): an 8-bit image with 3 or 4 channels is sRGB,
    anything else (1- or 2-channel masks, 16-bit, float) is linear.
    """
    if colorspace == "raw":
        return None
    if colorspace == "sRGB":
        return "srgb_rec709_scene"
    if file_colorspace:
        return None if file_colorspace in _NO_CONVERSION else file_colorspace
    if fmt == "uint8" and nchannels in (3, 4):
        return "srgb_rec709_scene"
    return None


def read_image(path: str, colorspace: str = "auto", warn=None, file_colorspace: str = ""):
    """Read an image as linear float32 (h, w, c), or None (with a warning).

    path : a resolved asset path: a file, or an asset inside a usdz package / from a studio
    resolver (read through USD's asset resolver, usdahd.usd.assets).
    colorspace, file_colorspace : see :func:`source_color_space`; the conversion to
    lin_rec709_scene is OpenImageIO's (``ImageBufAlgo.colorconvert``, usdahd.images).
    """
    problem = asset_problem(path)
    if problem:
        if warn:
            warn(f"cannot read texture {path}: it {problem}; fallback used")
        return None
    try:
        with assets.local_file(path) as local:
            try:
                data, fmt = images.read_texels(local)
            except ImageError as exc:
                if warn:
                    warn(f"cannot read texture {path} ({exc}); fallback used")
                return None
    except OSError as exc:
        if warn:
            warn(f"cannot read texture {path} ({one_line(exc, 200)}); fallback used")
        return None
    if data is None:
        if warn:
            warn(f"cannot decode texture {path}; fallback used")
        return None
    if colorspace not in ("raw", "sRGB", "auto") and warn:
        warn(f"texture {path}: unknown sourceColorSpace {colorspace!r}; treated as auto")
    space = source_color_space(colorspace, file_colorspace, fmt, data.shape[2])
    if space is not None:
        try:
            data = images.convert_color(data, space, LINEAR_SPACE)
        except ImageError as exc:
            if warn:
                warn(
                    f"texture {path}: OpenImageIO cannot convert colour space {space!r} to "
                    f"{LINEAR_SPACE} ({one_line(exc, 150)}); texels read unconverted"
                )
    return data
