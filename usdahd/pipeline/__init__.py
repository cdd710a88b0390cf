"""``usdahd bake`` end to end: stage -> scene -> texels -> SH -> fit -> textures -> schema.

The only orchestration module: each step lives in its own module (``usd/reader.py``,
``bake/texels.py``, ``bake/integrate.py``, ``bake/post.py``, ``models/``, ``images.py``,
``usd/schema.py``); this one decides what to bake, in what order, and what to skip.
Settings live in ``pipeline/settings.py``; output file names, commit, cleanup and the output
lock in ``pipeline/outputs.py``; the checks before any scene is read in ``pipeline/preflight.py``;
the per-mesh plan (``PrimJob``: settings, UVs, resolution) in ``pipeline/plan.py``.

Nothing is written until a prim's bake succeeded; every file is written atomically (temp file
+ rename) and the override layer last, so an interrupted bake leaves the previous outputs valid.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from usdahd import models
from usdahd._version import __version__
from usdahd.errors import BakeError, InputError, StageError, UsageError, UsdAhdError
from usdahd.pipeline.outputs import (
    FAULT_POINTS as FAULT_POINTS,
)
from usdahd.pipeline.outputs import (
    LIGHTMAPS_DIR,
    _commit_textures,
    _fault,
    _fsync,
    _inside_lightmaps,
    _referenced,
    _remove_legacy,
    cleanup_outputs,
    output_lock,
    texture_path,
)
from usdahd.pipeline.outputs import (
    layer_prefix as layer_prefix,
)
from usdahd.pipeline.outputs import (
    sanitize as sanitize,
)
from usdahd.pipeline.plan import (
    PrimJob,
    _plan,
    settings_resolution_given,
)
from usdahd.pipeline.preflight import (
    _check_stage,
    _check_values,
    _files_exist,
    _no_mesh_message,
    preflight,
)
from usdahd.pipeline.preflight import (
    default_output as default_output,
)
from usdahd.pipeline.settings import (
    DEFAULTS,
    TINY_RESOLUTION,
    BakeOptions,
    _check_options,
)
from usdahd.pipeline.settings import (
    MAX_RESOLUTION as MAX_RESOLUTION,
)
from usdahd.pipeline.settings import (
    resolve_settings as resolve_settings,
)
from usdahd.scene.hashing import (
    changed_parts,
    content_hash,
    is_dark,
    scene_hash_parts,
)
from usdahd.usd.author import generator_id
from usdahd.usd.stage import open_stage, utf8_problem


def _status(opts: BakeOptions, msg: str) -> None:
    if not opts.quiet:
        print(msg, file=sys.stderr)


# ------------------------------------------------------------------------------------ bake


def _previous_results(out: Path) -> tuple[dict, list[str]]:
    """(prim path -> BakeResults, warnings) from an existing output layer (empty if none).

    A record is only trusted when every texture it names is a regular file (not a symlink)
    inside the output's ``lightmaps/`` folder: a hand-edited layer pointing elsewhere
    (``../../x/...``) is ignored with a warning and the prim re-baked, so a bake never reads or
    keeps files outside its output folder.
    """
    if not out.is_file():
        return {}, []
    from usdahd.usd import schema

    try:
        stage = open_stage(out)
    except StageError:
        return {}, [f"{out}: the previous output layer is unreadable; every prim is re-baked"]
    prev, warnings = {}, []
    for prim in schema.prims_with_api(stage):
        try:
            res = schema.read_results(prim)
        except Exception:  # an invalid old record is simply re-baked
            continue
        if res is None:
            continue
        outside = [p for p in res.textures.values() if not _inside_lightmaps(Path(p), out)]
        if outside:
            shown = res.asset_paths.get(next(iter(res.asset_paths), ""), outside[0])
            warnings.append(
                f"{prim.GetPath()}: the previous bake record in {out.name} names textures "
                f"outside {out.parent / LIGHTMAPS_DIR} (e.g. {shown}); ignored, the prim is "
                "re-baked"
            )
            continue
        prev[str(prim.GetPath())] = res
    return prev, warnings


#: Bytes of working memory a whole bake may plan for (SH, fits and copies; see bake()).
MAX_BAKE_BYTES = int(
    os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    if hasattr(os, "sysconf") and "SC_PHYS_PAGES" in os.sysconf_names
    else 64 * 2**30
)


def _image_from_texels(values: np.ndarray, texels, fill=0) -> np.ndarray:
    """Scatter per-texel values (n, c) into an image (h, w, c) (row 0 = top)."""
    w, h = texels.resolution
    img = np.full((h, w, values.shape[-1]), fill, dtype=values.dtype)
    img[texels.xy[:, 1], texels.xy[:, 0]] = values
    return img


def bake(stage_path, opts: BakeOptions | None = None) -> dict:
    """Bake a stage; returns the report printed by ``usdahd bake --json``.

    Every check that can fail runs before tracing (:func:`preflight`: source readable, output
    folder writable, dependencies of the options present, prims exist, resolutions within
    limits); ``dry_run`` runs them all and reports the texel total. Raises
    InputError/StageError/UsageError/OutputError (exit 2) for unusable input or output; per-prim
    failures are reported in the result with ``exit_code`` 1.

    Outputs (see :func:`_commit`): textures go to new content-addressed names, the override
    layer's atomic replace is the single commit point, and files of this layer no layer
    references are removed afterwards. A lock file serialises bakes of one output: a second
    bake of the same output waits (with a message) until the first has committed.
    """
    from usdahd.progress import CompileNotice
    from usdahd.usd import plugin

    plugin.register()
    opts = opts or BakeOptions()
    _check_options(opts)
    t_start = time.perf_counter()
    src, out = preflight(stage_path, opts)
    try:
        stage = open_stage(src)
        if opts.scenario:  # before any check or read: the variant decides what the stage holds
            from usdahd.usd import scenarios

            chosen = scenarios.resolve(stage, opts.scenario)
            scenarios.select(stage, chosen)
            opts = dataclasses.replace(opts, scenario=chosen.spec())
        _check_stage(src, stage, opts)
        if opts.dry_run:
            return _bake_locked(src, out, stage, opts, t_start)
        with CompileNotice(quiet=bool(opts.quiet)), output_lock(out, opts):
            try:
                return _bake_locked(src, out, stage, opts, t_start)
            finally:
                cleanup_outputs(out)
    except UnicodeDecodeError:  # pxr hands Python a name or string that is not UTF-8
        raise StageError(utf8_problem(src)) from None


def _bake_locked(src: Path, out: Path, stage, opts: BakeOptions, t_start: float) -> dict:
    from usdahd.usd import schema
    from usdahd.usd.reader import load_scene

    # Meshes carrying the API select themselves (bake on); else every visible mesh.
    api_prims = {str(p.GetPath()): p for p in schema.prims_with_api(stage)}
    uv_default = opts.uv or DEFAULTS["uv"]
    checked = _check_values(src, stage, uv_default)
    scene = load_scene(stage, uv_name=uv_default, prims=opts.prims, time=opts.time)
    for m in scene.meshes:
        if m.path in checked.prim_errors:
            m.bake = False
    if api_prims:
        for m in scene.meshes:
            if m.bake:
                p = api_prims.get(m.path)
                m.bake = bool(p) and bool(schema.read_inputs(p, validate=False).bake)
    prev, untrusted = _previous_results(out)
    report = {
        "stage": str(src),
        "output": str(out),
        "time": scene.time_setting,
        **({"scenario": opts.scenario} if opts.scenario else {}),
        "prims": [],
        "warnings": list(checked.warnings) + list(scene.warnings) + untrusted,
        "notes": [],
        "dry_run": bool(opts.dry_run),
        "written": False,
        "output_exists": out.is_file(),
    }
    from pxr import UsdGeom

    if not UsdGeom.StageHasAuthoredMetersPerUnit(stage):
        report["warnings"].append(
            f"{src.name} does not author metersPerUnit, so USD's fallback applies "
            f"({scene.meters_per_unit:g} m per unit); texel densities are per metre. Author "
            "metersPerUnit on the root layer or pass --resolution if the lightmaps come out tiny"
        )
    from pxr import Sdf

    old_layer = Sdf.Layer.FindOrOpen(str(out)) if prev else None
    jobs = []
    failed = 0
    # Meshes the scene could not extract (bad points, topology, primvars): that prim fails,
    # the rest of the stage still bakes.
    selected = set(opts.prims or [])
    for path, msg in sorted(checked.prim_errors.items()):
        if not selected or any(path == p or path.startswith(p + "/") for p in selected):
            report["prims"].append({"path": path, "status": "failed", "error": msg})
            report["prims"][-1]["warnings"] = []
            failed += 1
    for path, msg in sorted(getattr(scene, "failed", {}).items()):
        report["prims"].append({"path": path, "status": "failed", "error": msg, "warnings": []})
        failed += 1
    for i, mesh in enumerate(scene.meshes):
        if not mesh.bake:
            continue
        entry = {"path": mesh.path, "warnings": list(mesh.warnings)}
        report["prims"].append(entry)
        try:
            job = _plan(scene, i, mesh, stage, opts, entry, prev, old_layer)
        except (InputError, UsageError, BakeError) as exc:
            entry.update(status="failed", error=str(exc))
            failed += 1
            continue
        entry["resolution"] = list(job.resolution)
        job.normals = scene.computed_normals.get(mesh.path)
        if max(job.resolution) < TINY_RESOLUTION and not settings_resolution_given(job):
            entry["warnings"].append(
                f"texel density {job.settings['texel_density']:g}/m gives only "
                f"{job.resolution[0]}x{job.resolution[1]} texels: check the stage's "
                "metersPerUnit or pass --texel-density / --resolution"
            )
        if job.unwrapped and not any(
            "xatlas" in w for w in entry["warnings"] + entry.get("notes", [])
        ):
            entry["warnings"].append(
                f"no UV set {job.settings['uv']!r}: unwrapped with xatlas into "
                f"{job.resolution[0]}x{job.resolution[1]}; the UVs are authored in the output layer"
            )
        jobs.append(job)
    if not jobs and not failed:
        raise InputError(_no_mesh_message(src, stage, api_prims))
    # Hash after planning, so unwrapped meshes hash the UVs that the output layer will hold
    # (the validator recomputes these from the output stage).
    parts = scene_hash_parts(scene)
    for job in jobs:
        job.content_hash, job.parts = content_hash(parts, job.path, job.settings, generator_id())
        old = prev.get(job.path)
        unchanged = old is not None and old.content_hash == job.content_hash
        if unchanged and not opts.force and _files_exist(old):
            job.report["status"] = "skipped"
            job.previous = old
            continue
        job.report["status"] = "planned"
        if old is not None and _files_exist(old):
            job.fallback = old  # a prim that fails now (e.g. disk full) keeps its old record
        if opts.force:
            reason = "forced"
        elif old is None:
            reason = "no previous bake"
        else:
            what = changed_parts(old.part_hashes, job.parts)
            reason = "changed: " + ", ".join(what) if what else "texture files missing"
            refit = _refit_source(job, old, what)
            if refit is not None:
                job.refit_from = refit
                changed = sorted(
                    k
                    for k in REFIT_SETTINGS
                    if _norm(old.settings).get(k) != _norm(job.settings).get(k)
                )
                reason = (
                    f"refit: only {', '.join(changed)} changed; fitted from the SH sidecar, "
                    "0 rays traced"
                )
        job.report["reason"] = reason
    # Prims not selected this time (--prim) or failing now keep their previous results: nothing
    # already baked is lost (the validator reports them stale if their inputs changed).
    planned = {j.path for j in jobs}
    for path, old in prev.items():
        if path not in planned and stage.GetPrimAtPath(path):
            keep = PrimJob(path=path, mesh=None, settings={}, previous=old)
            keep.report = {"path": path, "status": "kept"}
            jobs.append(keep)
    todo = [j for j in jobs if j.report["status"] == "planned"]
    texels_total = sum(int(j.resolution[0]) * int(j.resolution[1]) for j in todo)
    report["texels_total"] = texels_total
    # (n, 3, 9) float32 SH per texel plus the traced and fitted copies: a rough peak.
    report["memory_estimate_bytes"] = int(texels_total * 27 * 4 * 4)
    if report["memory_estimate_bytes"] > MAX_BAKE_BYTES:
        raise UsageError(
            f"{src}: the planned lightmaps total {texels_total:.3g} texels (about "
            f"{report['memory_estimate_bytes'] / 2**30:.1f} GiB while baking); lower "
            "--resolution / --texel-density or the ahdLightmap:resolution inputs, or bake "
            "fewer prims at once (--prim)"
        )
    if is_dark(scene):
        report["warnings"].append(
            "the stage has no lights and no emissive surfaces: every lightmap is black "
            "(nothing was traced); add a UsdLux light or an emissiveColor"
        )
    if opts.dry_run:
        report["exit_code"] = 1 if failed else 0
        report["seconds"] = time.perf_counter() - t_start
        return report

    if todo:
        _bake_jobs(scene, todo, out, opts)
    for j in todo:
        if j.report["status"] == "failed":
            failed += 1
    _fault("textures_staged")
    old_refs = _referenced(out) or set()
    if any(j.results is not None or j.previous is not None or j.fallback for j in jobs):
        _commit_textures([j for j in todo if j.results is not None], out)
        cleanup_outputs(out, staged_only=True)  # failed prims' partial files: free the space
        _fault("textures_committed")
        report["written"] = _author_layer(src, out, stage, jobs, opts.scenario)
        _fault("layer_replaced")
        if report["written"]:
            _remove_legacy(out, old_refs)
    for j in todo:
        if j.report["status"] == "failed" and j.fallback is not None:
            j.report["previous_kept"] = True
    report["exit_code"] = 1 if failed else 0
    report["seconds"] = time.perf_counter() - t_start
    return report


#: Settings that only change the fit and encoding of the baked SH, never the SH: a change of
#: only these refits from the previous bake's float32 SH sidecar instead of tracing.
REFIT_SETTINGS = ("model", "ratio", "solver", "padding", "container")


def _norm(settings: dict) -> dict:
    """Settings as the layer stores them (JSON round trip: tuples become lists)."""
    return json.loads(json.dumps(settings, sort_keys=True, default=str))


def _refit_source(job, old, changed: list[str]) -> str | None:
    """The previous bake's SH sidecar when ``job`` differs from it only in REFIT_SETTINGS (same
    geometry, UVs, lights, materials, baker, resolution), and the sidecar is the file that bake
    wrote (digest); else None (trace again)."""
    if not changed or set(changed) != {"settings"}:
        return None
    a, b = _norm(old.settings), _norm(job.settings)
    if {k for k in set(a) | set(b) if a.get(k) != b.get(k)} - set(REFIT_SETTINGS):
        return None
    side = old.textures.get("sh")
    if side is None or not Path(side).is_file() or tuple(old.resolution) != tuple(job.resolution):
        return None
    from usdahd.usd import schema

    want = old.digests.get("sh")
    if not want or schema.file_digest(side) != want:
        return None
    return side


def _refit_sh(job) -> None:
    """job.sh from the previous bake's sidecar at job's texels (the SH after fill, denoise and
    stitching, exactly what was fitted); BakeError if the sidecar does not cover them."""
    from usdahd import images
    from usdahd.bake.texels import rasterize
    from usdahd.usd import schema

    if job.texels is None:
        job.texels = rasterize(job.mesh, job.resolution)
    px = images.read(job.refit_from, channels=schema.SH_SIDECAR_CHANNELS).pixels
    w, h = job.texels.resolution
    if px.shape[:2] != (h, w):
        raise BakeError(f"{job.path}: SH sidecar {job.refit_from} is not {w}x{h}")
    vals = px[job.texels.xy[:, 1], job.texels.xy[:, 0]].astype(np.float32)
    if not (vals[:, 27] > 0.5).all():
        raise BakeError(f"{job.path}: SH sidecar {job.refit_from} does not cover every texel")
    job.sh = np.ascontiguousarray(vals[:, :27].reshape(-1, 3, 9))
    job.stats = {"rays": 0, "invalid": np.zeros(len(job.texels), bool)}
    job.report.update(
        texels=len(job.texels),
        rays=0,
        rays_saved=0,
        invalid_texels=0,
        trace_seconds=0.0,
        refit=True,
    )


def _author_layer(
    src: Path, out: Path, source_stage, jobs: list[PrimJob], scenario: str | None = None
) -> bool:
    """Write the override layer; its atomic replace is the bake's single commit point.

    The layer is built in memory by :func:`usdahd.usd.author.build_layer`, exported to a fresh
    temp file beside ``out`` (created by mkstemp and kept, so no other process can take its
    name), fsynced, then renamed over ``out``. returns False when the content is unchanged
    (nothing replaced). Raises OutputError when the layer cannot be written (disk full,
    read-only); ``out`` is then untouched.
    """
    from usdahd.usd import author

    out.parent.mkdir(parents=True, exist_ok=True)
    layer = author.build_layer(src, out, source_stage, jobs, scenario)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{out.stem}.", suffix=out.suffix, dir=out.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        author.export_layer(layer, tmp_name, out)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        _fsync(tmp)
        _fault("layer_exported")
        new = tmp.read_bytes()
        if out.is_file() and out.read_bytes() == new:
            return False
        os.replace(tmp, out)  # the commit point
        _fsync(out.parent, directory=True)
        return True
    finally:
        if tmp.exists():
            tmp.unlink()


def _job_seed(seed: int, path: str) -> int:
    """Independent, reproducible random stream per prim (does not depend on bake order)."""
    return int.from_bytes(hashlib.sha256(f"{seed}:{path}".encode()).digest()[:4], "little")


def _trace_jobs(scene, jobs: list[PrimJob], opts: BakeOptions) -> None:
    """Rasterise texels and integrate radiance SH for each job (sets job.texels/sh/stats)."""
    from usdahd.bake.integrate import bake_texels
    from usdahd.bake.texels import rasterize
    from usdahd.bake.trace import Tracer
    from usdahd.errors import UsdAhdError
    from usdahd.progress import Progress

    dark = is_dark(scene)
    t0 = time.perf_counter()
    tracer = None if dark else Tracer(scene)
    if not dark:
        _status(opts, f"BVH: {scene.triangle_count} triangles in {time.perf_counter() - t0:.2f}s")
    for k, job in enumerate(jobs):
        t1 = time.perf_counter()
        try:
            if job.texels is None:
                job.texels = rasterize(job.mesh, job.resolution)
            if len(job.texels) == 0:
                raise BakeError(
                    f"{job.path}: no texel covered at {job.resolution[0]}x{job.resolution[1]}: "
                    f"its UVs {job.settings['uv']!r} are degenerate or outside [0,1]"
                )
            if dark:  # nothing emits light: the radiance is exactly zero, trace nothing
                n = len(job.texels)
                job.sh = np.zeros((n, 3, 9), np.float32)
                job.stats = {"rays": 0, "invalid": np.zeros(n, bool)}
            else:
                bar = Progress(f"[{k + 1}/{len(jobs)}] {job.path}", quiet=opts.quiet)
                job.sh, job.stats = bake_texels(
                    scene,
                    tracer,
                    job.texels,
                    samples=int(job.settings["samples"]),
                    bounces=int(job.settings["bounces"]),
                    seed=_job_seed(opts.seed, job.path),
                    adaptive=bool(job.settings["adaptive"]),
                    progress=bar.update,
                    mesh=next((i for i, m in enumerate(scene.meshes) if m is job.mesh), None),
                )
                bar.close()
        except UsdAhdError as exc:
            job.report.update(status="failed", error=str(exc))
            continue
        st = job.texels.stats
        job.report.update(
            texels=len(job.texels),
            rays=int(job.stats.get("rays", 0)),
            rays_saved=int(job.stats.get("rays_saved", 0)),
            invalid_texels=int(np.count_nonzero(job.stats.get("invalid", []))),
            uv_overlap_texels=int(st.get("overlap_texels", 0)),
            uv_outside_fraction=float(st.get("uv_outside_fraction", 0.0)),
            trace_seconds=time.perf_counter() - t1,
        )
        if st.get("overlap_texels"):
            job.report["warnings"].append(
                f"{st['overlap_texels']} texels are covered by overlapping UV triangles"
            )
        if st.get("uv_outside_fraction"):
            job.report["warnings"].append(
                f"{100 * st['uv_outside_fraction']:.1f}% of UVs lie outside [0,1]"
            )


def _bake_jobs(scene, jobs: list[PrimJob], out: Path, opts: BakeOptions) -> None:
    """Trace, post-process, fit, encode and write textures for every job (atomically)."""
    from usdahd.bake import post

    refits = []
    for job in [j for j in jobs if j.refit_from]:
        try:
            _refit_sh(job)
            refits.append(job)
            _status(opts, f"{job.path}: refit from the SH sidecar, 0 rays traced")
        except (UsdAhdError, OSError) as exc:  # an unusable sidecar: trace after all
            job.refit_from = None
            job.report["reason"] += f" (sidecar unusable: {exc}; traced)"
    jobs = [j for j in jobs if j not in refits]
    if jobs:  # no BVH when every job refits
        _trace_jobs(scene, jobs, opts)
    _fault("traced")
    ok = [j for j in jobs if j.report.get("status") != "failed"]
    from usdahd.bake.texels import chart_ids

    # Order (docs/texels.md): fill invalid -> denoise -> stitch seams -> fit -> encode -> dilate.
    for job in ok:
        job.charts = chart_ids(job.mesh)[job.texels.triangle]
        invalid = np.asarray(job.stats.get("invalid", np.zeros(len(job.texels), bool)))
        if invalid.any():
            job.sh, unfilled = post.fill_invalid(job.sh, job.texels, invalid, charts=job.charts)
            if unfilled.any():
                faces = np.unique(job.mesh.face[job.texels.triangle[unfilled]])
                shown = ", ".join(str(int(f)) for f in faces[:8])
                more = f" and {len(faces) - 8} more" if len(faces) > 8 else ""
                job.report["warnings"].append(
                    f"{int(unfilled.sum())} texels see mostly back faces (inside geometry?) and "
                    f"have no valid neighbour in their chart: face(s) {shown}{more} keep their "
                    "own estimate, which treats back faces as two-sided; check those faces "
                    "for flipped normals, duplicates or enclosing geometry"
                )
    if opts.denoise:
        from usdahd.bake import denoise

        for job in ok:
            job.sh = denoise.denoise_sh(job.sh, job.texels, charts=job.charts)
    if ok:
        t0 = time.perf_counter()
        seams = post.find_seams([j.mesh for j in ok], [j.texels.resolution for j in ok])
        stitched = post.stitch([j.sh for j in ok], [j.texels for j in ok], seams)
        for job, values in zip(ok, stitched, strict=True):
            job.sh = np.asarray(values, dtype=np.float32)
        _status(opts, f"seams: stitched in {time.perf_counter() - t0:.2f}s")
    for job in refits + ok:
        try:
            _encode_and_write(job, out, opts)
        except UsdAhdError as exc:  # ImageError, BakeError, InputError: this prim only
            job.report.update(status="failed", error=_write_failure(job.path, exc, out))


def _write_failure(prim_path: str, exc: Exception, out: Path) -> str:
    """The message of a prim whose encode/write failed; a full disk is named as such."""
    import shutil

    from usdahd.errors import ImageError

    text = str(exc)
    folder = out.parent / LIGHTMAPS_DIR
    if isinstance(exc, ImageError) and folder.is_dir():
        free = shutil.disk_usage(folder).free
        if free < 4 * 2**20 or "No space" in text:
            return (
                f"{prim_path}: cannot write its lightmap textures in {folder}: the disk is full "
                f"({free / 1024:.0f} KiB free); free some space and re-run"
            )
    return f"{prim_path}: {text}" if prim_path not in text else text


def _write_ktx2(job, lay, img, mask, path: Path, factors: dict) -> None:
    """The KTX2 engine container of one texture (chart-aware mips, BC7 / RGBA16F), next to the
    EXR/PNG; its key/value data carries the packing and decode factors."""
    from usdahd import ktx2
    from usdahd.bake.texels import chart_ids

    if job.charts is None:
        job.charts = chart_ids(job.mesh)[job.texels.triangle]
    charts = _image_from_texels(np.asarray(job.charts)[:, None], job.texels, fill=-1)[..., 0]
    kv = {"usdahd:packing": lay.packing, "usdahd:role": lay.role}
    kv.update({f"usdahd:{k}": repr(float(v)) for k, v in factors.items()})
    info = ktx2.write(path, img, mask, charts, lay.format, attributes=kv)
    job.report.setdefault("ktx2", {})[lay.role] = {"path": str(path), **info}


def _factor_attrs(factors: dict) -> dict:
    """Decode factors also stored in each file's metadata (the schema is authoritative)."""
    return {f"usdahd:{k}": float(v) for k, v in factors.items()}


