"""Scene extraction: topology, orientation, transforms, visibility, instancing, subsets, UVs,
errors. Stages are built in memory / tmp dirs with pxr."""

import os

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

from usdahd.bake.trace import Tracer
from usdahd.errors import StageError
from usdahd.usd.scene import load_scene

SCENES = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "scenes")


def _stage():
    st = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, "Z")
    return st


def _mesh(st, path, pts, counts, idx):
    m = UsdGeom.Mesh.Define(st, path)
    m.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    m.CreateFaceVertexCountsAttr(counts)
    m.CreateFaceVertexIndicesAttr(idx)
    return m


QUAD = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
PENT = [(0, 0, 0), (1, 0, 0), (1.5, 1, 0), (0.5, 1.6, 0), (-0.5, 1, 0)]


def _tri_normals(md):
    p = md.points[md.triangles]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def test_ngon_triangulation_and_corners():
    st = _stage()
    _mesh(st, "/m", PENT + QUAD, [5, 4], [0, 1, 2, 3, 4, 5, 6, 7, 8])
    md = load_scene(st).meshes[0]
    assert md.triangles.shape == (5, 3)
    assert md.face.tolist() == [0, 0, 0, 1, 1]
    idx = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8])
    np.testing.assert_array_equal(idx[md.corner], md.triangles)
    assert np.all(_tri_normals(md)[:, 2] > 0)  # CCW seen from +Z
    area = 0.5 * np.linalg.norm(_tri_normals(md), axis=1)
    np.testing.assert_allclose(
        area[:3].sum(),
        0.5
        * abs(
            np.cross(np.array(PENT)[1:] - PENT[0], np.roll(np.array(PENT), -1, 0)[1:] - PENT[0])[
                :-1, 2
            ].sum()
        ),
    )


def test_left_handed_and_mirror_flip_winding():
    for left, mirror in [(False, False), (True, False), (False, True), (True, True)]:
        st = _stage()
        m = _mesh(st, "/m", QUAD, [4], [0, 1, 2, 3])
        if left:
            m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
        if mirror:
            m.AddScaleOp().Set(Gf.Vec3f(-1, 1, 1))
        md = load_scene(st).meshes[0]
        nz = _tri_normals(md)[:, 2]
        # a mirror keeps the front side where the inverse-transpose sends the normal (+Z here)
        want = -1.0 if left else 1.0
        assert np.all(np.sign(nz) == want), (left, mirror)
        # computed normals follow the front face
        assert np.all(np.sign(md.normals[..., 2]) == want)


def test_transform_time_samples_visibility_purpose():
    st = _stage()
    m = _mesh(st, "/a", QUAD, [4], [0, 1, 2, 3])
    m.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    pts = m.GetPointsAttr()
    pts.Clear()
    pts.Set([Gf.Vec3f(*p) for p in QUAD], Usd.TimeCode(3))  # time samples only
    _mesh(st, "/hidden", QUAD, [4], [0, 1, 2, 3]).CreateVisibilityAttr("invisible")
    _mesh(st, "/guide", QUAD, [4], [0, 1, 2, 3]).CreatePurposeAttr("guide")
    _mesh(st, "/render", QUAD, [4], [0, 1, 2, 3]).CreatePurposeAttr("render")
    sc = load_scene(st)
    assert [m.path for m in sc.meshes] == ["/a", "/render"]
    np.testing.assert_allclose(sc.meshes[0].points[:, 2], 5.0)
    assert any("time samples" in w for w in sc.warnings)
    assert sc.up_axis == "Z" and sc.meters_per_unit == pytest.approx(0.01)


