"""``usdahd bake`` that also keeps the integrator's per-texel variance of I_z (for ``compare``).

``python -m benchmarks.reference.bakevar OUT.npz STAGE -o LAYER [usdahd bake flags...]`` runs
usdahd's own CLI (``usdahd bake``, same arguments, same exit code, same stdout) in this
process with :func:`usdahd.bake.integrate.bake_texels` wrapped: every call's texel
coordinates and the two per-texel variance bounds the bake already computes for its denoiser
blend (``iz_variance``, s^2 / S, and ``iz_variance_halves``, the two interleaved halves) are
kept per mesh prim, with the texels the bake fills from their neighbours instead of using
their estimate (``stats["invalid"]``: inside geometry, covered, contacts) and the texels
whose sample point :func:`usdahd.bake.contacts.push_off_contacts` moved off the texel centre
(contacts, rim texels under a low cover: docs/texels.md), and written to ``OUT.npz``
(``xy_<i>``, ``s2_<i>``, ``halves_<i>``, ``invalid_<i>``, ``moved_<i>`` and ``paths``, a JSON
list of prim paths) after the bake. Nothing is traced twice: the variances are
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
    """{prim path: {"xy" (n, 2) int, "s2" (n,), "halves" (n,), "invalid" (n,) bool, "moved"
    (n,) bool (empty in a file written before it was kept)}} from a file :func:`main` wrote."""
    with np.load(path, allow_pickle=False) as d:
        paths = json.loads(str(d["paths"]))
        return {
            p: {
                "xy": d[f"xy_{i}"],
                "s2": d[f"s2_{i}"],
                "halves": d[f"halves_{i}"],
                "invalid": d[f"invalid_{i}"],
                "moved": d[f"moved_{i}"] if f"moved_{i}" in d.files else np.zeros(0, bool),
            }
            for i, p in enumerate(paths)
        }


def _rows_in(xy: np.ndarray, parts: list) -> np.ndarray:
    """(n,) bool: which rows of ``xy`` (n, 2) int are in any of ``parts`` ((m, 2) int each)."""
    if not parts:
        return np.zeros(len(xy), bool)
    w = int(max(xy[:, 0].max(initial=0), max(int(q[:, 0].max()) for q in parts))) + 1
    key = np.asarray(xy, np.int64) @ np.array([1, w])
    other = np.concatenate([np.asarray(q, np.int64) @ np.array([1, w]) for q in parts])
    return np.isin(key, other)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) < 2:
        print("usage: python -m benchmarks.reference.bakevar OUT.npz STAGE -o LAYER [flags]",
              file=sys.stderr)  # fmt: skip
        return 2
    out = Path(argv[0])
    import usdahd.bake.contacts as contacts
    import usdahd.bake.integrate as integ
    from usdahd import cli

    orig = integ.bake_texels
    orig_push = contacts.push_off_contacts
    kept: dict[str, list] = {}
    moved_xy: dict[str, list] = {}  # texels whose sample point left the texel centre

    def push_hook(texels, mesh, tracer):
        out, invalid = orig_push(texels, mesh, tracer)
        if out is not texels:
            mv = np.any(np.asarray(out.position) != np.asarray(texels.position), axis=1)
            if mv.any():
                moved_xy.setdefault(mesh.path, []).append(np.asarray(texels.xy)[mv])
        return out, invalid

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
    contacts.push_off_contacts = push_hook
    try:
        code = cli.main(["bake", *argv[1:]])
    finally:
        integ.bake_texels = orig
        contacts.push_off_contacts = orig_push
    arrays = {"paths": np.array(json.dumps(list(kept)))}
    for i, (path, parts) in enumerate(kept.items()):
        xy, s2, halves, stats = parts[-1]  # a re-trace of a prim replaces the earlier one
        arrays[f"xy_{i}"], arrays[f"s2_{i}"], arrays[f"halves_{i}"] = xy, s2, halves
        arrays[f"invalid_{i}"] = np.asarray(stats.get("invalid", np.zeros(len(s2), bool)), bool)
        arrays[f"moved_{i}"] = _rows_in(xy, moved_xy.get(path, []))
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".bakevar.", suffix=".npz", dir=out.parent)
    os.close(fd)
    np.savez(tmp, **arrays)
    os.replace(tmp, out)
    return int(code or 0)


if __name__ == "__main__":
    raise SystemExit(main())
