"""Scaling of the distributed bake (issue 15, docs/scaling.md): a plain bake vs ``--workers N``.

Bakes one sample (a copy in a temporary folder, ``--force`` each time) as a plain
single-process bake and on local Dask clusters of each ``--workers`` count, ``--repeat`` times
each, and prints a Markdown table: wall time (median, with the cluster start-up, which a
``--workers`` bake pays every time), tiles, tiles per second, the overhead per tile against the
plain bake, and the machine's load average while measuring. Also checks that every run wrote
the same SH sidecars and textures as the plain bake.

    python -m benchmarks.scaling                               # cornell_box, 128^2, 32 spp
    python -m benchmarks.scaling --stage classroom.usda --resolution 256 --workers 1 2 4

``--tile-texels`` sets the target tile size (default 8192 here, so the small default bake
has a few tiles per mesh; the bake's own default is ``usdahd.bake.tiles.TILE_TEXELS``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _outputs(folder: Path) -> dict[str, bytes]:
    return {
        p.name.split(".", 1)[1]: p.read_bytes()
        for p in sorted((folder / "lightmaps").iterdir())
        if p.is_file()
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stage", default="cornell_box.usda", help="a stage in samples/ or a path")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--tile-texels", type=int, default=8192)
    args = ap.parse_args(argv)

    from usdahd.bake import tiles
    from usdahd.pipeline import BakeOptions, bake

    tiles.TILE_TEXELS = args.tile_texels  # the client cuts the tiles: this process decides
    src = Path(args.stage) if Path(args.stage).is_file() else REPO / "samples" / args.stage
    tmp = Path(tempfile.mkdtemp(prefix="usdahd-scaling-"))
    try:
        shutil.copy(src, tmp / src.name)
        if (src.parent / "textures").is_dir():
            shutil.copytree(src.parent / "textures", tmp / "textures")
        stage = tmp / src.name
        base = dict(resolution=args.resolution, samples=args.samples, seed=1, force=True,
                    quiet=True)  # fmt: skip
        bake(stage, BakeOptions(**base))  # warm-up: numba kernels compiled/loaded here
        reference = _outputs(tmp)
        rows, loads = [], []
        for workers in [None, *args.workers]:
            walls, n_tiles = [], 0
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                report = bake(stage, BakeOptions(**base, workers=workers))
                walls.append(time.perf_counter() - t0)
                loads.append(os.getloadavg()[0])
                assert report["exit_code"] == 0, report
                n_tiles = sum(p.get("tiles", 0) for p in report["prims"])
                if _outputs(tmp) != reference:
                    print(f"outputs differ from the plain bake with --workers {workers}")
                    return 1
            texels = sum(p.get("texels", 0) for p in report["prims"])
            rows.append((workers, statistics.median(walls), walls, n_tiles, texels))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    plain = rows[0][1]
    print(
        f"{src.name}, {args.resolution}^2 per mesh, {args.samples} spp, {rows[0][4]} texels, "
        f"tiles of ~{args.tile_texels} texels; {os.cpu_count()} cores, load average "
        f"{min(loads):.1f}-{max(loads):.1f} while measuring; median of {args.repeat}\n"
    )
    print("| run | wall s (median) | runs s | tiles | tiles/s | overhead/tile s |")
    print("|---|---|---|---|---|---|")
    for workers, wall, walls, n_tiles, _ in rows:
        name = "plain bake" if workers is None else f"--workers {workers}"
        runs = ", ".join(f"{w:.1f}" for w in walls)
        if workers is None:
            print(f"| {name} | {wall:.2f} | {runs} | - | - | - |")
        else:
            over = (wall - plain) / max(n_tiles, 1)
            print(
                f"| {name} | {wall:.2f} | {runs} | {n_tiles} | {n_tiles / wall:.2f} | {over:+.3f} |"
            )
    print("\nevery run's SH sidecars and textures: identical to the plain bake")
    return 0


if __name__ == "__main__":
    sys.exit(main())
