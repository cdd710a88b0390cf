"""Power curve and false-alarm rate of ``usdahd validate --retrace`` (docs/validate.md).

For each sample stage and bake seed: a default (denoised) bake at ``--resolution``; copies
whose irradiance textures *and* SH sidecar are scaled by each factor (the sidecar consistent
with the rescaled textures, so IzCheck passes and only the physics can tell, as in
tests/validate/test_retrace.py); each validated with ``--retrace N`` at the default samples and the
retrace seed = the bake seed. A prim is *detected* when it has a ``RetraceMismatch`` error.
Factor 1.0 gives the false-alarm rate.

Each row also says which test caught it (``replay_hit``: the bake's own random stream
replayed; ``retrace_hit``: the independent retrace) and the replay's texels and population.
Stages: sample names (samples/) or the shared Cornell boxes (``cornell-box.usda``,
``cornell-box_rectlight.usda`` from ../shared/scenes/cornell_box).

``--bias`` instead replays *every* estimated texel of every prim of default bakes and prints
the replay's residual |sum b / sum p - 1| per prim (the denoiser's, fill's and stitching's
change of the prim's mean, no sampling error) and the largest: what the margin must bound;
and the two-stage replay test resampled on each real population (``--trials`` random texel
orders): its false-alarm rate and its detection rate of 0.5 % and 1 % rescales.

    python benchmarks/retrace_power.py --resolution 16 --seeds 3 cornell_box.usda
    python benchmarks/retrace_power.py --bias --resolution 32 --seeds 2
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
sys.path.insert(0, str(ROOT))  # the checkout: tests.conftest, tests.validate.test_retrace

FACTORS = (1.0, 0.99, 1.0025, 1.005, 1.01, 1.02, 1.04)
#: The third-party Cornell boxes (tests read ../shared relative to the repository root).
SHARED = ROOT.parent / "shared" / "scenes" / "cornell_box"


def _stage(folder: Path, name: str) -> Path:
    """A sample stage (samples/<name>) or a shared Cornell box file copied into ``folder``."""
    import shutil

    from tests.scenes import copy_sample

    if (SHARED / name).is_file():
        folder.mkdir(parents=True, exist_ok=True)
        for f in SHARED.glob("*.usda"):
            shutil.copy(f, folder / f.name)
        return folder / name
    return copy_sample(folder, name)


def _bake(src: Path, out: Path, resolution: int, *flags) -> Path:
    from usdahd import cli

    if not out.exists():
        args = ["bake", str(src), "-o", str(out), "-qq", *flags]
        if resolution:
            args += ["--resolution", str(resolution)]
        assert cli.main(args) == 0, args
    return out


def _retrace(layer: Path, n: int, seed: int) -> dict:
    import contextlib
    import io

    from usdahd import cli

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        cli.main(["validate", str(layer), "--json", "-q", "--retrace", str(n)]
                 + ["--retrace-seed", str(seed)])  # fmt: skip
    out = {}
    for f in json.loads(buf.getvalue())["findings"]:
        if f["rule"] == "Retrace":
            out.setdefault(f["prim"], []).append(f)
    return out


def _beyond(ratio, bound) -> bool:
    return any(r is not None and abs(r - 1.0) > b for r, b in zip(ratio or [], bound or []))


def power(args) -> None:
    from tests.scenes import sample_stages
    from tests.validate.test_retrace import _scaled_copy

    stages = args.stages or sample_stages()
    counts: dict = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for stage in stages:
            for seed in range(args.seeds):
                d = Path(tmp) / f"{stage}-{seed}"
                src = _stage(d, stage)
                base = _bake(
                    src, d / "f1.0" / "x.lightmaps.usda", args.resolution, "--seed", str(seed)
                )
                for f in FACTORS:
                    layer = base if f == 1.0 else _scaled_copy(base, f"f{f}", f)
                    for prim, fs in _retrace(layer, args.texels, seed).items():
                        codes = [x["code"] for x in fs]
                        if "Skipped" in codes:
                            continue
                        d0 = fs[0]["data"]
                        row = dict(
                            stage=stage,
                            seed=seed,
                            factor=f,
                            prim=prim,
                            hit="RetraceMismatch" in codes,
                            replay_hit=_beyond(d0.get("replay_ratio"), d0.get("replay_bound")),
                            retrace_hit=_beyond(d0.get("ratio"), d0.get("bound")),
                            outlier="RetraceOutlier" in codes,
                            ratio=d0.get("ratio"),
                            bound=d0.get("bound"),
                            replay_ratio=d0.get("replay_ratio"),
                            replay_bound=d0.get("replay_bound"),
                            replay_texels=d0.get("replay_texels"),
                            replay_population=d0.get("replay_population"),
                            replayed=d0.get("replayed"),
                            texels=d0.get("texels"),
                            seconds=round(d0.get("seconds", 0) + d0.get("replay_seconds", 0), 2),
                        )
                        c = counts.setdefault((stage, f), [0, 0, 0])
                        c[0] += row["hit"]
                        c[1] += 1
                        c[2] += row["outlier"]
                        print(json.dumps(row), flush=True)
    print(
        f"# {time.perf_counter() - t0:.0f} s; retrace N={args.texels}, resolution "
        f"{args.resolution or 'default'}, bake seeds {args.seeds}"
    )
    print("| stage | " + " | ".join(f"{f:g}" for f in FACTORS) + " |")
    print("|---" * (len(FACTORS) + 1) + "|")
    for stage in stages:
        cells = []
        for f in FACTORS:
            hit, tot, _ = counts.get((stage, f), (0, 0, 0))
            cells.append(f"{hit} / {tot}")
        print(f"| {stage} | " + " | ".join(cells) + " |")
    warn = sum(c[2] for (s, f), c in counts.items() if f == 1.0)
    tot = sum(c[1] for (s, f), c in counts.items() if f == 1.0)
    print(f"# clean bakes: {warn} / {tot} prims with a RetraceOutlier warning")


def _two_stage(b, p, factor, rng, margin, alpha):
    """One run of the replay's two-stage test (usdahd.validate.replay.run's loop) on a
    population (b, p) in a random texel order: (flagged, texels used)."""
    from usdahd.validate import replay as RP

    n_pop = len(b)
    order = rng.permutation(n_pop)
    n = min(n_pop, 1024)
    cap = min(n_pop, RP.REPLAY_CAP * 1024)
    while True:
        st = RP.compare_replay(
            factor * b[order[:n]], p[order[:n]], n_pop, margin=margin, alpha=alpha
        )
        need = RP.needed_texels(st, n_pop, margin)
        if need <= n or n >= cap:
            return bool(st["fail"].any()), n
        n = min(cap, max(need, n + 64))


def bias(args) -> None:
    """Every estimated texel of every prim of default (denoised) bakes replayed: the replay's
    residual |sum b / sum p - 1| on the whole population (the denoiser's, fill's and
    stitching's change of the prim's mean, no sampling error), and the two-stage test
    resampled ``--trials`` times on that real population (random texel orders, the rule's own
    functions, N = 1024 at the default samples): false alarms and detections of 0.5 % and 1 %."""
    from pxr import Usd

    from tests.scenes import sample_stages
    from usdahd import validate as V
    from usdahd.bake import integrate
    from usdahd.usd import schema
    from usdahd.validate import replay as RP
    from usdahd.validate import retrace as RT

    stages = args.stages or sample_stages()
    alpha = RT.OPTIONS.alpha * RP.REPLAY_ALPHA
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for stage in stages:
            for seed in range(args.seeds):
                d = Path(tmp) / f"{stage}-{seed}"
                layer = _bake(
                    _stage(d, stage), d / "x.lightmaps.usda", args.resolution, "--seed", str(seed)
                )
                st_ = Usd.Stage.Open(str(layer))
                for prim in schema.prims_with_api(st_):
                    got = RT.prim_candidates(prim)
                    if isinstance(got, str):
                        continue
                    bake, scene, tracer, mesh, texels, rows, _, est = got
                    path, st = str(prim.GetPath()), bake.results.settings
                    why = RP.replay_problem(bake.results, st, tracer)
                    if why is not None:
                        print(json.dumps(dict(stage=stage, prim=path, skipped=why)))
                        continue
                    mi = scene.meshes.index(mesh)
                    p, bf, _ = RP.replay_iz(
                        scene, tracer, texels, est, seed=RP.bake_seed(st["seed"], path),
                        samples=st["samples"], bounces=st["bounces"], mesh=mi,
                    )  # fmt: skip
                    sub = texels.take(est)
                    inside = integrate.inside_geometry(
                        tracer, sub, tracer.texel_offsets(sub, mi), bf, mesh=mi
                    )
                    b = RT.baked_iz(bake, rows[est])[~inside]
                    p = p[~inside]
                    ok = p.sum(axis=0) > 0
                    dev = float(np.abs(b.sum(axis=0)[ok] / p.sum(axis=0)[ok] - 1.0).max())
                    worst = max(worst, dev)
                    row = dict(stage=stage, seed=seed, prim=path, population=len(b))
                    row.update(residual=dev)
                    rng = np.random.default_rng([seed, len(b)])
                    for f in (1.0, 0.99, 1.01, 0.995, 1.005):
                        got_ = [_two_stage(b, p, f, rng, RT.DENOISE_BIAS_BOUND, alpha)
                                for _ in range(args.trials)]  # fmt: skip
                        row[f"flagged_{f:g}"] = sum(g[0] for g in got_) / args.trials
                        row[f"texels_{f:g}"] = int(np.median([g[1] for g in got_]))
                    print(json.dumps(row), flush=True)
                V.clear_caches()
    print(json.dumps(dict(worst_residual=worst, resolution=args.resolution, seeds=args.seeds)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("stages", nargs="*", help="sample stage file names (default: all samples)")
    p.add_argument("--resolution", type=int, default=16, help="0: the bake's default")
    p.add_argument("--seeds", type=int, default=2, help="bake (and retrace) seeds per stage")
    p.add_argument("--texels", type=int, default=1024, help="--retrace N")
    p.add_argument("--bias", action="store_true", help="replay whole populations (see doc)")
    p.add_argument("--trials", type=int, default=1000, help="--bias: resampled runs")
    args = p.parse_args()
    bias(args) if args.bias else power(args)


if __name__ == "__main__":
    main()
