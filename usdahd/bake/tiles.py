"""Work units of a distributed bake: tiles of texels within one mesh.

A tile is a contiguous run ``[first, stop)`` of one mesh's texels (in rasterisation order); a
tile never spans meshes. Its size is about :data:`TILE_TEXELS`, rounded to a whole number of
the integrator's chunks (:func:`usdahd.bake.integrate.chunk_texels`), so every tile starts on a
chunk boundary: each chunk draws from ``np.random.default_rng([seed, stream, first + start])``
keyed by the mesh-wide texel index, and each texel has its own stream seeded from that chunk
generator, so tracing the tiles anywhere and gathering them in texel order gives exactly the SH
of the whole-mesh bake (bit for bit, for any number of tiles or workers).

:func:`trace_tile` is what a worker runs: the contact push
(:func:`usdahd.bake.contacts.push_off_contacts`, per texel) and :func:`bake_texels` over the
tile. The Embree scene is built once per process and scene (:func:`tracer_for`, cached by a key
the client chooses), not once per tile. :func:`gather` puts the tiles of one mesh back together.
This module knows nothing of Dask (``usdahd/pipeline/distributed.py`` schedules the tiles).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, replace

import numpy as np

from usdahd.bake.types import Texels

__all__ = ["TILE_TEXELS", "Tile", "gather", "slice_texels", "split", "trace_tile"]

#: Target texels per tile (~64k: ~5 MB of texel data in, ~7 MB of SH out, and a few seconds of
#: tracing at 256 samples); rounded to whole integrator chunks.
TILE_TEXELS = 1 << 16
#: Scenes whose tracer a process keeps (a long-lived worker serving successive bakes).
CACHED_SCENES = 2

_TRACERS: OrderedDict = OrderedDict()
#: Per process: Embree scene builds done (what the tests check "once per worker" with).
builds = {"count": 0}


@dataclass
class Tile:
    """One work unit: texels ``[first, first + len(texels))`` of mesh ``mesh`` (its index in
    ``scene.meshes``, prim ``prim``), tile ``index`` of ``count`` of that prim, with the prim's
    trace settings."""

    prim: str
    mesh: int
    index: int
    count: int
    first: int
    texels: Texels
    samples: int
    bounces: int
    seed: int
    adaptive: bool

    def describe(self) -> str:
        last = self.first + len(self.texels) - 1
        return f"tile {self.index + 1}/{self.count} (texels {self.first}..{last}) of {self.prim}"


def split(n: int, chunk: int, target: int = TILE_TEXELS) -> list[tuple[int, int]]:
    """``[first, stop)`` ranges covering ``n`` texels, each a whole number of ``chunk``-texel
    chunks (about ``target`` texels; the last may be shorter)."""
    size = max(1, round(target / chunk)) * chunk
    return [(a, min(n, a + size)) for a in range(0, n, size)]


def slice_texels(texels: Texels, a: int, b: int) -> Texels:
    """Texels ``[a, b)`` as their own :class:`Texels` (copies, so a tile pickles small)."""
    return texels.take(slice(a, b))


def tracer_for(key, scene, backend: str, threads: int):
    """The process's :class:`~usdahd.bake.trace.Tracer` over ``scene`` (built on first use of
    ``key``; the :data:`CACHED_SCENES` most recent kept)."""
    tracer = _TRACERS.get(key)
    if tracer is None:
        from usdahd.bake.trace import Tracer

        while len(_TRACERS) >= CACHED_SCENES:
            _TRACERS.popitem(last=False)
        tracer = Tracer(scene, threads=threads, backend=backend)
        _TRACERS[key] = tracer
        builds["count"] += 1
    else:
        _TRACERS.move_to_end(key)
    return tracer


def trace_tile(key, scene, tile: Tile, backend: str, threads: int | None = None) -> dict:
    """Trace one tile: contact push, then :func:`bake_texels` with the mesh-wide texel index.

    threads: tracer threads (None: every core this process may use). Returns the tile's
    ``first``, ``sh`` (n, 3, 9), ``invalid``, ``backface_fraction``, ``samples``,
    ``iz_variance``, ``iz_variance_halves``, the sample ``position`` after the contact push,
    ``contact_texels``/``contact_invalid`` counts, ``rays``, ``rays_saved`` and ``seconds``."""
    from usdahd.bake.contacts import push_off_contacts
    from usdahd.bake.integrate import bake_texels

    t0 = time.perf_counter()
    if threads is None:
        import os

        threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1
    tracer = tracer_for(key, scene, backend, threads)
    texels, contact_invalid = push_off_contacts(tile.texels, scene.meshes[tile.mesh], tracer)
    sh, stats = bake_texels(
        scene,
        tracer,
        texels,
        samples=tile.samples,
        bounces=tile.bounces,
        seed=tile.seed,
        adaptive=tile.adaptive,
        mesh=tile.mesh,
        first=tile.first,
    )
    return {
        "first": tile.first,
        "sh": sh,
        "invalid": stats["invalid"] | contact_invalid,
        "covered": stats.get("covered", np.zeros(len(sh), bool)),
        "backface_fraction": stats["backface_fraction"],
        "samples": stats["samples"],
        "iz_variance": stats["iz_variance"],
        "iz_variance_halves": stats["iz_variance_halves"],
        "position": texels.position,
        "contact_texels": int(texels.stats.get("contact_texels", 0)),
        "contact_invalid": int(texels.stats.get("contact_invalid", 0)),
        "rays": int(stats["rays"]),
        "rays_saved": int(stats["rays_saved"]),
        "seconds": time.perf_counter() - t0,
    }


def gather(texels: Texels, results: list[dict]) -> tuple[Texels, np.ndarray, dict]:
    """(texels after the contact push, sh (n, 3, 9) float32, stats) of one mesh from its tile
    results (any order), as the whole-mesh ``push_off_contacts`` + ``bake_texels`` return
    them; stats ``time`` is the summed tracing time of the tiles."""
    n = len(texels)
    sh = np.zeros((n, 3, 9), np.float32)
    invalid = np.zeros(n, bool)
    cov = np.zeros(n, bool)
    backfrac = np.zeros(n, np.float32)
    used = np.zeros(n, np.int32)
    iz_var = np.zeros(n)
    iz_halves = np.zeros(n)
    position = texels.position.copy()
    covered = 0
    for r in results:
        sl = slice(r["first"], r["first"] + len(r["sh"]))
        sh[sl], invalid[sl], backfrac[sl] = r["sh"], r["invalid"], r["backface_fraction"]
        cov[sl] = r.get("covered", False)
        used[sl], position[sl], iz_var[sl] = r["samples"], r["position"], r["iz_variance"]
        iz_halves[sl] = r["iz_variance_halves"]
        covered += len(r["sh"])
    if covered != n:
        raise ValueError(f"tiles cover {covered} of {n} texels")
    moved = sum(r["contact_texels"] for r in results)
    stuck = sum(r["contact_invalid"] for r in results)
    if moved or stuck:
        stats = dict(texels.stats, contact_texels=moved, contact_invalid=stuck)
        texels = replace(texels, position=position, stats=stats)
    stats = {
        "rays": sum(r["rays"] for r in results),
        "time": sum(r["seconds"] for r in results),
        "invalid": invalid,
        "covered": cov,
        "backface_fraction": backfrac,
        "samples": used,
        "iz_variance": iz_var,
        "iz_variance_halves": iz_halves,
        "rays_saved": sum(r["rays_saved"] for r in results),
    }
    return texels, sh, stats
