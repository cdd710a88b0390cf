"""``usdahd bake`` end to end: :func:`bake` checks (:mod:`~usdahd.pipeline.preflight`), opens
the stage, takes the output lock, plans every prim (:mod:`~usdahd.pipeline.plan`), decides what
is skipped, kept, refitted or traced, runs the stages (:mod:`~usdahd.pipeline.stages`) and
commits (:mod:`~usdahd.pipeline.outputs`: textures, then the override layer, then cleanup).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from usdahd.errors import BakeError, InputError, StageError, UsageError
from usdahd.pipeline.density import (
    SHARED_DENSITY_SHARE,
    STAGE_MIN_TEXELS,
    auto_texel_density,
    density_ceiling,
    mesh_extent,
    shared_density,
    stage_extent,
)
from usdahd.pipeline.outputs import (
    LIGHTMAPS_DIR,
    author_layer,
    cleanup_outputs,
    commit_textures,
    fault_point,
    inside_lightmaps,
    output_lock,
    remove_legacy,
)
from usdahd.pipeline.plan import (
    REFIT_SETTINGS,
    PrimJob,
    plan_job,
    refit_source,
    settings_as_stored,
    settings_resolution_given,
)
from usdahd.pipeline.preflight import (
    check_stage_inputs,
    check_stage_values,
    files_exist,
    preflight,
)
from usdahd.pipeline.settings import (
    DEFAULT_TEXEL_BUDGET,
    DEFAULTS,
    DENSITY_AUTO_MAX,
    MIN_RESOLUTION,
    TINY_RESOLUTION,
    BakeOptions,
    authored_inputs,
    check_options,
)
from usdahd.pipeline.stages import bake_jobs
from usdahd.scene.hashing import changed_parts, content_hash, is_dark, scene_hash_parts
from usdahd.usd import author
from usdahd.usd.checks import no_mesh_message
from usdahd.usd.stage import meters_per_unit_authored, open_stage, prim_at, utf8_problem

__all__ = ["MAX_BAKE_BYTES", "bake"]


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
    # Mesh records and instance entries (an invalid old record is simply re-baked).
    for path, res in schema.stage_records(stage, errors=[]).items():
        outside = [p for p in res.textures.values() if not inside_lightmaps(Path(p), out)]
        if outside:
            shown = res.asset_paths.get(next(iter(res.asset_paths), ""), outside[0])
            warnings.append(
                f"{path}: the previous bake record in {out.name} names textures "
                f"outside {out.parent / LIGHTMAPS_DIR} (e.g. {shown}); ignored, the prim is "
                "re-baked"
            )
            continue
        prev[path] = res
    return prev, warnings


def _density_pool(scene, stage, api_prims: dict, opts: BakeOptions, checked) -> list:
    """Meshes on the automatic texel density: those a bake of the whole stage bakes (with
    --prim, also the ones outside the selection, so the density does not depend on it), minus
    those with an authored ahdLightmap:resolution or texelDensity. Empty when a --resolution
    or --texel-density flag applies to every prim."""
    from usdahd.errors import SchemaError
    from usdahd.usd import schema

    if opts.resolution is not None or opts.texel_density is not None:
        return []
    out = []
    for m in scene.meshes:
        if m.path in checked.prim_errors:
            continue
        prim = prim_at(stage, m.path)
        if not m.bake:
            if not opts.prims or prim is None or prim.IsInstanceProxy():
                continue
            api = api_prims.get(m.path)
            if api_prims and not (api and schema.read_inputs(api, validate=False).bake):
                continue
        # an instance copy's inputs are its prototype mesh's (plan_job reads them there too)
        source = m.instance.source if getattr(m, "instance", None) else m.path
        try:
            authored = authored_inputs(prim_at(stage, source)) if source in api_prims else {}
        except SchemaError:
            continue  # reported by the plan of that prim
        if "resolution" in authored or "texel_density" in authored:
            continue
        out.append(m)
    return out


def _auto_density(scene, stage, api_prims, opts, checked, report) -> float | None:
    """The stage's automatic texel density (density.auto_texel_density), reported; None when no
    prim uses it."""
    pool = _density_pool(scene, stage, api_prims, opts, checked)
    if not pool:
        return None
    budget = int(opts.texel_budget or DEFAULT_TEXEL_BUDGET)
    extents = [mesh_extent(m, scene.meters_per_unit) for m in pool]
    side = stage_extent(pool, scene.meters_per_unit)
    ceiling = density_ceiling(side)
    density, planned, fits = auto_texel_density(extents, budget, ceiling=ceiling)
    report["texel_density"] = {
        "density": density,
        "budget": budget,
        "prims": len(pool),
        "estimated_texels": planned,
        "ceiling": ceiling,
        "stage_extent": round(side, 6),
    }
    why = ""
    if ceiling > DENSITY_AUTO_MAX:
        why = (
            f" (raised from {DENSITY_AUTO_MAX:g}/m so that the stage's largest side, "
            f"{side:.3g} m, gets at least {STAGE_MIN_TEXELS} texels)"
        )
    report["notes"].append(
        f"texel density {density:g}/m for the {len(pool)} prim(s) without an explicit "
        f"resolution or density: the densest step up to {ceiling:g}/m{why} whose maps "
        f"(each at least {MIN_RESOLUTION}x{MIN_RESOLUTION}) fit the texel budget of {budget} "
        f"(about {planned} texels; --texel-budget, --texel-density or --resolution to change)"
    )
    if not fits:
        report["warnings"].append(
            f"the {len(pool)} prims' minimum maps ({MIN_RESOLUTION}x{MIN_RESOLUTION} each, "
            f"{planned} texels) exceed the texel budget of {budget}: raise --texel-budget, or "
            "pass --texel-density / --resolution"
        )
    return density


def _plan_meshes(
    scene, indices, stage, opts, prev, old_layer, auto_density, prop_side
) -> dict[int, tuple[dict, PrimJob | None]]:
    """Plan the meshes at ``indices`` (plan.plan_job): mesh index -> (its report entry, its
    job; None when the prim failed, the entry saying why)."""
    out = {}
    for i in indices:
        mesh = scene.meshes[i]
        entry = {"path": mesh.path, "warnings": list(mesh.warnings)}
        try:
            job = plan_job(
                scene, i, mesh, stage, opts, entry, prev, old_layer, auto_density, prop_side
            )
        except (InputError, UsageError, BakeError) as exc:
            entry.update(status="failed", error=str(exc))
            out[i] = (entry, None)
            continue
        entry["resolution"] = list(job.resolution)
        job.normals = scene.computed_normals.get(mesh.path)
        if (
            max(job.resolution) < TINY_RESOLUTION
            and not settings_resolution_given(job)
            and "min_resolution" not in job.settings
        ):
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
        out[i] = (entry, job)
    return out


def _on_auto_density(job: PrimJob) -> bool:
    return "min_resolution" in job.settings and job.settings.get("texel_density") is not None


def _left_alone(job: PrimJob) -> bool:
    """A prim on the automatic density whose map no prop rule raised."""
    return _on_auto_density(job) and job.raised_from is None


def _shared_density(scene, planned: list, density, report) -> float | None:
    """The density the prims on the automatic density that no prop rule raised are planned
    again at (density.shared_density; ``planned``: (entry, job) of every prim of the density's
    pool), reported; None when it stays ``density``."""
    if density is None:
        return None
    jobs = [job for _, job in planned if job is not None and _on_auto_density(job)]
    raised = [j for j in jobs if j.raised_from is not None]
    alone = [j for j in jobs if j.raised_from is None]
    if not raised or not alone:
        return None
    td = report["texel_density"]
    gains = [density * max(j.resolution) / max(j.raised_from) for j in raised]
    fixed = sum(int(j.resolution[0]) * int(j.resolution[1]) for j in raised)
    # the maps' extents from the UVs they were planned with (an unwrap: its packed atlas)
    extents = [mesh_extent(j.mesh, scene.meters_per_unit) for j in alone]
    new = shared_density(density, gains, extents, fixed, td["budget"])
    if new == density:
        return None
    td.update(
        shared_density=new,
        raised_prims=len(raised),
        raised_median_density=round(float(np.median(gains)), 1),
    )
    report["notes"].append(
        f"texel density {new:g}/m (not {density:g}/m) for the {len(alone)} prim(s) on the "
        f"automatic density whose maps no prop rule raised: {len(raised)} prim(s) got maps "
        f"raised for their charts (a median {td['raised_median_density']:g}/m), and prims on "
        f"one stage share one density (at least {SHARED_DENSITY_SHARE:g} x that, within the "
        f"texel budget of {td['budget']}; docs/texels.md)"
    )
    return new


#: Bytes of working memory a whole bake may plan for (SH, fits and copies; see bake()).
MAX_BAKE_BYTES = int(
    os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    if hasattr(os, "sysconf") and "SC_PHYS_PAGES" in os.sysconf_names
    else 64 * 2**30
)


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
    from usdahd.usd import plugin

    plugin.register()
    opts = opts or BakeOptions()
    check_options(opts)
    t_start = time.perf_counter()
    src, out = preflight(stage_path, opts)
    # an empty numba cache: a second process compiles some kernels meanwhile (issue 43 item 6)
    with _prefetch(opts):
        return _bake_checked(src, out, opts, t_start)


def _prefetch(opts: BakeOptions):
    if opts.dry_run:
        return contextlib.nullcontext()
    from usdahd import models
    from usdahd.bake.kernels.prefetch import Prefetch, groups_for

    irradz = models.REGISTRY.get(opts.model or DEFAULTS["model"], "").startswith(
        "usdahd.models.irradz"
    )
    return Prefetch(groups_for(fit=irradz, denoise=opts.denoise))


def _bake_checked(src: Path, out: Path, opts: BakeOptions, t_start: float) -> dict:
    from usdahd.progress import CompileNotice

    try:
        stage = open_stage(src)
        if opts.scenario:  # before any check or read: the variant decides what the stage holds
            from usdahd.usd import scenarios

            chosen = scenarios.resolve(stage, opts.scenario)
            scenarios.select(stage, chosen)
            opts = dataclasses.replace(opts, scenario=chosen.spec())
        check_stage_inputs(src, stage, opts)
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
    api_prims = schema.api_prims(stage)
    uv_default = opts.uv or DEFAULTS["uv"]
    checked = check_stage_values(src, stage, uv_default)
    scene = load_scene(stage, uv_name=uv_default, prims=opts.prims, time=opts.time)
    for m in scene.meshes:
        if m.path in checked.prim_errors:
            m.bake = False
    if api_prims:
        for m in scene.meshes:
            if m.bake:  # an instance copy: selected by its prototype mesh's API
                p = api_prims.get(m.instance.source if m.instance else m.path)
                if p is None and m.instance:
                    p = prim_at(stage, m.instance.source)
                    p = p if p is not None and schema.has_api(p) else None
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
    if not meters_per_unit_authored(stage):
        report["warnings"].append(
            f"{src.name} does not author metersPerUnit, so USD's fallback applies "
            f"({scene.meters_per_unit:g} m per unit); texel densities are per metre. Author "
            "metersPerUnit on the root layer or pass --resolution if the lightmaps come out tiny"
        )
    old_layer = author.previous_layer(out) if prev else None
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
    auto_density = _auto_density(scene, stage, api_prims, opts, checked, report)
    prop_side = 0  # the side a map on the automatic density may be raised to (plan.prop_cap)
    if auto_density is not None:
        from usdahd.pipeline.plan import prop_cap

        td = report["texel_density"]  # raises share what the plan leaves of the budget
        prop_side = prop_cap(td["budget"] - td["estimated_texels"], td["prims"])
    uvs = {m.path: (m.uv, m.uv_name) for m in scene.meshes}  # plan_job replaces a mesh's UVs
    planned = _plan_meshes(
        scene,
        [i for i, m in enumerate(scene.meshes) if m.bake],
        stage,
        opts,
        prev,
        old_layer,
        auto_density,
        prop_side,
    )
    # With --prim the pool's other prims are planned too (not baked), so that which prims are
    # raised, and so the shared density, does not depend on the selection.
    outside = {}
    if opts.prims and auto_density is not None:
        pool = {m.path for m in _density_pool(scene, stage, api_prims, opts, checked)}
        rest = [i for i, m in enumerate(scene.meshes) if not m.bake and m.path in pool]
        outside = _plan_meshes(scene, rest, stage, opts, {}, None, auto_density, prop_side)
        for i in rest:
            scene.meshes[i].uv, scene.meshes[i].uv_name = uvs[scene.meshes[i].path]
    shared = _shared_density(scene, [*planned.values(), *outside.values()], auto_density, report)
    if shared is not None:  # plan again the prims the prop rules left alone, on the new density
        again = [i for i, (_, job) in planned.items() if job is not None and _left_alone(job)]
        for i in again:
            scene.meshes[i].uv, scene.meshes[i].uv_name = uvs[scene.meshes[i].path]
        planned.update(_plan_meshes(scene, again, stage, opts, prev, old_layer, shared, prop_side))
    for entry, job in planned.values():
        report["prims"].append(entry)
        if job is None:
            failed += 1
        else:
            jobs.append(job)
    if not jobs and not failed:
        raise InputError(no_mesh_message(src, api_prims))
    # The plan's unwrapping is done: stop the xatlas worker process now (~60 MB held through
    # tracing and denoising otherwise; a later pack starts a new one).
    import sys

    unwrap_module = sys.modules.get("usdahd.bake.unwrap")  # not imported: nothing was unwrapped
    if unwrap_module is not None:
        unwrap_module.stop_worker()
    # Hash after planning, so unwrapped meshes hash the UVs that the output layer will hold
    # (the validator recomputes these from the output stage).
    parts = scene_hash_parts(scene)
    for job in jobs:
        job.content_hash, job.parts = content_hash(
            parts, job.path, job.settings, author.generator_id()
        )
        old = prev.get(job.path)
        unchanged = old is not None and old.content_hash == job.content_hash
        if unchanged and not opts.force and files_exist(old):
            job.report["status"] = "skipped"
            job.previous = old
            continue
        job.report["status"] = "planned"
        if old is not None and files_exist(old):
            job.fallback = old  # a prim that fails now (e.g. disk full) keeps its old record
        if opts.force:
            reason = "forced"
        elif old is None:
            reason = "no previous bake"
        else:
            what = changed_parts(old.part_hashes, job.parts)
            reason = "changed: " + ", ".join(what) if what else "texture files missing"
            refit = refit_source(job, old, what)
            if refit is not None:
                job.refit_from = refit
                changed = sorted(
                    k
                    for k in REFIT_SETTINGS
                    if settings_as_stored(old.settings).get(k)
                    != settings_as_stored(job.settings).get(k)
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
        if path not in planned and (
            prim_at(stage, path) is not None or schema.instance_carrier(stage, path)
        ):
            keep = PrimJob(path=path, mesh=None, settings={}, previous=old)
            keep.report = {"path": path, "status": "kept"}
            jobs.append(keep)
    todo = [j for j in jobs if j.report["status"] == "planned"]
    rebuild = _atlas_rebuild(jobs, todo, opts)
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
        if opts.atlas and (todo or rebuild):
            from usdahd.pipeline import atlas

            report["atlas"] = atlas.plan_pages(todo, rebuild, opts)
        report["exit_code"] = 1 if failed else 0
        report["seconds"] = time.perf_counter() - t_start
        return report

    if todo:
        bake_jobs(scene, todo, out, opts)
    if opts.atlas and (todo or rebuild):
        report["atlas"] = _write_atlas(todo, rebuild, jobs, out, opts)
    for j in todo:
        if j.report["status"] == "failed":
            failed += 1
    fault_point("textures_staged")
    old_refs = author.referenced_assets(out) or set()
    if any(j.results is not None or j.previous is not None or j.fallback for j in jobs):
        written = [j for j in todo + rebuild if j.results is not None]
        commit_textures(written, out)
        if "atlas" in report:
            from usdahd.pipeline import atlas

            _committed_page_files(report["atlas"], written)
            atlas.summary(report["atlas"], opts)
        cleanup_outputs(out, staged_only=True)  # failed prims' partial files: free the space
        fault_point("textures_committed")
        report["written"] = author_layer(src, out, stage, jobs, opts.scenario)
        fault_point("layer_replaced")
        if report["written"]:
            remove_legacy(out, old_refs)
    for j in todo:
        if j.report["status"] == "failed" and j.fallback is not None:
            j.report["previous_kept"] = True
    report["exit_code"] = 1 if failed else 0
    report["seconds"] = time.perf_counter() - t_start
    return report


def _atlas_rebuild(jobs: list[PrimJob], todo: list[PrimJob], opts: BakeOptions) -> list[PrimJob]:
    """Records not re-baked whose page must be rebuilt (usdahd.pipeline.atlas): every kept or
    skipped record of an encoding group that has a record re-baked now, or whose pages the
    current ``--atlas-size`` / ``--atlas-padding`` lay out differently (page sizes, which
    records share a page, rectangles: re-packed from the SH sidecars, 0 rays), and, with the
    atlas on, every record that has textures of its own (from a ``--atlas off`` bake)."""
    if not opts.atlas:
        return []
    from usdahd.numerics import atlas as packer
    from usdahd.pipeline.atlas import group_key, max_size, padding
    from usdahd.usd import schema

    affected = {group_key(j.settings) for j in todo}
    kept: dict[tuple, list[PrimJob]] = {}
    for j in jobs:
        old = j.previous
        if j.report.get("status") in ("skipped", "kept") and old is not None and old.atlas:
            kept.setdefault(group_key(old.settings), []).append(j)
    relaid = set()
    for key, members in kept.items():
        if key in affected:
            continue
        pages: dict[int, set] = {}
        for j in members:
            W, H = schema.page_size(j.previous)
            x, y, _, _ = schema.record_rect(j.previous, (W, H))
            pages.setdefault(j.previous.page, set()).add((j.path, x, y, W, H))
        packing = packer.pack(
            [tuple(int(r) for r in j.previous.resolution) for j in members],
            [j.path for j in members],
            max_size=max_size(opts),
            padding=padding(opts),
        )
        now: dict[int, set] = {}
        for j, p in zip(members, packing.placements, strict=True):
            now.setdefault(p.page, set()).add((j.path, p.x, p.y, *packing.pages[p.page]))
        if {frozenset(v) for v in pages.values()} != {frozenset(v) for v in now.values()}:
            affected.add(key)
            relaid.add(key)
    out = []
    for j in jobs:
        old = j.previous
        if j.report.get("status") not in ("skipped", "kept") or old is None:
            continue
        if group_key(old.settings) in affected or not old.atlas:
            out.append(j)
            if old.atlas and group_key(old.settings) in relaid:
                j.report["reason"] = (
                    "atlas layout changed (--atlas-size / --atlas-padding): re-packed from the "
                    "SH sidecar, 0 rays traced"
                )
    return out


def _write_atlas(todo, rebuild, jobs, out: Path, opts: BakeOptions) -> dict:
    """Write the atlas pages of the records baked now plus ``rebuild``; the report's atlas
    entry: {"max_size", "padding", "pages": [...]} (docs/bake report)."""
    from usdahd.pipeline import atlas

    items = []
    for j in todo:
        if j.report.get("status") != "failed" and j.sh is not None and j.texels is not None:
            items.append(atlas.item_from_job(j))
    kept_pages = set()
    cache: dict = {}  # one page sidecar in memory at a time
    by_page = sorted(rebuild, key=lambda j: (j.previous.textures.get("sh", ""), j.path))
    for j in by_page:
        try:
            items.append(atlas.item_from_record(j, j.previous, cache))
        except BakeError as exc:  # keep its old page as it is
            j.report.setdefault("warnings", []).append(f"{exc}; its previous page is kept")
            if j.previous.atlas:
                kept_pages.add(j.previous.page)
    rebuilt = {id(j) for j in rebuild}
    for j in jobs:
        old = j.previous
        if old is not None and old.atlas and id(j) not in rebuilt:
            kept_pages.add(old.page)
    pages = atlas.write_pages(items, out, opts, kept_pages) if items else []
    return {"max_size": atlas.max_size(opts), "padding": atlas.padding(opts), "pages": pages}


def _committed_page_files(entry: dict, written: list[PrimJob]) -> None:
    """The page entries of the report name the committed files (and their sizes)."""
    by_path = {j.path: j for j in written}
    for page in entry["pages"]:
        job = next((by_path[p] for p in page["records"] if p in by_path), None)
        if job is None or job.results is None:
            continue
        page["files"] = {r: str(f) for r, f in job.results.textures.items()}
        page["bytes"] = {r: Path(f).stat().st_size for r, f in page["files"].items()}
        for role, info in page.get("ktx2", {}).items():
            ktx = Path(page["files"][role]).with_suffix(".ktx2")
            info["path"] = str(ktx)
