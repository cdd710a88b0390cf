"""usdahd vs Cycles on one stage, per mesh: bias, relRMSE, Cycles' own noise, wall times.

Usage (project environment, from the repository root)::

    python -m benchmarks.reference compare samples/pillar_room.usda --resolution 64 \
        [--uv st] [--usdahd-args "--samples 1024"] [--spp N] [--truth-spp 4096] [--json]
    python -m benchmarks.reference compare samples/*.usda --resolution 32   # + a summary
    python -m benchmarks.reference bake STAGE --resolution 64 --spp 1024 -o iz.npz
    python -m benchmarks.reference summary A.json B.json ... [--plot PNG]

``compare`` bakes the stage with usdahd from the current tree (``python -m usdahd bake`` into
a temporary folder; the source is never written), exports the *baked* stage (its output layer
sublayers the source, so UVs the bake unwrapped are used) with ``export.py``, bakes the truth
(Cycles at ``--truth-spp``, seed 1, cached) and Cycles at equal samples per texel (``--spp``,
default: usdahd's samples, seed 0, cached), and compares per mesh on the texels that
the truth lights (covered, luminance above ``LIT_FRACTION`` of the stage's 99th percentile)
**and whose 8 neighbours it lights too**: chart-border texels are left out (usdahd samples
them at the closest point of the triangle, Cycles inside the texel) and so are texels next to
unlit ones, i.e. where a box stands on a floor (Cycles averages its jittered texel footprint
across the contact edge, usdahd samples the centre or fills texels inside geometry). Those
"contact" texels (lit, interior to the chart, next to an unlit texel) are reported apart per
mesh (``contact``), where a leak along a contact edge would show:

- ``bias = mean(Y_x) / mean(Y_truth) - 1`` (Rec. 709 luminance of I_z; ratio of means, so
  dark texels do not dominate);
- ``relRMSE = sqrt(mean((Y_x - Y_truth)^2)) / mean(Y_truth)``;
- for x = usdahd and x = Cycles at equal spp; ``truth noise`` = the truth's own relRMSE,
  included in both figures above: with independent noise, Cycles' measured relRMSE^2 =
  s^2 (1 + r) for r = spp / truth spp, so the truth's is relRMSE * sqrt(r / (1 + r)).

Exit 0 when the comparison ran (the figures are results, not a verdict), 2 on bad usage or a
missing bpy interpreter / failed bake.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import usdahd.usd  # noqa: F401  (registers the AhdLightmapAPI plugin before pxr builds its registry)
from benchmarks.reference import bakevar, export, runner

LUMA = np.array([0.2126, 0.7152, 0.0722])
#: A texel is "lit" when the truth's luminance exceeds this fraction of the stage's 99th
#: percentile (texels the reference does not light carry no relative error information).
LIT_FRACTION = 1e-3
TRUTH_SEED = 1
EQUAL_SEED = 0
REPO = Path(__file__).resolve().parents[2]


class CompareError(Exception):
    """Bad usage or a failed step (message says which and how to fix)."""


def _log(msg: str, quiet: bool = False) -> None:
    if not quiet:
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- usdahd side


def bake_usdahd(stage: Path, out_dir: Path, resolution: int | None, uv: str | None,
                extra: list[str], quiet: bool = False) -> dict:  # fmt: skip
    """``python -m usdahd bake`` into out_dir; returns {"report", "seconds", "layer"}."""
    layer = out_dir / f"{stage.stem}.lightmaps.usda"
    var_file = out_dir / "bake_variance.npz"
    # usdahd's own CLI, keeping the integrator's per-texel variances (bakevar.py)
    cmd = [sys.executable, "-m", "benchmarks.reference.bakevar", str(var_file), str(stage),
           "-o", str(layer), "--json"]  # fmt: skip
    if resolution:
        cmd += ["--resolution", str(resolution)]
    if uv:
        cmd += ["--uv", uv]
    cmd += extra
    _log("usdahd bake " + " ".join(shlex.quote(c) for c in cmd[4:]), quiet)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    seconds = time.perf_counter() - t0
    if r.returncode not in (0, 1) or not layer.is_file():
        tail = "\n".join(r.stderr.strip().splitlines()[-10:])
        raise CompareError(f"usdahd bake failed (exit {r.returncode}):\n{tail}")
    try:
        report = json.loads(r.stdout)
    except json.JSONDecodeError:
        report = {}
    variance = bakevar.read(var_file) if var_file.is_file() else {}
    return {"report": report, "seconds": seconds, "layer": layer, "variance": variance}


def usdahd_results(layer: Path) -> dict:
    """{prim path: {"uv", "resolution", "sidecar", "samples"}} from a bake's output layer."""
    from pxr import Usd

    from usdahd.usd import plugin, schema

    plugin.register()
    stage = Usd.Stage.Open(str(layer))
    out = {}
    # mesh records and instance entries (keyed by the copy's path: a scenegraph copy's
    # instance proxy, which export_stage traverses)
    for path, res in schema.stage_records(stage).items():
        out[path] = {
            "uv": res.uv_primvar,
            "resolution": list(res.resolution),
            "sidecar": res.textures.get(schema.SIDECAR_ROLE),
            "samples": int((res.settings or {}).get("samples") or 0),
            "record": res,
        }
    return out


