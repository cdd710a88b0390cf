"""Light leaks at contacts (issue 17 item 5): bright outlier texels next to where surfaces meet.

Bakes each stage with ``python -m usdahd bake`` (this checkout) and, per mesh, compares every
covered texel's luminance ``I_z`` with the median over the covered texels of its 5x5
neighbourhood (itself included). A texel whose sample point sits on a contact (e.g. the ground
where an overhanging face meets it) and whose ray origin ends up on the wrong side of that
face comes out far brighter than its neighbours: a thin bright line. Reported per stage:

- ``outliers``: texels with ``I_z / max(median, floor) > 1.5`` (floor = 1e-3 x the mesh's
  99th-percentile ``I_z``, so a lit texel among black ones counts with a large finite ratio);
  ``outliers_3``: the same above 3 (a sunlit texel next to shadowed ones is about
  (sun + sky) / sky = 2.6 above its median here: real edges stay below 3, leaks do not);
- ``max_ratio`` and the 99.9th percentile of the ratio;
- the number of texels the contact rule moved (``contact_texels`` in the bake report) and the
  bake's trace time.

Monte Carlo noise alone gives some ratios above 1.5 (how many depends on the sample count), so
compare runs at equal settings. The castle (``$USDAHD_SHARED_SCENES/castle/castle.usda``,
default ``/work/shared/scenes``) has no lights; a wrapper stage beside the output adds the
sun and sky of ``samples/exterior_sun_sky.usda``.

    python -m benchmarks.contacts [--resolution 256] [--out DIR] [--json OUT.json]
                                  [--repeat 3] [--usdahd-repo CHECKOUT] [--probe-cost]

``--repeat N`` bakes each stage N times (``--force``) and reports the median trace seconds per
mesh (and the load average); ``--usdahd-repo`` bakes with another checkout (e.g. a worktree of
main, for the cost of a change), measured by this script; ``--probe-cost`` also times the
contact probes alone (median of 3, in process) on each baked mesh.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

SHARED = Path(os.environ.get("USDAHD_SHARED_SCENES", "/work/shared/scenes"))
RATIO = 1.5
WINDOW = 5

SUN_SKY = """\
#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    subLayers = [@{src}@]
    upAxis = "Y"
)