def test_instances_pointinstancer_and_implicit_gprims():
    st = _stage()
    proto = st.DefinePrim("/Proto", "Xform")
    _mesh(st, "/Proto/m", QUAD, [4], [0, 1, 2, 3])
    for i in range(2):
        p = st.DefinePrim(f"/inst{i}", "Xform")
        p.GetReferences().AddInternalReference("/Proto")
        p.SetInstanceable(True)
        UsdGeom.Xformable(p).AddTranslateOp().Set(Gf.Vec3d(10 * (i + 1), 0, 0))
    proto.SetActive(True)
    pi = UsdGeom.PointInstancer.Define(st, "/pi")
    UsdGeom.Cube.Define(st, "/pi/protos/cube").CreateSizeAttr(1.0)
    pi.CreatePrototypesRel().SetTargets([Sdf.Path("/pi/protos/cube")])
    pi.CreateProtoIndicesAttr([0, 0, 0])
    pi.CreatePositionsAttr([Gf.Vec3f(0, 0, 20), Gf.Vec3f(0, 0, 30), Gf.Vec3f(0, 0, 40)])
    UsdGeom.Sphere.Define(st, "/ball").CreateRadiusAttr(2.0)
    sc = load_scene(st)
    paths = [m.path for m in sc.meshes]
    assert "/inst0/m" in paths and "/inst1/m" in paths
    assert sum(p.startswith("/pi/instance_") for p in paths) == 3
    byp = {m.path: m for m in sc.meshes}
    assert not byp["/inst0/m"].bake and byp["/Proto/m"].bake
    np.testing.assert_allclose(byp["/inst1/m"].points[:, 0].min(), 20.0)
    cubes = [m for m in sc.meshes if m.path.startswith("/pi/instance_")]
    zs = sorted(float(c.points[:, 2].mean()) for c in cubes)
    np.testing.assert_allclose(zs, [20, 30, 40], atol=1e-9)
    assert len(cubes[0].triangles) == 12 and not cubes[0].bake
    ball = byp["/ball"]
    assert not ball.bake
    r = np.linalg.norm(ball.points, axis=1)
    assert r.max() == pytest.approx(2.0)
    # implicit surfaces face outward
    c = ball.points[ball.triangles].mean(1)
    assert np.all(np.einsum("ij,ij->i", _tri_normals(ball), c) > 0)
    assert any("instanced" in w for w in sc.warnings)
    sc2 = load_scene(st, prims=["/Proto"])
    assert [m.path for m in sc2.meshes if m.bake] == ["/Proto/m"]


