"""Structure of the sample stages (samples/) and validity of the bad-stage corpus manifest.

The samples are inputs for the README, the bake tests and the benchmarks, so their promises
are checked here with pxr and numpy only: lightmap UVs ``st`` inside [0, 1], without overlap,
charts at least 2 texels apart at 64x64, uniform texel density per mesh; authored normals that
agree with the winding; real UsdLux lights; UsdPreviewSurface materials bound to every face;
textures that exist and decode. The bad-stage corpus is checked for a well-formed manifest
whose files exist and open (or fail to open) as declared. Both generators are re-run into a
temporary folder and must reproduce the committed files.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLES_DIR = ROOT / "samples"
BAD_DIR = ROOT / "tests" / "data" / "bad_stages"
SAMPLES = ["cornell_box.usda", "pillar_room.usda", "normal_wall.usda", "open_plane.usda"]

# Tolerances, each with its reason.
PACK_RES = 64  # the resolution at which the gutter promise is stated
MIN_GUTTER_UV = 2.0 / PACK_RES - 1e-6  # >= 2 texels; 1e-6 covers the 6-decimal rounding of st
RASTER_N = 256  # overlap raster: 256^2 samples, 4 per texel at 64x64
UV_EPS = 1e-6  # st is authored with 6 decimals (float32 holds them to ~6e-8)
NORMAL_DOT = 0.999  # authored flat normals vs the winding normal (float32 rounding only)
DENSITY_SPREAD = 1.01  # max/min UV-area-per-world-area within a mesh (one packing scale)
MAX_TEXTURE_BYTES = 100_000
MAX_TOTAL_BYTES = 2_000_000


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module", params=SAMPLES)
def stage(request) -> Usd.Stage:
    st = Usd.Stage.Open(str(SAMPLES_DIR / request.param))
    assert st, request.param
    return st


def _meshes(stage: Usd.Stage) -> list[UsdGeom.Mesh]:
    return [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]


def _lights(stage: Usd.Stage) -> list[Usd.Prim]:
    return [p for p in stage.Traverse() if p.HasAPI(UsdLux.LightAPI)]


# --------------------------------------------------------------------------------------------
# Mesh helpers (numpy)
# --------------------------------------------------------------------------------------------


def _topology(mesh: UsdGeom.Mesh):
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int64)
    points = np.asarray(mesh.GetPointsAttr().Get(), np.float64)
    return counts, indices, points


def _corner_values(mesh: UsdGeom.Mesh, values, interpolation: str, n_corners: int):
    """Per face-vertex values from a vertex or faceVarying array: (n_corners, k)."""
    _, indices, points = _topology(mesh)
    values = np.asarray(values, np.float64)
    if interpolation == UsdGeom.Tokens.faceVarying:
        assert len(values) == n_corners
        return values
    assert interpolation == UsdGeom.Tokens.vertex, interpolation
    assert len(values) == len(points)
    return values[indices]


def _corner_uvs(mesh: UsdGeom.Mesh, name: str = "st") -> np.ndarray:
    pv = UsdGeom.PrimvarsAPI(mesh).GetPrimvar(name)
    assert pv and pv.HasValue(), f"{mesh.GetPath()} has no primvars:{name}"
    assert pv.GetTypeName() in (Sdf.ValueTypeNames.TexCoord2fArray, Sdf.ValueTypeNames.Float2Array)
    n = len(mesh.GetFaceVertexIndicesAttr().Get())
    return _corner_values(mesh, pv.ComputeFlattened(), pv.GetInterpolation(), n)


def _fan(counts: np.ndarray) -> np.ndarray:
    """(t, 3) corner indices of a fan triangulation of every polygon."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tris = [(s, s + i, s + i + 1) for s, c in zip(starts, counts) for i in range(1, c - 1)]
    return np.asarray(tris, np.int64).reshape(-1, 3)


def _cross2(o, a, b) -> np.ndarray:
    """2-D cross product (a - o) x (b - o) over the last axis (broadcasts)."""
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (
        b[..., 0] - o[..., 0]
    )


def _signed_area_2d(a, b, c) -> np.ndarray:
    return 0.5 * _cross2(a, b, c)


