"""The per-prim stages of a bake, in order: trace (or refit from the SH sidecar), fill invalid
texels, denoise, stitch seams, fit the model, encode, dilate and write the textures + SH sidecar.
Each stage fills in its :class:`~usdahd.pipeline.plan.PrimJob` fields; a failure marks that
job ``failed`` in its report and the other prims go on. :func:`bake_jobs` runs them all (what
:mod:`usdahd.pipeline.run` calls once the plan is made).
"""

from __future__ import annotations

import hashlib
import sys
import time
from pathlib import Path

import numpy as np

from usdahd import models
from usdahd.errors import BakeError, UsdAhdError
from usdahd.pipeline.outputs import LIGHTMAPS_DIR, fault_point, texture_path, write_role_texture
from usdahd.pipeline.plan import PrimJob
from usdahd.pipeline.settings import BakeOptions
from usdahd.scene.hashing import is_dark
from usdahd.version import __version__

__all__ = ["bake_jobs"]


def _status(opts: BakeOptions, msg: str) -> None:
    if not opts.quiet:
        print(msg, file=sys.stderr)


def _refit_sh(job: PrimJob) -> None:
    """job.sh from the previous bake's sidecar at job's texels (the SH after fill, denoise and
    stitching, exactly what was fitted); BakeError if the sidecar does not cover them."""
    from usdahd import sidecar
    from usdahd.bake import post
    from usdahd.bake.texels import rasterize
    from usdahd.usd import schema

    if job.texels is None:
        job.texels = rasterize(job.mesh, job.resolution)
    if job.fallback is not None and job.fallback.textures.get(schema.SIDECAR_ROLE) == str(
        job.refit_from
    ):  # the record's region of the sidecar (its page's, in an atlas)
        px = sidecar.read_record(job.fallback)
    else:
        px = sidecar.read(job.refit_from)
    w, h = job.texels.resolution
    if px.shape[:2] != (h, w):
        raise BakeError(f"{job.path}: SH sidecar {job.refit_from} is not {w}x{h}")
    vals = post.from_image(job.texels, px).astype(np.float32)
    if not (vals[:, sidecar.COVERAGE] > 0.5).all():
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


def _job_seed(seed: int, path: str) -> int:
    """Independent, reproducible random stream per prim (does not depend on bake order)."""
    return int.from_bytes(hashlib.sha256(f"{seed}:{path}".encode()).digest()[:4], "little")


#: Prims traced at once. Each prim's texels are spread over the tracer's threads, but a prim
#: ends with a tail (its last parts on one thread) and has serial steps around its tracing
#: (contacts, chunk set-up, the inside-geometry test); other prims in flight fill both.
#: Results do not depend on it (each prim has its own random stream and ray count). Warm
#: 256-spp bakes at 32² (report seconds, medians of 5-7): 2 -> 3 prims stretched_boxes 232 ->
#: 226-228 ms, exterior_sun_sky 257 -> 249, cornell_box 1,180 -> 1,172; 4: no better.
JOB_THREADS = 3


class _Cancelled(Exception):
    """Raised in a prim's progress callback once another prim has failed unexpectedly."""


