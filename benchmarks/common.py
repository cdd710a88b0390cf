"""Shared pieces of ``benchmarks/run.py``: paths, machine facts, timing, error measures, tables,
reading the SH sidecar of a bake, plots.

Error measures (all against the model-free SH irradiance target ``usdahd.sh.irradiance``):

- ``hemi_errors(model, params, sh)`` integrates the squared RGB difference and the squared target
  over the upper hemisphere with a 12 x 24 Gauss-Legendre product rule (288 directions: exact
  for the polynomial target, and at most ~1e-3 relative off for models with a ``max()``);
- the *relative hemispherical RMSE* of a texel is sqrt(err / target energy)
  (``usdahd.numerics.stats.rmse_over_rms``); of a set of texels (a scene) it is
  sqrt(sum err / sum target energy) (``pooled_rmse_over_rms``), i.e. dominated by bright
  texels, as an image difference would be. ``usdahd validate`` and ``usdahd fit`` report the
  other definition, RMSE over mean |target| (``rmse_over_mean_abs``).
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from usdahd import models  # noqa: E402
from usdahd.numerics import sh as shm  # noqa: E402
from usdahd.numerics.stats import pooled_rmse_over_rms, rmse_over_rms  # noqa: E402

SAMPLES = REPO / "samples"
CACHE = REPO / "benchmarks" / "cache"
DOCS = REPO / "docs"
PLOTS = DOCS / "benchmarks"

#: Hemisphere rule for model-vs-target errors (see module docstring).
HEMI_RULE = (12, 24)
#: Texels per chunk when evaluating on the hemisphere rule (chunk x 288 x 3 float64 ~ 55 MB).
EVAL_CHUNK = 8192
#: Bytes per channel of each texture format (usdahd.models.base.FORMATS).
FORMAT_BYTES = {"half": 2, "float": 4, "unorm8": 1, "snorm8": 1}


#: Progress lines on stderr (run.py --quiet turns them off).
VERBOSE = True


def log(msg: str) -> None:
    """Progress line on stderr (the benchmark's stdout is the report path only)."""
    if VERBOSE:
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------- machine


def _version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _git() -> str:
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO,
            capture_output=True,
            text=True,
        ).stdout.strip()
    except OSError:
        return "unknown"
    if not head:
        return "unknown"
    return head + (" (with uncommitted changes)" if dirty else "")


def machine_facts() -> dict:
    """What the numbers depend on: date, CPU, cores, load, library versions, commit."""
    from pxr import Usd

    from usdahd.version import __version__

    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        usable = os.cpu_count()
    try:
        load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        load = "?"
    return {
        "date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": _cpu_model(),
        "cores": f"{os.cpu_count()} logical, {usable} usable",
        "load average (1/5/15 min) at start": load,
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "numpy": _version("numpy"),
        "numba": _version("numba"),
        "embreex": _version("embreex"),
        "usd-core": f"{_version('usd-core')} (USD {'.'.join(map(str, Usd.GetVersion()))})",
        "OpenImageIO": _version("OpenImageIO"),
        "pyoidn": _version("pyoidn"),
        "matplotlib": _version("matplotlib"),
        "usdahd": f"{__version__}, commit {_git()}",
    }


# ----------------------------------------------------------------------------------- timing


def median(values) -> float:
    return float(np.median(np.asarray(values, dtype=np.float64)))


def timed(fn, *args, **kwargs):
    """(result, seconds) of one call."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


# ----------------------------------------------------------------------------------- errors


def hemi_errors(model: str, params: dict, sh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared hemispherical error of a fitted model and the target's energy, per texel.

    model : registry name; params : the model's params with leading shape (n,);
    sh : (n, 3, 9) radiance SH (the target is its normalized irradiance).
    returns : err (n,) float64 = int_{z>0} |I_model - I_sh|^2 dw (RGB summed),
    energy (n,) float64 = int_{z>0} |I_sh|^2 dw.
    """
    mod = models.get(model)
    d, w = shm.hemisphere_quadrature(*HEMI_RULE)
    sh = np.asarray(sh, dtype=np.float64)
    n = sh.shape[0]
    err = np.empty(n)
    energy = np.empty(n)
    for a in range(0, n, EVAL_CHUNK):
        b = min(n, a + EVAL_CHUNK)
        target = shm.irradiance(sh[a:b, None], d[None])  # (k, m, 3)
        p = {k: np.asarray(v)[a:b] for k, v in params.items()}
        got = np.asarray(mod.evaluate(p, np.broadcast_to(d, (b - a,) + d.shape)), np.float64)
        err[a:b] = np.einsum("kmc,m->k", (got - target) ** 2, w)
        energy[a:b] = np.einsum("kmc,m->k", target**2, w)
    return err, energy


