"""Lightmap UV unwrapping with xatlas for meshes that have no lightmap UV set.

xatlas's requested atlas resolution is a target, not a cap (facts.md): we always set
``texels_per_unit`` ourselves, leave xatlas's resolution at 0 (one atlas, never several pages),
and check the size that comes back.

UV convention: xatlas's pixel y axis points down the image; our rows also count down from the
top (``usdahd.bake.types``), so ``v = 1 - y / height``. With this flip xatlas charts come out
counter-clockwise in UV (not mirrored), so tangent frames are right-handed.
"""

from __future__ import annotations

import numpy as np

from usdahd.bake.texels import MAX_RESOLUTION
from usdahd.errors import BakeError, InputError, UsageError
from usdahd.scene.types import MeshData

#: Attempts at shrinking texels_per_unit until the atlas fits a requested resolution.
MAX_ATTEMPTS = 8
#: Rough packing efficiency of xatlas charts (atlas area / chart area), used only for the first
#: guess of texels_per_unit and the early size check; the real size is always measured.
PACK_EFFICIENCY = 0.6
#: Wall-clock limit of one isolated xatlas run, seconds: a fixed allowance (interpreter start-up,
#: imports) plus a per-triangle one. Far above xatlas's real cost (the 82k-triangle icosphere
#: unwraps in seconds); it only turns a wedged native child into an error instead of a bake
#: (and a CI job) that never ends.
UNWRAP_TIMEOUT_S = 300.0
UNWRAP_TIMEOUT_PER_TRIANGLE_S = 2e-3


def _world_area(points: np.ndarray, triangles: np.ndarray) -> float:
    p = points[triangles]
    return float(0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())


def _run_xatlas(points, triangles, texels_per_unit, padding):
    """One xatlas run at a fixed texel density (single atlas; resolution left at 0)."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(points, triangles)
    chart_options = xatlas.ChartOptions()
    pack = xatlas.PackOptions()
    pack.padding = int(padding)
    pack.bilinear = True
    pack.texels_per_unit = float(texels_per_unit)
    pack.resolution = 0
    pack.bruteForce = False
    atlas.generate(chart_options, pack)
    if atlas.atlas_count != 1:
        raise BakeError(f"xatlas produced {atlas.atlas_count} atlases, expected 1")
    vmapping, indices, uvs = atlas.get_mesh(0)
    return atlas.width, atlas.height, vmapping, indices, uvs, atlas.chart_count


def _pack(points, triangles, texels_per_unit, target, padding, max_resolution, path):
    """The xatlas part of :func:`unwrap`: returns (w, h, vmap, idx, uvs, target)."""
    if texels_per_unit is not None:
        w, h, vmap, idx, uvs, _ = _run_xatlas(points, triangles, texels_per_unit, padding)
        if max(w, h) > max_resolution:
            raise UsageError(
                f"{path}: {texels_per_unit:g} texels per unit gives a {w}x{h} lightmap, "
                f"above the maximum {max_resolution}; lower --texel-density"
            )
        return w, h, vmap, idx, uvs, (w, h)
    area = _world_area(points.astype(np.float64), triangles.astype(np.int64))
    tpu = min(target) * np.sqrt(PACK_EFFICIENCY / area)
    best = None
    for _ in range(MAX_ATTEMPTS):
        w, h, vmap, idx, uvs, _ = _run_xatlas(points, triangles, tpu, padding)
        fit = max(w / target[0], h / target[1])
        if fit <= 1.0:
            best = (w, h, vmap, idx, uvs)
            if fit > 0.9:
                break
            tpu *= min(1.0 / fit, 1.5) * 0.98
        else:
            if best is not None:
                break
            tpu *= 0.98 / fit
    if best is None:
        raise BakeError(
            f"{path}: could not pack the unwrapped charts into {target[0]}x{target[1]} texels "
            f"(padding {padding}); raise --resolution"
        )
    return (*best, target)


def _child_main() -> None:
    """Child-process entry point: read pickled args on stdin, run :func:`_pack`, pickle the
    result (or the error) to stdout."""
    import pickle
    import sys

    args = pickle.load(sys.stdin.buffer)
    try:
        msg = ("ok", _pack(*args))
    except UsageError as exc:
        msg = ("usage", str(exc))
    except Exception as exc:  # noqa: BLE001 - reported to the parent as a BakeError
        msg = ("error", f"{type(exc).__name__}: {exc}")
    sys.stdout.buffer.write(pickle.dumps(msg))
    sys.stdout.buffer.flush()


def _pack_isolated(args, path):
    """Run :func:`_pack` in a child Python process: xatlas 0.0.11 segfaults on some meshes
    (e.g. a subdivided icosphere of 82k triangles), which must fail one prim, not kill the
    baker. A plain subprocess (not multiprocessing) so the caller's __main__ is not re-run."""
    import os
    import pickle
    import subprocess
    import sys

    import usdahd

    root = os.path.dirname(os.path.dirname(os.path.abspath(usdahd.__file__)))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    code = "from usdahd.bake.unwrap import _child_main; _child_main()"
    limit = UNWRAP_TIMEOUT_S + UNWRAP_TIMEOUT_PER_TRIANGLE_S * len(args[1])
    try:
        proc = subprocess.run(
            [sys.executable, "-c", code],
            input=pickle.dumps(args),
            capture_output=True,
            env=env,
            check=False,
            timeout=limit,
        )
    except subprocess.TimeoutExpired:
        raise BakeError(
            f"{path}: xatlas did not finish unwrapping this mesh within {limit:.0f} s "
            "(the child process was stopped); author a lightmap UV set for it and pass it "
            "with --uv"
        ) from None
    if proc.returncode != 0 or not proc.stdout:
        detail = proc.stderr.decode(errors="replace").strip().splitlines()
        detail = detail[-1] if detail else f"exit code {proc.returncode}"
        raise BakeError(
            f"{path}: xatlas crashed while unwrapping this mesh ({detail}); "
            "author a lightmap UV set for it and pass it with --uv"
        )
    kind, value = pickle.loads(proc.stdout)
    if kind == "usage":
        raise UsageError(value)
    if kind == "error":
        raise BakeError(f"{path}: unwrapping failed: {value}")
    return value