def test_geomsubset_materials_and_uv_interpolations():
    st = _stage()
    m = _mesh(st, "/m", QUAD + [(2, 0, 0), (2, 1, 0)], [4, 4], [0, 1, 2, 3, 1, 4, 5, 2])
    mats = []
    for name, c in (("red", (1, 0, 0)), ("blue", (0, 0, 1))):
        mat = UsdShade.Material.Define(st, f"/mat/{name}")
        s = UsdShade.Shader.Define(st, f"/mat/{name}/s")
        s.CreateIdAttr("UsdPreviewSurface")
        s.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*c))
        mat.CreateSurfaceOutput().ConnectToSource(s.ConnectableAPI(), "surface")
        mats.append(mat)
    api = UsdShade.MaterialBindingAPI.Apply(m.GetPrim())
    api.Bind(mats[0])
    sub = UsdGeom.Subset.CreateGeomSubset(
        m, "right", "face", Vt.IntArray([1]), familyName="materialBind"
    )
    UsdShade.MaterialBindingAPI.Apply(sub.GetPrim()).Bind(mats[1])
    pv = UsdGeom.PrimvarsAPI(m)
    uv = pv.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    uv.Set([(0, 0), (0.5, 0), (0.5, 1), (0, 1), (0.5, 0), (1, 0), (1, 1), (0.5, 1)])
    vx = pv.CreatePrimvar("uv2", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    vx.Set([(p[0] / 2, p[1]) for p in QUAD + [(2, 0, 0), (2, 1, 0)]])
    ix = pv.CreatePrimvar("uv3", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    ix.Set([(0, 0), (1, 1)])
    ix.SetIndices(Vt.IntArray([0, 0, 1, 1, 0, 1, 1, 0]))
    sc = load_scene(st)
    md = sc.meshes[0]
    alb = np.array([sc.materials[i].albedo for i in md.material])
    np.testing.assert_allclose(alb[md.face == 0], [[1, 0, 0]] * 2)
    np.testing.assert_allclose(alb[md.face == 1], [[0, 0, 1]] * 2)
    # faceVarying and vertex UVs agree here (u = x/2, v = y) at every corner
    np.testing.assert_allclose(md.uv[..., 0], md.points[md.triangles][..., 0] / 2, atol=1e-6)
    for name in ("uv2", "uv3"):
        md2 = load_scene(st, uv_name=name).meshes[0]
        assert md2.uv.shape == (4, 3, 2)
    md3 = load_scene(st, uv_name="uv3").meshes[0]
    fv = np.array([(0, 0), (0, 0), (1, 1), (1, 1), (0, 0), (1, 1), (1, 1), (0, 0)])
    np.testing.assert_allclose(md3.uv, fv[md.corner])
    assert load_scene(st, uv_name="nope").meshes[0].uv is None


def test_authored_normals_transformed():
    st = _stage()
    m = _mesh(st, "/m", QUAD, [4], [0, 1, 2, 3])
    m.CreateNormalsAttr([Gf.Vec3f(0, 0, 1)] * 4)
    m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    m.AddRotateXOp().Set(90.0)
    md = load_scene(st).meshes[0]
    np.testing.assert_allclose(md.normals.reshape(-1, 3), [[0, -1, 0]] * 6, atol=1e-6)


def test_hash_parts_track_changes():
    st = _stage()
    m = _mesh(st, "/m", QUAD, [4], [0, 1, 2, 3])
    _mesh(st, "/occ", QUAD, [4], [0, 1, 2, 3])
    h1 = load_scene(st, prims=["/m"]).hash_parts()
    assert set(h1) == {"/m", "occluders", "lights", "materials"}
    assert load_scene(st, prims=["/m"]).hash_parts() == h1
    m.GetPointsAttr().Set([Gf.Vec3f(*p) for p in QUAD[:3] + [(0, 2, 0)]])
    h2 = load_scene(st, prims=["/m"]).hash_parts()
    assert h2["/m"] != h1["/m"] and h2["occluders"] == h1["occluders"]


def test_tracer_maps_hits_back(tmp_path):
    st = _stage()
    _mesh(st, "/a", QUAD, [4], [0, 1, 2, 3])
    m = _mesh(st, "/b", QUAD, [4], [0, 1, 2, 3])
    m.AddTranslateOp().Set(Gf.Vec3d(0, 0, 2))
    sc = load_scene(st)
    tr = Tracer(sc)
    o = np.array([[0.25, 0.75, 1.0], [0.25, 0.75, 1.0], [5, 5, 1]])
    d = np.array([[0, 0, -1.0], [0, 0, 1.0], [0, 0, 1.0]])
    h = tr.intersect(o, d)
    assert h["tri"][2] == -1 and np.isinf(h["t"][2])
    assert [sc.meshes[tr.tri_mesh[t]].path for t in h["tri"][:2]] == ["/a", "/b"]
    np.testing.assert_allclose(h["t"][:2], 1.0, rtol=1e-6)
    np.testing.assert_allclose(
        tr.hit_points(h["tri"][:2], h["u"][:2], h["v"][:2]),
        [[0.25, 0.75, 0], [0.25, 0.75, 2]],
        atol=1e-6,
    )
    occ = tr.occluded(o, d, np.array([0.5, 5.0, 5.0]))
    assert occ.tolist() == [False, True, False]
    assert tr.build_time > 0 and tr.rays_traced >= 6


def test_errors(tmp_path):
    with pytest.raises(StageError, match="no such file"):
        load_scene(tmp_path / "missing.usda")
    bad = tmp_path / "bad.usda"
    bad.write_text("this is not usd")
    with pytest.raises(StageError, match="not a readable USD"):
        load_scene(bad)
    with pytest.raises(StageError, match="no visible"):
        load_scene(_stage())
    st = _stage()
    _mesh(st, "/nan", [(0, 0, 0), (1, 0, 0), (float("nan"), 1, 0)], [3], [0, 1, 2])
    with pytest.raises(StageError, match="/nan.*NaN"):
        load_scene(st)
    st = _stage()
    _mesh(st, "/counts", QUAD, [4, 3], [0, 1, 2, 3])
    with pytest.raises(StageError, match="/counts.*faceVertexCounts"):
        load_scene(st)
    st = _stage()
    _mesh(st, "/range", QUAD, [4], [0, 1, 2, 9])
    with pytest.raises(StageError, match="/range.*out of range"):
        load_scene(st)
    st = _stage()
    _mesh(st, "/m", QUAD, [4], [0, 1, 2, 3])
    with pytest.raises(StageError, match="/nowhere"):
        load_scene(st, prims=["/nowhere"])


@pytest.mark.skipif(not os.path.isdir(os.path.join(SCENES, "mcusd")), reason="no shared scenes")
def test_mcusd_loads_with_fallback_lights():
    sc = load_scene(os.path.join(SCENES, "mcusd", "McUsd.usda"))
    kinds = sorted(type(lt).__name__ for lt in sc.lights)
    assert "DomeLight" in kinds and "DistantLight" in kinds
    assert any(m.opacity_tex is not None or m.albedo_tex is not None for m in sc.materials)
