"""``usdahd bake`` that also keeps the integrator's per-texel variance of I_z (for ``compare``).

``python -m benchmarks.reference.bakevar OUT.npz STAGE -o LAYER [usdahd bake flags...]`` runs
usdahd's own CLI (``usdahd bake``, same arguments, same exit code, same stdout) in this
process with :func:`usdahd.bake.integrate.bake_texels` wrapped: every call's texel
coordinates and the two per-texel variance bounds the bake already computes for its denoiser
blend (``iz_variance``, s^2 / S, and ``iz_variance_halves``, the two interleaved halves) are
kept per mesh prim, with the texels the bake fills from their neighbours instead of using
their estimate (``stats["invalid"]``: inside geometry, covered, contacts), and written to
``OUT.npz`` (``xy_<i>``, ``s2_<i>``, ``halves_<i>``, ``invalid_<i>`` and ``paths``, a JSON list of
prim paths) after the bake. Nothing is traced twice: the variances are
a by-product of the bake being compared. ``compare`` turns them into the bake's own standard
error on each mesh's mean (:func:`benchmarks.reference.compare.bake_mean_error`).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["main", "read"]


def read(path) -> dict[str, dict[str, np.ndarray]]:
    """{prim path: {"xy" (n, 2) int, "s2" (n,), "halves" (n,), "invalid" (n,) bool}} from a
    file :func:`main` wrote."""
    with np.load(path, allow_pickle=False) as d:
        paths = json.loads(str(d["paths"]))
        return {
            p: {
                "xy": d[f"xy_{i}"],
                "s2": d[f"s2_{i}"],
                "halves": d[f"halves_{i}"],
                "invalid": d[f"invalid_{i}"],
            }
            for i, p in enumerate(paths)
        }


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) < 2:
        print("usage: python -m benchmarks.reference.bakevar OUT.npz STAGE -o LAYER [flags]",
              file=sys.stderr)  # fmt: skip
        return 2
    out = Path(argv[0])
    import usdahd.bake.integrate as integ
    from usdahd import cli

    orig = integ.bake_texels
    kept: dict[str, list] = {}

    def hook(scene, tracer, texels, **kw):
        sh, stats = orig(scene, tracer, texels, **kw)
        mesh = kw.get("mesh")
        if mesh is not None and stats.get("iz_variance") is not None:
            path = scene.meshes[mesh].path
            halves = stats.get("iz_variance_halves")
            s2 = np.asarray(stats["iz_variance"], np.float64)
            # the stats dict itself: the pipeline adds push_off_contacts' texels to "invalid"
            kept.setdefault(path, []).append(
                (np.asarray(texels.xy), s2, s2 if halves is None else np.asarray(halves), stats)
            )
        return sh, stats

    integ.bake_texels = hook
    try:
        code = cli.main(["bake", *argv[1:]])
    finally:
        integ.bake_texels = orig
    arrays = {"paths": np.array(json.dumps(list(kept)))}
    for i, parts in enumerate(kept.values()):
        xy, s2, halves, stats = parts[-1]  # a re-trace of a prim replaces the earlier one
        arrays[f"xy_{i}"], arrays[f"s2_{i}"], arrays[f"halves_{i}"] = xy, s2, halves
        arrays[f"invalid_{i}"] = np.asarray(stats.get("invalid", np.zeros(len(s2), bool)), bool)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".bakevar.", suffix=".npz", dir=out.parent)
    os.close(fd)
    np.savez(tmp, **arrays)
    os.replace(tmp, out)
    return int(code or 0)


if __name__ == "__main__":
    raise SystemExit(main())
