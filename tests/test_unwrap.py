"""xatlas unwrapping: valid, non-overlapping, deterministic lightmap UVs."""

from __future__ import annotations

import numpy as np
import pytest

from usdahd.bake import texels as tx
from usdahd.bake.unwrap import unwrap
from usdahd.errors import BakeError, UsageError

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("xatlas")


def box_mesh(extents=(1.0, 2.0, 0.5)):
    m = trimesh.creation.box(extents=extents)
    return tx.mesh_from_arrays(m.vertices, m.faces, path="/box")


@pytest.fixture(scope="module")
def box_unwrapped():
    mesh = box_mesh()
    uv, res = unwrap(mesh, texels_per_unit=20.0, isolate=False)
    mesh.uv = uv
    return mesh, res


def test_cube_uvs_valid_and_non_overlapping(box_unwrapped):
    mesh, res = box_unwrapped
    uv = mesh.uv
    assert uv.shape == (len(mesh.triangles), 3, 2) and uv.dtype == np.float32
    assert (uv >= 0).all() and (uv <= 1).all()
    t = tx.rasterize(mesh, res)
    assert t.stats["overlap_texels"] == 0
    assert t.stats["uv_outside_fraction"] == 0.0
    assert t.stats["degenerate_uv_triangles"] == 0
    # frames are orthonormal; mirrored charts (kept as xatlas lays them out) have det -1
    det = np.linalg.det(t.frame.astype(np.float64))
    np.testing.assert_allclose(np.abs(det), 1.0, atol=1e-5)
    assert int((det < 0).sum()) == t.stats["mirrored_texels"]
    # one chart per face at least; conservatively rasterised charts never share a texel
    charts = tx.chart_ids(mesh)
    assert charts.max() + 1 >= 6
    seen = np.zeros(res[::-1], dtype=np.int32)
    for c in range(charts.max() + 1):
        sel = charts == c
        part = tx.mesh_from_arrays(mesh.points, mesh.triangles[sel], uv=mesh.uv[sel])
        pt = tx.rasterize(part, res)
        seen[pt.xy[:, 1], pt.xy[:, 0]] += 1
    assert seen.max() == 1 and seen.sum() == len(t)


def test_texel_density_is_honoured(box_unwrapped):
    mesh, res = box_unwrapped
    # xatlas scales charts by exactly texels_per_unit (up to float32 UV rounding)
    assert tx.texel_density(mesh, res) == pytest.approx(20.0, rel=1e-3)


def test_deterministic_and_isolated_run_matches():
    mesh = box_mesh()
    a, ra = unwrap(mesh, texels_per_unit=20.0, isolate=False)
    b, rb = unwrap(mesh, texels_per_unit=20.0, isolate=False)
    c, rc = unwrap(mesh, texels_per_unit=20.0)  # default: in a child process
    assert ra == rb == rc
    assert np.array_equal(a, b) and np.array_equal(a, c)


def test_requested_resolution_is_exact():
    mesh = box_mesh()
    uv, res = unwrap(mesh, resolution=64, isolate=False)
    assert res == (64, 64)
    assert (uv >= 0).all() and (uv <= 1).all()
    mesh.uv = uv
    t = tx.rasterize(mesh, res)
    assert t.stats["overlap_texels"] == 0
    # packed reasonably: more than a quarter of the lightmap is used
    assert len(t) > 0.25 * 64 * 64


def test_unwrap_errors():
    mesh = box_mesh()
    with pytest.raises(UsageError, match="exactly one"):
        unwrap(mesh)
    with pytest.raises(UsageError, match="exactly one"):
        unwrap(mesh, texels_per_unit=1.0, resolution=32)
    with pytest.raises(UsageError, match="above the maximum"):
        unwrap(mesh, texels_per_unit=1e6, isolate=False)
    with pytest.raises(UsageError, match="resolution"):
        unwrap(mesh, resolution=0, isolate=False)


def test_interlocking_charts_do_not_overlap():
    # A bumpy, non-convex surface gives xatlas L-shaped, interlocking charts, some mirrored;
    # they must keep xatlas's packing (flipping a chart in its box made it overlap neighbours).
    m = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(3)
    v = m.vertices * (1.0 + 0.25 * rng.random((len(m.vertices), 1)))
    mesh = tx.mesh_from_arrays(v, m.faces, path="/bumpy")
    uv, res = unwrap(mesh, texels_per_unit=40.0, isolate=False)
    mesh.uv = uv
    t = tx.rasterize(mesh, res)
    assert t.stats["overlap_texels"] == 0