def usdahd_iz(record) -> tuple[np.ndarray, np.ndarray]:
    """I_z (h, w, 3) float64 and coverage (h, w) bool from a bake record's float32 SH sidecar:
    the record's rectangle of its atlas page (``atlas:scaleOffset``), or its own file with
    ``--atlas off``. A path (str) reads the whole file (a sidecar that is the record's own)."""
    from usdahd import sidecar
    from usdahd.numerics import sh as shm

    if isinstance(record, (str, Path)):
        px = sidecar.read(str(record))
    else:
        px = sidecar.read_record(record)
    sh, covered = sidecar.split(np.asarray(px, np.float64))
    return shm.iz(sh), covered


# ------------------------------------------------------------------------------- stats


def interior(mask: np.ndarray) -> np.ndarray:
    """Texels of ``mask`` (h, w) whose 8 neighbours are in ``mask`` too."""
    p = np.pad(mask, 1, constant_values=False)
    out = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out &= p[1 + dy : 1 + dy + mask.shape[0], 1 + dx : 1 + dx + mask.shape[1]]
    return out


def error_stats(x: np.ndarray, truth: np.ndarray) -> dict:
    """Luminance bias and relRMSE of x against truth over the same texels (n, 3)."""
    yx, yt = x @ LUMA, truth @ LUMA
    mt = float(yt.mean()) if len(yt) else float("nan")
    if not len(yt) or mt <= 0:
        return {"bias": float("nan"), "rel_rmse": float("nan")}
    return {
        "bias": float(yx.mean()) / mt - 1.0,
        "rel_rmse": float(np.sqrt(np.mean((yx - yt) ** 2))) / mt,
    }


def truth_noise(rel_rmse: float, spp: int, truth_spp: int) -> float:
    """The truth's own relRMSE from Cycles-at-spp's measured relRMSE against it (noise of
    variance proportional to 1/spp, independent seeds)."""
    r = spp / truth_spp
    return rel_rmse * math.sqrt(r / (1 + r))


def bake_mean_error(variance, lit: np.ndarray, mean_truth: float) -> dict | None:
    """The bake's own standard error on a mesh's bias (relative to the truth's mean) from the
    integrator's per-texel variances of its I_z luminance ``variance`` = (s2 (h, w), halves
    (h, w)) (:mod:`benchmarks.reference.bakevar`; NaN: not traced) over the ``lit`` texels:
    texels' noise is independent (one random stream per texel chunk, no shared samples), so
    the variance of the mean is sum(var) / n^2. Both per-texel figures are upper bounds of the
    stratified estimate's variance with one (halves) or many (s2) degrees of freedom per texel;
    summed over a mesh both are well determined and the smaller is used (``se``; ``se_s2`` and
    ``se_halves`` kept). The undenoised estimate's error: the denoiser keeps each chart's sum
    (usdahd.bake.denoise), so the denoised mean scatters as much. None when any lit texel
    has no variance or the truth's mean is not positive."""
    n = int(lit.sum())
    if variance is None or not n or not mean_truth > 0:
        return None
    out = {}
    for name, img in zip(("s2", "halves"), variance, strict=True):
        v = np.asarray(img, np.float64)[lit]
        if not np.isfinite(v).all():
            return None
        out[f"se_{name}"] = float(np.sqrt(v.sum())) / n / mean_truth
    out["se"] = min(out["se_s2"], out["se_halves"])
    return out