def _charts(counts, indices, uv) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Faces connected through shared UV vertices (same point and same UV) form a chart.

    Returns ``(chart id per face, boundary edges as corner index pairs)``.
    """
    keys = [(int(p), round(u, 6), round(v, 6)) for p, (u, v) in zip(indices, uv)]
    parent = list(range(len(counts)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    face_of_corner = np.repeat(np.arange(len(counts)), counts)
    first: dict = {}
    for corner, key in enumerate(keys):
        f = int(face_of_corner[corner])
        if key in first:
            parent[find(f)] = find(first[key])
        else:
            first[key] = f
    chart = np.array([find(f) for f in range(len(counts))])
    edges: dict = {}
    start = 0
    for c in counts:
        for i in range(c):
            a, b = start + i, start + (i + 1) % c
            k = frozenset((keys[a], keys[b]))
            edges.setdefault(k, []).append((a, b))
        start += c
    boundary = [v[0] for v in edges.values() if len(v) == 1]
    return chart[face_of_corner], boundary


def _point_segment_distance(p, a, b) -> np.ndarray:
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def _segment_distances(p0, p1, q0, q1) -> np.ndarray:
    """Distances between 2-D segments p0p1 and q0q1 (broadcast arrays of shape (..., 2))."""

    def orient(a, b, c):
        return np.sign(_cross2(a, b, c))

    crossing = (orient(p0, p1, q0) * orient(p0, p1, q1) < 0) & (
        orient(q0, q1, p0) * orient(q0, q1, p1) < 0
    )
    d = np.minimum.reduce(
        [
            _point_segment_distance(p0, q0, q1),
            _point_segment_distance(p1, q0, q1),
            _point_segment_distance(q0, p0, p1),
            _point_segment_distance(q1, p0, p1),
        ]
    )
    return np.where(crossing, 0.0, d)


def _coverage(tri_uv: np.ndarray, n: int = RASTER_N) -> np.ndarray:
    """How many UV triangles contain each of n x n sample points: (n, n) int.

    Samples sit at an irrational offset from the texel grid so that none lies exactly on the
    axis-aligned or diagonal chart edges the samples use; a sample on a shared edge would
    otherwise be counted by both triangles (or by neither).
    """
    offset = 0.5 + 0.1234567
    xs = (np.arange(n) + offset) / n
    count = np.zeros((n, n), np.int32)
    for a, b, c in tri_uv:
        lo = np.floor(np.minimum.reduce([a, b, c]) * n - offset).astype(int) - 1
        hi = np.ceil(np.maximum.reduce([a, b, c]) * n - offset).astype(int) + 1
        ix = np.arange(max(lo[0], 0), min(hi[0], n - 1) + 1)
        iy = np.arange(max(lo[1], 0), min(hi[1], n - 1) + 1)
        px, py = np.meshgrid(xs[ix], xs[iy], indexing="ij")
        p = np.stack([px, py], -1)
        area = _cross2(a, b, c)
        w0 = _cross2(p, b, c) / area
        w1 = _cross2(p, c, a) / area
        inside = (w0 > 0) & (w1 > 0) & (1.0 - w0 - w1 > 0)
        count[np.ix_(ix, iy)] += inside
    return count


# --------------------------------------------------------------------------------------------
# Samples
# --------------------------------------------------------------------------------------------


def test_sample_files_exist():
    for name in SAMPLES:
        assert (SAMPLES_DIR / name).is_file(), name
    assert (SAMPLES_DIR / "README.md").is_file()


def test_stage_metadata(stage):
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    # Static scenes: nothing is animated.
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            assert attr.GetNumTimeSamples() == 0, attr.GetPath()


def test_mesh_topology_and_size(stage):
    meshes = _meshes(stage)
    assert meshes
    total = 0
    for mesh in meshes:
        counts, indices, points = _topology(mesh)
        assert len(points) and np.isfinite(points).all(), mesh.GetPath()
        assert counts.min() >= 3 and counts.sum() == len(indices), mesh.GetPath()
        assert indices.min() >= 0 and indices.max() < len(points), mesh.GetPath()
        assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
        tris = _fan(counts)
        p = points[indices[tris]]
        area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=-1)
        assert area.min() > 1e-6, f"{mesh.GetPath()}: degenerate triangle"
        total += len(tris)
    assert 100 <= total <= 1000, f"{total} triangles: samples stay small"


def test_normals_agree_with_winding(stage):
    for mesh in _meshes(stage):
        counts, indices, points = _topology(mesh)
        normals = mesh.GetNormalsAttr().Get()
        assert normals is not None, f"{mesh.GetPath()}: normals are authored in every sample"
        n = _corner_values(mesh, normals, mesh.GetNormalsInterpolation(), len(indices))
        assert np.allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-6)
        tris = _fan(counts)
        p = points[indices[tris]]
        g = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        g /= np.linalg.norm(g, axis=-1, keepdims=True)
        assert mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.rightHanded
        for k in range(3):
            dots = np.sum(g * n[tris[:, k]], -1)
            assert dots.min() > NORMAL_DOT, mesh.GetPath()


def test_lightmap_uvs(stage):
    """st in [0, 1], counter-clockwise, non-overlapping, >= 2 texels between charts at 64^2,
    one texel density per mesh."""
    for mesh in _meshes(stage):
        path = mesh.GetPath()
        counts, indices, points = _topology(mesh)
        uv = _corner_uvs(mesh)
        assert np.isfinite(uv).all(), path
        assert uv.min() >= 0.0 and uv.max() <= 1.0, f"{path}: st leaves [0, 1]"
        tris = _fan(counts)
        t = uv[tris]
        signed = _signed_area_2d(t[:, 0], t[:, 1], t[:, 2])
        assert signed.min() > 0.0, f"{path}: flipped or degenerate UV triangle"

        p = points[indices[tris]]
        world = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=-1)
        density = signed / world
        assert density.max() / density.min() < DENSITY_SPREAD, f"{path}: texel density varies"

        count = _coverage(t)
        assert count.max() <= 1, f"{path}: UV triangles overlap"
        # Area-sum check: the covered fraction matches the summed triangle area to within the
        # samples of a band one sample wide around the chart boundaries.
        chart_of_corner, boundary = _charts(counts, indices, uv)
        perimeter = sum(np.linalg.norm(uv[a] - uv[b]) for a, b in boundary)
        covered = (count > 0).mean()
        assert abs(covered - signed.sum()) <= 2.0 * perimeter / RASTER_N, path

        charts = np.unique(chart_of_corner)
        if len(charts) > 1:
            e = np.asarray(boundary)
            ea, eb = uv[e[:, 0]], uv[e[:, 1]]
            owner = chart_of_corner[e[:, 0]]
            d = _segment_distances(ea[:, None], eb[:, None], ea[None], eb[None])
            other = owner[:, None] != owner[None, :]
            gap = d[other].min()
            assert gap >= MIN_GUTTER_UV, f"{path}: charts {gap * PACK_RES:.2f} texels apart"
        # Charts keep a border to the image edge too (at least one texel).
        assert uv.min() >= 1.0 / PACK_RES - UV_EPS and uv.max() <= 1 - 1.0 / PACK_RES + UV_EPS


def test_segment_triangle_helper():
    tri = np.array([[[-1.0, 1.0, -1.0], [1.0, 1.0, -1.0], [0.0, 1.0, 1.0]]])
    targets = np.array([[0.0, 2.0, 0.0], [0.0, 0.5, 0.0], [5.0, 2.0, 0.0]])
    assert _segments_hit_triangles(np.zeros(3), targets, tri).tolist() == [True, False, False]


def test_uv_tools_detect_bad_layouts():
    """The checks above are not vacuous: overlap and a too-small gutter are detected."""
    square = np.array([[0.1, 0.1], [0.5, 0.1], [0.5, 0.5], [0.1, 0.5]])
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    one = square[tris]
    assert _coverage(one).max() == 1
    assert _coverage(np.concatenate([one, one + 0.2])).max() == 2
    d = _segment_distances(np.array([0.0, 0.0]), np.array([1.0, 0.0]),
                           np.array([0.5, 0.01]), np.array([0.5, 1.0]))  # fmt: skip
    assert d == pytest.approx(0.01)
    assert _segment_distances(np.array([0.0, 0.0]), np.array([1.0, 1.0]),
                              np.array([0.0, 1.0]), np.array([1.0, 0.0])) == 0.0  # fmt: skip
    counts = np.array([4, 4])
    indices = np.array([0, 1, 2, 3, 4, 5, 6, 7])
    uv = np.concatenate([square, square + [0.42, 0.0]])
    chart, boundary = _charts(counts, indices, uv)
    assert len(np.unique(chart)) == 2 and len(boundary) == 8


def _surface_shader(material: UsdShade.Material) -> UsdShade.Shader:
    source = material.ComputeSurfaceSource()
    shader = source[0] if isinstance(source, tuple) else source
    assert shader, material.GetPath()
    return shader


def test_materials_bound_to_every_face(stage):
    for mesh in _meshes(stage):
        counts = mesh.GetFaceVertexCountsAttr().Get()
        api = UsdShade.MaterialBindingAPI(mesh)
        subsets = api.GetMaterialBindSubsets()
        bound = []
        if subsets:
            assert UsdGeom.Subset.ValidateFamily(
                mesh, UsdGeom.Tokens.face, UsdShade.Tokens.materialBind
            )[0]
            assert api.GetMaterialBindSubsetsFamilyType() == UsdGeom.Tokens.partition
            covered = set()
            for subset in subsets:
                mat, _ = UsdShade.MaterialBindingAPI(subset).ComputeBoundMaterial()
                assert mat, subset.GetPath()
                bound.append(mat)
                covered |= set(subset.GetIndicesAttr().Get())
            assert covered == set(range(len(counts))), mesh.GetPath()
        else:
            mat, _ = api.ComputeBoundMaterial()
            assert mat, f"{mesh.GetPath()} has no bound material"
            bound.append(mat)
        for mat in bound:
            shader = _surface_shader(mat)
            assert shader.GetIdAttr().Get() == "UsdPreviewSurface", mat.GetPath()
            diffuse = shader.GetInput("diffuseColor")
            assert diffuse and (diffuse.HasConnectedSource() or diffuse.Get() is not None)
            value = diffuse.Get()
            assert value is not None and 0.0 <= min(value) and max(value) < 1.0, mat.GetPath()


def _texture_files(stage: Usd.Stage) -> list[Path]:
    files = []
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            if attr.GetTypeName() == Sdf.ValueTypeNames.Asset:
                value = attr.Get()
                if value and value.path:
                    assert value.resolvedPath, f"{attr.GetPath()}: {value.path} does not resolve"
                    files.append(Path(value.resolvedPath))
    return files


def test_textures_exist_and_decode(stage):
    oiio = pytest.importorskip("OpenImageIO")
    for path in _texture_files(stage):
        assert path.is_file() and path.stat().st_size < MAX_TEXTURE_BYTES, path
        assert path.resolve().is_relative_to(SAMPLES_DIR), path
        image = oiio.ImageBuf(str(path))
        assert not image.has_error, image.geterror()
        pixels = image.get_pixels(oiio.FLOAT)
        assert pixels.size and np.isfinite(pixels).all() and pixels.min() >= 0.0, path


def _emission(light: Usd.Prim) -> np.ndarray:
    api = UsdLux.LightAPI(light)
    return (
        api.GetIntensityAttr().Get()
        * 2.0 ** api.GetExposureAttr().Get()
        * np.asarray(api.GetColorAttr().Get())
    )


def test_lights_are_explicit_and_positive(stage):
    lights = _lights(stage)
    assert lights, "every sample has UsdLux lights"
    for light in lights:
        api = UsdLux.LightAPI(light)
        for attr in (
            api.GetIntensityAttr(),
            api.GetExposureAttr(),
            api.GetColorAttr(),
            api.GetNormalizeAttr(),
        ):
            assert attr.HasAuthoredValue(), attr.GetPath()
        e = _emission(light)
        assert np.isfinite(e).all() and e.min() > 0.0, light.GetPath()
        assert not light.HasAPI(UsdLux.ShapingAPI), "samples use only supported features"


def _world(prim: Usd.Prim) -> Gf.Matrix4d:
    return UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())


def _emit_dir(prim: Usd.Prim) -> np.ndarray:
    """World direction a light emits along (its local -Z)."""
    d = _world(prim).TransformDir(Gf.Vec3d(0, 0, -1))
    return np.asarray(d) / np.linalg.norm(d)


def _bounds(prim: Usd.Prim) -> tuple[np.ndarray, np.ndarray]:
    cache = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_])
    box = cache.ComputeWorldBound(prim).ComputeAlignedRange()
    return np.asarray(box.GetMin()), np.asarray(box.GetMax())


def _segment_hits_box(a, b, lo, hi) -> bool:
    """Slab test: does the segment a->b pass through the axis-aligned box?"""
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - a) / d, (hi - a) / d
    tmin = np.nanmax(np.minimum(t0, t1))
    tmax = np.nanmin(np.maximum(t0, t1))
    return bool(tmax >= max(tmin, 0.0) and tmin <= 1.0)


def _world_triangles(mesh: UsdGeom.Mesh) -> np.ndarray:
    """(t, 3, 3) world-space triangles of a mesh (fan triangulation)."""
    counts, indices, points = _topology(mesh)
    m = np.asarray(_world(mesh.GetPrim()))  # row-vector convention: p' = [p, 1] @ m
    world = points @ m[:3, :3] + m[3, :3]
    return world[indices[_fan(counts)]]


def _segments_hit_triangles(origin, targets, tri) -> np.ndarray:
    """Moller-Trumbore: (n,) whether the segment origin->targets[i] crosses any triangle."""
    d = targets - origin  # (n, 3)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]  # (t, 3)
    p = np.cross(d[:, None], e2[None])  # (n, t, 3)
    det = np.sum(p * e1[None], -1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - tri[:, 0]  # (t, 3)
    u = np.sum(p * s[None], -1) * inv
    q = np.cross(s, e1)  # (t, 3)
    v = np.sum(d[:, None] * q[None], -1) * inv
    t = np.sum(e2 * q, -1)[None] * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < 1)
    return hit.any(axis=1)


def test_cornell_box_layout():
    stage = Usd.Stage.Open(str(SAMPLES_DIR / "cornell_box.usda"))
    light = stage.GetPrimAtPath("/World/Lights/CeilingLight")
    assert light.IsA(UsdLux.RectLight)
    assert np.allclose(_emit_dir(light), [0, -1, 0], atol=1e-9)
    pos = np.asarray(_world(light).ExtractTranslation())
    lo, hi = _bounds(stage.GetPrimAtPath("/World/Geometry"))
    assert (pos > lo).all() and (pos < hi).all() and hi[1] - pos[1] < 0.05

    def colour(path):
        mat, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(path)).ComputeBoundMaterial()
        return np.asarray(_surface_shader(mat).GetInput("diffuseColor").Get())

    assert colour("/World/Geometry/LeftWall").argmax() == 0  # red
    assert colour("/World/Geometry/RightWall").argmax() == 1  # green
    assert _bounds(stage.GetPrimAtPath("/World/Geometry/LeftWall"))[1][0] < 0

    # README's analytic direct value assumes the floor centre sees the whole light: every
    # segment from (0, 0, 0) to a 9 x 9 grid on the light misses both boxes.
    rect = UsdLux.RectLight(light)
    g = np.linspace(-0.5, 0.5, 9)
    local = [Gf.Vec3d(x * rect.GetWidthAttr().Get(), y * rect.GetHeightAttr().Get(), 0)
             for x in g for y in g]  # fmt: skip
    targets = np.array([_world(light).Transform(p) for p in local])
    for box in ("TallBox", "ShortBox"):
        tri = _world_triangles(UsdGeom.Mesh(stage.GetPrimAtPath(f"/World/Geometry/{box}")))
        assert not _segments_hit_triangles(np.zeros(3), targets, tri).any(), box


def test_pillar_room_layout():
    """A low light shadowed by the pillar, and a thin partition lit from behind."""
    stage = Usd.Stage.Open(str(SAMPLES_DIR / "pillar_room.usda"))
    lamp = stage.GetPrimAtPath("/World/Lights/FloorLamp")
    lamp_pos = np.asarray(_world(lamp).ExtractTranslation())
    assert lamp_pos[1] < 0.5, "the lamp sits near the floor"
    lo, hi = _bounds(stage.GetPrimAtPath("/World/Geometry/Pillar"))
    room_lo, room_hi = _bounds(stage.GetPrimAtPath("/World/Geometry/Room"))
    behind = np.array([room_hi[0], lamp_pos[1], lamp_pos[2]])  # right wall, same height
    assert _segment_hits_box(lamp_pos, behind, lo, hi), "the pillar shadows the right wall"

    part_lo, part_hi = _bounds(stage.GetPrimAtPath("/World/Geometry/Partition"))
    assert (part_hi - part_lo).min() < 0.1, "the partition is thin"
    disk = stage.GetPrimAtPath("/World/Lights/BehindPartition")
    disk_pos = np.asarray(_world(disk).ExtractTranslation())
    assert disk_pos[0] > part_hi[0] and np.allclose(_emit_dir(disk), [-1, 0, 0], atol=1e-9)
    target = disk_pos + _emit_dir(disk) * 2.0
    assert _segment_hits_box(disk_pos, target, part_lo, part_hi)
    assert not _segment_hits_box(lamp_pos, disk_pos, part_lo - 10, part_lo), "disk is behind"

    # The back wall has the highest albedo (the paper's bounce); one surface is emissive.
    room = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath("/World/Geometry/Room"))
    albedo = {}
    for subset in room.GetMaterialBindSubsets():
        mat, _ = UsdShade.MaterialBindingAPI(subset).ComputeBoundMaterial()
        albedo[subset.GetPrim().GetName()] = max(
            _surface_shader(mat).GetInput("diffuseColor").Get()
        )
    assert max(albedo, key=albedo.get) == "BackWall"
    sign, _ = UsdShade.MaterialBindingAPI(
        stage.GetPrimAtPath("/World/Geometry/ExitSign")
    ).ComputeBoundMaterial()
    assert max(_surface_shader(sign).GetInput("emissiveColor").Get()) > 0


def test_normal_wall_normal_map():
    oiio = pytest.importorskip("OpenImageIO")
    stage = Usd.Stage.Open(str(SAMPLES_DIR / "normal_wall.usda"))
    wall = stage.GetPrimAtPath("/World/Geometry/Wall")
    mat, _ = UsdShade.MaterialBindingAPI(wall).ComputeBoundMaterial()
    normal = _surface_shader(mat).GetInput("normal")
    assert normal.HasConnectedSource()
    tex = UsdShade.Shader(normal.GetConnectedSources()[0][0].source.GetPrim())
    assert tex.GetIdAttr().Get() == "UsdUVTexture"
    assert tex.GetInput("sourceColorSpace").Get() == "raw"
    reader = UsdShade.Shader(tex.GetInput("st").GetConnectedSources()[0][0].source.GetPrim())
    varname = reader.GetInput("varname").Get()
    assert UsdGeom.PrimvarsAPI(wall).GetPrimvar(varname).HasValue()
    scale = np.asarray(tex.GetInput("scale").Get())[:3]
    bias = np.asarray(tex.GetInput("bias").Get())[:3]
    path = tex.GetInput("file").Get().resolvedPath
    pixels = oiio.ImageBuf(path).get_pixels(oiio.FLOAT)[..., :3]
    n = pixels * scale + bias
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0, atol=0.02)  # 8-bit quantization
    assert n[..., 2].min() > 0.5, "tangent-space normals stay in the upper hemisphere"
    assert n[..., :2].std() > 0.05, "the map is not flat"
    # The lightmap set runs the same way as the texture set (tangent frames agree).
    uv, st = _corner_uvs(UsdGeom.Mesh(wall), varname), _corner_uvs(UsdGeom.Mesh(wall))
    du, dst = uv - uv[0], st - st[0]
    assert np.allclose(dst * (du[:, 0].max() / dst[:, 0].max()), du, atol=1e-4)
    sun = stage.GetPrimAtPath("/World/Lights/Sun")
    d = _emit_dir(sun)
    assert d[2] < 0 and abs(d[2]) < 0.6, "the sun grazes the wall (z = 0, facing +z)"
    dome = UsdLux.DomeLight(stage.GetPrimAtPath("/World/Lights/Sky"))
    assert dome.GetTextureFormatAttr().Get() == UsdLux.Tokens.latlong


def test_open_plane_is_the_analytic_case():
    stage = Usd.Stage.Open(str(SAMPLES_DIR / "open_plane.usda"))
    lights = _lights(stage)
    assert len(lights) == 1 and lights[0].IsA(UsdLux.DomeLight)
    dome = UsdLux.DomeLight(lights[0])
    assert not dome.GetTextureFileAttr().Get()
    assert dome.GetNormalizeAttr().Get() is False
    assert np.array_equal(_emission(lights[0]), [1.0, 1.0, 1.0]), "radiance-1 sky"
    meshes = _meshes(stage)
    assert len(meshes) == 1
    points = np.asarray(meshes[0].GetPointsAttr().Get())
    assert np.ptp(points[:, 1]) == 0.0, "one flat plane: nothing else is visible from it"
    assert UsdGeom.PrimvarsAPI(meshes[0]).GetPrimvar("st").GetInterpolation() == "vertex"


def _layer_text(path: Path) -> str:
    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    assert layer, path
    return layer.ExportToString()


def test_samples_regenerate_identically(tmp_path):
    """make_samples.py reproduces the committed stages (compared as layers re-serialized by the
    installed pxr, so a different usd-core version does not fail this) and textures."""
    module = _load(SAMPLES_DIR / "make_samples.py", "make_samples")
    assert module.main(["--out", str(tmp_path)]) == 0
    for name in SAMPLES:
        assert _layer_text(tmp_path / name) == _layer_text(SAMPLES_DIR / name), name
    oiio = pytest.importorskip("OpenImageIO")
    fresh = sorted(p.name for p in (tmp_path / "textures").iterdir())
    assert fresh == sorted(p.name for p in (SAMPLES_DIR / "textures").iterdir())
    for name in fresh:
        a = oiio.ImageBuf(str(tmp_path / "textures" / name)).get_pixels(oiio.FLOAT)
        b = oiio.ImageBuf(str(SAMPLES_DIR / "textures" / name)).get_pixels(oiio.FLOAT)
        assert np.array_equal(a, b), name


def test_committed_size_budget():
    """Samples + corpus stay under 2 MB (other files under samples/, such as bake outputs a
    user writes there, are not counted)."""
    files = [SAMPLES_DIR / n for n in [*SAMPLES, "make_samples.py", "README.md"]]
    files += sorted((SAMPLES_DIR / "textures").iterdir())
    files += [p for p in BAD_DIR.iterdir() if p.is_file()]
    assert sum(p.stat().st_size for p in files) < MAX_TOTAL_BYTES


# --------------------------------------------------------------------------------------------
# Bad-stage corpus manifest
# --------------------------------------------------------------------------------------------

CASE_KEYS = {
    "id": str,
    "file": str,
    "description": str,
    "exit_code": int,
    "severity": str,
    "message": (str, type(None)),
    "prim": (str, type(None)),
    "args": list,
    "exists": bool,
    "opens": bool,
    "aux": list,
    "check": (str, type(None)),
    "setup": (str, type(None)),
}
CHECKS = {None, "distinct_texture_names", "texture_names_fit", "inside_output_dir", "no_warning"}
#: Defects of the surroundings the corpus test creates (tests/pipeline/test_bad_stages.py::_setup).
SETUPS = {
    None,
    "lightmaps_file",
    "lightmaps_dangling_symlink",
    "readonly_lightmaps",
    "output_is_directory",
    "readonly_layer",
    "fifo_texture",
    "non_utf8_name",
}


@pytest.fixture(scope="module")
def manifest() -> dict:
    return json.loads((BAD_DIR / "cases.json").read_text(encoding="utf-8"))


def test_manifest_is_well_formed(manifest):
    cases = manifest["cases"]
    assert manifest["format"] == 1 and len(cases) >= 30
    ids = [c["id"] for c in cases]
    assert len(ids) == len(set(ids))
    runs = [(c["file"], tuple(c["args"])) for c in cases]
    assert len(runs) == len(set(runs)), "two cases run the same file with the same args"
    for c in cases:
        assert set(c) == set(CASE_KEYS), c["id"]
        for key, kind in CASE_KEYS.items():
            assert isinstance(c[key], kind), (c["id"], key)
        assert c["exit_code"] in (0, 1, 2), c["id"]
        assert c["severity"] in ("error", "warning", "none"), c["id"]
        assert (c["severity"] == "error") == (c["exit_code"] != 0), c["id"]
        assert (c["severity"] == "none") == (c["message"] is None), c["id"]
        assert c["message"] is None or c["message"].strip(), c["id"]
        assert c["prim"] is None or Sdf.Path.IsValidPathString(c["prim"]), c["id"]
        assert c["check"] in CHECKS, c["id"]
        assert c["setup"] in SETUPS, c["id"]
        assert c["description"].strip() and "\n" not in c["description"], c["id"]
    # Every exit code and every kind of defect is represented.
    assert {c["exit_code"] for c in cases} == {0, 1, 2}
    assert sum(not c["exists"] for c in cases) == 1


def test_manifest_files_exist_and_open_as_declared(manifest):
    listed = {"cases.json", "make_bad_stages.py"}
    for c in manifest["cases"]:
        path = BAD_DIR / c["file"]
        assert path.is_file() == c["exists"], c["id"]
        listed.add(c["file"])
        for aux in c["aux"]:
            assert (BAD_DIR / aux).is_file(), (c["id"], aux)
            listed.add(aux)
        if not c["exists"]:
            continue
        try:
            stage = Usd.Stage.Open(str(path))
        except pxr.Tf.ErrorException:
            stage = None
        assert bool(stage) == c["opens"], c["id"]
        if stage and c["prim"]:
            assert stage.GetPrimAtPath(c["prim"]), (c["id"], c["prim"])
    present = {p.name for p in BAD_DIR.iterdir() if p.is_file()}
    assert present == listed - {c["file"] for c in manifest["cases"] if not c["exists"]}


def test_corpus_defects_are_present(manifest):
    """Spot-check that a few files carry exactly the defect the manifest claims."""

    stages = {}

    def mesh(case_id, path="/World/Bad"):
        stage = stages.setdefault(case_id, Usd.Stage.Open(str(BAD_DIR / f"{case_id}.usda")))
        return UsdGeom.Mesh(stage.GetPrimAtPath(path))

    assert np.isnan(np.asarray(mesh("nan_points").GetPointsAttr().Get())).any()
    assert np.isinf(np.asarray(mesh("inf_points").GetPointsAttr().Get())).any()
    m = mesh("fvc_mismatch")
    assert sum(m.GetFaceVertexCountsAttr().Get()) != len(m.GetFaceVertexIndicesAttr().Get())
    st = UsdGeom.PrimvarsAPI(mesh("uv_float3")).GetPrimvar("st")
    assert st.GetTypeName() == Sdf.ValueTypeNames.Float3Array
    assert mesh("huge_resolution").GetPrim().GetAttribute("ahdLightmap:resolution").Get() == 10**6
    good = mesh("nan_points", "/World/Good")
    assert np.isfinite(np.asarray(good.GetPointsAttr().Get())).all()
    stage = Usd.Stage.Open(str(BAD_DIR / "negative_intensity.usda"))
    light = UsdLux.LightAPI(stage.GetPrimAtPath("/World/Lights/Bad"))
    assert light.GetIntensityAttr().Get() < 0


def test_bad_stages_regenerate_identically(tmp_path, manifest):
    module = _load(BAD_DIR / "make_bad_stages.py", "make_bad_stages")
    assert module.main(["--out", str(tmp_path)]) == 0
    fresh = json.loads((tmp_path / "cases.json").read_text(encoding="utf-8"))
    assert fresh == manifest
    for c in manifest["cases"]:
        if c["opens"]:
            for name in [c["file"], *[a for a in c["aux"] if a.endswith(".usda")]]:
                assert _layer_text(tmp_path / name) == _layer_text(BAD_DIR / name), name
