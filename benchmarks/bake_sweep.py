"""Bake run time against error (section 1) and what skipping saves (section 4).

Every bake goes through the public pipeline, ``usdahd.pipeline.bake(stage, BakeOptions(...))``,
into a temporary output layer; errors are measured on the SH sidecar it writes (the baked
radiance SH after invalid-texel fill, denoising and seam stitching), so they are what a user of
``usdahd bake`` gets.

Error of a bake: luminance of I_z = ``usdahd.sh.iz(sh)`` per covered texel, against the same
texels of a converged *reference* (the mean of two bakes with independent seeds at many samples,
cached in ``benchmarks/cache/``); relative RMSE, bias and 99th-percentile absolute error, each
divided by the scene's mean reference I_z. The reference's own noise is estimated from the
difference of its two seeds: noise of the mean = rms(A - B) / 2 (relative likewise).
"""

from __future__ import annotations

import hashlib
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from common import (
    CACHE,
    PLOTS,
    REPO,
    log,
    md_table,
    median,
    pyplot,
    read_baked_sh,
    save_figure,
    timed,
)

from usdahd.numerics import sh as shm
from usdahd.version import __version__

#: Seeds of the two reference bakes (sweep bakes use 1, 2, 3, ... so they never share streams).
REFERENCE_SEEDS = (1001, 1002)


@dataclass(frozen=True)
class Config:
    name: str
    adaptive: bool = False
    denoise: bool = False


CONFIGS = (
    Config("plain"),
    Config("adaptive", adaptive=True),
    Config("denoise", denoise=True),
    Config("adaptive+denoise", adaptive=True, denoise=True),
)


def denoise_available() -> str | None:
    """None when ``--denoise`` works here, else the reason it does not."""
    try:
        from usdahd.bake import denoise

        denoise._pyoidn()
    except Exception as exc:  # UsageError (pyoidn missing) or a broken install
        return str(exc)
    return None


def bake_once(stage: Path, *, resolution: int, samples: int, seed: int, out_dir=None, **flags):
    """One ``usdahd.pipeline.bake`` into ``out_dir`` (a fresh temporary one by default).

    returns : dict(seconds (wall, whole call), rays, rays_saved, texels, statuses, sh (see
    common.read_baked_sh), layer).
    """
    from usdahd.pipeline import BakeOptions, bake

    tmp = None
    if out_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="usdahd-bench-")
        out_dir = tmp.name
    layer = Path(out_dir) / f"{stage.stem}.lightmaps.usda"
    opts = BakeOptions(
        output=str(layer),
        resolution=resolution,
        samples=samples,
        seed=seed,
        force=flags.pop("force", True),
        quiet=True,
        **flags,
    )
    try:
        report, seconds = timed(bake, str(stage), opts)
        failed = [p for p in report["prims"] if p.get("status") == "failed"]
        if failed:
            raise RuntimeError(f"{stage.name}: bake failed: {failed[0].get('error')}")
        prims = report["prims"]
        return {
            "seconds": seconds,
            "rays": sum(int(p.get("rays", 0)) for p in prims),
            "rays_saved": sum(int(p.get("rays_saved", 0)) for p in prims),
            "texels": sum(int(p.get("texels", 0)) for p in prims),
            "statuses": sorted({p.get("status", "?") for p in prims}),
            "sh": read_baked_sh(layer),
            "layer": layer,
        }
    finally:
        if tmp is not None:
            tmp.cleanup()


#: Sources a bake's numbers depend on: a change to any of them invalidates cached references.
BAKE_SOURCES = (
    "usdahd/bake/*.py",
    "usdahd/bake/kernels/*.py",
    "usdahd/usd/*.py",
    "usdahd/scene/*.py",
    "usdahd/pipeline/*.py",
    "usdahd/numerics/*.py",
)