def _texel_xy(variance: dict, path: str, shape):
    """(record, its (n, 2) int texel coordinates) of one prim from ``bakevar.read``, or None
    when the prim has none or a coordinate lies outside ``shape`` (h, w, ...)."""
    v = variance.get(path)
    if v is None:
        return None
    xy = np.asarray(v["xy"], np.int64)
    h, w = shape[:2]
    if not len(xy) or xy[:, 0].max() >= w or xy[:, 1].max() >= h or xy.min() < 0:
        return None
    return v, xy


def texel_mask(variance: dict, path: str, shape, names=("invalid",)):
    """(h, w) bool image of one prim's texels flagged in any of its ``bakevar.read`` masks
    ``names`` (e.g. ``invalid``: filled from neighbours; ``moved``: sampled off the centre; a
    mask missing or empty in an older file flags nothing), or None (see :func:`_texel_xy`)."""
    got = _texel_xy(variance, path, shape)
    if got is None:
        return None
    v, xy = got
    flag = np.zeros(len(xy), bool)
    for name in names:
        m = np.asarray(v.get(name, np.zeros(0, bool)), bool)
        if m.shape == flag.shape:
            flag |= m
    img = np.zeros(shape[:2], bool)
    img[xy[:, 1], xy[:, 0]] = flag
    return img


#: Texels whose value is not usdahd's estimate at the texel centre, the point the point truth
#: probes: filled from neighbours (``invalid``) or sampled off the centre (``moved``, contacts
#: and rim texels under a low cover). Reported apart here, left out by the sample benchmark
#: (``benchmarks/reference_bench.py``): one rule for both.
NOT_AT_CENTRE = ("invalid", "moved")


def variance_images(variance: dict, path: str, shape):
    """(s2, halves) (h, w) images (NaN where not traced) and the (h, w) bool image of texels
    not estimated at their centre (:data:`NOT_AT_CENTRE`) of one prim from ``bakevar.read``,
    or None."""
    got = _texel_xy(variance, path, shape)
    if got is None:
        return None
    v, xy = got
    out = []
    for name in ("s2", "halves"):
        img = np.full(shape[:2], np.nan)
        img[xy[:, 1], xy[:, 0]] = v[name]
        out.append(img)
    return (out[0], out[1]), texel_mask(variance, path, shape, NOT_AT_CENTRE)


