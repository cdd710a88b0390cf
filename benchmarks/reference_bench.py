"""usdahd and Cycles on the same stages in one run: error against a converged truth vs time.

Usage (project environment; bpy interpreter from --bpy-python or $USDAHD_BPY_PYTHON;
matplotlib from the ``bench`` extra for the plot)::

    python benchmarks/reference_bench.py [--stages cornell_box pillar_room floor_lamp]
        [--resolution 32] [--samples 16 64 256 1024] [--truth-spp 4096]
        [--centre STAGE ...] [--centre-spp N] [--variant=--no-denoise ...] [--repeats N]
        [--warm] [--out docs/benchmarks/reference.md]

For each stage (samples/<name>.usda, lightmap UVs ``st``): usdahd bakes at each
``--samples`` count with otherwise default settings; Cycles bakes at the same counts; both
are compared with the truth (Cycles at ``--truth-spp``, seed 1, cached in
~/.cache/usdahd-reference/) on the texels of ``benchmarks.reference.compare`` (interior,
lit), less the texels whose usdahd value is not its estimate at the texel centre (filled
from neighbours, or sampled off the centre at a contact or rim: docs/texels.md) in any run,
for both renderers. Reported per run: overall luminance bias and relRMSE, and time:
usdahd's own bake time (its ``--json`` report, interpreter start-up excluded) and Cycles'
bake call (Blender start-up and scene set-up excluded); wall times of both processes are in
the JSON. The truth's own noise is Cycles' relRMSE at spp S scaled by sqrt(S / truth spp).

Writes the markdown section to ``--out``, the plot next to it (``reference_time_error.png``)
and the raw rows to ``reference_bench.json``; prints the markdown path on stdout.

The truths are the slow part (at 128^2 about 1.5 h per Cornell box on 2 cores) and need no
quiet machine: compute them first, untimed, with the same stages and resolution, e.g.
``nice python benchmarks/reference_bench.py --truths-only --stages ... --resolution 128``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks.reference import compare, export, runner  # noqa: E402
from usdahd.errors import UsageError  # noqa: E402


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def compile_package(pkg: Path | None = None) -> int:
    """Byte-compile usdahd's modules (``__pycache__`` beside them) before any timed run, as a
    user's ``pip install`` does for an installed package; returns how many were (re)written.
    An editable install under ``PYTHONDONTWRITEBYTECODE=1`` (this project's sessions) never
    writes them, so every ``usdahd bake`` process compiled its ~100 modules from source:
    0.45 s of CPU and ~1 s of wall at a load of 6 on a 32^2 floor_lamp bake (report seconds
    1.7 -> 0.78 s, docs/time-to-quality.md), time a user's command does not spend. Files that
    cannot be written (a read-only tree) are skipped: the run then times what it finds."""
    import compileall
    import contextlib
    import io

    pkg = REPO / "usdahd" if pkg is None else Path(pkg)
    before = {p: p.stat().st_mtime for p in pkg.rglob("__pycache__/*.pyc")}
    with contextlib.redirect_stdout(io.StringIO()):
        compileall.compile_dir(str(pkg), quiet=2)
    after = {p: p.stat().st_mtime for p in pkg.rglob("__pycache__/*.pyc")}
    return sum(1 for p, t in after.items() if before.get(p) != t)


def net_of_truth_noise(rel_rmse: float, truth_noise: float | None) -> float:
    """An error against a noisy truth with the truth's own noise taken out (independent noise
    adds in quadrature: measured^2 = error^2 + truth^2); 0 when the truth's noise dominates."""
    if truth_noise is None or not math.isfinite(truth_noise):
        return rel_rmse
    return math.sqrt(max(rel_rmse**2 - truth_noise**2, 0.0))