over "World"
{{
    def Xform "ContactLights"
    {{
        def DistantLight "Sun"
        {{
            float inputs:angle = 0.53
            color3f inputs:color = (1, 0.95, 0.85)
            float inputs:intensity = 3
            bool inputs:normalize = 1
            float3 xformOp:rotateXYZ = (-50, 30, 0)
            uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
        }}

        def DomeLight "Sky"
        {{
            color3f inputs:color = (0.3, 0.45, 0.7)
            float inputs:intensity = 1
        }}
    }}
}}
"""


def castle_stage(out: Path) -> Path:
    """The shared castle with a sun and sky added by a wrapper stage in ``out``."""
    src = SHARED / "castle" / "castle.usda"
    if not src.is_file():
        raise SystemExit(f"{src}: not found; set USDAHD_SHARED_SCENES to the shared scenes folder")
    stage = out / "castle_sun_sky.usda"
    stage.write_text(SUN_SKY.format(src=src.resolve()))
    return stage


def neighbourhood_ratio(iz: np.ndarray, cov: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """``iz / max(median of covered texels in the window, floor)`` per covered texel (h, w)."""
    h, w = iz.shape
    r = window // 2
    pad = np.pad(np.where(cov, iz, np.nan), r, constant_values=np.nan)
    stack = np.stack(
        [pad[dy : dy + h, dx : dx + w] for dy in range(window) for dx in range(window)], axis=0
    )
    with warnings.catch_warnings():  # windows without a covered texel (outside charts)
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(np.where(cov[None], stack, np.nan), axis=0)
    floor = 1e-3 * max(float(np.percentile(iz[cov], 99)), 1e-30) if cov.any() else 1.0
    return np.where(cov, iz / np.maximum(np.nan_to_num(med), floor), np.nan)


def _bake(stage: Path, layer: Path, resolution: int, extra: list[str], repo: Path) -> dict:
    cmd = [sys.executable, "-m", "usdahd", "bake", str(stage), "-o", str(layer), "--json"]
    cmd += ["--resolution", str(resolution), "--force", *extra]
    env = dict(os.environ, PYTHONPATH=str(repo))
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=repo, env=env)
    wall = time.perf_counter() - t0
    if r.returncode not in (0, 1) or not layer.is_file():
        raise SystemExit(f"bake of {stage} failed ({r.returncode}):\n{r.stderr[-2000:]}")
    return {"wall": wall, "prims": {p["path"]: p for p in json.loads(r.stdout).get("prims", [])}}


def measure(
    stage: Path, out: Path, resolution: int, extra: list[str], repeat: int = 1, repo: Path = REPO
) -> dict:
    """Bake ``stage`` into ``out`` (``repeat`` times) and return the statistics per mesh."""
    from benchmarks.common import read_baked_sh
    from usdahd.numerics import sh as shm

    layer = out / f"{stage.stem}.lightmaps.usda"
    runs = [_bake(stage, layer, resolution, extra, repo) for _ in range(max(1, repeat))]
    prims = runs[-1]["prims"]
    wall = float(np.median([r["wall"] for r in runs]))
    rows = {}
    for path, (sh, cov) in read_baked_sh(layer).items():
        iz = shm.iz(sh.astype(np.float64)) @ np.array([0.2126, 0.7152, 0.0722])
        ratio = neighbourhood_ratio(iz, cov)
        rv = ratio[cov]
        p = prims.get(path, {})
        rows[path] = {
            "texels": int(cov.sum()),
            "outliers": int((rv > RATIO).sum()),
            "outliers_3": int((rv > 3.0).sum()),
            "max_ratio": float(np.nanmax(rv)),
            "p999_ratio": float(np.nanpercentile(rv, 99.9)),
            "contact_texels": p.get("contact_texels"),
            "trace_seconds": float(
                np.median([r["prims"].get(path, {}).get("trace_seconds", np.nan) for r in runs])
            ),
        }
    return {"stage": str(stage), "wall_seconds": wall, "meshes": rows}


def probe_cost(layer: Path, repeat: int = 3) -> dict:
    """Median seconds of :func:`push_off_contacts` per baked mesh of an output layer (this
    checkout, in process, the tracer's default threads), with the texel count."""
    from benchmarks.reference.compare import usdahd_results
    from usdahd.bake.contacts import push_off_contacts
    from usdahd.bake.texels import rasterize
    from usdahd.bake.trace import Tracer
    from usdahd.usd.reader import load_scene

    baked = usdahd_results(layer)
    out = {}
    for uv in sorted({v["uv"] for v in baked.values()}):
        scene = load_scene(str(layer), uv_name=uv)
        tracer = Tracer(scene)
        for m in scene.meshes:
            if m.path not in baked or baked[m.path]["uv"] != uv:
                continue
            tx = rasterize(m, tuple(baked[m.path]["resolution"]))
            secs = []
            for _ in range(repeat):
                t0 = time.perf_counter()
                push_off_contacts(tx, m, tracer)
                secs.append(time.perf_counter() - t0)
            out[m.path] = {"texels": len(tx), "seconds": float(np.median(secs))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--out", type=Path, default=None, help="bake folder (default: a temp dir)")
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    ap.add_argument("--skip-castle", action="store_true")
    ap.add_argument("--repeat", type=int, default=1, help="bakes per stage (median times)")
    ap.add_argument("--usdahd-repo", type=Path, default=REPO, help="checkout that bakes")
    ap.add_argument("--probe-cost", action="store_true", help="also time the contact probes alone")
    ap.add_argument("extra", nargs="*", help="extra bake arguments (after --)")
    a = ap.parse_args(argv)
    out = a.out or Path(tempfile.mkdtemp(prefix="usdahd-contacts-"))
    out.mkdir(parents=True, exist_ok=True)
    stages = [] if a.skip_castle else [castle_stage(out)]
    stages.append(REPO / "samples" / "exterior_sun_sky.usda")
    results = []
    load0 = os.getloadavg()
    for st in stages:
        res = measure(st, out, a.resolution, a.extra, a.repeat, a.usdahd_repo.resolve())
        if a.probe_cost:
            cost = probe_cost(out / f"{st.stem}.lightmaps.usda", max(3, a.repeat))
            for path, c in cost.items():
                res["meshes"][path]["probe_seconds"] = c["seconds"]
                print(f"{st.stem:18s} {path:28s} contact probes {c['seconds']:.3f}s", flush=True)
        results.append(res)
        for path, row in res["meshes"].items():
            print(
                f"{Path(res['stage']).stem:18s} {path:28s} texels {row['texels']:6d}  "
                f"ratio>{RATIO}: {row['outliers']:5d}  >3: {row['outliers_3']:5d}  "
                f"max {row['max_ratio']:10.3g}  "
                f"p99.9 {row['p999_ratio']:6.3f}  contact texels {row['contact_texels']}  "
                f"trace {row['trace_seconds'] or 0:.2f}s",
                flush=True,
            )
    load = (load0, os.getloadavg())
    print(f"load average before/after: {load[0][0]:.2f} / {load[1][0]:.2f} (1 min)")
    if a.json:
        doc = {"resolution": a.resolution, "repeat": a.repeat, "load": load, "results": results}
        a.json.write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