def compare_images(meshes, truth, equal, ours, spp: int, truth_spp: int,
                   variance: dict | None = None, filled: dict | None = None) -> dict:  # fmt: skip
    """Per-mesh and overall figures. truth/equal: {mesh index: (h, w, 3)}; ours:
    {mesh index: (iz (h, w, 3), covered (h, w))}; variance: {mesh index: (s2, halves)} (h, w)
    per-texel variances of usdahd's I_z luminance (:func:`bake_mean_error`; a mesh's row gets
    ``bake_se``); filled: {mesh index: (h, w) bool} texels usdahd did not estimate at their
    centre (:data:`NOT_AT_CENTRE`: filled from neighbours inside geometry or covered, sampled
    off the centre at contacts): reported apart (``filled``), as the contact texels are.
    Returns {"meshes": [...], "overall": {...}}."""
    variance = variance or {}
    filled = filled or {}
    all_lum = np.concatenate(
        [(np.nan_to_num(truth[k].reshape(-1, 3)) @ LUMA) for k in truth]
    ) if truth else np.zeros(0)  # fmt: skip
    p99 = float(np.percentile(all_lum, 99)) if all_lum.size else 0.0
    rows, pool = [], {"t": [], "c": [], "u": [], "v": []}
    for k, m in enumerate(meshes):
        if not m["baked"] or k not in truth:
            continue
        t = truth[k]
        cov = np.isfinite(t[..., 0])
        bright = cov & (np.nan_to_num(t) @ LUMA > LIT_FRACTION * p99)
        # Compared: lit texels whose 8 neighbours are lit too (so not on a chart border, and
        # not next to where the surface is covered by contact, e.g. under a box: Cycles
        # averages its texel footprint there, usdahd samples the centre or fills it).
        lit = interior(bright)
        contact = interior(cov) & bright & ~lit
        fill = filled.get(k)
        if fill is not None and fill.shape == lit.shape:
            fill = fill & lit
            lit = lit & ~fill
        row = {"path": m["path"], "resolution": m["resolution"], "covered": int(cov.sum()),
               "compared": int(lit.sum())}  # fmt: skip
        if k in ours:
            iz, ucov = ours[k]
            if iz.shape != t.shape:
                row["error"] = f"usdahd lightmap is {iz.shape[1]}x{iz.shape[0]}, reference " \
                               f"{t.shape[1]}x{t.shape[0]}"  # fmt: skip
                rows.append(row)
                continue
            missing = lit & ~ucov
            row["usdahd_uncovered"] = int(missing.sum())
            lit &= ucov
            row["compared"] = int(lit.sum())
            row["usdahd"] = error_stats(iz[lit], t[lit])
            pool["u"].append(iz[lit])
            se = bake_mean_error(variance.get(k), lit, float((t[lit] @ LUMA).mean())) \
                if lit.any() else None  # fmt: skip
            if se is not None:
                row["bake_se"] = se["se"]
                row["bake_se_bounds"] = {"s2": se["se_s2"], "halves": se["se_halves"]}
                pool["v"].append(np.stack([variance[k][0][lit], variance[k][1][lit]]))
            contact &= ucov
            if contact.any():  # reported apart: where leaks at contact edges would show
                row["contact"] = {"texels": int(contact.sum()),
                                  **error_stats(iz[contact], t[contact])}  # fmt: skip
            if fill is not None and (fill & ucov).any():  # the fill rule's, not an estimate
                f = fill & ucov
                row["filled"] = {"texels": int(f.sum()), **error_stats(iz[f], t[f])}
        c = equal.get(k)
        if c is not None:
            ok = lit & np.isfinite(c[..., 0])
            row["cycles"] = error_stats(c[ok], t[ok])
        pool["t"].append(t[lit])
        pool["c"].append(c[lit] if c is not None else t[lit] * np.nan)
        rows.append(row)
    overall = {"compared": int(sum(len(a) for a in pool["t"]))}
    if pool["t"]:
        tt = np.concatenate(pool["t"])
        if pool["u"] and len(pool["u"]) == len(pool["t"]):
            overall["usdahd"] = error_stats(np.concatenate(pool["u"]), tt)
        if pool["v"] and sum(v.shape[1] for v in pool["v"]) == len(tt):  # every texel has one
            vv = np.concatenate(pool["v"], axis=1)
            se = bake_mean_error((vv[0], vv[1]), np.ones(len(tt), bool), float((tt @ LUMA).mean()))
            if se is not None:
                overall["bake_se"] = se["se"]
        cc = np.concatenate(pool["c"])
        if np.isfinite(cc).all():
            overall["cycles"] = error_stats(cc, tt)
    c_rel = overall.get("cycles", {}).get("rel_rmse")
    if c_rel is not None and truth_spp:
        overall["truth_noise"] = truth_noise(c_rel, spp, truth_spp)
    for row in rows:
        cr = row.get("cycles", {}).get("rel_rmse")
        if cr is not None:
            row["truth_noise"] = truth_noise(cr, spp, truth_spp)
        ur = row.get("usdahd", {}).get("rel_rmse")
        if cr and ur is not None:
            row["rmse_ratio"] = ur / cr
    if overall.get("usdahd") and overall.get("cycles") and overall["cycles"]["rel_rmse"]:
        overall["rmse_ratio"] = overall["usdahd"]["rel_rmse"] / overall["cycles"]["rel_rmse"]
    return {"meshes": rows, "overall": overall}


def _pct(v) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{100 * v:+.2f} %"


def _pct0(v) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{100 * v:.2f} %"


