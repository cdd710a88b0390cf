"""Run ``cycles_bake.py`` with a bpy interpreter, and cache its results on disk.

The bpy interpreter is a separate Python 3.11 with ``bpy`` (bpy 5.0.1 pins numpy 1.26, which
breaks OpenImageIO in the project's environment, so it cannot be an extra of the package):
``--bpy-python PATH`` or ``$USDAHD_BPY_PYTHON``. Results are cached under
``$USDAHD_REFERENCE_CACHE`` (default ``~/.cache/usdahd-reference/``), keyed by the exported
scene's digest, spp, seed and the bake script's own hash.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.reference.npzio import save_npz
from benchmarks.reference.probes import probes_digest, scene_probes, write_probes

HERE = Path(__file__).resolve().parent
SCRIPT = HERE / "cycles_bake.py"
ENV_VAR = "USDAHD_BPY_PYTHON"
CACHE_VAR = "USDAHD_REFERENCE_CACHE"
HOW_TO = (
    "create one with: python3.11 -m venv .venv-ref && .venv-ref/bin/pip install bpy==5.0.1, "
    f"then pass --bpy-python .venv-ref/bin/python or set {ENV_VAR}"
)


class ReferenceUnavailable(Exception):
    """No usable bpy interpreter (the message says how to create one)."""


def find_bpy(explicit: str | None = None, check: bool = True) -> str:
    """Path of a Python interpreter that can ``import bpy``; ReferenceUnavailable if none."""
    cand = explicit or os.environ.get(ENV_VAR)
    if not cand:
        raise ReferenceUnavailable(f"no bpy interpreter configured; {HOW_TO}")
    if not (os.path.isfile(cand) and os.access(cand, os.X_OK)):
        raise ReferenceUnavailable(f"bpy interpreter {cand!r} is not an executable file; {HOW_TO}")
    if check:
        try:
            r = subprocess.run(
                [cand, "-c", "import bpy; print(bpy.app.version_string)"],
                capture_output=True,
                text=True,
                timeout=120,
            )
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise ReferenceUnavailable(f"{cand}: cannot run ({exc}); {HOW_TO}") from None
        if r.returncode != 0:
            last = (r.stderr.strip().splitlines() or ["?"])[-1]
            raise ReferenceUnavailable(f"{cand}: 'import bpy' fails ({last}); {HOW_TO}")
    return cand


def cache_dir() -> Path:
    return Path(os.environ.get(CACHE_VAR) or Path.home() / ".cache" / "usdahd-reference")


#: Cycles truths kept in the repository (``reference_bench.py --truths-only --store``), read
#: after the user cache: the reference section's truths take ~2.5 h of Cycles at 128^2 on 2
#: cores, and a new machine starts with an empty cache. Same file names (cache keys) as the
#: cache; a key the code no longer produces is simply never read.
STORE_DIR = HERE / "truths"

#: Every cache file :func:`cached_cycles` read or wrote in this process, in order (what
#: ``--store`` copies into :data:`STORE_DIR`).
files_used: list[Path] = []


def cached_file(key: str) -> Path | None:
    """The cached result of ``key``: the user cache's file, else the repository store's."""
    for d in (cache_dir(), STORE_DIR):
        path = d / f"{key}.npz"
        if path.is_file():
            return path
    return None


def _half(img: np.ndarray) -> tuple[np.ndarray, float]:
    """(float16 image, power-of-two scale): ``img`` / scale puts its largest |value| in
    (2^14, 2^15], so every value within 2^28 of the largest is a normal float16 with 11
    significant bits (relative rounding <= 2^-11 = 0.049 %, RMS ~0.02 %); scaling by a power
    of two is exact."""
    peak = float(np.nanmax(np.abs(img))) if img.size else 0.0
    scale = 2.0 ** (np.ceil(np.log2(peak)) - 15) if peak > 0 and np.isfinite(peak) else 1.0
    return (img / scale).astype(np.float16), scale


def read_images(data, meshes) -> dict:
    """{mesh index: (h, w, 3) float32} from an opened result ``data`` (a cache file's float32
    ``iz_<k>``, or the store's float16 ``iz_<k>`` with its scale ``scale_<k>``)."""
    out = {}
    for m in meshes:
        k = m["index"]
        img = np.asarray(data[f"iz_{k}"], np.float32)
        if f"scale_{k}" in data.files:
            img = img * np.float32(data[f"scale_{k}"])
        out[k] = img
    return out


def store(paths) -> list[Path]:
    """Copy cached results into :data:`STORE_DIR`, skipping those already there; returns the
    files written. Images are kept as float16 with a power-of-two scale each (:func:`_half`:
    ~0.02 % RMS rounding, far below a 4096-spp truth's own noise; the point truth's two halves
    round independently, so their difference counts it as truth noise) and deflated: 720 KB
    for the ten reference stages at 32², half of deflated float32's 1.4 MB."""
    written = []
    for src in paths:
        dst = STORE_DIR / Path(src).name
        if dst.is_file() or Path(src).resolve() == dst.resolve():
            continue
        with np.load(src, allow_pickle=False) as data:
            arrays = {}
            for k in data.files:
                a = np.array(data[k])
                if k.startswith("iz_") and a.dtype == np.float32:
                    a, arrays[f"scale_{k[3:]}"] = _half(a)
                arrays[k] = a
        STORE_DIR.mkdir(parents=True, exist_ok=True)
        save_npz(dst, arrays, prefix=".store.", compress=True)
        written.append(dst)
    return written


def _script_hash() -> str:
    return hashlib.sha256(SCRIPT.read_bytes()).hexdigest()[:16]


def cache_key(digest: str, spp: int, seed: int, oversample: int = 1,
              point: str | None = None) -> str:  # fmt: skip
    """The cache file name of a Cycles bake: the scene's digest, samples, seed, cycles_bake.py's
    hash, and for a point truth ``point``, the probes' own content hash
    (:func:`benchmarks.reference.probes.probes_digest`), so a change to probes.py recomputes
    only the truths whose probes it changes."""
    extra = "" if oversample == 1 else f":os{oversample}"
    if point:
        extra += ":probes:" + point
    key = f"{digest}:{spp}:{seed}:{_script_hash()}{extra}"
    return hashlib.sha256(key.encode()).hexdigest()[:32]


def run_cycles(
    scene_file, spp: int, *, seed: int = 0, bpy: str, threads: int = 0, quiet: bool = False,
    oversample: int = 1, point: bool = False,
) -> tuple[dict, dict]:  # fmt: skip
    """Bake ``scene_file`` with Cycles; returns (info, {mesh index: iz (h, w, 3) float32}).

    ``point``: Cycles samples each texel's centre point through probe triangles (probes.py)
    instead of jittering over the texel's box.

    info has the per-mesh paths, ``bake_seconds`` (Cycles' bake call) and ``wall_seconds``
    (the whole subprocess, Blender start-up and scene set-up included).
    """
    with tempfile.TemporaryDirectory(prefix="usdahd-cycles-") as tmp:
        out = Path(tmp) / "out.npz"
        cmd = [bpy, str(SCRIPT), str(scene_file), str(out), "--spp", str(int(spp))]
        cmd += ["--seed", str(int(seed)), "--threads", str(int(threads))]
        cmd += ["--oversample", str(int(oversample))]
        if point:
            write_probes(scene_file, Path(tmp) / "probes.npz")
            cmd += ["--probes", str(Path(tmp) / "probes.npz")]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if r.returncode != 0 or not out.is_file():
            tail = "\n".join((r.stderr or r.stdout).strip().splitlines()[-15:])
            raise RuntimeError(f"Cycles bake failed (exit {r.returncode}):\n{tail}")
        data = np.load(out, allow_pickle=False)
        info = json.loads(str(data["meta"]))
        images = {m["index"]: np.array(data[f"iz_{m['index']}"]) for m in info["meshes"]}
    info["wall_seconds"] = wall
    if not quiet:
        print(f"cycles: {spp} spp in {wall:.1f}s (bake {info['bake_seconds']:.1f}s)",
              file=sys.stderr)  # fmt: skip
    return info, images


def cached_cycles(
    scene, scene_file, spp: int, *, seed: int = 0, bpy: str | None, use_cache: bool = True,
    threads: int = 0, quiet: bool = False, oversample: int = 1, point: bool = False,
) -> tuple[dict, dict, bool]:  # fmt: skip
    """Like :func:`run_cycles`, through the on-disk cache; returns (info, images, hit)."""
    probes = probes_digest(scene_probes(scene_file)) if point else None
    key = cache_key(scene.digest(), spp, seed, oversample, probes)
    path = cache_dir() / f"{key}.npz"
    found = cached_file(key) if use_cache else None
    if found is not None:
        with np.load(found, allow_pickle=False) as data:
            info = json.loads(str(data["meta"]))
            images = read_images(data, info["meshes"])
        info["cached"] = str(found)
        files_used.append(found)
        return info, images, True
    if bpy is None:
        raise ReferenceUnavailable(f"Cycles result not cached and no bpy interpreter; {HOW_TO}")
    info, images = run_cycles(
        scene_file, spp, seed=seed, bpy=bpy, threads=threads, quiet=quiet, oversample=oversample,
        point=point,
    )  # fmt: skip
    if use_cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {f"iz_{k}": v for k, v in images.items()}
        arrays["meta"] = np.array(json.dumps(info))
        save_npz(path, arrays, prefix=".ref.")
        files_used.append(path)
    return info, images, False
