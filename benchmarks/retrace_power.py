"""Power curve and false-alarm rate of ``usdahd validate --retrace`` (docs/validate.md).

For each sample stage and bake seed: a default (denoised) bake at ``--resolution``; copies
whose irradiance textures *and* SH sidecar are scaled by each factor (the sidecar consistent
with the rescaled textures, so IzCheck passes and only the physics can tell, as in
tests/test_retrace.py); each validated with ``--retrace N`` at the default samples and the
retrace seed = the bake seed. A prim is *detected* when it has a ``RetraceMismatch`` error.
Factor 1.0 gives the false-alarm rate.

``--bias`` instead measures the residual bias of the default bake's mean over the retrace's
candidate texels: per prim, the denoised bake against a ``--no-denoise`` bake at
``--long`` samples (and against the un-denoised bake of the same seed, which isolates the
denoiser's own change). Prints one JSON line per prim and a summary.

    python benchmarks/retrace_power.py --resolution 16 --seeds 3 cornell_box.usda
    python benchmarks/retrace_power.py --bias --resolution 16
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

FACTORS = (1.0, 1.005, 1.01, 1.02, 1.03)


def _bake(src: Path, out: Path, resolution: int, *flags) -> Path:
    from usdahd import cli

    if not out.exists():
        args = ["bake", str(src), "-o", str(out), "--resolution", str(resolution), "-qq", *flags]
        assert cli.main(args) == 0, args
    return out


def _mismatch(layer: Path, n: int, seed: int) -> dict:
    import contextlib
    import io

    from usdahd import cli

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        cli.main(
            [
                "validate",
                str(layer),
                "--json",
                "-q",
                "--retrace",
                str(n),
                "--retrace-seed",
                str(seed),
            ]
        )
    out = {}
    for f in json.loads(buf.getvalue())["findings"]:
        if f["rule"] == "Retrace":
            out.setdefault(f["prim"], []).append(f)
    return out


def power(args) -> None:
    from conftest import copy_sample, sample_stages
    from test_retrace import _scaled_copy

    stages = args.stages or sample_stages()
    counts = {f: [0, 0] for f in FACTORS}
    rows = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for stage in stages:
            for seed in range(args.seeds):
                d = Path(tmp) / f"{stage}-{seed}"
                src = copy_sample(d, stage)
                base = _bake(
                    src, d / "f1.0" / "x.lightmaps.usda", args.resolution, "--seed", str(seed)
                )
                for f in FACTORS:
                    layer = base if f == 1.0 else _scaled_copy(base, f"f{f}", f)
                    for prim, fs in _mismatch(layer, args.texels, seed).items():
                        codes = [x["code"] for x in fs]
                        if "Skipped" in codes:
                            continue
                        hit = "RetraceMismatch" in codes
                        counts[f][0] += hit
                        counts[f][1] += 1
                        d0 = fs[0]["data"]
                        rows.append(
                            dict(
                                stage=stage,
                                seed=seed,
                                factor=f,
                                prim=prim,
                                hit=hit,
                                ratio=d0.get("ratio"),
                                se=d0.get("standard_error"),
                                texels=d0.get("texels"),
                                samples=d0.get("samples"),
                            )
                        )
                        print(json.dumps(rows[-1]), flush=True)
    print(
        f"# {time.perf_counter() - t0:.0f} s; retrace N={args.texels}, resolution "
        f"{args.resolution}, bake seeds {args.seeds}, stages {', '.join(stages)}"
    )
    print("| scale | prims flagged | detection rate |")
    print("|---|---|---|")
    for f, (hit, tot) in counts.items():
        print(f"| {f:g} | {hit} / {tot} | {hit / max(tot, 1):.3f} |")


def bias(args) -> None:
    from conftest import copy_sample, sample_stages
    from pxr import Usd

    from usdahd import validate as V
    from usdahd.usd import schema
    from usdahd.validate import retrace as RT

    stages = args.stages or sample_stages()
    worst = {"den_vs_raw": 0.0, "den_vs_long": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        for stage in stages:
            d = Path(tmp) / stage
            src = copy_sample(d, stage)
            layers = {
                "den": _bake(src, d / "den" / "x.lightmaps.usda", args.resolution),
                "raw": _bake(src, d / "raw" / "x.lightmaps.usda", args.resolution, "--no-denoise"),
                "long": _bake(
                    src,
                    d / "long" / "x.lightmaps.usda",
                    args.resolution,
                    "--no-denoise",
                    "--samples",
                    str(args.long),
                    "--seed",
                    "7",
                ),
            }
            sums: dict = {}
            for name, layer in layers.items():
                stage_ = Usd.Stage.Open(str(layer))
                for prim in schema.prims_with_api(stage_):
                    cand = RT.candidate_rows(prim)
                    if cand is None:
                        continue
                    bake = V.load_bake(prim)
                    iz = V.shm.iz(np.asarray(bake.sh[cand], np.float64)).sum(axis=0)
                    sums.setdefault(str(prim.GetPath()), {})[name] = (iz, len(cand))
                V.clear_caches()
            for prim, s in sums.items():
                if len(s) < 3 or not (s["long"][0] > 0).all():
                    continue
                dr = float(np.abs(s["den"][0] / s["raw"][0] - 1).max())
                dl = float(np.abs(s["den"][0] / s["long"][0] - 1).max())
                worst["den_vs_raw"] = max(worst["den_vs_raw"], dr)
                worst["den_vs_long"] = max(worst["den_vs_long"], dl)
                print(
                    json.dumps(
                        dict(
                            stage=stage,
                            prim=prim,
                            texels=s["den"][1],
                            den_vs_raw=dr,
                            den_vs_long=dl,
                        )
                    ),
                    flush=True,
                )
    print(json.dumps(dict(summary=worst, resolution=args.resolution, long=args.long)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("stages", nargs="*", help="sample stage file names (default: all samples)")
    p.add_argument("--resolution", type=int, default=16)
    p.add_argument("--seeds", type=int, default=2, help="bake (and retrace) seeds per stage")
    p.add_argument("--texels", type=int, default=1024, help="--retrace N")
    p.add_argument("--bias", action="store_true", help="measure the default bake's bias")
    p.add_argument("--long", type=int, default=4096, help="samples of the reference bake")
    args = p.parse_args()
    bias(args) if args.bias else power(args)


if __name__ == "__main__":
    main()