def table(result: dict) -> str:
    """Markdown table of a :func:`run_compare` result."""
    r = result
    lines = [
        f"stage `{r['stage']}`, usdahd `{' '.join(r['usdahd_args'])}` ({r['usdahd_samples']} "
        f"spp), Cycles {r['spp']} spp vs truth {r['truth_spp']} spp "
        f"(truth noise ~{_pct0(r['overall'].get('truth_noise'))} relRMSE)",
        "",
        "| mesh | texels | usdahd bias | usdahd relRMSE | Cycles bias | Cycles relRMSE | ratio "
        "| contact texels: usdahd bias | filled or moved texels: usdahd bias | bake SE of mean |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m in r["meshes"] + [dict(r["overall"], path="**overall**")]:
        u, c = m.get("usdahd", {}), m.get("cycles", {})
        ratio = m.get("rmse_ratio")
        ct, fl = m.get("contact"), m.get("filled")
        ct = "—" if not ct else f"{ct['texels']}: {_pct(ct['bias'])}"
        fl = "—" if not fl else f"{fl['texels']}: {_pct(fl['bias'])}"
        lines.append(
            f"| {m['path']} | {m.get('compared', 0)} | {_pct(u.get('bias'))} | "
            f"{_pct0(u.get('rel_rmse'))} | {_pct(c.get('bias'))} | {_pct0(c.get('rel_rmse'))} | "
            f"{'—' if ratio is None else f'{ratio:.2f}x'} | {ct} | {fl} | "
            f"{_pct0(m.get('bake_se'))} |"
        )
    t = r["seconds"]
    lines += [
        "",
        f"wall: usdahd {t['usdahd']:.1f} s, Cycles {r['spp']} spp {t['cycles']:.1f} s "
        f"(bake {t['cycles_bake']:.1f} s), truth {t['truth']}",
    ]
    if r.get("warnings"):
        lines += ["", "warnings: " + "; ".join(r["warnings"][:8])]
    return "\n".join(lines)


def summary(results: list[dict]) -> str:
    """One line per stage (from ``compare --json`` outputs): pooled figures and the mesh with
    the largest |usdahd bias|."""
    lines = [
        "| stage | texels | usdahd bias | worst mesh bias | usdahd relRMSE | Cycles relRMSE "
        "(equal spp) | ratio | truth noise | usdahd s | Cycles s |",
        "|---" * 10 + "|",
    ]
    for r in results:
        ov = r["overall"]
        worst = max(
            (m for m in r["meshes"] if "usdahd" in m and np.isfinite(m["usdahd"]["bias"])),
            key=lambda m: abs(m["usdahd"]["bias"]),
            default=None,
        )
        w = "—" if worst is None else f"{_pct(worst['usdahd']['bias'])} ({worst['path']})"
        ratio = ov.get("rmse_ratio")
        c_rel = ov.get("cycles", {}).get("rel_rmse")
        noise = truth_noise(c_rel, r["spp"], r["truth_spp"]) if c_rel is not None else None
        lines.append(
            f"| {Path(r['stage']).name} | {ov.get('compared', 0)} | "
            f"{_pct(ov.get('usdahd', {}).get('bias'))} | {w} | "
            f"{_pct0(ov.get('usdahd', {}).get('rel_rmse'))} | "
            f"{_pct0(ov.get('cycles', {}).get('rel_rmse'))} | "
            f"{'—' if ratio is None else f'{ratio:.2f}x'} | {_pct0(noise)} | "
            f"{r['seconds']['usdahd']:.1f} | {r['seconds']['cycles']:.1f} |"
        )
    return "\n".join(lines)


#: The per-mesh bounds of README.md ("the issue's targets"): |usdahd bias| and usdahd's relRMSE
#: over Cycles' at equal spp.
BIAS_BOUND = 0.01
RATIO_BOUND = 1.5


#: A mesh's bias bound is ``BIAS_BOUND`` plus this many standard errors of its mean: the
#: truth's and the bake's own, combined (:func:`bias_bound`).
NOISE_SIGMAS = 2.0


def truth_mean_error(m: dict) -> float | None:
    """Standard error of a mesh's mean in the truth (relative): its per-texel relRMSE
    ``truth_noise`` over sqrt(compared texels), texels' noise independent (Cycles' seeds)."""
    tn, k = m.get("truth_noise"), m.get("compared", 0)
    return None if tn is None or not k else tn / math.sqrt(k)


def bias_bound(m: dict) -> float:
    """README.md's per-mesh bias bound: ``BIAS_BOUND + NOISE_SIGMAS * sqrt(SE_truth^2 +
    SE_bake^2)``, the truth's standard error on the mesh's mean (:func:`truth_mean_error`) and
    the bake's own (``bake_se``, :func:`bake_mean_error`); a figure a result does not have
    counts as 0 (so an old result without either is held to the bare 1 %)."""
    se_t = truth_mean_error(m) or 0.0
    se_b = m.get("bake_se") or 0.0
    return BIAS_BOUND + NOISE_SIGMAS * math.hypot(se_t, se_b)


def within(m: dict) -> bool:
    """Whether a compare row is within README.md's bounds: |bias| <= :func:`bias_bound` and
    usdahd's relRMSE <= ``RATIO_BOUND`` x Cycles' at equal spp."""
    b, ratio = m["usdahd"]["bias"], m.get("rmse_ratio")
    return abs(b) <= bias_bound(m) and (ratio is None or ratio <= RATIO_BOUND)


def bounds(results: list[dict], noise: bool = False) -> str:
    """Per mesh of every stage: usdahd's bias and relRMSE ratio against README.md's bounds
    (|bias| <= 1 % + 2 x the combined standard error of the mesh's mean, :func:`bias_bound`;
    ratio <= 1.5x), the meshes outside named in a last line.

    noise: also Cycles' own bias at equal spp, the truth's and the bake's standard errors and
    the bias bound they give; a mesh within only thanks to them (|bias| > 1 %) reads
    ``yes (noise)``."""
    head = "| stage | mesh | texels | usdahd bias | usdahd relRMSE | Cycles relRMSE | ratio "
    if noise:
        head += "| Cycles bias | truth SE of mean | bake SE of mean | bias bound "
    lines = [head + "| within |", "|---" * (12 if noise else 8) + "|"]
    out, n, noisy = [], 0, []
    for r in results:
        for m in r["meshes"]:
            if "usdahd" not in m or not np.isfinite(m["usdahd"]["bias"]):
                continue
            n += 1
            b, ratio = m["usdahd"]["bias"], m.get("rmse_ratio")
            name = f"{Path(r['stage']).name} {m['path']}"
            ok = within(m)
            verdict = "yes" if ok else "**no**"
            if not ok:
                out.append(name)
            elif abs(b) > BIAS_BOUND:
                noisy.append(name)
                if noise:
                    verdict = "yes (noise)"
            row = (
                f"| {Path(r['stage']).name} | {m['path']} | {m.get('compared', 0)} | {_pct(b)} | "
                f"{_pct0(m['usdahd'].get('rel_rmse'))} | "
                f"{_pct0(m.get('cycles', {}).get('rel_rmse'))} | "
                f"{'—' if ratio is None else f'{ratio:.2f}x'} | "
            )
            if noise:
                row += (
                    f"{_pct(m.get('cycles', {}).get('bias'))} | {_pct0(truth_mean_error(m))} | "
                    f"{_pct0(m.get('bake_se'))} | {_pct0(bias_bound(m))} | "
                )
            lines.append(row + f"{verdict} |")
    lines += [
        "",
        f"{n - len(out)} of {n} meshes within |bias| <= {100 * BIAS_BOUND:g} % + "
        f"{NOISE_SIGMAS:g} x sqrt(SE_truth^2 + SE_bake^2) and ratio <= {RATIO_BOUND:g}x"
        + (f"; outside: {', '.join(out)}" if out else ""),
    ]
    if noise:
        lines += [
            "",
            f"{len(noisy)} of them within only by the standard errors (|bias| > "
            f"{100 * BIAS_BOUND:g} %): " + (", ".join(noisy) or "none"),
        ]
    return "\n".join(lines)


# ------------------------------------------------------------------------------- driver


def run_compare(stage, *, resolution: int | None, uv: str | None = None,
                usdahd_args: str = "", spp: int | None = None, truth_spp: int = 4096,
                bpy: str | None = None, use_cache: bool = True, keep: str | None = None,
                threads: int = 0, quiet: bool = False, oversample: int = 1,
                point: bool = False, cache_equal: bool = False) -> dict:  # fmt: skip
    stage = Path(stage).resolve()
    if not stage.is_file():
        raise CompareError(f"{stage}: no such file")
    if truth_spp < 1 or (spp is not None and spp < 1):
        raise CompareError("--spp and --truth-spp must be >= 1")
    if oversample < 1 or oversample % 2 == 0:
        raise CompareError(f"--oversample must be odd and >= 1, got {oversample}")
    if point and oversample != 1:
        raise CompareError("--point samples texel centres; drop --oversample")
    bpy = runner.find_bpy(bpy)  # fail before any long work
    extra = shlex.split(usdahd_args)
    tmp_ctx = None
    if keep:
        work = Path(keep).resolve()
        work.mkdir(parents=True, exist_ok=True)
    else:
        tmp_ctx = tempfile.TemporaryDirectory(prefix="usdahd-compare-")
        work = Path(tmp_ctx.name)
    try:
        baked = bake_usdahd(stage, work, resolution, uv, extra, quiet)
        _log(f"usdahd: {baked['seconds']:.1f} s", quiet)
        results = usdahd_results(baked["layer"])
        if not results:
            raise CompareError(f"usdahd baked no prim of {stage} (see its report)")
        scene = export.export_stage(baked["layer"], baked=results)
        sf = export.save_scene(scene, work / "reference_scene.npz")
        samples = max(r["samples"] for r in results.values())
        spp_eq = int(spp or samples or 256)
        _log(f"Cycles truth: {truth_spp} spp", quiet)
        t_info, truth, hit = runner.cached_cycles(
            scene, sf, truth_spp, seed=TRUTH_SEED, bpy=bpy, use_cache=use_cache,
            threads=threads, quiet=quiet, oversample=oversample, point=point,
        )  # fmt: skip
        _log(f"Cycles at equal spp: {spp_eq}", quiet)
        e_info, equal, _ = runner.cached_cycles(
            scene, sf, spp_eq, seed=EQUAL_SEED, bpy=bpy, use_cache=cache_equal and use_cache,
            threads=threads,
            quiet=quiet, oversample=oversample, point=point,
        )  # fmt: skip
        ours, variance, filled = {}, {}, {}
        for k, m in enumerate(scene.meshes):
            r = results.get(m["path"])
            if m["baked"] and r and r.get("sidecar"):
                ours[k] = usdahd_iz(r["record"])
                v = variance_images(baked["variance"], m["path"], ours[k][1].shape)
                if v is not None:
                    variance[k], filled[k] = v
        out = compare_images(scene.meshes, truth, equal, ours, spp_eq, truth_spp, variance,
                             filled)  # fmt: skip
        out.update(
            stage=str(stage),
            usdahd_args=[
                *(["--resolution", str(resolution)] if resolution else []),
                *(["--uv", uv] if uv else []),
                *extra,
            ],  # fmt: skip
            usdahd_samples=samples,
            spp=spp_eq,
            truth_spp=truth_spp,
            oversample=oversample,
            footprint="point" if point else "box",
            seconds={
                "usdahd": baked["seconds"],
                "cycles": e_info["wall_seconds"],
                "cycles_bake": e_info["bake_seconds"],
                "truth": "cached" if hit else f"{t_info['wall_seconds']:.1f} s",
            },
            warnings=scene.warnings
            + [w for p in baked["report"].get("prims", []) for w in p.get("warnings", [])][
                :20
            ],  # fmt: skip
            blender=e_info.get("blender"),
        )
        return out
    finally:
        if tmp_ctx is not None:
            tmp_ctx.cleanup()


def run_bake(stage, out, *, resolution, uv="st", spp=1024, seed=0, bpy=None, quiet=False):
    """Cycles I_z of every mesh carrying ``uv`` into ``out`` (.npz: ``iz_<k>``, ``meta``)."""
    bpy = runner.find_bpy(bpy)
    scene = export.export_stage(stage, uv=uv, resolution=resolution)
    with tempfile.TemporaryDirectory(prefix="usdahd-refbake-") as tmp:
        sf = export.save_scene(scene, Path(tmp) / "scene.npz")
        info, images = runner.run_cycles(sf, spp, seed=seed, bpy=bpy, quiet=quiet)
    arrays = {f"iz_{k}": v for k, v in images.items()}
    info["paths"] = {str(k): scene.meshes[k]["path"] for k in images}
    info["warnings"] = scene.warnings
    arrays["meta"] = np.array(json.dumps(info))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **arrays)
    return info


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reference")
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("compare", help="usdahd vs Cycles on one stage")
    c.add_argument("stage", nargs="+", help="one or more stages (several: a summary at the end)")
    c.add_argument("--resolution", type=int, help="passed to usdahd bake (lightmap side)")
    c.add_argument("--uv", help="passed to usdahd bake")
    c.add_argument("--usdahd-args", default="", help='more usdahd bake flags, e.g. "--samples 64"')
    c.add_argument("--spp", type=int, help="Cycles samples per texel (default: usdahd's)")
    c.add_argument("--truth-spp", type=int, default=4096)
    c.add_argument("--bpy-python", help=f"Python with bpy (default ${runner.ENV_VAR})")
    c.add_argument("--no-cache", action="store_true", help="re-bake the truth")
    c.add_argument("--keep", help="keep the work folder (bake, scene file) here")
    c.add_argument("--threads", type=int, default=0, help="Cycles threads (0: all)")
    c.add_argument("--oversample", type=int, default=1,
                   help="Cycles bakes at k x resolution (odd) and keeps texel centres")  # fmt: skip
    c.add_argument("--point", action="store_true",
                   help="Cycles samples each texel's centre point (probes.py), as usdahd does, "
                        "for the truth and the equal-spp run")  # fmt: skip
    c.add_argument("--cache-equal", action="store_true",
                   help="cache Cycles' equal-spp run too (it does not depend on usdahd's seed, "
                        "so a re-run with another --usdahd-args seed reuses it)")  # fmt: skip
    c.add_argument("--json", action="store_true")
    c.add_argument("--quiet", action="store_true")
    b = sub.add_parser("bake", help="Cycles I_z per mesh of a stage with lightmap UVs")
    b.add_argument("stage")
    b.add_argument("--resolution", type=int, required=True)
    b.add_argument("--uv", default="st")
    b.add_argument("--spp", type=int, default=1024)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("-o", "--output", required=True)
    b.add_argument("--bpy-python")
    b.add_argument("--quiet", action="store_true")
    s = sub.add_parser("summary", help="one line per stage from compare --json files")
    s.add_argument("files", nargs="+")
    s.add_argument(
        "--meshes", action="store_true", help="one line per mesh against README.md's bounds"
    )
    s.add_argument(
        "--noise",
        action="store_true",
        help="with --meshes: Cycles' bias and the truth's and the bake's standard errors on "
        "each mesh's mean",
    )
    s.add_argument(
        "--plot",
        metavar="PNG",
        help="also write per-mesh errors and time to equal error to PNG (production_plot.py)",
    )
    a = p.parse_args(argv)
    if a.cmd == "summary":
        res = []
        try:
            for f in a.files:
                got = json.loads(Path(f).read_text())
                res += got if isinstance(got, list) else [got]
        except (OSError, json.JSONDecodeError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(bounds(res, noise=a.noise) if a.meshes else summary(res))
        if a.plot:
            from benchmarks.reference import production_plot

            print(f"plot: {production_plot.plot(res, Path(a.plot))}", file=sys.stderr)
        return 0
    try:
        if a.cmd == "bake":
            info = run_bake(a.stage, a.output, resolution=a.resolution, uv=a.uv, spp=a.spp,
                            seed=a.seed, bpy=a.bpy_python, quiet=a.quiet)  # fmt: skip
            print(json.dumps(info))
            return 0
        if a.keep and len(a.stage) > 1:
            raise CompareError("--keep takes one stage")
        for stage in a.stage:  # every input checked before any long work
            if not Path(stage).is_file():
                raise CompareError(f"{stage}: no such file")
        results = []
        for stage in a.stage:
            res = run_compare(
                stage, resolution=a.resolution, uv=a.uv, usdahd_args=a.usdahd_args, spp=a.spp,
                truth_spp=a.truth_spp, bpy=a.bpy_python, use_cache=not a.no_cache,
                keep=a.keep, threads=a.threads, quiet=a.quiet, oversample=a.oversample,
                point=a.point, cache_equal=a.cache_equal,
            )  # fmt: skip
            results.append(res)
            if not a.json:
                print(table(res) + "\n", flush=True)
    except (runner.ReferenceUnavailable, CompareError, export.ExportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.json:
        print(json.dumps(results[0] if len(results) == 1 else results, indent=1))
    elif len(results) > 1:
        print(summary(results))
    return 0
