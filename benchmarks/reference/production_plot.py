"""One figure of ``compare --json`` results on production stages (issue 43 item 3).

    python -m benchmarks.reference summary A.json B.json ... --plot docs/benchmarks/production.png

Left: per mesh, usdahd's relRMSE against Cycles' at equal samples per texel (both against the
same point truth, so both include its noise), with the lines y = x and y = ``RATIO_BOUND`` x
(README.md's per-mesh bound). Right: per stage, error net of the truth's noise against time;
usdahd is one point (its whole ``usdahd bake`` process), Cycles a curve through its equal-spp
bake call, error falling as 1/sqrt(time) (1/sqrt(spp) at a constant rate per sample), and the
time at which that curve reaches usdahd's error is marked: usdahd's time over it is the ratio
of docs/benchmarks.md's "Time to equal error".
"""

from __future__ import annotations

import math
from pathlib import Path

from benchmarks.reference.compare import RATIO_BOUND, truth_noise
from benchmarks.reference_bench import net_of_truth_noise


def stage_label(r: dict) -> str:
    """``sponza 64²`` from a result's stage path and its meshes' resolution; ``classroom
    auto`` for a bake at usdahd's automatic texel density (no ``--resolution``: each mesh's
    resolution is its own)."""
    args = r.get("usdahd_args") or []
    if "--resolution" not in args and "--texel-density" not in args:
        return f"{Path(r['stage']).stem} auto"
    res = next((m["resolution"][0] for m in r["meshes"] if m.get("resolution")), None)
    return f"{Path(r['stage']).stem}" + ("" if res is None else f" {res}²")


def equal_error(r: dict) -> dict | None:
    """Net errors and times of one result: ``{"usdahd": (s, err), "cycles": (s, err),
    "cycles_at_usdahd_error": s, "ratio": usdahd s / that}``; None without Cycles figures."""
    ov = r["overall"]
    u, c = ov.get("usdahd", {}).get("rel_rmse"), ov.get("cycles", {}).get("rel_rmse")
    t_c = r["seconds"].get("cycles_bake") or r["seconds"].get("cycles")
    if u is None or c is None or not t_c:
        return None
    noise = ov.get("truth_noise") or truth_noise(c, r["spp"], r["truth_spp"])
    eu, ec = net_of_truth_noise(u, noise), net_of_truth_noise(c, noise)
    if eu <= 0 or ec <= 0:
        return None
    t_eq = t_c * (ec / eu) ** 2
    t_u = r["seconds"]["usdahd"]
    return {"usdahd": (t_u, eu), "cycles": (t_c, ec), "cycles_at_usdahd_error": t_eq,
            "ratio": t_u / t_eq}  # fmt: skip


def _minor_label(v: float, _pos) -> str:
    """Label a log axis' minor ticks at 2, 3 and 5 times a power of ten."""
    if v <= 0:
        return ""
    lead = v / 10 ** math.floor(math.log10(v))
    return f"{v:g}" if any(abs(lead - k) < 1e-6 for k in (2, 3, 5)) else ""


def plot(results: list[dict], path: Path) -> Path:
    """Write the two-panel figure of ``results`` (``compare --json`` dicts) to ``path``."""
    from benchmarks.common import pyplot, save_figure

    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 5.6))
    lo, hi = 1.0, 0.0
    for i, r in enumerate(results):
        colour = f"C{i}"
        pts = [(m["cycles"]["rel_rmse"] * 100, m["usdahd"]["rel_rmse"] * 100)
               for m in r["meshes"] if "usdahd" in m and "cycles" in m
               and math.isfinite(m["usdahd"]["rel_rmse"])]  # fmt: skip
        if pts:
            xs, ys = zip(*pts, strict=True)
            ax.scatter(xs, ys, s=14, color=colour, label=f"{stage_label(r)} ({len(pts)} meshes)")
            lo, hi = min(lo, *xs, *ys), max(hi, *xs, *ys)
        eq = equal_error(r)
        if eq is None:
            continue
        (t_u, e_u), (t_c, e_c), t_eq = eq["usdahd"], eq["cycles"], eq["cycles_at_usdahd_error"]
        ts = [t_c * 2 ** (k / 4) for k in range(-8, 1 + 4 * math.ceil(math.log2(t_eq / t_c) + 1))]
        bx.plot(ts, [e_c * 100 * math.sqrt(t_c / t) for t in ts], "--", color=colour)
        bx.scatter([t_c], [e_c * 100], marker="s", color=colour)
        bx.scatter([t_u], [e_u * 100], marker="o", s=50, color=colour,
                   label=f"{stage_label(r)}: usdahd {t_u:.0f} s, Cycles {t_eq:.0f} s to equal "
                   f"error ({eq['ratio']:.2f}x)")  # fmt: skip
        bx.scatter([t_eq], [e_u * 100], marker="x", s=50, color=colour)
    line = [lo * 0.8, hi * 1.25]
    ax.plot(line, line, "k-", lw=0.8, label="equal error")
    ax.plot(line, [v * RATIO_BOUND for v in line], "k:", lw=0.8, label=f"bound {RATIO_BOUND}x")
    ax.set(xscale="log", yscale="log", xlabel="Cycles relRMSE, % (equal spp)",
           ylabel="usdahd relRMSE, %", title="Per mesh, against the same point truth")  # fmt: skip
    ax.legend(fontsize=7)
    bx.set(xscale="log", yscale="log", xlabel="seconds (usdahd: whole process; Cycles: bake call)",
           ylabel="relRMSE net of the truth's noise, %")  # fmt: skip
    title = "Time to equal error (o usdahd, ■ Cycles at equal spp, x Cycles at usdahd's error)"
    bx.set_title(title, fontsize=8)
    bx.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14))
    for a in (ax, bx):
        a.yaxis.set_major_formatter(plt.FuncFormatter(lambda v, _: f"{v:g}"))
        a.yaxis.set_minor_formatter(plt.FuncFormatter(_minor_label))
    fig.tight_layout()
    return save_figure(fig, Path(path).name, Path(path).parent)
