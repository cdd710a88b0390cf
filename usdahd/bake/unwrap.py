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
        w, h, vmap, idx, uvs, charts = _run_xatlas(points, triangles, tpu, padding)
        if best is None and charts * (1 + padding) ** 2 > target[0] * target[1]:
            # every chart takes at least one texel and its padding: no scale fits them
            side = int(np.ceil(np.sqrt(charts) * (1 + padding)))
            raise BakeError(
                f"{path}: xatlas cut this mesh into {charts} charts, which need at least "
                f"{side}x{side} texels with padding {padding}; the lightmap is "
                f"{target[0]}x{target[1]}: raise --resolution"
            )
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
    """Worker-process entry point: for each request on stdin (an 8-byte big-endian length,
    then the pickled arguments of :func:`_pack`), run it and answer on stdout in the same
    framing with ("ok", result), ("usage" | "bake" | "error", message); stop at EOF."""
    import pickle
    import sys

    inp, out = sys.stdin.buffer, sys.stdout.buffer
    while True:
        head = inp.read(8)
        if len(head) < 8:
            return
        args = pickle.loads(inp.read(int.from_bytes(head, "big")))
        try:
            msg = ("ok", _pack(*args))
        except UsageError as exc:
            msg = ("usage", str(exc))
        except BakeError as exc:  # already names the prim
            msg = ("bake", str(exc))
        except Exception as exc:  # noqa: BLE001 - reported to the parent as a BakeError
            msg = ("error", f"{type(exc).__name__}: {exc}")
        data = pickle.dumps(msg)
        out.write(len(data).to_bytes(8, "big") + data)
        out.flush()


#: What the worker process runs (a module attribute so a test can make it crash).
_CHILD_CODE = "from usdahd.bake.unwrap import _child_main; _child_main()"


class _Worker:
    """One long-lived child Python process that runs :func:`_pack` for mesh after mesh, so an
    unwrap costs xatlas's time, not an interpreter start-up each (classroom, 74 meshes
    without UVs: ~0.12 s each). xatlas 0.0.11 segfaults on some meshes (e.g. a subdivided
    icosphere of 82k triangles): that kills the worker, fails that one prim, and the next
    mesh starts a new worker. A plain subprocess (not multiprocessing) so the caller's
    __main__ is not re-run."""

    def __init__(self):
        import os
        import subprocess
        import sys
        import tempfile

        import usdahd

        root = os.path.dirname(os.path.dirname(os.path.abspath(usdahd.__file__)))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        # stderr to a file, not a pipe: a child that writes warnings mesh after mesh must not
        # block on a full pipe nobody reads until it dies
        self.err = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _CHILD_CODE],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.err,
            env=env,
        )

    def alive(self) -> bool:
        return self.proc.poll() is None

    def request(self, data: bytes, timeout: float):
        """Send one pickled request; returns the unpickled reply, or None when the worker
        died; raises TimeoutError after ``timeout`` seconds (the worker is then stopped)."""
        import pickle
        import time

        try:
            self.proc.stdin.write(len(data).to_bytes(8, "big") + data)
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            return None
        end = time.monotonic() + timeout
        head = self._read(8, end)
        if head is None:
            return None
        body = self._read(int.from_bytes(head, "big"), end)
        return None if body is None else pickle.loads(body)

    def _read(self, n: int, end: float):
        import os
        import selectors
        import time

        fd = self.proc.stdout.fileno()
        buf = b""
        with selectors.DefaultSelector() as sel:
            sel.register(fd, selectors.EVENT_READ)
            while len(buf) < n:
                left = end - time.monotonic()
                if left <= 0 or not sel.select(left):
                    self.stop()
                    raise TimeoutError
                chunk = os.read(fd, n - len(buf))
                if not chunk:
                    return None
                buf += chunk
        return buf

    def failure(self) -> str:
        """The dead worker's last stderr line or its exit code."""
        try:
            self.proc.wait(timeout=5)
            self.err.seek(0)
            err = self.err.read().decode(errors="replace").strip().splitlines()
        except Exception:  # noqa: BLE001 - best effort: the message only
            err = []
        return err[-1] if err else f"exit code {self.proc.returncode}"

    def stop(self) -> None:
        if self.alive():
            self.proc.kill()
        try:
            self.proc.wait(timeout=5)
        except Exception:  # noqa: BLE001 - nothing more to do for a stuck child
            pass
        for f in (self.proc.stdin, self.proc.stdout, self.err):
            try:
                f.close()
            except OSError:
                pass


_worker: _Worker | None = None


def _stop_worker() -> None:
    global _worker
    if _worker is not None:
        _worker.stop()
        _worker = None


def _pack_isolated(args, path):
    """Run :func:`_pack` in the worker process (started on first use, restarted after a
    crash; stopped at interpreter exit)."""
    import atexit
    import pickle

    global _worker
    limit = UNWRAP_TIMEOUT_S + UNWRAP_TIMEOUT_PER_TRIANGLE_S * len(args[1])
    # A worker that dies on a mesh gets one retry in a fresh worker: a death from outside
    # (a signal, memory pressure) then fails no prim, and xatlas's segfaults, which follow the
    # mesh, fail the second time too.
    for attempt in range(2):
        if _worker is None or not _worker.alive():
            if _worker is None:
                atexit.register(_stop_worker)
            else:
                _worker.stop()
            _worker = _Worker()
        try:
            reply = _worker.request(pickle.dumps(args), limit)
        except TimeoutError:
            _worker = None
            raise BakeError(
                f"{path}: xatlas did not finish unwrapping this mesh within {limit:.0f} s "
                "(the child process was stopped); author a lightmap UV set for it and pass it "
                "with --uv"
            ) from None
        if reply is not None:
            break
        detail = _worker.failure()
        _worker.stop()
        if attempt:
            _worker = None
            raise BakeError(
                f"{path}: xatlas crashed while unwrapping this mesh ({detail}); "
                "author a lightmap UV set for it and pass it with --uv"
            )
    kind, value = reply
    if kind == "usage":
        raise UsageError(value)
    if kind == "bake":
        raise BakeError(value)
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