def _cache_key(stage: Path, resolution: int, samples: int, seeds) -> str:
    h = hashlib.sha256(stage.read_bytes())
    for pattern in BAKE_SOURCES:
        for src in sorted(REPO.glob(pattern)):
            h.update(src.read_bytes())
    # "raw": references are baked without the denoiser (before 2026-12-05 they were denoised,
    # the default since 2868392, which hid part of their error from the two-seed noise figure)
    h.update(json.dumps([resolution, samples, list(seeds), __version__, "raw"]).encode())
    return f"{stage.stem}-r{resolution}-s{samples}-{h.hexdigest()[:12]}"


def reference(stage: Path, *, resolution: int, samples: int, seeds=REFERENCE_SEEDS) -> dict:
    """The converged reference bake of a scene (cached on disk; computed when missing), baked
    without the denoiser: its noise figure is the difference of its two seeds, which a
    denoiser's residual (the same in both) would hide.

    returns : dict(sh {prim: (mean sh (h,w,3,9), covered)}, seeds_iz [(n,) lum I_z per seed],
    noise_rel (relative rms noise of the mean), seconds (to compute it), cached (bool)).
    The cache key is the stage file's bytes, the baker's sources (BAKE_SOURCES), resolution,
    samples, seeds and usdahd version, so a changed integrator recomputes its reference.
    """
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / (_cache_key(stage, resolution, samples, seeds) + ".npz")
    if path.is_file():
        data = np.load(path, allow_pickle=False)
        meta = json.loads(str(data["meta"]))
        runs = [
            {p: (data[f"s{k}_{i}"], data[f"m_{i}"]) for i, p in enumerate(meta["prims"])}
            for k in range(len(seeds))
        ]
        seconds, cached = meta["seconds"], True
    else:
        log(f"reference bake {stage.name}: {resolution}^2, {samples} spp x {len(seeds)} seeds")
        results = [
            bake_once(stage, resolution=resolution, samples=samples, seed=s, denoise=False)
            for s in seeds
        ]
        runs = [r["sh"] for r in results]
        seconds, cached = sum(r["seconds"] for r in results), False
        prims = list(runs[0])
        arrays = {f"m_{i}": runs[0][p][1] for i, p in enumerate(prims)}
        for k, run in enumerate(runs):
            arrays.update({f"s{k}_{i}": run[p][0] for i, p in enumerate(prims)})
        meta = {"prims": prims, "seconds": seconds, "samples": samples, "seeds": list(seeds)}
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, meta=json.dumps(meta), **arrays)
        tmp.replace(path)
    prims = list(runs[0])
    mean = {
        p: (np.mean([run[p][0] for run in runs], axis=0).astype(np.float32), runs[0][p][1])
        for p in prims
    }
    seeds_iz = [lum_iz(run) for run in runs]
    ref_iz = lum_iz(mean)
    scale = max(float(ref_iz.mean()), 1e-30)
    noise = float("nan")
    if len(runs) == 2:
        noise = float(np.sqrt(np.mean((seeds_iz[0] - seeds_iz[1]) ** 2)) / 2.0 / scale)
    return {
        "sh": mean,
        "noise_rel": noise,
        "seconds": seconds,
        "cached": cached,
        "samples": samples,
        "texels": int(ref_iz.size),
    }


def lum_iz(baked: dict) -> np.ndarray:
    """Luminance of I_z of every covered texel, prims in sorted order: (n,) float64."""
    parts = [shm.luminance(shm.iz(img[mask].astype(np.float64))) for img, mask in baked.values()]
    return np.concatenate(parts) if parts else np.zeros(0)


def error_stats(baked: dict, ref: dict) -> dict:
    """I_z luminance error of a bake against the reference (both read_baked_sh-like dicts)."""
    if list(baked) != list(ref):
        raise RuntimeError(f"prims differ from the reference: {list(baked)} vs {list(ref)}")
    y, r = lum_iz(baked), lum_iz(ref)
    if y.shape != r.shape:
        raise RuntimeError("covered texels differ from the reference bake")
    scale = max(float(r.mean()), 1e-30)
    d = y - r
    return {
        "rel_rmse": float(np.sqrt(np.mean(d**2)) / scale),
        "bias": float(d.mean() / scale),
        "p99": float(np.percentile(np.abs(d), 99) / scale),
    }