def centre_truth(scene, sf, spp: int, bpy: str) -> tuple[dict, float]:
    """A point-sampled truth (Cycles at each texel's centre point through the probes of
    benchmarks/reference/probes.py: the quantity usdahd estimates, docs/texels.md) and its own
    relRMSE noise.

    Two independent halves (seeds 1 and 2, ``spp // 2`` each, cached) are averaged; the noise
    of the mean is rms(A - B) / 2 relative to the mean (var(A - B) = 2 s^2, var((A+B)/2) = s^2/2).
    Returns ({mesh index: (h, w, 3)}, noise) with noise measured on the compared texels.
    """
    half = max(1, spp // 2)
    _, a, _ = runner.cached_cycles(scene, sf, half, seed=compare.TRUTH_SEED, bpy=bpy,
                                   point=True)  # fmt: skip
    _, b, _ = runner.cached_cycles(scene, sf, half, seed=compare.TRUTH_SEED + 1, bpy=bpy,
                                   point=True)  # fmt: skip
    truth = {i: 0.5 * (a[i] + b[i]) for i in a if i in b}
    res = compare.compare_images(scene.meshes, a, b, {}, half, half)  # (its truth_noise unused)
    diff = res["overall"].get("cycles", {}).get("rel_rmse")
    return truth, (None if diff is None else 0.5 * diff)


def _truths(stage: Path, baked: dict, results: dict, tmp: Path, truth_spp: int, centre: bool,
            centre_spp: int | None, bpy: str):  # fmt: skip
    """Export the scene of a usdahd bake of ``stage`` and get its Cycles truths (cached): returns
    (scene, scene file, box truth, whether it was cached, (point truth, its noise) or None
    when not ``centre``). The one place bench_stage and cache_truths build truths, so they
    share cache keys."""
    scene = export.export_stage(baked["layer"], baked=results)
    sf = export.save_scene(scene, tmp / "scene.npz")
    _log(f"{stage.name}: truth {truth_spp} spp")
    _, truth, hit = runner.cached_cycles(scene, sf, truth_spp, seed=compare.TRUTH_SEED, bpy=bpy)
    centred = None
    if centre:
        cs = centre_spp or truth_spp
        _log(f"{stage.name}: point-sampled truth {cs} spp")
        centred = centre_truth(scene, sf, cs, bpy)
    return scene, sf, truth, hit, centred


def cache_truths(stage: Path, resolution: int, truth_spp: int, bpy: str,
                 centre_spp: int | None = None) -> dict:  # fmt: skip
    """Compute (and cache) the Cycles truths :func:`bench_stage` judges ``stage`` against, untimed:
    the box truth at ``truth_spp`` and the point-sampled truth at ``centre_spp`` (default
    ``truth_spp``). At 128^2 the Cornell boxes' truths take about 1.5 h on 2 cores, so they can
    be computed beforehand, e.g. at a low priority beside other work, and the timed runs then
    need a quiet machine only for themselves. The scene is exported from a 4-spp usdahd bake
    (the cache key depends on the geometry, texel layout and probes, not on the baked values).
    Returns {"seconds", "box_cached"}."""
    with tempfile.TemporaryDirectory(prefix="usdahd-truths-") as tmp:
        tmp = Path(tmp)
        (tmp / "u").mkdir()
        baked = compare.bake_usdahd(stage, tmp / "u", resolution, None, ["--samples", "4"],
                                    quiet=True)  # fmt: skip
        t0 = time.perf_counter()
        hit = _truths(stage, baked, compare.usdahd_results(baked["layer"]), tmp, truth_spp,
                      True, centre_spp, bpy)[3]  # fmt: skip
        return {"seconds": time.perf_counter() - t0, "box_cached": hit}


def bench_stage(stage: Path, resolution: int, samples: list[int], truth_spp: int, bpy: str,
                centre: bool = True, centre_spp: int | None = None,
                variants: list[str] = (), repeats: int = 1, warm=None,
                cycles_samples: list[int] | None = None):  # fmt: skip
    """Rows {"stage", "renderer", "spp", "seconds", "seconds_runs", "load", "wall", "bias",
    "rel_rmse", "rel_rmse_net", "truth", "truth_noise"}.

    Each renderer is compared with the converged value of the quantity it estimates: Cycles
    with its own box-filtered truth (``truth_spp``); usdahd with :func:`centre_truth` (the
    point-sampled truth, ``centre_spp`` samples, default ``truth_spp``), or with the box truth
    too when ``centre`` is False. ``rel_rmse_net`` is ``rel_rmse`` net of the truth's noise.
    ``variants``: more usdahd runs at every sample count, each with these extra bake flags (a
    lever, e.g. ``"--no-denoise"``); their renderer is ``"usdahd <flags>"``.
    ``repeats``: every run is timed this many times, the repeats after the first interleaved
    (usdahd and Cycles in turn at each sample count, so a load change hits both);
    ``seconds_runs`` holds each repeat's time, ``seconds`` their median, ``load`` the 1-minute
    load average before each. Errors come from the first repeat (each renderer is seeded, so
    a repeat gives the same estimate).
    ``warm``: a :class:`benchmarks.reference.warm.WarmBaker`; every usdahd run is also timed
    as a bake call in that running process (renderer ``"<renderer> (warm)"``, ``"timing":
    "warm"``, the same errors: same code and seed), after one untimed bake of the stage.
    ``cycles_samples``: Cycles' sample counts when not ``samples`` (at 128^2 Cycles' runs
    below the 1024-spp target cost most of a stage's time and only draw its curve).
    """
    rows, box_usdahd = [], []
    judged, filled = [], {}  # (usdahd row, its images); {mesh index: (h, w) bool} left out
    ctruth = cnoise = None
    with tempfile.TemporaryDirectory(prefix="usdahd-refbench-") as tmp:
        tmp = Path(tmp)
        scene = sf = truth = None
        runs = [("usdahd", [], n) for n in samples]
        runs += [(f"usdahd {v}", shlex.split(v), n) for v in variants for n in samples]
        for i, (renderer, extra, n) in enumerate(runs):
            out = tmp / f"usdahd{i}"
            out.mkdir()
            load = os.getloadavg()[0]
            baked = compare.bake_usdahd(stage, out, resolution, None,
                                        ["--samples", str(n), *extra], quiet=True)  # fmt: skip
            results = compare.usdahd_results(baked["layer"])
            if scene is None:
                scene, sf, truth, _, centred = _truths(stage, baked, results, tmp, truth_spp,
                                                       centre, centre_spp, bpy)  # fmt: skip
                ctruth, cnoise = centred or (None, None)
            ours = {}
            for k, m in enumerate(scene.meshes):
                r = results.get(m["path"])
                if m["baked"] and r and r.get("sidecar"):
                    ours[k] = compare.usdahd_iz(r["record"])
                    _add_left_out(filled, k, baked.get("variance") or {}, m["path"], ours[k][1])
            secs = float(baked["report"].get("seconds", baked["seconds"]))
            rows.append(
                {"stage": stage.stem, "renderer": renderer, "spp": n, "seconds": secs,
                 "seconds_runs": [secs], "load": [load], "flags": extra,
                 "wall": baked["seconds"], "truth": "point" if ctruth else "box",
                 "truth_noise": cnoise}
            )  # fmt: skip
            judged.append((rows[-1], ours))
            _log(f"{stage.name}: {renderer} {n} spp {secs:.1f}s")
            if warm is not None:
                if i == 0:  # loads this stage's kernels and caches into the process
                    (tmp / "warmup").mkdir()
                    warm.bake(stage, tmp / "warmup" / "w.usda", resolution, ["--samples", "4"])
                secs_w = _warm_seconds(warm, stage, tmp / f"warm{i}", resolution,
                                       ["--samples", str(n), *extra])  # fmt: skip
                rows.append(dict(rows[-1], renderer=f"{renderer} (warm)", timing="warm",
                                 seconds=secs_w, seconds_runs=[secs_w], load=[load]))  # fmt: skip
                judged.append((rows[-1], ours))  # the same estimate (same code and seed)
                _log(f"{stage.name}: {renderer} (warm) {n} spp {secs_w:.2f}s")
        # every run judged on one set of texels: those usdahd estimates at the texel centre in
        # every run (texels any run filled from neighbours or sampled off the centre are left
        # out for both renderers: the point truth probes the centre; compare.py reports the
        # filled ones apart)
        for row, ours in judged:
            res = compare.compare_images(scene.meshes, ctruth or truth, {}, ours, row["spp"],
                                         truth_spp, filled=filled)  # fmt: skip
            ov = res["overall"].get("usdahd", {})
            row.update(ov, texels=res["overall"]["compared"], left_out=_left_out_count(filled))
            if ctruth is None:
                box_usdahd.append(row)  # its truth noise is known after Cycles' runs
            else:
                row["rel_rmse_net"] = net_of_truth_noise(ov.get("rel_rmse", math.nan), cnoise)
            _log(f"{stage.name}: {row['renderer']} {row['spp']} spp "
                 f"relRMSE {ov.get('rel_rmse', 0):.4f}")  # fmt: skip
        for n in cycles_samples or samples:
            load = os.getloadavg()[0]
            info, images = runner.run_cycles(sf, n, seed=compare.EQUAL_SEED, bpy=bpy, quiet=True)
            res = compare.compare_images(scene.meshes, truth, images, {}, n, truth_spp,
                                         filled=filled)  # fmt: skip
            ov = res["overall"].get("cycles", {})
            tn = res["overall"].get("truth_noise")
            net = net_of_truth_noise(ov.get("rel_rmse", math.nan), tn)
            rows.append({"stage": stage.stem, "renderer": "cycles", "spp": n,
                         "seconds": info["bake_seconds"], "seconds_runs": [info["bake_seconds"]],
                         "load": [load], "wall": info["wall_seconds"], **ov,
                         "texels": res["overall"]["compared"], "truth": "box",
                         "truth_noise": tn, "rel_rmse_net": net})  # fmt: skip
            _log(f"{stage.name}: cycles {n} spp {info['bake_seconds']:.1f}s "
                 f"relRMSE {ov.get('rel_rmse', 0):.4f}")  # fmt: skip
        for rep in range(1, repeats):
            _retime(rows, stage, resolution, sf, bpy, tmp / f"repeat{rep}", rep, warm)
    for r in rows:
        r["seconds"] = statistics.median(r["seconds_runs"])
    box_noise = [r["truth_noise"] for r in rows if r["renderer"] == "cycles" and r["truth_noise"]]
    for r in box_usdahd:  # the box truth's noise: its lowest estimate over Cycles' runs
        r["truth_noise"] = min(box_noise) if box_noise else None
        r["rel_rmse_net"] = net_of_truth_noise(r.get("rel_rmse", math.nan), r["truth_noise"])
    return rows


def _add_left_out(left: dict, k: int, variance: dict, path: str, covered) -> None:
    """OR into ``left[k]`` the texels of mesh ``k`` (prim ``path``, coverage ``covered`` (h, w)
    bool) whose value is not usdahd's estimate at the texel centre, the point the point truth
    probes (bakevar's ``invalid``: filled from neighbours, e.g. covered by another surface or
    inside geometry; and ``moved``: sampled off the centre, at a contact or a rim texel under a
    low cover; docs/texels.md)."""
    img = compare.texel_mask(variance, path, covered.shape, compare.NOT_AT_CENTRE)
    if img is None:
        return
    left[k] = img | left[k] if k in left else img


def _left_out_count(left: dict) -> int:
    """Texels left out of the comparison (:func:`_add_left_out`), over every mesh."""
    return int(sum(int(f.sum()) for f in left.values()))


def _warm_seconds(warm, stage: Path, out: Path, resolution: int, flags: list[str]) -> float:
    """One bake in the warm process: its report's seconds."""
    out.mkdir()
    baked = warm.bake(stage, out / f"{stage.stem}.lightmaps.usda", resolution, flags)
    return float(baked["report"].get("seconds", baked["seconds"]))


def _retime(rows: list[dict], stage: Path, resolution: int, sf, bpy: str, tmp: Path, rep: int,
            warm=None):  # fmt: skip
    """One more timing of every run in ``rows`` (one stage), interleaved by sample count:
    at each count usdahd's runs, then Cycles'; appends to ``seconds_runs`` and ``load``."""
    tmp.mkdir()
    for n in sorted({r["spp"] for r in rows}):
        for i, r in enumerate(x for x in rows if x["spp"] == n):
            load = os.getloadavg()[0]
            if r["renderer"] == "cycles":
                info, _ = runner.run_cycles(sf, n, seed=compare.EQUAL_SEED, bpy=bpy, quiet=True)
                secs = float(info["bake_seconds"])
            elif r.get("timing") == "warm":
                flags = ["--samples", str(n), *r["flags"]]
                secs = _warm_seconds(warm, stage, tmp / f"w{n}-{i}", resolution, flags)
            else:
                out = tmp / f"n{n}-{i}"
                out.mkdir()
                flags = ["--samples", str(n), *r["flags"]]
                baked = compare.bake_usdahd(stage, out, resolution, None, flags, quiet=True)
                secs = float(baked["report"].get("seconds", baked["seconds"]))
            r["seconds_runs"].append(secs)
            r["load"].append(load)
            _log(f"{stage.name}: repeat {rep + 1} {r['renderer']} {n} spp {secs:.1f}s "
                 f"(load {load:.1f})")  # fmt: skip


def _err(r: dict) -> float:
    """The error a row is judged by: net of its truth's noise when known."""
    return r.get("rel_rmse_net", r.get("rel_rmse"))


def time_to_quality(rows: list[dict], target_spp: int = 1024, repeat: int | None = None
                    ) -> list[dict]:  # fmt: skip
    """Per stage: the wall time each renderer needs to reach Cycles' error at ``target_spp``
    (errors net of the truth's noise where the rows have ``rel_rmse_net``).

    usdahd's time is interpolated between its two measured runs that bracket the target error,
    linearly in log(time) against log(relRMSE) (both fall as a power law in the samples);
    ``None`` when none of its runs reaches the target (bias-limited, or more samples needed).
    Returns [{"stage", "renderer", "target", "cycles_seconds", "usdahd_seconds", "ratio",
    "ratios"}], one per stage and usdahd renderer (``"usdahd"`` and each variant). Times are
    the rows' ``seconds`` (the median over repeats), or with ``repeat`` = k that repeat's own
    (``seconds_runs[k]``); ``ratios`` lists the ratio of every repeat (same-repeat times of
    both renderers, so its spread is the ratio's own over the run).
    """
    if repeat is not None:
        rows = [dict(r, seconds=r["seconds_runs"][repeat]) for r in rows]
    out = []
    for stage in dict.fromkeys(r["stage"] for r in rows):
        cyc = [r for r in rows if r["stage"] == stage and r["renderer"] == "cycles"]
        ref = next((r for r in cyc if r["spp"] == target_spp and "rel_rmse" in r), None)
        if ref is None:
            continue
        target = _err(ref)
        renderers = dict.fromkeys(
            r["renderer"] for r in rows
            if r["stage"] == stage and r["renderer"].startswith("usdahd")
        )  # fmt: skip
        for renderer in renderers:
            out.append(_reach(rows, stage, renderer, target, ref["seconds"]))
    if repeat is None:
        n_rep = min((len(r.get("seconds_runs") or [0]) for r in rows), default=1)
        per = [time_to_quality(rows, target_spp, k) for k in range(n_rep)] if n_rep > 1 else []
        for t in out:
            t["ratios"] = [
                x["ratio"] for p in per for x in p
                if x["stage"] == t["stage"] and x["renderer"] == t["renderer"]
            ]  # fmt: skip
    return out


def _reach(rows: list[dict], stage: str, renderer: str, target: float, cycles_s: float) -> dict:
    """One row of :func:`time_to_quality`: when ``renderer``'s runs on ``stage`` reach
    ``target`` (runs in order of samples: timings on a shared machine are noisier)."""
    ours = [
        (r["seconds"], _err(r))
        for r in sorted(rows, key=lambda r: r["spp"])
        if r["stage"] == stage and r["renderer"] == renderer and "rel_rmse" in r
    ]
    t_reach = None
    for (t0, e0), (t1, e1) in zip(ours, ours[1:], strict=False):
        if e0 <= target:
            t_reach = t0
            break
        if e1 <= target < e0 and t1 > 0 and t0 > 0 and e1 > 0:
            f = (math.log(e0) - math.log(target)) / (math.log(e0) - math.log(e1))
            t_reach = math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
            break
    if t_reach is None and ours and ours[-1][1] <= target:
        t_reach = ours[-1][0]
    return {
        "stage": stage,
        "renderer": renderer,
        "target": target,
        "cycles_seconds": cycles_s,
        "usdahd_seconds": t_reach,
        "ratio": None if t_reach is None else t_reach / cycles_s,
    }


def _secs(x: float) -> str:
    """Seconds with two significant decimals below 10 s (warm bakes take 0.1-1 s)."""
    return f"{x:.2f}" if x < 10 else f"{x:.1f}"


def markdown(rows: list[dict], args, plot_name: str | None) -> str:
    noise = {}
    for r in rows:
        if r["renderer"] == "cycles" and r.get("truth_noise") is not None:
            noise.setdefault(r["stage"], []).append(r["truth_noise"])
    centred = {r["stage"]: r for r in rows if r.get("truth") == "point"}
    boxed = sorted({r["stage"] for r in rows if r["renderer"] != "cycles"} - set(centred))
    n_rep = min((len(r.get("seconds_runs") or [0]) for r in rows), default=1)
    cmd = (
        f"python benchmarks/reference_bench.py --resolution {args.resolution} "
        f"--samples {' '.join(map(str, args.samples))} --truth-spp {args.truth_spp}"
    )
    cyc_spp = sorted({r["spp"] for r in rows if r["renderer"] == "cycles"})
    if cyc_spp and cyc_spp != sorted(set(args.samples)):
        cmd += f" --cycles-samples {' '.join(map(str, cyc_spp))}"
    if boxed:  # the default judges every stage against the point truth
        cmd += " --centre" + "".join(f" {s}" for s in sorted(centred))
    if n_rep > 1:
        cmd += f" --repeats {n_rep}"
    for ren in dict.fromkeys(r["renderer"] for r in rows):
        if ren.startswith("usdahd ") and not ren.endswith("(warm)"):
            cmd += f" --variant={ren.removeprefix('usdahd ')}"
    if any(r.get("timing") == "warm" for r in rows):
        cmd += " --warm"
    loads = [x for r in rows for x in r.get("load") or []]
    left_out = {r["stage"]: r["left_out"] for r in rows if r.get("left_out")}
    timing = (
        f" Times are the median of {n_rep} repeats, interleaved (usdahd and Cycles in turn at "
        "each sample count)" if n_rep > 1 else " Times are one run each"
    ) + (
        f"; 1-minute load average before the runs: median {statistics.median(loads):.1f} "
        f"(range {min(loads):.1f}-{max(loads):.1f})." if loads else "."
    )  # fmt: skip
    lines = [
        f"## usdahd vs Cycles at {args.resolution}² per mesh: error against a converged truth "
        "vs time",
        "",
        f"Generated by `{cmd}` ({time.strftime('%Y-%m-%d')}). Both renderers bake the same "
        f"stages at {args.resolution}² per mesh; usdahd with default settings except "
        f"`--samples`. Truth: Cycles at {args.truth_spp} spp (seed 1, cached); its own noise "
        "(relRMSE): "
        + ", ".join(f"{s} {100 * min(v):.2f} %" for s, v in noise.items())
        + ". Errors: Rec. 709 luminance of I_z on interior texels the truth lights "
        "(benchmarks/reference/compare.py), less the texels whose usdahd value is not its "
        "estimate at the texel centre that the point truth probes: filled from neighbours "
        "(covered by another surface, inside geometry) or sampled off the centre (contacts, "
        "rim texels under a low cover; docs/texels.md), left out for both renderers"
        + (
            " (" + ", ".join(f"{s} {n}" for s, n in left_out.items()) + " texels)"
            if left_out
            else ""
        )
        + "; *relRMSE* includes the truth's noise, *net* has it "
        "taken out in quadrature. Time: usdahd's bake (its report) and Cycles' bake call, both "
        "on the same 2 shared cores; *(warm)* rows time the same usdahd bake as a call in a "
        "running process (benchmarks/reference/warm.py: imports and numba kernel loading, "
        "about 0.5-0.9 s per `usdahd bake` process, excluded as Blender's start-up is for "
        "Cycles), the others the `usdahd bake` command (its modules byte-compiled first, as "
        "`pip install` does: compile_package). Texel convention: usdahd samples "
        "each texel at its centre "
        "(docs/texels.md), Cycles jitters over the texel (a box filter), so at a small light's "
        "hotspot or a hard shadow edge the two estimate different quantities and usdahd's "
        "error against Cycles' box truth stops falling with more samples. Each renderer is "
        "therefore judged against the converged value of what it estimates: Cycles against "
        "its box-filtered truth, usdahd against a point-sampled Cycles truth (Cycles bakes a "
        "probe triangle 1/100 texel wide at each texel's centre point, "
        "benchmarks/reference/probes.py; calibrated to 0.02 % on the analytic cases; two "
        "independent halves whose difference gives its noise: "
        + (
            ", ".join(
                f"{s} {100 * (r.get('truth_noise') or math.nan):.2f} %" for s, r in centred.items()
            )  # fmt: skip
            or "none here"
        )
        + ")."
        + timing,
        "",
        "| stage | renderer | truth | spp | time (s) | bias | relRMSE | net |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['stage']} | {r['renderer']} | {r.get('truth', 'box')} | {r['spp']} | "
            f"{_secs(r['seconds'])} | {100 * r.get('bias', math.nan):+.2f} % | "
            f"{100 * r.get('rel_rmse', math.nan):.2f} % | {100 * _err(r):.2f} % |"
        )
    if plot_name:
        lines += ["", f"![relRMSE vs time]({plot_name})"]
    ttq = time_to_quality(rows)
    if ttq:
        lines += [
            "",
            "### Time to Cycles' 1024-spp error",
            "",
            "Wall time each renderer needs to reach the error (net of the truth's noise) Cycles "
            "reaches at 1024 spp (usdahd's interpolated in log-log between its measured runs; "
            '"not reached" when no run of it gets there: bias-limited or more samples needed). '
            "Issue 43's targets: a ratio <= 0.1 at 128² and <= 0.3 at 32² per mesh (issue 16's "
            "was <= 0.2).",
            "",
            "| stage | usdahd | Cycles 1024-spp relRMSE | Cycles (s) | usdahd (s) | ratio | "
            "ratio per repeat |",
            "|---|---|---|---|---|---|---|",
        ]
        for t in ttq:
            ours = "not reached" if t["usdahd_seconds"] is None else _secs(t["usdahd_seconds"])
            ratio = "-" if t["ratio"] is None else f"{t['ratio']:.2f}"
            reps = ", ".join("-" if x is None else f"{x:.2f}" for x in t.get("ratios") or [])
            flags = t["renderer"].removeprefix("usdahd").strip() or "defaults"
            lines.append(
                f"| {t['stage']} | {flags} | {100 * t['target']:.2f} % | "
                f"{_secs(t['cycles_seconds'])} | {ours} | {ratio} | {reps or '-'} |"
            )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> bool:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import NullFormatter
    except ImportError:
        _log("matplotlib not installed (pip install -e benchmarks/): no plot")
        return False
    stages = list(dict.fromkeys(r["stage"] for r in rows))
    cols = min(len(stages), 4) or 1
    nrow = math.ceil(len(stages) / cols) or 1
    fig, axes = plt.subplots(nrow, cols, figsize=(3.2 * cols, 2.7 * nrow), squeeze=False)
    style = {"cycles": ("s--", "C0"), "usdahd": ("o-", "C1")}
    for ax, s in zip(axes.ravel(), stages, strict=False):
        present = dict.fromkeys(r["renderer"] for r in rows if r["stage"] == s)
        for j, ren in enumerate(present):
            mk, col = style.get(ren, ("^:", f"C{2 + j}"))
            pts = [
                (r["seconds"], _err(r))
                for r in sorted(rows, key=lambda r: r["spp"])
                if r["stage"] == s and r["renderer"] == ren and "rel_rmse" in r
            ]
            pts = [(t, e) for t, e in pts if t > 0 and e > 0]
            if pts:
                ax.plot(*zip(*pts), mk, color=col, label=ren, markersize=4)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(s, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.yaxis.set_minor_formatter(NullFormatter())
    for ax in axes.ravel()[len(stages) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    spp = ", ".join(map(str, sorted({r["spp"] for r in rows})))
    fig.supxlabel(f"bake time (s, 2 shared cores; points: {spp} spp)", fontsize=9)
    fig.supylabel("relRMSE of I_z vs truth (net of its noise)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


#: The sizes, stages' sample counts and repeats of the ``reference`` section of
#: benchmarks/run.py, per plan: one entry per lightmap size, all run in the one section (issue 43:
#: time to quality at 128² and at 32² per mesh, the worst ratio of each in the summary).
SECTION_PLANS = {
    "full": [
        # 128^2 per mesh, issue 16's own resolution. Cycles runs only at 256 and 1024 spp (its
        # 1024-spp error is the target; below it Cycles' runs cost most of a stage's time and
        # only draw its curve); usdahd from 4.
        {
            "resolution": 128,
            "samples": [4, 16, 64, 256],
            "cycles_samples": [256, 1024],
            "truth_spp": 4096,
            "variants": [],
            "repeats": 2,
            "warm": True,
        },
        # 32^2 per mesh: Cycles' 1024-spp bake takes 1-10 s here, so per-bake fixed costs
        # decide the ratio (docs/time-to-quality.md); was a separate run (docs/benchmarks-32.md).
        # 512 too: with a fixed cost a the time a + b s is convex in log-log against the error
        # c s^-1/2, so the chord between 256 and 1024 (where Cycles' 1024-spp error falls at
        # this size) overstates the time between them; a run there measures it instead.
        {
            "resolution": 32,
            "samples": [16, 64, 256, 512, 1024],
            "cycles_samples": [256, 1024],
            "truth_spp": 4096,
            "variants": [],
            "repeats": 2,
            "warm": True,
        },
    ],
    "quick": [
        {"resolution": 16, "samples": [16, 64, 256], "truth_spp": 1024, "variants": []},
        {"resolution": 8, "samples": [16, 64, 256], "truth_spp": 1024, "variants": []},
    ],
}
#: Issue 16 judges every lit stage of samples/ (open_plane is lit by a uniform dome, exact for
#: both renderers) and the shared Cornell boxes (``../shared/scenes``, skipped when absent).
SECTION_STAGES = (
    "cornell_box",
    "pillar_room",
    "floor_lamp",
    "exterior_sun_sky",
    "emissive_only",
    "indirect_ceiling",
    "normal_wall",
    "stretched_boxes",
)
SHARED_STAGES = (
    "scenes/cornell_box/cornell-box.usda",
    "scenes/cornell_box/cornell-box_rectlight.usda",
)


def section_stages(names: list[str] | None = None) -> list[Path]:
    """The stage files of the ``reference`` section: SECTION_STAGES, then the SHARED_STAGES
    present beside the checkout; ``names`` (file stems, e.g. ``cornell_box``,
    ``cornell-box_rectlight``) keeps only those. Raises UsageError naming the choices for an
    unknown or absent name, before any work starts."""
    stages = [REPO / "samples" / f"{name}.usda" for name in SECTION_STAGES]
    stages += [p for p in (REPO.parent / "shared" / s for s in SHARED_STAGES) if p.is_file()]
    if names is None:
        return stages
    by_name = {p.stem: p for p in stages}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise UsageError(
            f"unknown reference stage {', '.join(unknown)}; choose from {', '.join(by_name)} "
            "(the shared ones need ../shared/scenes beside the checkout)"
        )
    return [by_name[n] for n in dict.fromkeys(names)]


def stage_paths(names: list[str]) -> list[Path]:
    """``--stages`` as files: a ``.usda`` path as given, else a name of :func:`section_stages`
    (the samples and the shared Cornell boxes, e.g. ``cornell-box_rectlight``) or of
    ``samples/``. Raises UsageError naming the missing file."""
    known = {p.stem: p for p in section_stages()}
    paths = []
    for s in names:
        path = Path(s) if s.endswith(".usda") else known.get(s, REPO / "samples" / f"{s}.usda")
        if not path.is_file():
            raise UsageError(f"{path}: no such stage")
        paths.append(path)
    return paths


def run_section(
    plan_name: str, plots_dir: Path, bpy_python: str | None = None, stages: list[str] | None = None
) -> dict:
    """The ``reference`` section of benchmarks/run.py: both renderers on SECTION_STAGES (or the
    ``stages`` named, see :func:`section_stages`) at every size of ``SECTION_PLANS[plan_name]``.

    Returns {"sizes": [{"rows", "args", "plot"}, ...]} (one per size, in plan order; every row
    also has its "resolution") or {"skipped": why} when no bpy interpreter is set up (the
    section then says how to set one up instead of failing the whole run).
    """
    paths = section_stages(stages)
    try:
        bpy = runner.find_bpy(bpy_python)
    except runner.ReferenceUnavailable as exc:
        return {"skipped": str(exc)}
    _log(f"usdahd byte-compiled ({compile_package()} modules written), as pip install does")
    from benchmarks.reference.warm import WarmBaker

    sizes = []
    cfgs = SECTION_PLANS[plan_name]
    warm = WarmBaker() if any(c.get("warm") for c in cfgs) else None
    try:
        for cfg in cfgs:
            rows = []
            for path in paths:
                rows += bench_stage(path, cfg["resolution"],
                                    cfg["samples"], cfg["truth_spp"], bpy,
                                    variants=cfg["variants"],
                                    repeats=cfg.get("repeats", 1),
                                    warm=warm if cfg.get("warm") else None,
                                    cycles_samples=cfg.get("cycles_samples"))  # fmt: skip
            for r in rows:
                r["resolution"] = cfg["resolution"]
            plots_dir.mkdir(parents=True, exist_ok=True)
            png = plots_dir / f"reference_time_error_{cfg['resolution']}.png"
            sizes.append(
                {"rows": rows, "args": dict(cfg), "plot": png.name if plot(rows, png) else None}
            )
    finally:
        if warm is not None:
            warm.close()
    return {"sizes": sizes}


def size_results(result: dict) -> list[dict]:
    """The per-size results of :func:`run_section` ({"rows", "args", "plot"} each); a result
    of one size (before issue 43: {"rows", "args", "plot"} at the top) as a list of one."""
    if "sizes" in result:
        return result["sizes"]
    return [result] if "rows" in result else []


def section(result: dict, plots_rel: str = "benchmarks") -> str:
    """Markdown of :func:`run_section`'s result (headings one level below the page's): one
    subsection per size."""
    if "skipped" in result:
        return (
            "## usdahd vs Cycles: error against a converged truth vs time\n\n"
            f"Not run: {result['skipped']}\n"
        )
    parts = []
    for one in size_results(result):
        plot_name = f"{plots_rel}/{one['plot']}" if one.get("plot") else None
        parts.append(markdown(one["rows"], argparse.Namespace(**one["args"]), plot_name))
    return "\n".join(parts)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--stages", nargs="+", default=["cornell_box", "pillar_room", "floor_lamp"])
    p.add_argument("--resolution", type=int, default=32)
    p.add_argument("--samples", type=int, nargs="+", default=[16, 64, 256, 1024])
    p.add_argument("--truth-spp", type=int, default=4096)
    p.add_argument("--cycles-samples", type=int, nargs="+", metavar="N",
                   help="Cycles' sample counts (default: --samples); must include 1024, the "
                        "target")  # fmt: skip
    p.add_argument("--centre", nargs="*", metavar="STAGE",
                   help="only these stages judge usdahd against the point-sampled truth, the "
                        "others against Cycles' box truth (default: every stage; none: "
                        "--centre with no stage)")  # fmt: skip
    p.add_argument("--centre-spp", type=int, help="samples of the point-sampled truth "
                   "(default: --truth-spp)")  # fmt: skip
    p.add_argument("--variant", action="append", default=[], metavar="FLAGS",
                   help="more usdahd runs with these bake flags (a lever), e.g. "
                        "--variant=--no-denoise; repeatable")  # fmt: skip
    p.add_argument(
        "--repeats",
        type=int,
        default=1,
        help="time every run this many times, interleaved (medians and spreads)",
    )
    p.add_argument("--warm", action="store_true",
                   help="also time every usdahd run as a bake call in a running process "
                        "(benchmarks/reference/warm.py), as Cycles' bake is timed")  # fmt: skip
    p.add_argument("--truths-only", action="store_true",
                   help="only compute (cache) the stages' Cycles truths, untimed, and exit: "
                        "run it beforehand (e.g. with nice) so the timed runs find them "
                        "cached")  # fmt: skip
    p.add_argument("--store", action="store_true",
                   help="with --truths-only: also keep the truths in the repository "
                        "(benchmarks/reference/truths/, compressed), read after the user "
                        "cache, so a new machine finds them")  # fmt: skip
    p.add_argument("--bpy-python")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "benchmarks" / "reference.md")
    p.add_argument("--from-json", type=Path, help="rewrite table + plot from saved rows")
    a = p.parse_args(argv)
    if a.from_json:
        rows = json.loads(a.from_json.read_text())
        a.out.parent.mkdir(parents=True, exist_ok=True)
        png = a.out.with_name("reference_time_error.png")
        has_plot = plot(rows, png)
        a.out.write_text(markdown(rows, a, png.name if has_plot else None), encoding="utf-8")
        print(a.out)
        return 0
    if a.store and not a.truths_only:
        print("error: --store keeps the truths that --truths-only computes; add --truths-only",
              file=sys.stderr)  # fmt: skip
        return 2
    if a.cycles_samples and 1024 not in a.cycles_samples:
        print("error: --cycles-samples must include 1024 (the target's sample count)",
              file=sys.stderr)  # fmt: skip
        return 2
    try:
        stages = stage_paths(a.stages)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        bpy = runner.find_bpy(a.bpy_python)
    except runner.ReferenceUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.truths_only:
        for st in stages:
            _log(f"{st.name}: truths at {a.resolution}^2 ...")
            first = len(runner.files_used)
            got = cache_truths(st, a.resolution, a.truth_spp, bpy, a.centre_spp)
            kept = runner.store(runner.files_used[first:]) if a.store else []
            print(f"{st.name}: truths in {got['seconds']:.0f} s"
                  f"{' (box truth cached)' if got['box_cached'] else ''}"
                  f"{f', {len(kept)} file(s) stored' if a.store else ''}")  # fmt: skip
        return 0
    rows = []
    _log(f"usdahd byte-compiled ({compile_package()} modules written), as pip install does")
    from benchmarks.reference.warm import WarmBaker

    warm = WarmBaker() if a.warm else None
    try:
        for st in stages:
            centre = a.centre is None or st.stem in a.centre
            rows += bench_stage(st, a.resolution, a.samples, a.truth_spp, bpy, centre,
                                a.centre_spp, a.variant, a.repeats, warm,
                                a.cycles_samples)  # fmt: skip
            # rows so far, so an interrupted run keeps its finished stages (--from-json redraws)
            a.out.parent.mkdir(parents=True, exist_ok=True)
            a.out.with_name("reference_bench.json").write_text(json.dumps(rows, indent=1))
    finally:
        if warm is not None:
            warm.close()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    png = a.out.with_name("reference_time_error.png")
    has_plot = plot(rows, png)
    a.out.write_text(markdown(rows, a, png.name if has_plot else None), encoding="utf-8")
    a.out.with_name("reference_bench.json").write_text(json.dumps(rows, indent=1))
    print(a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
