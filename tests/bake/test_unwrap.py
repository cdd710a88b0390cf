"""xatlas unwrapping: valid, non-overlapping, deterministic lightmap UVs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from usdahd.bake import texels as tx
from usdahd.bake import unwrap_worker
from usdahd.bake.unwrap import unrepresentable_corners, unwrap
from usdahd.errors import BakeError, UsageError
from usdahd.scene.types import MeshData

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

    unwrap_mod.stop_worker()  # the next request waits for a fresh worker's start-up
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

    unwrap_mod.stop_worker()
    a = unwrap(box_mesh(), texels_per_unit=20.0)
    pid = unwrap_worker._worker.proc.pid
    b = unwrap(box_mesh(), texels_per_unit=20.0)
    assert unwrap_worker._worker.proc.pid == pid and np.array_equal(a[0], b[0])
    unwrap_worker._worker.proc.kill()  # dies between two meshes
    unwrap_worker._worker.proc.wait()
    assert np.array_equal(unwrap(box_mesh(), texels_per_unit=20.0)[0], a[0])
    assert unwrap_worker._worker.proc.pid != pid
    # a worker that dies while unwrapping (stands in for xatlas's segfault)
    unwrap_mod.stop_worker()
    crash = (
        "import os, sys; sys.stdin.buffer.read(8); "
        "sys.stderr.write('Segmentation fault\\n'); sys.stderr.flush(); os._exit(139)"
    )
    monkeypatch.setattr(unwrap_worker, "CHILD_CODE", crash)
    with pytest.raises(BakeError, match=r"/box: xatlas crashed .*Segmentation fault.*--uv"):
        unwrap(box_mesh(), texels_per_unit=20.0)
    monkeypatch.undo()
    assert np.array_equal(unwrap(box_mesh(), texels_per_unit=20.0)[0], a[0])


def test_a_worker_killed_during_one_mesh_fails_no_prim(monkeypatch, tmp_path):
    """A worker that dies once (killed from outside while unwrapping) is retried in a fresh
    worker: the mesh unwraps. (A crash that follows the mesh fails twice: the test above.)"""
    from usdahd.bake import unwrap as unwrap_mod

    unwrap_mod.stop_worker()
    want = unwrap(box_mesh(), texels_per_unit=20.0)
    unwrap_mod.stop_worker()
    marker = tmp_path / "died"
    once = (
        f"import os, sys; m = {str(marker)!r}\n"
        "if not os.path.exists(m):\n"
        "    open(m, 'w').close(); sys.stdin.buffer.read(8); os._exit(137)\n"
        f"{unwrap_worker.CHILD_CODE}"
    )
    monkeypatch.setattr(unwrap_worker, "CHILD_CODE", once)
    got = unwrap(box_mesh(), texels_per_unit=20.0)
    assert marker.exists() and np.array_equal(got[0], want[0]) and got[1] == want[1]
    unwrap_mod.stop_worker()


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


# ------------------------------------------------------------------ polygons (issue 37, row 1)

NGON_STAGE = Path(__file__).resolve().parents[1] / "data" / "production" / "ngon_stage.usda"


def fan_mesh(points, counts, indices, path="/ngon") -> MeshData:
    """A polygon mesh fan-triangulated as the USD reader does (``corner`` indexes
    faceVertexIndices, ``face`` the polygon), without a stage."""
    face, corner, s = [], [], 0
    for f, n in enumerate(counts):
        for j in range(n - 2):
            corner.append((s, s + j + 1, s + j + 2))
            face.append(f)
        s += n
    corner = np.asarray(corner, dtype=np.int32)
    mesh = tx.mesh_from_arrays(points, np.asarray(indices)[corner], path=path)
    mesh.face = np.asarray(face, dtype=np.int32)
    mesh.corner = corner
    return mesh


def goldberg(subdivisions: int, roughness: float = 0.15, seed: int = 1) -> MeshData:
    """The dual of an icosphere (12 pentagons, the rest hexagons), its corners pushed in and
    out at random so the polygons are not planar: xatlas cuts many of them."""
    ico = trimesh.creation.icosphere(subdivisions=subdivisions)
    verts, faces = np.asarray(ico.vertices), np.asarray(ico.faces)
    centre = verts[faces].mean(axis=1)
    centre /= np.linalg.norm(centre, axis=1, keepdims=True)
    around = [[] for _ in verts]
    for f, tri in enumerate(faces):
        for v in tri:
            around[v].append(f)
    counts, indices = [], []
    for v, ring in enumerate(around):
        ring = np.asarray(ring)
        n = verts[v] / np.linalg.norm(verts[v])
        u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        c = centre[ring]
        counts.append(len(ring))
        indices += [int(i) for i in ring[np.argsort(np.arctan2(c @ w, c @ u))]]
    rng = np.random.default_rng(seed)
    points = centre * (1.0 + roughness * rng.random((len(centre), 1)))
    return fan_mesh(points, counts, indices, path="/goldberg")


def _check_representable(mesh, uv, res, degenerate=0):
    """The UVs a faceVarying primvar can hold exactly, valid as a lightmap (at most
    ``degenerate`` zero-area UV triangles: xatlas makes a few on some meshes)."""
    assert unrepresentable_corners(mesh.corner, uv) == 0
    assert (uv >= 0).all() and (uv <= 1).all()
    mesh.uv = uv
    t = tx.rasterize(mesh, res)
    assert t.stats["overlap_texels"] == 0
    assert t.stats["degenerate_uv_triangles"] <= degenerate
    # what the output layer holds (one UV per polygon corner) is what was rasterised
    held = np.zeros((int(mesh.corner.max()) + 1, 2), np.float32)
    held[mesh.corner] = uv
    assert np.array_equal(held[mesh.corner], uv)


def test_unrepresentable_corners_counts_corners_with_two_uvs():
    corner = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.zeros((2, 3, 2), np.float32)
    assert unrepresentable_corners(corner, uv) == 0
    uv[1, 0] = (0.5, 0.5)  # corner 0 differs between the two triangles
    uv[1, 1] = (0.1, 0.0)  # and corner 2
    assert unrepresentable_corners(corner, uv) == 2


def test_overlap_test_tells_overlap_from_touching():
    from usdahd.numerics.charts import overlaps as _overlaps

    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    edge = np.array([[[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]])  # shares the hypotenuse
    corner_only = np.array([[[1.0, 0.0], [2.0, 0.0], [2.0, 1.0]]])
    inside = np.array([[[0.1, 0.1], [0.3, 0.1], [0.1, 0.3]]])
    crossing = np.array([[[0.5, -0.5], [0.6, 0.9], [-0.4, 0.4]]])
    assert not _overlaps(tri, edge) and not _overlaps(tri, corner_only)
    assert _overlaps(tri, inside) and _overlaps(tri, crossing)
    assert _overlaps(tri, np.concatenate([edge, inside]))


@pytest.fixture(scope="module")
def ngon_scene():
    from usdahd.usd.reader import load_scene

    return load_scene(str(NGON_STAGE))


def test_ngon_stage_is_what_its_generator_writes(tmp_path):
    import subprocess
    import sys

    gen = NGON_STAGE.parent / "make_ngon.py"
    subprocess.run([sys.executable, str(gen), "--out", str(tmp_path)], check=True, timeout=120)
    assert (tmp_path / NGON_STAGE.name).read_text() == NGON_STAGE.read_text()


def test_xatlas_alone_cuts_polygons_of_the_ngon_stage(ngon_scene):
    """The control: xatlas's own charts split polygons of these meshes (what the old unwrap
    authored as overlapping UVs), so the tests below exercise the repair."""
    from usdahd.bake.unwrap import _chart_pass

    split = 0
    for mesh in ngon_scene.meshes:
        tri = np.ascontiguousarray(mesh.triangles, np.uint32)
        split += _chart_pass(mesh.points, tri, mesh.corner, mesh.face, mesh.path)[3][
            "split_polygons"
        ]
    assert split >= 10


@pytest.mark.parametrize("resolution", [32, 64])
def test_polygons_stay_whole_on_the_ngon_stage(ngon_scene, resolution):
    repaired = 0
    for mesh in ngon_scene.meshes:
        info = {}
        uv, res = unwrap(mesh, resolution=resolution, isolate=False, info=info)
        assert res == (resolution, resolution)
        _check_representable(mesh, uv, res)
        repaired += info["split_polygons"]
        assert info["extended"] + info["own_chart"] == info["split_polygons"]
    assert repaired >= 10


def test_polygons_stay_whole_on_a_rough_goldberg_sphere():
    mesh = goldberg(3)
    info = {}
    uv, res = unwrap(mesh, texels_per_unit=40.0, isolate=False, info=info)
    _check_representable(mesh, uv, res)
    # most cut polygons rejoin a chart; some need one of their own
    assert info["split_polygons"] > 100 and info["extended"] > info["own_chart"] > 0
    # the texel density is kept (xatlas rounds chart extents up to whole texels)
    assert tx.texel_density(mesh, res) == pytest.approx(40.0, rel=0.1)


def test_a_polygon_that_fits_no_chart_gets_its_own(monkeypatch):
    """When every re-joined polygon would overlap its chart, each becomes a chart of its
    own: still one UV per corner and no overlap."""
    from usdahd.bake import unwrap as unwrap_mod

    monkeypatch.setattr(unwrap_mod, "overlaps", lambda tri, others, eps=0: len(others) > 0)
    mesh = goldberg(2)
    info = {}
    uv, res = unwrap(mesh, resolution=128, isolate=False, info=info)
    assert info["split_polygons"] > 0 and info["own_chart"] == info["split_polygons"]
    monkeypatch.undo()
    _check_representable(mesh, uv, res)


def test_polygon_unwrap_is_deterministic_and_isolated_run_matches():
    mesh = goldberg(2)
    a = unwrap(mesh, resolution=96, isolate=False)
    b = unwrap(mesh, resolution=96)
    assert a[1] == b[1] and np.array_equal(a[0], b[0])


# ----------------------------------------------- bake, validate, re-bake (issue 37, row 1)

BAKE_FAST = ["--resolution", "32", "--samples", "4", "--bounces", "1", "--no-denoise"]
NGON_MESHES = ("Ground", "Disk", "Cylinder", "Dodecahedron", "Box", "Torus", "HexTerrain")


def _cli(capsys, *argv):
    from usdahd import cli

    code = cli.main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    return code, cap.out, cap.err


def _uv_findings(out: str) -> list[str]:
    return [
        ln
        for ln in out.splitlines()
        if ln.startswith(("error", "warning")) and ("Staleness:" in ln or "UVSet:" in ln)
    ]


def _authored_st(layer_path) -> dict[str, np.ndarray]:
    from pxr import Sdf

    layer = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    out = {}
    for name in NGON_MESHES:
        spec = layer.GetAttributeAtPath(f"/World/Geometry/{name}.primvars:st")
        out[name] = np.asarray(spec.default, dtype=np.float32)
    return out


@pytest.fixture
def ngon_baked(tmp_path):
    """The n-gon stage baked from scratch by ``python -m usdahd bake`` (a subprocess)."""
    import os
    import shutil
    import subprocess
    import sys

    import usdahd

    stage = tmp_path / NGON_STAGE.name
    shutil.copy2(NGON_STAGE, stage)
    env = dict(os.environ, PYTHONPATH=str(Path(usdahd.__file__).resolve().parents[1]))
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), *BAKE_FAST],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "could not be represented" not in proc.stdout + proc.stderr
    return stage, tmp_path / "ngon_stage.lightmaps.usda"


def test_a_fresh_bake_of_polygon_meshes_validates_clean_and_rebakes_identically(ngon_baked, capsys):
    stage, layer = ngon_baked
    code, out, _ = _cli(capsys, "validate", layer)
    assert _uv_findings(out) == [] and code == 0, out
    first = layer.read_bytes()
    code, out, _ = _cli(capsys, "bake", stage, *BAKE_FAST)
    assert code == 0 and out.count("unchanged, skipped") == len(NGON_MESHES), out
    assert layer.read_bytes() == first
    # a second bake from scratch authors the very same UVs (the unwrap is deterministic)
    again = stage.parent / "again" / "ngon_stage.lightmaps.usda"
    assert _cli(capsys, "bake", stage, *BAKE_FAST, "-o", again)[0] == 0
    a, b = _authored_st(layer), _authored_st(again)
    assert all(np.array_equal(a[k], b[k]) for k in NGON_MESHES)


def test_a_rebake_does_not_reuse_an_unwrap_that_overlaps(ngon_baked, capsys):
    """A layer whose unwrap overlaps (as the old unwrap wrote it: polygons xatlas cut were
    authored with one UV per corner): validate names it, and the re-bake the finding asks
    for unwraps again (a warning naming the prim) and validates clean."""
    from pxr import Sdf, Vt

    stage, layer = ngon_baked
    good = _authored_st(layer)
    sdf = Sdf.Layer.FindOrOpen(str(layer))
    spec = sdf.GetAttributeAtPath("/World/Geometry/Dodecahedron.primvars:st")
    bad = good["Dodecahedron"].copy()
    bad[5:10] = bad[0:5]  # pentagon 1 on top of pentagon 0
    bad[10:15] = bad[0:5]  # and pentagon 2
    spec.default = Vt.Vec2fArray.FromNumpy(bad)
    sdf.Save()
    code, out, _ = _cli(capsys, "validate", layer)
    assert code == 1 and any("Dodecahedron> UVSet:" in ln for ln in _uv_findings(out)), out
    code, out, _ = _cli(capsys, "bake", stage, *BAKE_FAST)
    assert code == 0
    warned = [ln for ln in out.splitlines() if "is not reused" in ln]
    assert len(warned) == 1 and "/World/Geometry/Dodecahedron: the xatlas unwrap 'st'" in warned[0]
    assert "overlaps itself" in warned[0]
    code, out, _ = _cli(capsys, "validate", layer)
    assert _uv_findings(out) == [] and code == 0, out
    assert np.array_equal(_authored_st(layer)["Dodecahedron"], good["Dodecahedron"])


def test_zero_area_uv_triangles_stay_in_their_chart_when_packed():
    """xatlas ignores zero-area triangles of a UV mesh and leaves the vertices only they use
    unpacked (at 0 they made a sliver across the atlas: 5 % overlap on the castle); such a
    vertex is put on a packed vertex of its triangle."""
    from usdahd.bake.unwrap import _run_pack

    verts = np.array(
        [[0, 0], [10, 0], [10, 10], [0, 10], [10, 20], [30, 0], [40, 0], [40, 10]],
        dtype=np.float32,
    )
    indices = np.array([[0, 1, 2], [0, 2, 3], [1, 2, 4], [5, 6, 7]], dtype=np.uint32)
    w, h, uv, _ = _run_pack(verts, indices, 1.0, 1)
    assert np.array_equal(uv[2, 2], uv[2, 0]) or np.array_equal(uv[2, 2], uv[2, 1])
    lo, hi = uv[:2].reshape(-1, 2).min(axis=0), uv[:2].reshape(-1, 2).max(axis=0)
    assert (uv[2] >= lo).all() and (uv[2] <= hi).all()  # inside the square's chart


@pytest.mark.skipif(
    not (Path(__file__).resolve().parents[3] / "shared" / "scenes" / "castle").is_dir(),
    reason="../shared/scenes/castle is absent",
)
def test_castle_unwraps_without_overlap():
    from usdahd.usd.reader import load_scene

    stage = Path(__file__).resolve().parents[3] / "shared" / "scenes" / "castle" / "castle.usda"
    mesh = load_scene(str(stage)).meshes[0]
    uv, res = unwrap(mesh, resolution=256, isolate=False)
    _check_representable(mesh, uv, res, degenerate=5)
    # at the automatic density the bake plans for it (16/m, 14.4 m stage): the second chart
    # option with its rings cut overlapped on 2,746 texels (1.6 %) and won on fill; a layout
    # that overlaps now ranks below every one that does not
    mesh = load_scene(str(stage)).meshes[0]
    uv, res = unwrap(mesh, texels_per_unit=16.0, isolate=False)
    _check_representable(mesh, uv, res, degenerate=5)


def test_candidate_layouts_count_their_overlapping_texels():
    """unwrap's candidate key counts overlap as validate's UVOverlap rule does (centres
    strictly inside two triangles), so an overlapping layout never wins on fill."""
    from usdahd.bake.unwrap import _covered

    quad = np.array([[[0, 0], [8, 0], [8, 8]], [[0, 0], [8, 8], [0, 8]]], np.float32)
    covered, overlap = _covered(quad, 16, 16)
    assert (covered, overlap) == (64, 0)
    shifted = np.concatenate([quad, quad + np.float32(4)])  # a copy over a quarter of it
    covered, overlap = _covered(shifted, 16, 16)
    # the 16 centres both squares hold, less the 4 on their shared diagonal (on the edge
    # between a square's two triangles, so strictly inside only the other square's)
    assert covered == 64 + 64 - 16 and overlap == 16 - 4


def test_small_charts_keep_one_texel_of_padding_and_fill_their_map():
    """At a low density (127 charts a few texels wide: what the automatic density gives a
    level's props) the default 1-texel chart padding (on top of xatlas's bilinear ring) and
    brute-force placement cover about twice the share of the map that 2 texels did (measured
    35 % vs 18 %), with the same covered texels, and charts still do not overlap."""
    from usdahd.bake.unwrap import CHART_PADDING, PACK_BRUTE_FORCE

    assert CHART_PADDING == 1 and PACK_BRUTE_FORCE
    share, covered = {}, {}
    for padding in (CHART_PADDING, 2):
        mesh = goldberg(3)
        uv, res = unwrap(mesh, texels_per_unit=4.0, padding=padding, isolate=False)
        _check_representable(mesh, uv, res)
        mesh.uv = uv
        t = tx.rasterize(mesh, res)
        covered[padding] = len(t.xy)
        share[padding] = len(t.xy) / (res[0] * res[1])
    assert covered[1] == pytest.approx(covered[2], rel=0.05)
    assert share[1] > 1.6 * share[2] and share[1] > 0.3


def frames(count=6, nx=5, ny=20, q=0.1, seed=0) -> MeshData:
    """``count`` flat picture frames (an nx x ny grid of q-metre quads without its inner
    (nx - 2) x (ny - 2) quads: a window's moulding), each at its own place and turn."""
    rng = np.random.default_rng(seed)
    pts, counts, idx = [], [], []
    gx, gy = np.arange(nx + 1) * q, np.arange(ny + 1) * q
    for f in range(count):
        a = rng.uniform(0, np.pi)
        rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        base = len(pts)
        for y in gy:
            for x in gx:
                pts.append(rot @ np.array([x, y, 0.0]) + np.array([3.0 * f, 0.0, 0.0]))
        for j in range(ny):
            for i in range(nx):
                if 0 < i < nx - 1 and 0 < j < ny - 1:
                    continue
                v = base + j * (nx + 1) + i
                counts.append(4)
                idx += [v, v + 1, v + nx + 2, v + nx + 1]
    return fan_mesh(np.array(pts), counts, idx, path="/frames")


def test_split_rings_cuts_a_frame_into_its_sides_and_keeps_solid_charts():
    from usdahd.numerics.charts import split_rings as _split_rings

    mesh = frames(count=1)
    tris = mesh.points[mesh.triangles]  # the frame lies in one plane through the y axis
    u = np.linalg.norm(tris[..., [0, 2]], axis=-1)
    uv = np.stack([u, tris[..., 1]], axis=-1) * 10.0  # 10 texels per metre
    labels = np.zeros(len(uv), np.int64)
    cut = _split_rings(uv, labels, mesh.face, 0.5)  # the frame covers 46 % of its rectangle
    assert len(np.unique(cut)) == 4  # four sides
    for f in np.unique(mesh.face):  # whole polygons move
        assert len(np.unique(cut[mesh.face == f])) == 1
    # not a ring below that fraction; a solid chart (a square quad) is never one
    assert np.array_equal(_split_rings(uv, labels, mesh.face, 0.4), labels)
    square = np.array([[[0, 0], [10, 0], [10, 10]], [[0, 0], [10, 10], [0, 10]]], float)
    flat = _split_rings(square, np.zeros(2, np.int64), np.zeros(2, np.int64), 0.99)
    assert np.array_equal(flat, np.zeros(2, np.int64))


def test_ring_charts_are_cut_when_that_makes_the_map_smaller(monkeypatch):
    """Window frames (thin rings) packed whole leave their holes empty; cut into their sides
    the map is smaller for the same texels per metre, with every chart still disjoint and
    every polygon whole (measured: 56x57 against 54x63 at 20 texels/m)."""
    import usdahd.bake.unwrap as unwrap_module

    got = {}
    default = unwrap_module.RING_SOLIDITY
    for solidity in (default, ()):  # (): no chart is a ring
        monkeypatch.setattr(unwrap_module, "RING_SOLIDITY", solidity)
        mesh = frames()
        info = {}
        # the ring cut alone: no width floor (it would widen the 2-texel sides)
        uv, res = unwrap(mesh, texels_per_unit=20.0, isolate=False, info=info, min_chart_width=0.0)
        _check_representable(mesh, uv, res)
        assert tx.texel_density(mesh, res) == pytest.approx(20.0, rel=2e-2)
        again, res2 = unwrap(mesh, texels_per_unit=20.0, isolate=False, min_chart_width=0.0)
        assert res2 == res and np.array_equal(again, uv)
        got[solidity] = (res[0] * res[1], info["rings_cut"])
    cut, whole = got[default], got[()]
    assert cut[1] == 6 and whole[1] == 0
    assert cut[0] < 0.95 * whole[0]


def test_widen_thin_stretches_slivers_across_and_leaves_wide_charts():
    from usdahd.numerics.charts import convex_hull, min_area_rect, signed_area2, widen_thin

    a = np.deg2rad(30.0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    quad = np.array([[[0, 0], [20, 0], [20, 1]], [[0, 0], [20, 1], [0, 1]]], float)
    sliver = (quad * [1.0, 0.25]) @ rot.T + [5.0, 5.0]  # 20 x 0.25 units, turned 30 degrees
    square = quad * [0.5, 10.0] + [40.0, 0.0]  # 10 x 10 units
    uv = np.concatenate([sliver, square])
    labels = np.array([0, 0, 1, 1])
    out, count = widen_thin(uv, labels, 2.0, 2.0)  # 2 texels per unit: the sliver is 0.5 across
    assert count == 1
    assert np.array_equal(out[2:], uv[2:])
    _, lo, hi = min_area_rect(convex_hull(out[:2].reshape(-1, 2)))
    assert sorted((hi - lo) * 2.0) == pytest.approx([2.0, 40.0])
    assert (np.sign(signed_area2(out)) == np.sign(signed_area2(uv))).all()
    assert np.array_equal(widen_thin(uv, labels, 2.0, 0.0)[0], uv)
    assert widen_thin(uv, labels, 2.0, 0.5)[1] == 0  # 0.5 texels across is not below 0.5


def thin_bars(count=8, side=0.06, length=2.0) -> MeshData:
    """``count`` square bars ``side`` metres thick and ``length`` long, side by side (a
    moulding's slivers: at 8 texels per metre each face is about half a texel wide)."""
    m = trimesh.creation.box(extents=(side, length, side))
    verts = np.concatenate([m.vertices + [0.5 * i, 0.0, 0.0] for i in range(count)])
    tris = np.concatenate([m.faces + i * len(m.vertices) for i in range(count)])
    return tx.mesh_from_arrays(verts, tris, path="/bars")


def test_min_chart_width_stretches_slivers_and_covers_more_texels():
    """At a texel density that makes each face of thin bars about half a texel wide, the
    default CHART_MIN_WIDTH stretches those charts to 2 texels across: more covered texels
    (each a sample of its own face), no overlap, the long side's density kept; 0 turns it
    off; a negative width is a usage error."""
    from usdahd.bake.unwrap import CHART_MIN_WIDTH

    assert CHART_MIN_WIDTH == 2.0
    got = {}
    for width in (None, 0.0):
        mesh = thin_bars()
        info = {}
        uv, res = unwrap(mesh, texels_per_unit=8.0, isolate=False, info=info, min_chart_width=width)
        _check_representable(mesh, uv, res)
        t = tx.rasterize(mesh, res)
        got[width] = (len(t.xy), res, info["widened"])
    covered, _, widened = got[None]
    assert widened > 0 and got[0.0][2] == 0
    assert covered > 1.3 * got[0.0][0]
    with pytest.raises(UsageError, match="min_chart_width"):
        unwrap(thin_bars(), texels_per_unit=8.0, isolate=False, min_chart_width=-1.0)


def test_a_stalled_worker_is_retried_then_fails_naming_the_prim(monkeypatch, tmp_path):
    """A worker that stops using CPU while it unwraps (xatlas's thread pool deadlocked: every
    thread waiting) is stopped after UNWRAP_STALL_S and the mesh retried once in a fresh
    worker; stalling again fails that prim with a message naming it and the fix."""
    from usdahd.bake import unwrap as unwrap_mod

    unwrap_mod.stop_worker()
    want = unwrap(box_mesh(), texels_per_unit=20.0)
    unwrap_mod.stop_worker()
    monkeypatch.setattr(unwrap_worker, "STALL_S", 1.0)
    monkeypatch.setattr(unwrap_worker, "STALL_POLL_S", 0.1)
    marker = tmp_path / "stalled"
    once = (
        f"import os, sys, time; m = {str(marker)!r}\n"
        "if not os.path.exists(m):\n"
        "    open(m, 'w').close(); sys.stdin.buffer.read(8); time.sleep(600)\n"
        f"{unwrap_worker.CHILD_CODE}"
    )
    monkeypatch.setattr(unwrap_worker, "CHILD_CODE", once)
    got = unwrap(box_mesh(), texels_per_unit=20.0)
    assert marker.exists() and np.array_equal(got[0], want[0]) and got[1] == want[1]
    unwrap_mod.stop_worker()
    monkeypatch.setattr(
        unwrap_worker, "CHILD_CODE", "import sys, time; sys.stdin.buffer.read(8); time.sleep(600)"
    )
    with pytest.raises(BakeError, match=r"/box: xatlas crashed .*no CPU time for 1 s.*--uv"):
        unwrap(box_mesh(), texels_per_unit=20.0)
    monkeypatch.undo()
    unwrap_mod.stop_worker()
    assert np.array_equal(unwrap(box_mesh(), texels_per_unit=20.0)[0], want[0])


def test_pass_one_is_reused_across_unwraps_of_one_mesh_and_repeated_packs_run_once(monkeypatch):
    """The plan unwraps a mesh at its density, then maybe again into a requested map: pass 1
    (xatlas's charts, the costly part) runs once per chart option for both, and a candidate
    that comes out the same as an earlier one (a floor widening nothing more) is not packed
    again; the layouts are those of fresh runs."""
    from usdahd.bake import unwrap as unwrap_mod

    mesh = frames(count=2)
    fresh_density = unwrap(mesh, texels_per_unit=20.0, isolate=False)
    unwrap_mod._chart_cache.clear()
    fresh_map = unwrap(mesh, resolution=64, isolate=False)
    unwrap_mod._chart_cache.clear()
    runs = []
    real = unwrap_mod._chart_pass

    def counted(*args, **kwargs):
        runs.append(args[-1])
        return real(*args, **kwargs)

    monkeypatch.setattr(unwrap_mod, "_chart_pass", counted)
    info: dict = {}
    a = unwrap(mesh, texels_per_unit=20.0, isolate=False, info=info)
    b = unwrap(mesh, resolution=64, isolate=False)
    assert len(runs) == len(unwrap_mod.CHART_OPTIONS)
    assert np.array_equal(a[0], fresh_density[0]) and a[1] == fresh_density[1]
    assert np.array_equal(b[0], fresh_map[0]) and b[1] == fresh_map[1]
    # candidates: options x (uncut + ring cuts) x floors, some skipped or repeated
    assert 1 <= info["packs"] <= len(unwrap_mod.CHART_OPTIONS) * 3 * 2


def test_one_or_two_workers_give_the_in_process_layout(monkeypatch):
    """The chart options' parts run in two workers at once or one after the other in one
    worker (UNWRAP_WORKERS = 1, or a 1-core machine): the same layout as in-process."""
    from usdahd.bake import unwrap as unwrap_mod

    mesh = frames(count=2)
    want = unwrap(mesh, texels_per_unit=20.0, isolate=False)
    for workers in (2, 1):
        unwrap_mod.stop_worker()
        monkeypatch.setattr(unwrap_mod, "UNWRAP_WORKERS", workers)
        got = unwrap(mesh, texels_per_unit=20.0)
        assert np.array_equal(got[0], want[0]) and got[1] == want[1]
        assert len([w for w in unwrap_worker._helpers if w is not None]) == workers - 1
    unwrap_mod.stop_worker()


def test_atlases_outlive_their_use_by_the_retire_time(monkeypatch):
    """xatlas 0.0.11's Destroy can deadlock right after an atlas's last task
    (unwrap_worker.ATLAS_RETIRE_S): an atlas is kept until that long after the next one is
    made, and dropped after."""
    from usdahd.bake import unwrap_worker as w

    monkeypatch.setattr(w, "_ATLASES", [])
    monkeypatch.setattr(w, "ATLAS_RETIRE_S", 60.0)
    a = w.new_atlas()
    b = w.new_atlas()
    kept = [e[0] for e in w._ATLASES]
    assert kept[0] is a and kept[1] is b
    assert w._ATLASES[0][1] is not None and w._ATLASES[1][1] is None  # a done, b in use
    monkeypatch.setattr(w, "ATLAS_RETIRE_S", 0.0)
    c = w.new_atlas()
    assert [e[0] for e in w._ATLASES] == [c]
    del a, b, kept
    w._ATLASES.clear()  # destroyed here, long after their (empty) use


def test_unwrap_worker_leaves_at_end_of_input_with_exit_code_0(tmp_path):
    """The worker process leaves with os._exit(0) at EOF (its last atlases never destroyed)."""
    import subprocess
    import sys

    from usdahd.bake import unwrap_worker as w

    proc = subprocess.run(
        [sys.executable, "-c", w.CHILD_CODE], input=b"", capture_output=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr.decode()