# ------------------------------------------------------------------------------------ sweep


def sweep(scenes, *, resolution, spps, configs, repeats, ref_samples) -> dict:
    """Section 1: every scene x config x samples-per-texel, ``repeats`` seeds each.

    returns : dict(rows [per scene/config/spp medians], references {scene: info}).
    """
    # Warm-up: numba kernels load from cache (or compile) once, outside every timing.
    bake_once(scenes[0], resolution=8, samples=8, seed=0)
    refs, rows = {}, []
    for stage in scenes:
        ref = reference(stage, resolution=resolution, samples=ref_samples)
        refs[stage.stem] = {k: v for k, v in ref.items() if k != "sh"}
        for cfg in configs:
            for spp in spps:
                runs = []
                for rep in range(repeats):
                    b = bake_once(
                        stage,
                        resolution=resolution,
                        samples=spp,
                        seed=1 + rep,
                        adaptive=cfg.adaptive,
                        denoise=cfg.denoise,
                    )
                    runs.append({**error_stats(b["sh"], ref["sh"]), **b})
                row = {
                    "scene": stage.stem,
                    "config": cfg.name,
                    "spp": spp,
                    "texels": runs[0]["texels"],
                    "repeats": repeats,
                }
                for key in ("seconds", "rays", "rays_saved", "rel_rmse", "bias", "p99"):
                    row[key] = median([r[key] for r in runs])
                rows.append(row)
                log(
                    f"bake {stage.stem:12} {cfg.name:17} {spp:5} spp: {row['seconds']:.2f}s "
                    f"rel RMSE {row['rel_rmse']:.4f}"
                )
    return {"rows": rows, "references": refs}


def pareto_plot(result: dict, name: str = "bake_pareto.png", plots_dir=PLOTS) -> Path:
    """Error vs wall time, one panel per scene, one line per configuration."""
    plt = pyplot()
    rows = result["rows"]
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    configs = list(dict.fromkeys(r["config"] for r in rows))
    cols = min(2, len(scenes))
    nrows = (len(scenes) + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 3.6 * nrows), squeeze=False)
    for ax, scene in zip(axes.flat, scenes):
        noise = result["references"][scene]["noise_rel"]
        for cfg in configs:
            pts = [  # in samples-per-texel order (rows are), so the line follows the sweep
                (r["seconds"], max(r["rel_rmse"], 1e-7), r["spp"])
                for r in rows
                if r["scene"] == scene and r["config"] == cfg
            ]
            if not pts:
                continue
            xs, ys, ss = zip(*pts)
            ax.plot(xs, ys, marker="o", ms=3, label=cfg)
            for x, y, s in (pts[0], pts[-1]):
                ax.annotate(str(s), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        if noise > 0:
            ax.axhline(noise, color="grey", ls=":", lw=1, label="reference noise")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(scene, fontsize=10)
        ax.set_xlabel("wall time per bake [s]")
        ax.set_ylabel("I_z relative RMSE")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(scenes) :]:
        ax.set_visible(False)
    fig.suptitle(
        "Bake: I_z error vs wall time (labels: samples per texel; errors of 0 drawn at 1e-7)",
        fontsize=10,
    )
    fig.tight_layout()
    return save_figure(fig, name, plots_dir)


