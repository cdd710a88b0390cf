"""usdahd.pipeline.stages.bake_jobs: the per-prim stages (trace, fill, denoise, stitch, fit,
encode, write) on jobs planned the way usdahd.pipeline.plan plans them, checked against the
analytic irradiance of a sun on a black quad, with the written files read back by OpenImageIO
and hashed with hashlib (not through usdahd's readers)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from tests.scenes import define_quad, distant_light, new_stage, preview_material, square
from usdahd import models
from usdahd.pipeline.outputs import LIGHTMAPS_DIR, texture_path
from usdahd.pipeline.plan import PrimJob
from usdahd.pipeline.settings import BakeOptions, record_time, resolve_settings
from usdahd.pipeline.stages import bake_jobs
from usdahd.usd import schema
from usdahd.usd.reader import load_scene

oiio = pytest.importorskip("OpenImageIO")

RES = 16
SUN = 2.0  # W/m^2 at normal incidence: I_z = E / pi on a black receiver (no bounce light)
FLOAT_TOL = 2e-5  # float32 SH through the sidecar


def _stage(lit=True, degenerate_uv=False):
    st = new_stage()
    black = preview_material(st, "/mat/black", (0, 0, 0), emission=None)
    uv = [(0, 0), (1, 0), (1, 1), (0, 1)]
    define_quad(st, "/World/Ground", square(0.0, 1.0), black, uv, scheme="none")
    bad = [(0.5, 0.5)] * 4 if degenerate_uv else uv
    define_quad(st, "/World/Shelf", square(-1.0, 0.5), black, bad, scheme="none")  # below
    if lit:
        distant_light(st, "/Sun", SUN)
    return st


def _jobs(scene, opts):
    jobs = []
    for mesh in scene.meshes:
        settings = resolve_settings(opts, {}, scene.meters_per_unit)
        record_time(settings, scene)
        assert mesh.uv_name == settings["uv"] == "st"
        report = {"path": mesh.path, "warnings": [], "reason": "no previous bake"}
        jobs.append(PrimJob(mesh.path, mesh, settings, (RES, RES), report=report))
    return jobs


def _bake(tmp_path, **stage_kw):
    # atlas=False: per-prim maps (with the atlas, run.py packs and writes pages after bake_jobs)
    opts = BakeOptions(resolution=RES, samples=16, denoise=False, quiet=True, atlas=False)
    scene = load_scene(_stage(**stage_kw))
    jobs = _jobs(scene, opts)
    out = tmp_path / "x.lightmaps.usda"
    (tmp_path / LIGHTMAPS_DIR).mkdir()
    bake_jobs(scene, jobs, out, opts)
    return out, {j.path: j for j in jobs}


def _read_sidecar(path):
    """(spec, (n, 28) pixels in SH_SIDECAR_CHANNELS order), by channel name (EXR stores the
    channels sorted by name)."""
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    px = np.asarray(inp.read_image(format="float"), np.float64).reshape(-1, spec.nchannels)
    inp.close()
    names = list(spec.channelnames)
    assert sorted(names) == sorted(schema.SH_SIDECAR_CHANNELS)
    return spec, px[:, [names.index(c) for c in schema.SH_SIDECAR_CHANNELS]]


def test_bake_jobs_writes_every_role_and_the_sidecar_with_the_analytic_irradiance(tmp_path):
    out, jobs = _bake(tmp_path)
    job = jobs["/World/Ground"]
    assert job.report["status"] == "baked", job.report
    res = job.results
    lays = models.get(res.model).layout(res.ratio)
    assert set(res.textures) == {lay.role for lay in lays} | {schema.SIDECAR_ROLE}
    # each file is the staged (hidden) name texture_path gives, inside out's lightmaps/ only
    for lay in lays:
        assert res.textures[lay.role] == str(texture_path(out, job.path, lay.role, lay.extension))
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert all(p.parts[0] == LIGHTMAPS_DIR and p.name.startswith(".") for p in written)
    assert len(written) == 2 * len(res.textures)  # both prims, nothing else
    # digests are the sha256 of the files as written
    for role, path in res.textures.items():
        assert res.digests[role] == "sha256:" + hashlib.sha256(Path(path).read_bytes()).hexdigest()
    # the float sidecar: 27 SH coefficients + coverage; every texel of the full-UV quad covered,
    # I_z (usdahd's l=1,m=0 rule checked against the sun's E / pi) the same in R, G, B
    spec, px = _read_sidecar(res.textures[schema.SIDECAR_ROLE])
    assert (spec.width, spec.height) == (RES, RES) == res.resolution
    assert (px[:, 27] == 1).all()
    sh = px[:, :27].reshape(-1, 3, 9)
    # hemispherical radiance: E_z = integral of L cos = sqrt(4 pi / 3) L_1^0 (cos = sqrt(4 pi / 3)
    # Y_1^0), normalised by pi
    iz = np.sqrt(4.0 * np.pi / 3.0) * sh[..., 2] / np.pi
    np.testing.assert_allclose(iz, SUN / np.pi, rtol=1e-4)
    # rays were traced, none invalid
    assert job.report["rays"] > 0 and not job.stats["invalid"].any()


def test_a_prim_that_fails_does_not_stop_the_others(tmp_path):
    """A prim whose UVs cover no texel is marked failed with a message naming it; the other
    prim of the same bake is baked."""
    _, jobs = _bake(tmp_path, degenerate_uv=True)
    bad, good = jobs["/World/Shelf"], jobs["/World/Ground"]
    assert bad.report["status"] == "failed" and bad.results is None
    assert bad.report["error"].startswith("/World/Shelf: no texel covered at 16x16")
    assert "'st'" in bad.report["error"]
    assert good.report["status"] == "baked" and good.results is not None


def test_a_dark_stage_traces_nothing_and_writes_black(tmp_path):
    """No light and no emission: the radiance is zero, no ray is traced, and the textures are
    still written (a valid black lightmap)."""
    _, jobs = _bake(tmp_path, lit=False)
    for job in jobs.values():
        assert job.report["status"] == "baked"
        assert job.stats["rays"] == 0
        _, px = _read_sidecar(job.results.textures[schema.SIDECAR_ROLE])
        assert (px[px[:, 27] > 0, :27] == 0).all()


def _sample_jobs(resolution=8, samples=16):
    from usdahd.pipeline.settings import resolve_settings as resolve

    opts = BakeOptions(resolution=resolution, samples=samples, denoise=False, quiet=True)
    scene = load_scene(str(Path(__file__).parents[2] / "samples" / "stretched_boxes.usda"))
    jobs = []
    for mesh in scene.meshes:
        settings = resolve(opts, {}, scene.meters_per_unit)
        record_time(settings, scene)
        report = {"path": mesh.path, "warnings": [], "reason": "no previous bake"}
        jobs.append(PrimJob(mesh.path, mesh, settings, (resolution,) * 2, report=report))
    return scene, jobs, opts


def test_prims_traced_at_once_give_the_same_bake_as_one_at_a_time(monkeypatch):
    """JOB_THREADS prims in flight share the tracer's threads; each prim's SH, statistics and
    ray count are those of a bake that traces the prims one after another."""
    from usdahd.pipeline import stages

    baked = {}
    for threads in (1, 2, 3):
        monkeypatch.setattr(stages, "JOB_THREADS", threads)
        scene, jobs, opts = _sample_jobs()
        assert len(jobs) == 3
        stages._trace_jobs(scene, jobs, opts)
        baked[threads] = jobs
    for threads in (2, 3):
        for one, two in zip(baked[1], baked[threads], strict=True):
            assert one.path == two.path
            np.testing.assert_array_equal(one.sh, two.sh)
            assert one.report["rays"] == two.report["rays"] == one.stats["rays"] > 0
            np.testing.assert_array_equal(one.stats["samples"], two.stats["samples"])
            np.testing.assert_array_equal(one.stats["invalid"], two.stats["invalid"])


def test_a_prim_that_breaks_stops_the_prims_in_flight(monkeypatch):
    """An unexpected error in one prim (not a UsdAhdError, which marks only that prim failed)
    reaches the caller, and the other prim in flight stops at its next chunk instead of
    tracing on."""
    from usdahd.bake import integrate
    from usdahd.pipeline import stages

    real = integrate.bake_texels
    calls = []

    def bake_texels(scene, tracer, texels, **kw):
        calls.append(kw["mesh"])
        if kw["mesh"] == 1:
            raise RuntimeError("boom")
        return real(scene, tracer, texels, **kw)

    monkeypatch.setattr(integrate, "bake_texels", bake_texels)
    monkeypatch.setattr(stages, "JOB_THREADS", 2)  # two of the three prims in flight
    monkeypatch.setattr(integrate, "NATIVE_CHUNK_RAYS", 64 * 64)  # 16 chunks of 64 texels
    scene, jobs, opts = _sample_jobs(resolution=32, samples=64)
    with pytest.raises(RuntimeError, match="boom"):
        stages._trace_jobs(scene, jobs, opts)
    assert 2 not in calls  # the third prim never started
    assert jobs[0].sh is None  # the first stopped at a chunk after the error
