"""Optional Intel Open Image Denoise (``pyoidn``) for baked radiance SH, chart by chart.

``denoise_sh(sh, texels, charts=...)`` denoises all 27 coefficients consistently:

- ``filter="RTLightmap"`` (default; OIDN's lightmap network, no guide images): the band-0
  RGB coefficient is denoised as an HDR lightmap; each higher coefficient ``c_lm`` is divided
  by ``sqrt(2l+1) * c_00`` (in [-1, 1] for any non-negative radiance), denoised with OIDN's
  ``directional`` mode, and multiplied back by the denoised ``c_00``. This is OIDN's documented
  path for directional (SH) lightmaps.
- ``filter="RT"``: OIDN's RT network with ``albedo`` and ``normal`` guides (per texel); band 0
  as HDR, the normalized higher coefficients mapped to [0, 1] as LDR.

Charts are never mixed: each chart's bounding box is denoised on its own, with the texels of
other charts and empty texels replaced by the chart's own values grown outward (dilation), so
the network sees no foreign data; only the chart's texels are written back.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.post import dilate
from usdahd.bake.types import Texels
from usdahd.errors import InputError, UsageError

FILTERS = ("RTLightmap", "RT")
#: sqrt(2l + 1) per coefficient: |c_lm| <= sqrt(2l+1) c_00 for non-negative functions.
_BAND_BOUND = np.sqrt(2.0 * np.array([0, 1, 1, 1, 2, 2, 2, 2, 2]) + 1.0)
#: Margin (texels) of dilated context around each chart's box.
MARGIN = 4


def _pyoidn():
    try:
        import pyoidn
    except ImportError:
        raise UsageError(
            "denoising needs Intel Open Image Denoise: pip install pyoidn "
            "(or 'usdahd[denoise]'), or bake without --denoise"
        ) from None
    return pyoidn


class _Denoiser:
    """One OIDN device and one filter per (type, hdr, directional) setting, reused."""

    def __init__(self, quality: str):
        self.oidn = _pyoidn()
        self.device = self.oidn.Device()
        self.device.commit()
        self.quality = {
            "high": self.oidn.OIDN_QUALITY_HIGH,
            "balanced": self.oidn.OIDN_QUALITY_BALANCED,
            "fast": self.oidn.OIDN_QUALITY_FAST,
        }[quality]

    def run(self, color, *, filter_type, hdr=False, directional=False, albedo=None, normal=None):
        oidn = self.oidn
        color = np.ascontiguousarray(color, dtype=np.float32)
        out = np.zeros_like(color)
        flt = oidn.Filter(self.device, filter_type)
        try:
            flt.set_image(oidn.OIDN_IMAGE_COLOR, color, oidn.OIDN_FORMAT_FLOAT3)
            if albedo is not None:
                albedo = np.ascontiguousarray(albedo, dtype=np.float32)
                flt.set_image(oidn.OIDN_IMAGE_ALBEDO, albedo, oidn.OIDN_FORMAT_FLOAT3)
            if normal is not None:
                normal = np.ascontiguousarray(normal, dtype=np.float32)
                flt.set_image(oidn.OIDN_IMAGE_NORMAL, normal, oidn.OIDN_FORMAT_FLOAT3)
            flt.set_image(oidn.OIDN_IMAGE_OUTPUT, out, oidn.OIDN_FORMAT_FLOAT3)
            if filter_type == "RTLightmap":
                flt.set_bool("directional", bool(directional))
            else:
                flt.set_bool("hdr", bool(hdr))
            flt.set_int("quality", self.quality)
            flt.commit()
            flt.execute()
            err = self.device.get_error()
            if err is not None:
                raise InputError(f"Open Image Denoise failed: {err}")
        finally:
            flt.release()
        return out

    def close(self):
        if hasattr(self.device, "release"):
            self.device.release()


def denoise_sh(
    sh: np.ndarray,
    texels: Texels,
    *,
    charts: np.ndarray | None = None,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    filter: str = "RTLightmap",
    quality: str = "high",
) -> np.ndarray:
    """Denoised copy of radiance SH ``(n, 3, 9)`` (float32), chart by chart.

    charts : (n,) chart id per texel (``chart_ids(mesh)[texels.triangle]``); None = one chart.
    albedo, normal : (n, 3) guides for ``filter="RT"`` (ignored by RTLightmap, which takes
    none); normals in world space, e.g. ``texels.frame[:, 2]``.
    Raises UsageError if pyoidn is not installed.
    """
    if filter not in FILTERS:
        raise UsageError(f"unknown denoise filter {filter!r}; use one of {FILTERS}")
    if quality not in ("high", "balanced", "fast"):
        raise UsageError(f"unknown denoise quality {quality!r}")
    sh = np.asarray(sh)
    n = len(texels)
    if sh.shape != (n, 3, 9):
        raise InputError(f"denoise_sh needs SH of shape ({n}, 3, 9), got {sh.shape}")
    charts = np.zeros(n, np.int64) if charts is None else np.asarray(charts)
    den = _Denoiser(quality)
    out = sh.astype(np.float32, copy=True)
    w, h = texels.resolution
    try:
        for c in np.unique(charts):
            sel = np.nonzero(charts == c)[0]
            xy = texels.xy[sel].astype(np.int64)
            x0 = max(int(xy[:, 0].min()) - MARGIN, 0)
            y0 = max(int(xy[:, 1].min()) - MARGIN, 0)
            x1 = min(int(xy[:, 0].max()) + MARGIN + 1, w)
            y1 = min(int(xy[:, 1].max()) + MARGIN + 1, h)
            lx, ly = xy[:, 0] - x0, xy[:, 1] - y0
            mask = np.zeros((y1 - y0, x1 - x0), dtype=bool)
            mask[ly, lx] = True

            def crop(values, mask=mask, ly=ly, lx=lx):
                img = np.zeros((*mask.shape, values.shape[-1]), np.float32)
                img[ly, lx] = values
                return dilate(img, mask, None)

            guides = {}
            if filter == "RT":
                if albedo is not None:
                    guides["albedo"] = np.clip(crop(np.asarray(albedo)[sel]), 0.0, 1.0)
                if normal is not None:
                    guides["normal"] = np.clip(crop(np.asarray(normal)[sel]), -1.0, 1.0)
            c00 = np.maximum(sh[sel, :, 0], 0.0)
            base = den.run(crop(c00), filter_type=filter, hdr=True, **guides)
            base = np.maximum(base, 0.0)
            out[sel, :, 0] = base[ly, lx]
            safe = np.where(c00 > 0, c00, 1.0)
            for k in range(1, 9):
                ratio = np.where(c00 > 0, sh[sel, :, k] / (_BAND_BOUND[k] * safe), 0.0)
                ratio = np.clip(ratio, -1.0, 1.0)
                if filter == "RTLightmap":
                    d = den.run(crop(ratio), filter_type=filter, directional=True)
                else:
                    d = den.run(crop(0.5 * (ratio + 1.0)), filter_type=filter, **guides) * 2 - 1
                d = np.clip(d[ly, lx], -1.0, 1.0)
                out[sel, :, k] = d * _BAND_BOUND[k] * out[sel, :, 0]
    finally:
        den.close()
    return out