def relative_rmse(err: np.ndarray, energy: np.ndarray) -> tuple[float, float]:
    """(``pooled_rmse_over_rms``, mean over texels of ``rmse_over_rms``): the "over RMS"
    definitions of :mod:`usdahd.numerics.stats`.

    Texels with zero target energy are left out of the per-texel mean.
    """
    agg = pooled_rmse_over_rms(err, energy)
    ok = energy > 0
    per = float(np.mean(rmse_over_rms(err[ok], energy[ok]))) if ok.any() else 0.0
    return agg, per


def bytes_per_texel(model: str, ratio: str) -> int:
    """Stored bytes per texel of a model's textures (sum over its layout)."""
    return sum(
        FORMAT_BYTES[lay.format] * len(lay.channels) for lay in models.get(model).layout(ratio)
    )


def roundtrip(model: str, params: dict, ratio: str) -> dict:
    """encode -> decode: what an engine reads back (quantization included)."""
    mod = models.get(model)
    channels, factors = mod.encode(params, ratio=ratio)
    return mod.decode(channels, ratio=ratio, factors=factors)


def variants() -> list[tuple[str, str]]:
    """Every (model, ratio) pair of the registry, in registry order."""
    return [(name, ratio) for name in models.names() for ratio in models.get(name).RATIOS]


# ----------------------------------------------------------------------------------- bakes


def sample_scenes() -> list[Path]:
    """The sample stages (samples/*.usda without baked outputs), sorted by name."""
    return sorted(p for p in SAMPLES.glob("*.usda") if not p.name.endswith(".lightmaps.usda"))


def read_baked_sh(layer: Path) -> dict:
    """The SH sidecar of every baked prim of an output layer.

    returns : {prim path: (sh (h, w, 3, 9) float32, covered (h, w) bool)}, sorted by path.
    """
    from pxr import Sdf, Usd

    from usdahd import sidecar
    from usdahd.usd import plugin, schema

    plugin.register()
    cached = Sdf.Layer.Find(str(layer))
    if cached is not None:
        cached.Reload(force=True)
    stage = Usd.Stage.Open(str(layer))
    out = {}
    for prim in schema.prims_with_api(stage):
        res = schema.read_results(prim)
        if res is None or schema.SIDECAR_ROLE not in res.textures:
            continue
        px = np.asarray(sidecar.read_record(res), dtype=np.float32)  # rectangle of its page
        out[str(prim.GetPath())] = sidecar.split(px)
    return dict(sorted(out.items()))


def texels_of(baked: dict) -> np.ndarray:
    """All covered texels of read_baked_sh() output, concatenated: (n, 3, 9) float32."""
    parts = [img[mask] for img, mask in baked.values()]
    return np.concatenate(parts) if parts else np.zeros((0, 3, 9), np.float32)


# ----------------------------------------------------------------------------------- tables


def fmt(x, digits: int = 3) -> str:
    """A compact number for tables (``-`` for None/NaN)."""
    if x is None:
        return "-"
    if isinstance(x, (int, np.integer)):
        return f"{int(x):,}"
    x = float(x)
    if not np.isfinite(x):
        return "nan" if np.isnan(x) else ("inf" if x > 0 else "-inf")
    if x == 0:
        return "0"
    if 1e-3 <= abs(x) < 1e5:
        return f"{x:.{digits}g}"
    return f"{x:.{max(digits - 1, 1)}e}"


def md_table(headers: list[str], rows: list[list]) -> str:
    """A GitHub markdown table; cells that are not strings go through fmt()."""
    cells = [[c if isinstance(c, str) else fmt(c) for c in row] for row in rows]
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in cells]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------ plots


def pyplot():
    """matplotlib.pyplot with a file-only backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, name: str, out_dir: Path = PLOTS) -> Path:
    """Save a figure as a small PNG (8-bit palette when Pillow is available); returns the path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / name
    fig.savefig(path, dpi=90, bbox_inches="tight")
    pyplot().close(fig)
    try:  # quantize to a palette: plots have few colours, this cuts the size ~3x
        from PIL import Image

        with Image.open(path) as im:
            im.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(
                path, optimize=True
            )
    except Exception:  # Pillow missing or unable: keep matplotlib's PNG
        pass
    return path
