"""Speed of a light-linked stage (issue 38): the Cornell box with its RectLight's lightLink
excluding ``TallBox`` and its shadowLink excluding ``ShortBox``, baked on 2000 floor texels.

    python -m benchmarks.linking                   # this checkout, 3 repeats
    PYTHONPATH=/other/checkout python benchmarks/linking.py   # another tree's usdahd

Prints the CPU seconds (``getrusage``: every thread) and wall seconds of ``bake_texels``
(256 samples, default bounces, native tracer; the best of the repeats), the rays traced and
the mean Iz of the texels, and the same for the unlinked box. Before issue 38 a linked stage
took the numpy integrator on the native tracer; since, the native kernel runs it. Other work
on this 2-core machine inflates the wall time far more than the CPU time.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def linked_stage(out: Path) -> Path:
    """Write the linked Cornell box next to nothing else (a flattened copy) and return it."""
    from pxr import Usd, UsdLux

    import usdahd.usd.reader  # noqa: F401  (registers the schema before any stage opens)

    stage = Usd.Stage.Open(str(REPO / "samples" / "cornell_box.usda"))
    path = out / "cornell_linked.usda"
    stage.Flatten().Export(str(path))
    stage = Usd.Stage.Open(str(path))
    api = UsdLux.LightAPI(stage.GetPrimAtPath("/World/Lights/CeilingLight"))
    api.GetLightLinkCollectionAPI().GetExcludesRel().AddTarget("/World/Geometry/TallBox")
    api.GetShadowLinkCollectionAPI().GetExcludesRel().AddTarget("/World/Geometry/ShortBox")
    stage.GetRootLayer().Save()
    return path


def bench(stage_path: Path, repeats: int, samples: int = 256, n: int = 2000) -> dict:
    from pxr import Usd

    from usdahd.bake.integrate import bake_texels
    from usdahd.bake.trace import Tracer
    from usdahd.bake.types import Texels
    from usdahd.usd.reader import load_scene

    scene = load_scene(Usd.Stage.Open(str(stage_path)))
    mesh = [m.path for m in scene.meshes].index("/World/Geometry/Floor")
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-0.9, 0.9, n), np.zeros(n), rng.uniform(-0.9, 0.9, n)]
    frame = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float32)
    tex = Texels((n, 1), np.zeros((n, 2), np.int32), p.astype(np.float32),
                 np.tile([0, 1, 0], (n, 1)).astype(np.float32), np.tile(frame, (n, 1, 1)),
                 np.zeros(n, np.int32), np.ones(n, bool))  # fmt: skip
    tr = Tracer(scene, backend="native")
    bake_texels(scene, tr, tex, samples=8, mesh=mesh)  # compile / load the kernels
    cpu = wall = np.inf
    for _ in range(repeats):
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF).ru_utime, time.perf_counter()
        sh, st = bake_texels(scene, tr, tex, samples=samples, seed=1, mesh=mesh)
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, resource.getrusage(resource.RUSAGE_SELF).ru_utime - r0)
    tr.close()
    iz = float(np.mean(sh[:, :, 0] @ np.array([0.2126, 0.7152, 0.0722])))
    return {"cpu_s": cpu, "wall_s": wall, "rays": int(st["rays"]), "mean_y00": iz}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.linking", description=__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    import usdahd

    print(f"usdahd from {Path(usdahd.__file__).parent}", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        for name, path in [
            ("linked", linked_stage(Path(tmp))),
            ("unlinked", REPO / "samples" / "cornell_box.usda"),
        ]:
            r = bench(path, args.repeats)
            print(f"{name}: cpu {r['cpu_s']:.2f} s, wall {r['wall_s']:.2f} s, rays {r['rays']}, "
                  f"mean luminance Y00 {r['mean_y00']:.5f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
