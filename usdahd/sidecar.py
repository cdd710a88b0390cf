"""The SH sidecar: one reader and writer of the float32 EXR beside every bake record.

A sidecar image is ``(h, w, 28)`` float32 with channels :data:`CHANNELS`: the radiance SH of
R, G and B (coefficient order of :mod:`usdahd.sh`, so the first 27 reshape to ``(3, 9)``),
then coverage ``A`` (1 = texel baked, 0 = empty). EXR stores channels sorted by name, so they
are always read by name (:func:`read`). The baker writes it (:func:`pack`, :func:`write`), and
re-fits (``--refit``), ``usdahd validate`` (IzCheck) and ``benchmarks/`` read it
(:func:`read`, :func:`read_record`, :func:`split`, :func:`covered`); docs/schema.md documents
the file.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["CHANNELS", "COVERAGE", "covered", "pack", "read", "read_record", "split", "write"]

#: Channel names, in the order of the values: R0..R8, G0..G8, B0..B8, A.
CHANNELS = tuple(f"{c}{k}" for c in "RGB" for k in range(9)) + ("A",)
#: Index of the coverage channel.
COVERAGE = 27


def pack(sh: np.ndarray) -> np.ndarray:
    """Sidecar values (n, 28) float32 of covered texels with SH ``sh`` (n, 3, 9)."""
    n = len(sh)
    return np.concatenate(
        [sh.reshape(n, 27).astype(np.float32), np.ones((n, 1), np.float32)], axis=1
    )


def split(px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(SH (h, w, 3, 9), coverage (h, w) bool) of a sidecar image ``px`` (h, w, 28), in its
    dtype."""
    h, w = px.shape[:2]
    return px[..., :27].reshape(h, w, 3, 9), px[..., COVERAGE] > 0.5


def covered(px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(xy (n, 2) int32, SH (n, 3, 9) float32) of the covered texels of ``px`` (h, w, 28),
    in row-major order."""
    ys, xs = np.nonzero(px[..., COVERAGE] > 0.5)
    sh = np.ascontiguousarray(px[ys, xs, :27].astype(np.float32).reshape(-1, 3, 9))
    return np.stack([xs, ys], axis=-1).astype(np.int32), sh


def read(path: str | os.PathLike) -> np.ndarray:
    """The sidecar image (h, w, 28) at ``path`` (ImageError when unreadable or a channel is
    missing)."""
    from usdahd import images

    return images.read(path, channels=CHANNELS).pixels


def read_record(results) -> np.ndarray:
    """The sidecar image of a bake record (``usd.schema.BakeResults``): its rectangle of its
    atlas page, or its own file."""
    from usdahd.usd import schema

    return schema.read_record_pixels(results, schema.SIDECAR_ROLE, CHANNELS)


def write(path: str | os.PathLike, px: np.ndarray) -> None:
    """Write the sidecar image ``px`` (h, w, 28) float32 atomically to ``path`` (EXR)."""
    from usdahd import images

    images.write(path, px, format="float", color_space="raw", channels=CHANNELS)