def unwrap(
    mesh: MeshData,
    *,
    texels_per_unit: float | None = None,
    resolution: int | tuple[int, int] | None = None,
    padding: int = 2,
    max_resolution: int = MAX_RESOLUTION,
    isolate: bool = True,
) -> tuple[np.ndarray, tuple[int, int]]:
    """Unwrap ``mesh`` into one lightmap atlas.

    Give exactly one of ``texels_per_unit`` (world-space texel density; the atlas size is what
    xatlas needs) or ``resolution`` (n or (w, h): the atlas is packed as densely as fits, and
    placed in the top-left corner of a w x h lightmap, so the returned resolution is exactly the
    requested one). ``padding`` is the gutter in texels between charts. ``isolate`` runs xatlas
    in a child process (it can segfault on some meshes; that becomes a BakeError).

    Returns ``uv : (t, 3, 2) float32`` per-corner lightmap UVs in [0, 1] (same triangle order as
    ``mesh.triangles``; author them as a faceVarying primvar via ``mesh.corner``) and
    ``resolution : (w, h)``. xatlas lays out some charts mirrored (about 45 % on the castle
    scene); they are kept as they are (flipping a chart inside its bounding box made it overlap
    interlocking neighbours): their tangent frames are left-handed, b = -cross(n, t), as
    docs/texels.md specifies.
    Deterministic for a given mesh and options.
    Raises UsageError if the atlas would exceed ``max_resolution``.
    """
    if (texels_per_unit is None) == (resolution is None):
        raise UsageError("unwrap needs exactly one of texels_per_unit or resolution")
    points = np.ascontiguousarray(mesh.points, dtype=np.float32)
    triangles = np.ascontiguousarray(mesh.triangles, dtype=np.uint32)
    if len(triangles) == 0:
        raise InputError(f"{mesh.path}: mesh has no triangles to unwrap")
    if not np.isfinite(points).all():
        raise InputError(f"{mesh.path}: points contain NaN or infinity; cannot unwrap")
    area = _world_area(points.astype(np.float64), triangles.astype(np.int64))
    if area <= 0.0:
        raise InputError(f"{mesh.path}: mesh has zero surface area; cannot unwrap")
    if padding < 0:
        raise UsageError(f"unwrap padding must be >= 0, got {padding}")

    target = None
    if texels_per_unit is not None:
        if not np.isfinite(texels_per_unit) or texels_per_unit <= 0:
            raise UsageError(f"texel density must be positive, got {texels_per_unit!r}")
        estimate = texels_per_unit * np.sqrt(area / PACK_EFFICIENCY)
        if estimate > 2 * max_resolution:
            raise UsageError(
                f"{mesh.path}: {texels_per_unit:g} texels per unit needs about a "
                f"{estimate:.0f}^2 lightmap, above the maximum {max_resolution}; "
                "lower --texel-density"
            )
        texels_per_unit = float(texels_per_unit)
    else:
        if np.isscalar(resolution):
            target = (int(resolution), int(resolution))
        else:
            target = tuple(int(r) for r in resolution)
        if len(target) != 2 or min(target) < 1 or max(target) > max_resolution:
            raise UsageError(
                f"lightmap resolution {resolution!r} must be n or (w, h) in 1..{max_resolution}"
            )

    args = (points, triangles, texels_per_unit, target, padding, max_resolution, mesh.path)
    if isolate:
        w, h, vmap, idx, uvs, target = _pack_isolated(args, mesh.path)
    else:
        w, h, vmap, idx, uvs, target = _pack(*args)

    idx = np.asarray(idx, dtype=np.int64)
    vmap = np.asarray(vmap, dtype=np.int64)
    if idx.shape != triangles.shape or not np.array_equal(vmap[idx], triangles):
        raise BakeError(f"{mesh.path}: xatlas changed the triangle list; cannot map UVs back")
    # xatlas uvs are normalized by its own (w, h); pixel coords -> our lightmap of size target
    pix = np.asarray(uvs, dtype=np.float64)[idx] * np.array([w, h], dtype=np.float64)
    uv = np.empty_like(pix)
    uv[..., 0] = pix[..., 0] / target[0]
    uv[..., 1] = 1.0 - pix[..., 1] / target[1]
    return uv.astype(np.float32), (int(target[0]), int(target[1]))