def _encode_and_write(job: PrimJob, out: Path, opts: BakeOptions) -> None:
    """Fit the model, quantize, dilate, write textures + SH sidecar; set job.results."""
    from usdahd import images
    from usdahd.bake import post
    from usdahd.usd import schema

    t0 = time.perf_counter()
    s = job.settings
    mod = models.get(s["model"])
    fitted = models.fit(job.sh, s["model"], ratio=s["ratio"], solver=s["solver"])
    channels, factors = mod.encode(fitted.params, ratio=s["ratio"])
    decoded = mod.decode(channels, ratio=s["ratio"], factors=factors)
    # Quantization error at n = z (what validate's IzCheck measures): the decoded model against
    # the unquantized fit (for IrradZ models the fit's I_z = max(0, I_z of the SH) exactly).
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0], np.float32), (len(job.texels), 3))
    got = mod.evaluate(decoded, z)
    want = mod.evaluate(models.representable(fitted, mod), z).astype(np.float64)
    scale = np.maximum(np.abs(want).max(axis=-1, keepdims=True), 1e-6)
    err = np.abs(got - want) / scale
    job.report["iz_max_rel_error"] = float(err.max()) if err.size else 0.0
    if not np.isfinite(got).all():
        raise BakeError(f"{job.path}: decoded lightmap contains NaN/Inf (please report a bug)")

    w, h = job.texels.resolution
    mask = np.zeros((h, w), bool)
    mask[job.texels.xy[:, 1], job.texels.xy[:, 0]] = True
    padding = int(s["padding"])
    textures, digests = {}, {}
    for lay in mod.layout(s["ratio"]):
        values = np.asarray(channels[lay.role])
        values = values.reshape(len(job.texels), -1)
        img = post.dilate(_image_from_texels(values, job.texels), mask, padding)
        img = img.astype(values.dtype, copy=False)
        path = texture_path(out, job.path, lay.role, lay.extension)
        images.write(
            path,
            img,
            format=lay.format,
            color_space=lay.color_space,
            channels=lay.channels,
            attributes=_factor_attrs(factors),
        )
        textures[lay.role] = str(path)
        digests[lay.role] = schema.file_digest(path)
        if s.get("container") == "ktx2":
            _write_ktx2(job, lay, img, mask, path.with_suffix(".ktx2"), factors)
    # The SH sidecar (float32, with coverage) the validator checks I_z against.
    side = np.concatenate(
        [
            job.sh.reshape(len(job.texels), 27).astype(np.float32),
            np.ones((len(job.texels), 1), np.float32),
        ],
        axis=1,
    )
    side_img = _image_from_texels(side, job.texels)
    side_path = texture_path(out, job.path, schema.SIDECAR_ROLE, ".exr")
    images.write(
        side_path, side_img, format="float", color_space="raw", channels=schema.SH_SIDECAR_CHANNELS
    )
    textures[schema.SIDECAR_ROLE] = str(side_path)
    digests[schema.SIDECAR_ROLE] = schema.file_digest(side_path)
    job.results = schema.BakeResults(
        model=s["model"],
        ratio=s["ratio"],
        solver=s["solver"],
        uv_primvar=s["uv"],
        resolution=(int(w), int(h)),
        textures=textures,
        factors={k: float(v) for k, v in factors.items()},
        content_hash=job.content_hash,
        part_hashes=job.parts,
        settings=s,
        generator=f"usdahd {__version__}",
        digests=digests,
    )
    job.report["status"] = "baked"
    job.report["seconds"] = job.report.get("trace_seconds", 0.0) + time.perf_counter() - t0