def test_a_wedged_xatlas_child_is_stopped_with_an_error_naming_the_prim(monkeypatch):
    # A limit far below the child's interpreter start-up stands in for a child that never ends.
    from usdahd.bake import unwrap as unwrap_mod

    unwrap_mod._stop_worker()  # the next request waits for a fresh worker's start-up
    monkeypatch.setattr(unwrap_mod, "UNWRAP_TIMEOUT_S", 0.01)
    monkeypatch.setattr(unwrap_mod, "UNWRAP_TIMEOUT_PER_TRIANGLE_S", 0.0)
    with pytest.raises(BakeError, match=r"/box: xatlas did not finish .* within 0 s.*--uv"):
        unwrap(box_mesh(), texels_per_unit=20.0)
    monkeypatch.undo()
    assert unwrap(box_mesh(), texels_per_unit=20.0)[1]  # a new worker takes the next mesh


def test_one_worker_unwraps_mesh_after_mesh_and_survives_a_crash(monkeypatch):
    """The xatlas child is started once and reused; when it dies on a mesh (xatlas can
    segfault) that prim fails with a message naming it and the fix, and the next mesh gets a
    new worker; a worker that died between meshes is replaced without failing anyone."""
    from usdahd.bake import unwrap as unwrap_mod

    unwrap_mod._stop_worker()
    a = unwrap(box_mesh(), texels_per_unit=20.0)
    pid = unwrap_mod._worker.proc.pid
    b = unwrap(box_mesh(), texels_per_unit=20.0)
    assert unwrap_mod._worker.proc.pid == pid and np.array_equal(a[0], b[0])
    unwrap_mod._worker.proc.kill()  # dies between two meshes
    unwrap_mod._worker.proc.wait()
    assert np.array_equal(unwrap(box_mesh(), texels_per_unit=20.0)[0], a[0])
    assert unwrap_mod._worker.proc.pid != pid
    # a worker that dies while unwrapping (stands in for xatlas's segfault)
    unwrap_mod._stop_worker()
    crash = (
        "import os, sys; sys.stdin.buffer.read(8); "
        "sys.stderr.write('Segmentation fault\\n'); sys.stderr.flush(); os._exit(139)"
    )
    monkeypatch.setattr(unwrap_mod, "_CHILD_CODE", crash)
    with pytest.raises(BakeError, match=r"/box: xatlas crashed .*Segmentation fault.*--uv"):
        unwrap(box_mesh(), texels_per_unit=20.0)
    monkeypatch.undo()
    assert np.array_equal(unwrap(box_mesh(), texels_per_unit=20.0)[0], a[0])


def test_a_worker_killed_during_one_mesh_fails_no_prim(monkeypatch, tmp_path):
    """A worker that dies once (killed from outside while unwrapping) is retried in a fresh
    worker: the mesh unwraps. (A crash that follows the mesh fails twice: the test above.)"""
    from usdahd.bake import unwrap as unwrap_mod

    unwrap_mod._stop_worker()
    want = unwrap(box_mesh(), texels_per_unit=20.0)
    unwrap_mod._stop_worker()
    marker = tmp_path / "died"
    once = (
        f"import os, sys; m = {str(marker)!r}\n"
        "if not os.path.exists(m):\n"
        "    open(m, 'w').close(); sys.stdin.buffer.read(8); os._exit(137)\n"
        f"{unwrap_mod._CHILD_CODE}"
    )
    monkeypatch.setattr(unwrap_mod, "_CHILD_CODE", once)
    got = unwrap(box_mesh(), texels_per_unit=20.0)
    assert marker.exists() and np.array_equal(got[0], want[0]) and got[1] == want[1]
    unwrap_mod._stop_worker()


def test_too_many_charts_for_the_resolution_fail_at_once():
    """A mesh xatlas cuts into more charts than the lightmap can hold with their padding
    fails after one xatlas run (not MAX_ATTEMPTS), saying how many texels it needs."""
    from usdahd.bake import unwrap as unwrap_mod

    m = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(3)
    v = m.vertices * (1.0 + 0.25 * rng.random((len(m.vertices), 1)))
    mesh = tx.mesh_from_arrays(v, m.faces, path="/bumpy")
    runs = []
    real = unwrap_mod._run_pack

    def counted(*a):
        runs.append(1)
        return real(*a)

    unwrap_mod._run_pack, saved = counted, unwrap_mod._run_pack
    try:
        with pytest.raises(
            BakeError,
            match=r"/bumpy: xatlas cut this mesh into \d+ charts, "
            r"which need at least \d+x\d+ texels .* 8x8: raise --resolution",
        ):
            unwrap(mesh, resolution=8, isolate=False)
    finally:
        unwrap_mod._run_pack = saved
    assert len(runs) == 1