def _trace_jobs(scene, jobs: list[PrimJob], opts: BakeOptions) -> None:
    """Rasterise texels and integrate radiance SH for each job (sets job.texels/sh/stats),
    ``JOB_THREADS`` prims at a time; with ``--workers`` / ``--scheduler`` the tracing runs in
    tiles on a Dask cluster (:mod:`usdahd.pipeline.distributed`), with the same results."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from usdahd.bake.texels import rasterize
    from usdahd.bake.trace import Tracer

    dark = is_dark(scene)
    cluster = not dark and (opts.workers is not None or opts.scheduler is not None)
    if cluster:
        remote = []
        for job in jobs:
            try:
                if job.texels is None:
                    job.texels = rasterize(job.mesh, job.resolution)
                _check_covered(job)
            except UsdAhdError as exc:
                job.report.update(status="failed", error=str(exc))
                continue
            mesh = next((i for i, m in enumerate(scene.meshes) if m is job.mesh), None)
            remote.append((job, mesh, _job_seed(opts.seed, job.path)))
        if remote:
            from usdahd.pipeline import distributed

            distributed.trace_jobs(scene, remote, opts, _record_trace)
        return
    tracer = None
    if not dark:
        t0 = time.perf_counter()
        tracer = Tracer(scene)
        _status(opts, f"BVH: {scene.triangle_count} triangles in {time.perf_counter() - t0:.2f}s")
    running: list[int] = []  # jobs being traced; on a terminal the first one draws its bar
    lock = threading.Lock()
    stop = threading.Event()

    def first(k: int) -> bool:
        with lock:
            return not running or running[0] == k

    def one(k: int, job: PrimJob) -> None:
        if stop.is_set():  # another prim broke: start no more
            return
        with lock:
            running.append(k)
        try:
            _trace_job(scene, tracer, k, jobs, opts, first, stop)
        except UsdAhdError as exc:
            job.report.update(status="failed", error=str(exc))
        except _Cancelled:
            pass
        except BaseException:
            stop.set()
            raise
        finally:
            with lock:
                running.remove(k)

    try:
        if len(jobs) < 2 or JOB_THREADS < 2:
            for k, job in enumerate(jobs):
                one(k, job)
            return
        with ThreadPoolExecutor(JOB_THREADS, thread_name_prefix="usdahd-prim") as pool:
            futures = [pool.submit(one, k, job) for k, job in enumerate(jobs)]
            try:
                for f in futures:
                    f.result()
            except BaseException:  # Ctrl-C or a bug: the prims in flight stop at their next chunk
                stop.set()
                for f in futures:
                    f.cancel()
                raise
    finally:
        if tracer is not None:
            tracer.close()


def _check_covered(job: PrimJob) -> None:
    if len(job.texels) == 0:
        raise BakeError(
            f"{job.path}: no texel covered at {job.resolution[0]}x{job.resolution[1]}: "
            f"its UVs {job.settings['uv']!r} are degenerate or outside [0,1]"
        )


def _trace_job(scene, tracer, k: int, jobs: list[PrimJob], opts, first, stop) -> None:
    """Trace ``jobs[k]`` on its own fork of ``tracer`` (None: the scene is dark); ``first(k)``
    says whether its bar may draw on a terminal, ``stop`` (set) cancels it at its next chunk."""
    from usdahd.bake.contacts import push_off_contacts
    from usdahd.bake.integrate import bake_texels
    from usdahd.bake.texels import rasterize
    from usdahd.progress import Progress

    job = jobs[k]
    t1 = time.perf_counter()
    if job.texels is None:
        job.texels = rasterize(job.mesh, job.resolution)
    _check_covered(job)
    if tracer is None:  # nothing emits light: the radiance is exactly zero, trace nothing
        n = len(job.texels)
        job.sh = np.zeros((n, 3, 9), np.float32)
        job.stats = {"rays": 0, "invalid": np.zeros(n, bool)}
        _record_trace(job, t1)
        return
    own = tracer.fork()
    mesh = next((i for i, m in enumerate(scene.meshes) if m is job.mesh), None)
    # sample points on contacts moved in front of the surface they touch
    # (docs/texels.md, "Contacts"); the rest of the texel stays as rasterised
    job.texels, contact_invalid = push_off_contacts(job.texels, job.mesh, own)
    bar = Progress(f"[{k + 1}/{len(jobs)}] {job.path}", quiet=opts.quiet)

    def progress(done, total=None):
        if stop.is_set():
            raise _Cancelled
        bar.update(done, total, draw=not bar.tty or first(k))

    job.sh, job.stats = bake_texels(
        scene,
        own,
        job.texels,
        samples=int(job.settings["samples"]),
        bounces=int(job.settings["bounces"]),
        seed=_job_seed(opts.seed, job.path),
        adaptive=bool(job.settings["adaptive"]),
        progress=progress,
        mesh=mesh,
    )
    bar.close()
    job.stats["invalid"] = job.stats["invalid"] | contact_invalid
    _record_trace(job, t1)


def _record_trace(job: PrimJob, t1: float) -> None:
    """A traced job's report: texel and ray counts, contact/UV statistics and warnings."""
    st = job.texels.stats
    job.report.update(
        texels=len(job.texels),
        rays=int(job.stats.get("rays", 0)),
        rays_saved=int(job.stats.get("rays_saved", 0)),
        invalid_texels=int(np.count_nonzero(job.stats.get("invalid", []))),
        contact_texels=int(st.get("contact_texels", 0)),
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


def bake_jobs(scene, jobs: list[PrimJob], out: Path, opts: BakeOptions) -> None:
    """Trace, post-process, fit, encode and write textures for every job (atomically).

    Subdivision meshes (catmullClark / loop) are traced on their refinement for the duration
    (:func:`usdahd.scene.subdiv.refine_scene`); the cages are put back before authoring."""
    from usdahd.scene import subdiv

    t0 = time.perf_counter()
    undo = subdiv.refine_scene(scene, jobs)
    if undo:
        _status(
            opts,
            f"subdivision: {len(undo)} meshes refined in {time.perf_counter() - t0:.2f}s "
            f"({scene.triangle_count} triangles traced)",
        )
    try:
        _bake_jobs(scene, jobs, out, opts)
    finally:
        subdiv.restore_scene(scene, undo)


def _bake_jobs(scene, jobs: list[PrimJob], out: Path, opts: BakeOptions) -> None:
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
    fault_point("traced")
    ok = [j for j in jobs if j.report.get("status") != "failed"]
    from usdahd.bake.texels import chart_ids

    # Order (docs/texels.md): fill invalid -> denoise -> stitch seams -> fit -> encode -> dilate.
    for job in ok:
        job.charts = chart_ids(job.mesh)[job.texels.triangle]
        invalid = np.asarray(job.stats.get("invalid", np.zeros(len(job.texels), bool)))
        if invalid.any():
            job.sh, unfilled = post.fill_invalid(job.sh, job.texels, invalid, charts=job.charts)
            # a chart wholly covered (e.g. a base resting on a floor): unseen, keep its estimate
            unfilled &= ~np.asarray(job.stats.get("covered", np.zeros(len(invalid), bool)))
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
    if opts.denoise and ok:
        from usdahd.bake import denoise

        t0 = time.perf_counter()
        records = []
        for job in ok:
            iz_var = denoise.integrator_iz_variance(job.stats)
            var = None if iz_var is None else denoise.sh_variance(job.sh, iz_var)
            if var is not None:  # float32: the denoiser pools it on float32 canvases anyway
                # (one value per channel, broadcast over the 9 coefficients: 12 bytes a texel)
                var = np.broadcast_to(var[:, :, :1].astype(np.float32), var.shape)
            records.append(dict(sh=job.sh, texels=job.texels, charts=job.charts, variance=var))
        # every prim's charts at once: one OIDN run per mosaic image and coefficient
        denoised = denoise.denoise_records(
            records, variance_bound=True, variance_pool=denoise.VARIANCE_POOL, inplace=True
        )
        del records
        for job, sh in zip(ok, denoised, strict=True):
            job.sh = sh
        _status(opts, f"denoised in {time.perf_counter() - t0:.2f}s (--no-denoise skips it)")
    if ok:
        t0 = time.perf_counter()
        seams = post.find_seams([j.mesh for j in ok], [j.texels.resolution for j in ok])
        stitched = post.stitch([j.sh for j in ok], [j.texels for j in ok], seams)
        for job, values in zip(ok, stitched, strict=True):
            job.sh = np.asarray(values, dtype=np.float32)
        _status(opts, f"seams: stitched in {time.perf_counter() - t0:.2f}s")
    if opts.atlas:
        # Fit, encode and write per page (usdahd.pipeline.atlas, called by run.py once the
        # records kept from the previous bake are known); the chart ids are taken now, while
        # subdivision meshes are still refined (job.texels index the refined triangles).
        for job in refits + ok:
            if job.charts is None:
                job.charts = chart_ids(job.mesh)[job.texels.triangle]
        return
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


def _write_ktx2(job: PrimJob, lay, img, mask, path: Path, factors: dict, bc: bool) -> None:
    """The KTX2 engine container of one texture (chart-aware mips; lossless, or BC6H / BC7 with
    ``bc``), next to the EXR/PNG; its key/value data carries the packing and decode factors."""
    from usdahd import ktx2
    from usdahd.bake import post
    from usdahd.bake.texels import chart_ids

    if job.charts is None:
        job.charts = chart_ids(job.mesh)[job.texels.triangle]
    charts = post.to_image(job.texels, np.asarray(job.charts), fill=-1)
    kv = {"usdahd:packing": lay.packing, "usdahd:role": lay.role}
    kv.update({f"usdahd:{k}": repr(float(v)) for k, v in factors.items()})
    comp = "bc" if bc else "none"
    info = ktx2.write(path, img, mask, charts, lay.format, compression=comp, attributes=kv)
    job.report.setdefault("ktx2", {})[lay.role] = {"path": str(path), **info}


def _encode_and_write(job: PrimJob, out: Path, opts: BakeOptions) -> None:
    """Fit the model, quantize, dilate, write textures + SH sidecar; set job.results."""
    from usdahd import sidecar
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
    mask = post.coverage_mask(job.texels)
    padding = int(s["padding"])
    textures, digests = {}, {}
    for lay in mod.layout(s["ratio"]):
        values = np.asarray(channels[lay.role])
        values = values.reshape(len(job.texels), -1)
        img = post.dilate(post.to_image(job.texels, values), mask, padding)
        img = img.astype(values.dtype, copy=False)
        path, digests[lay.role] = write_role_texture(out, job.path, lay, img, factors)
        textures[lay.role] = path
        path = Path(path)
        if s.get("container") in ("ktx2", "ktx2-bc"):
            bc = s["container"] == "ktx2-bc"
            _write_ktx2(job, lay, img, mask, path.with_suffix(".ktx2"), factors, bc)
    # The SH sidecar (float32, with coverage) the validator checks I_z against.
    side_img = post.to_image(job.texels, sidecar.pack(job.sh.reshape(len(job.texels), 3, 9)))
    side_path = texture_path(out, job.path, schema.SIDECAR_ROLE, ".exr")
    sidecar.write(side_path, side_img)
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