def sweep_markdown(result: dict, *, resolution: int, ref_samples: int) -> str:
    refs = result["references"]
    ref_rows = [
        [
            s,
            info["texels"],
            f"2 x {info['samples']}",
            info["noise_rel"],
            f"{info['seconds']:.1f}" + (" (cached)" if info["cached"] else ""),
        ]
        for s, info in refs.items()
    ]
    parts = [
        md_table(
            ["scene", "texels", "reference spp (seeds)", "reference noise (rel.)", "ref. seconds"],
            ref_rows,
        ),
        "",
        md_table(
            [
                "scene",
                "config",
                "spp",
                "seconds",
                "rays",
                "Mrays/s",
                "rel. RMSE",
                "bias",
                "p99 |err|",
            ],
            [
                [
                    r["scene"],
                    r["config"],
                    r["spp"],
                    r["seconds"],
                    int(r["rays"]),
                    r["rays"] / r["seconds"] / 1e6,
                    r["rel_rmse"],
                    r["bias"],
                    r["p99"],
                ]
                for r in result["rows"]
            ],
        ),
    ]
    return "\n".join(parts)


# --------------------------------------------------------------------------------- skipping


def incremental(stage: Path, *, resolution: int, samples: int, repeats: int) -> dict:
    """Section 4a: bake, then bake the unchanged stage again into the same output (no --force).

    returns : dict(first_s, second_s, rays_first, rays_second, statuses_second) medians.
    """
    runs = []
    for rep in range(repeats):
        with tempfile.TemporaryDirectory(prefix="usdahd-bench-") as d:
            a = bake_once(
                stage, resolution=resolution, samples=samples, seed=1 + rep, out_dir=d, force=False
            )
            b = bake_once(
                stage, resolution=resolution, samples=samples, seed=1 + rep, out_dir=d, force=False
            )
            runs.append((a, b))
    return {
        "scene": stage.stem,
        "spp": samples,
        "first_s": median([a["seconds"] for a, _ in runs]),
        "second_s": median([b["seconds"] for _, b in runs]),
        "rays_first": median([a["rays"] for a, _ in runs]),
        "rays_second": median([b["rays"] for _, b in runs]),
        "statuses_second": runs[0][1]["statuses"],
        "repeats": repeats,
    }


def adaptive_savings(result: dict) -> list[dict]:
    """Section 4b: adaptive vs plain at equal spp, from the same sweep (same run, same seeds)."""
    rows = result["rows"]
    plain = {(r["scene"], r["spp"]): r for r in rows if r["config"] == "plain"}
    out = []
    for r in rows:
        p = plain.get((r["scene"], r["spp"]))
        if r["config"] != "adaptive" or p is None:
            continue
        out.append(
            {
                "scene": r["scene"],
                "spp": r["spp"],
                "rays_saved": r["rays_saved"],
                "rays_ratio": r["rays"] / max(p["rays"], 1),
                "time_ratio": r["seconds"] / max(p["seconds"], 1e-9),
                # None when plain sampling is exact (nothing to compare against)
                "error_ratio": r["rel_rmse"] / p["rel_rmse"] if p["rel_rmse"] > 1e-9 else None,
            }
        )
    return out


def skipping_markdown(inc: list[dict], adaptive: list[dict]) -> str:
    a = md_table(
        [
            "scene",
            "spp",
            "first bake [s]",
            "unchanged re-bake [s]",
            "seconds saved",
            "rays first",
            "rays re-bake",
            "re-bake prim status",
        ],
        [
            [
                r["scene"],
                r["spp"],
                r["first_s"],
                r["second_s"],
                f"{100 * (1 - r['second_s'] / r['first_s']):.0f} %",
                int(r["rays_first"]),
                int(r["rays_second"]),
                ", ".join(r["statuses_second"]),
            ]
            for r in inc
        ],
    )
    b = md_table(
        [
            "scene",
            "spp",
            "rays saved",
            "rays adaptive / plain",
            "time adaptive / plain",
            "I_z RMSE adaptive / plain",
        ],
        [
            [
                r["scene"],
                r["spp"],
                int(r["rays_saved"]),
                r["rays_ratio"],
                r["time_ratio"],
                r["error_ratio"],
            ]
            for r in adaptive
        ],
    )
    return a + "\n\n" + b
