"""Scene extraction: topology, orientation, transforms, visibility, instancing, subsets, UVs,
errors. Stages are built in memory / tmp dirs with pxr."""

import os

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

from tests.scenes import define_mesh, new_stage
from usdahd.bake.trace import Tracer
from usdahd.errors import StageError
from usdahd.usd.reader import load_scene

SCENES = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "scenes")


QUAD = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
PENT = [(0, 0, 0), (1, 0, 0), (1.5, 1, 0), (0.5, 1.6, 0), (-0.5, 1, 0)]


def _tri_normals(md):
    p = md.points[md.triangles]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def test_ngon_triangulation_and_corners():
    st = new_stage()
    define_mesh(st, "/m", PENT + QUAD, [(0, 1, 2, 3, 4), (5, 6, 7, 8)], scheme=None)
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
        st = new_stage()
        m = define_mesh(st, "/m", QUAD, [(0, 1, 2, 3)], scheme=None)
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
    st = new_stage()
    m = define_mesh(st, "/a", QUAD, [(0, 1, 2, 3)], scheme=None)
    m.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    pts = m.GetPointsAttr()
    pts.Clear()
    pts.Set([Gf.Vec3f(*p) for p in QUAD], Usd.TimeCode(3))  # time samples only
    define_mesh(st, "/hidden", QUAD, [(0, 1, 2, 3)], scheme=None).CreateVisibilityAttr("invisible")
    define_mesh(st, "/guide", QUAD, [(0, 1, 2, 3)], scheme=None).CreatePurposeAttr("guide")
    define_mesh(st, "/render", QUAD, [(0, 1, 2, 3)], scheme=None).CreatePurposeAttr("render")
    sc = load_scene(st)
    assert [m.path for m in sc.meshes] == ["/a", "/render"]
    np.testing.assert_allclose(sc.meshes[0].points[:, 2], 5.0)
    assert any("time samples" in w for w in sc.warnings)
    assert sc.up_axis == "Z" and sc.meters_per_unit == pytest.approx(0.01)


def test_instances_pointinstancer_and_implicit_gprims():
    st = new_stage()
    proto = st.DefinePrim("/Proto", "Xform")
    define_mesh(st, "/Proto/m", QUAD, [(0, 1, 2, 3)], scheme=None)
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
    # the prototype has no lightmap UVs: its copies stay occluders, and the reader says why
    # (copies of a prototype with UVs are baked: tests/usd/test_instances.py)
    assert any("</Proto/m>: prototype mesh has no lightmap UV set" in w for w in sc.warnings)
    assert byp["/inst0/m"].instance.carrier == "/inst0" and cubes[0].instance is None
    sc2 = load_scene(st, prims=["/Proto"])
    assert [m.path for m in sc2.meshes if m.bake] == ["/Proto/m"]


def test_geomsubset_materials_and_uv_interpolations():
    st = new_stage()
    m = define_mesh(
        st, "/m", QUAD + [(2, 0, 0), (2, 1, 0)], [(0, 1, 2, 3), (1, 4, 5, 2)], scheme=None
    )
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
    st = new_stage()
    m = define_mesh(st, "/m", QUAD, [(0, 1, 2, 3)], scheme=None)
    m.CreateNormalsAttr([Gf.Vec3f(0, 0, 1)] * 4)
    m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    m.AddRotateXOp().Set(90.0)
    md = load_scene(st).meshes[0]
    np.testing.assert_allclose(md.normals.reshape(-1, 3), [[0, -1, 0]] * 6, atol=1e-6)


def test_hash_parts_track_changes():
    st = new_stage()
    m = define_mesh(st, "/m", QUAD, [(0, 1, 2, 3)], scheme=None)
    define_mesh(st, "/occ", QUAD, [(0, 1, 2, 3)], scheme=None)
    h1 = load_scene(st, prims=["/m"]).hash_parts()
    assert set(h1) == {"/m", "occluders", "lights", "materials"}
    assert load_scene(st, prims=["/m"]).hash_parts() == h1
    m.GetPointsAttr().Set([Gf.Vec3f(*p) for p in QUAD[:3] + [(0, 2, 0)]])
    h2 = load_scene(st, prims=["/m"]).hash_parts()
    assert h2["/m"] != h1["/m"] and h2["occluders"] == h1["occluders"]


def test_tracer_maps_hits_back(tmp_path):
    st = new_stage()
    define_mesh(st, "/a", QUAD, [(0, 1, 2, 3)], scheme=None)
    m = define_mesh(st, "/b", QUAD, [(0, 1, 2, 3)], scheme=None)
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
        load_scene(new_stage())
    st = new_stage()
    define_mesh(st, "/m", QUAD, [(0, 1, 2, 3)], scheme=None)
    with pytest.raises(StageError, match="/nowhere"):
        load_scene(st, prims=["/nowhere"])


def _good_and(st):
    """A valid quad /good next to the defect, so the stage itself stays usable."""
    define_mesh(st, "/good", QUAD, [(0, 1, 2, 3)], scheme=None)
    return st


def _failed(st, path="/bad", **kw):
    """load_scene must not raise; the mesh is recorded as failed and dropped."""
    sc = load_scene(st, **kw)
    assert path in sc.failed, (sc.failed, sc.warnings)
    assert path not in [m.path for m in sc.meshes]
    assert [m.path for m in sc.meshes] == ["/good"]
    msg = sc.failed[path]
    assert msg.startswith(path + ":") and "\n" not in msg
    return msg


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize(
    "pts, counts, idx, pattern",
    [
        ([(0, 0, 0), (1, 0, 0), (NAN, 1, 0)], [3], [0, 1, 2], "NaN"),
        ([(0, 0, 0), (1, 0, 0), (INF, 1, 0)], [3], [0, 1, 2], "Inf"),
        (QUAD, [4, 3], [0, 1, 2, 3], "faceVertexCounts sum to 7"),
        (QUAD, [4], [0, 1, 2, 9], "faceVertexIndices out of range"),
        (QUAD, [4], [0, 1, 2, -1], "faceVertexIndices out of range"),
        (QUAD, [5, -1], [0, 1, 2, 3], "negative"),
        ([(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)], [4], [0, 1, 2, 3], "zero surface area"),
    ],
)
def test_bad_mesh_goes_to_failed(pts, counts, idx, pattern):
    st = _good_and(new_stage())
    define_mesh(st, "/bad", pts, counts=counts, indices=idx, scheme=None)
    assert pattern in _failed(st)


def test_bad_transforms_go_to_failed():
    for op, value, pattern in [
        ("scale", Gf.Vec3f(0, 0, 0), "not invertible"),
        ("scale", Gf.Vec3f(1, 1, 0), "not invertible"),
        ("translate", Gf.Vec3d(NAN, 0, 0), "NaN"),
        ("translate", Gf.Vec3d(1e9, 0, 0), "precision"),
    ]:
        st = _good_and(new_stage())
        m = define_mesh(st, "/bad", QUAD, [(0, 1, 2, 3)], scheme=None)
        getattr(m, f"Add{op.capitalize()}Op")().Set(value)
        assert pattern in _failed(st), op
    # a rank-2 matrix (the bad_stages corpus case) and a zero-scaled parent
    st = _good_and(new_stage())
    m = define_mesh(st, "/bad", QUAD, [(0, 1, 2, 3)], scheme=None)
    m.AddTransformOp().Set(Gf.Matrix4d(1, 0, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1))
    assert "transform" in _failed(st)
    st = _good_and(new_stage())
    UsdGeom.Xform.Define(st, "/grp").AddScaleOp().Set(Gf.Vec3f(0, 1, 1))
    define_mesh(st, "/grp/bad", QUAD, [(0, 1, 2, 3)], scheme=None)
    assert "not invertible" in _failed(st, "/grp/bad")


def test_precision_rule_scales_with_size():
    # a 1 cm quad 1 km from the origin is fine (ulp 6e-5 m: 160 ulps across) ...
    st = new_stage()
    m = define_mesh(
        st, "/far", [(x * 0.01, y * 0.01, 0) for x, y, _ in QUAD], [(0, 1, 2, 3)], scheme=None
    )
    m.AddTranslateOp().Set(Gf.Vec3d(1000.0, 0, 0))
    sc = load_scene(st)
    assert not sc.failed and np.isfinite(sc.meshes[0].points).all()
    # ... a 1e-9 quad at the origin bakes with a "small" warning next to a 1 m quad
    st = _good_and(new_stage())
    define_mesh(
        st, "/tiny", [(x * 1e-9, y * 1e-9, 1e-9) for x, y, _ in QUAD], [(0, 1, 2, 3)], scheme=None
    )
    sc = load_scene(st)
    assert not sc.failed and "/tiny" in [m.path for m in sc.meshes]
    assert any("1 baked meshes are very small" in w and "/tiny (" in w for w in sc.warnings)


def test_degenerate_triangles_dropped_with_warning():
    st = new_stage()
    pts = QUAD + [(2, 0, 0), (3, 0, 0)]
    # quad, a triangle with a repeated vertex, a triangle of three collinear points
    define_mesh(st, "/m", pts, [(0, 1, 2, 3), (0, 0, 1), (1, 4, 5)], scheme=None)
    sc = load_scene(st)
    md = sc.meshes[0]
    assert md.triangles.shape == (2, 3) and md.face.tolist() == [0, 0]
    np.testing.assert_array_equal(np.array([0, 1, 2, 3, 0, 0, 1, 1, 4, 5])[md.corner], md.triangles)
    assert any("2 degenerate" in w for w in sc.warnings)


def test_empty_meshes_skipped_with_warning():
    st = _good_and(new_stage())
    UsdGeom.Mesh.Define(st, "/empty")
    define_mesh(st, "/nofaces", QUAD, counts=[], indices=[], scheme=None)
    define_mesh(st, "/lines", QUAD, counts=[2, 2], indices=[0, 1, 2, 3], scheme=None)
    sc = load_scene(st)
    assert [m.path for m in sc.meshes] == ["/good"] and not sc.failed
    text = "\n".join(sc.warnings)
    assert "/empty: empty mesh" in text and "/nofaces" in text and "/lines" in text


def _uv(m, values, type_name=Sdf.ValueTypeNames.TexCoord2fArray, interp="faceVarying", idx=None):
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", type_name, interp)
    pv.Set(values)
    if idx is not None:
        pv.SetIndices(Vt.IntArray(idx))
    return pv


def test_bad_lightmap_uvs_go_to_failed():
    fv = [(0, 0), (1, 0), (1, 1), (0, 1)]
    cases = [
        (dict(values=[(0, 0, 0)] * 4, type_name=Sdf.ValueTypeNames.Float3Array), "float3[]"),
        (dict(values=["a"] * 4, type_name=Sdf.ValueTypeNames.StringArray), "string[]"),
        (dict(values=fv[:3]), "has 3 values, needs 4"),
        (dict(values=[(0, 0)], interp="constant"), "constant interpolation"),
        (dict(values=[(0, 0)], interp="uniform"), "uniform interpolation"),
        (dict(values=fv[:3] + [(NAN, 0.5)]), "NaN"),
        (dict(values=fv[:2], idx=[0, 1, 7, 1]), "indices out of range"),
    ]
    for kw, pattern in cases:
        st = _good_and(new_stage())
        _uv(define_mesh(st, "/bad", QUAD, [(0, 1, 2, 3)], scheme=None), **kw)
        msg = _failed(st)
        assert pattern in msg and "primvars:st" in msg, (pattern, msg)
    # the same primvar is only a warning when it is not the lightmap set (a material's)
    st = _good_and(new_stage())
    _uv(define_mesh(st, "/bad", QUAD, [(0, 1, 2, 3)], scheme=None), values=[(0, 0, 0)] * 4,
        type_name=Sdf.ValueTypeNames.Float3Array)  # fmt: skip
    sc = load_scene(st, uv_name="uv2")
    assert not sc.failed and len(sc.meshes) == 2


def test_failed_outside_prims_selection_is_a_warning():
    st = _good_and(new_stage())
    define_mesh(st, "/bad", [(0, 0, 0), (1, 0, 0), (NAN, 1, 0)], [(0, 1, 2)], scheme=None)
    sc = load_scene(st, prims=["/good"])
    assert not sc.failed
    assert any(w.startswith("/bad: points contain NaN") for w in sc.warnings)
    # a mesh whose only problem is fatal and which is the only one: failed, no raise
    st = new_stage()
    define_mesh(st, "/bad", [(0, 0, 0), (1, 0, 0), (NAN, 1, 0)], [(0, 1, 2)], scheme=None)
    sc = load_scene(st)
    assert list(sc.failed) == ["/bad"] and sc.meshes == []


def test_bad_instance_prototype_is_a_warning():
    st = _good_and(new_stage())
    pi = UsdGeom.PointInstancer.Define(st, "/pi")
    define_mesh(st, "/pi/protos/m", [(0, 0, 0), (1, 0, 0), (NAN, 1, 0)], [(0, 1, 2)], scheme=None)
    pi.CreatePrototypesRel().SetTargets([Sdf.Path("/pi/protos/m")])
    pi.CreateProtoIndicesAttr([0, 0])
    pi.CreatePositionsAttr([Gf.Vec3f(0, 0, 2), Gf.Vec3f(0, 0, 3)])
    sc = load_scene(st)
    assert not sc.failed and [m.path for m in sc.meshes] == ["/good"]
    text = "\n".join(sc.warnings)
    assert "/pi/instance_0: points contain NaN" in text and "occluder dropped" in text
    assert "/pi/instance_1" not in text  # one warning per prototype, not per instance


def test_stage_metadata(tmp_path):
    for mpu in (0.0, -1.0, INF):
        st = _good_and(new_stage())
        UsdGeom.SetStageMetersPerUnit(st, mpu)
        with pytest.raises(StageError, match="metersPerUnit"):
            load_scene(st)
    st = _good_and(new_stage())
    st.SetMetadata("upAxis", "X")
    sc = load_scene(st)
    assert sc.up_axis == "Y" and any("upAxis = 'X'" in w for w in sc.warnings)


def test_composition_errors(tmp_path):
    a, b = str(tmp_path / "a.usda"), str(tmp_path / "b.usda")
    st = _good_and(Usd.Stage.CreateNew(a))
    st.DefinePrim("/M").GetReferences().AddReference("./nowhere.usda")
    st.Save()
    sc = load_scene(a)
    assert any("nowhere.usda" in w and "composition error" in w for w in sc.warnings)
    other = Usd.Stage.CreateNew(b)
    other.DefinePrim("/W").GetReferences().AddReference("./a.usda", "/W")
    other.Save()
    st.DefinePrim("/W").GetReferences().AddReference("./b.usda", "/W")
    st.Save()
    with pytest.raises(StageError, match="composition cycle"):
        load_scene(a)


def _light_stage(kind="SphereLight", **inputs):
    st = _good_and(new_stage())
    lt = getattr(UsdLux, kind).Define(st, "/L")
    for k, v in inputs.items():
        lt.GetPrim().GetAttribute(f"inputs:{k}").Set(v) if lt.GetPrim().GetAttribute(
            f"inputs:{k}"
        ) else None
        getattr(lt, f"Create{k[0].upper()}{k[1:]}Attr")(v)
    return st, lt


@pytest.mark.parametrize(
    "inputs, pattern",
    [
        (dict(intensity=-1.0), "inputs:intensity is negative"),
        (dict(intensity=NAN), "inputs:intensity is NaN"),
        (dict(intensity=INF), "inputs:intensity is Inf"),
        (dict(exposure=NAN), "inputs:exposure is NaN"),
        (dict(exposure=200.0), "exposure"),
        (dict(exposure=5000.0), "exposure"),
        (dict(color=Gf.Vec3f(NAN, 1, 1)), "inputs:color is NaN"),
        (dict(color=Gf.Vec3f(-1, 1, 1)), "inputs:color is negative"),
        (dict(intensity=1e10, radius=1e-6), "overflows"),  # normalized by a tiny area
    ],
)
def test_broken_lights_raise_naming_the_light(inputs, pattern):
    normalize = inputs.pop("radius", None)
    st, lt = _light_stage(**inputs)
    if normalize:
        lt.CreateRadiusAttr(normalize)
        lt.CreateNormalizeAttr(True)
    with pytest.raises(StageError, match="/L") as err:
        load_scene(st)
    assert pattern in str(err.value) and "\n" not in str(err.value)


def test_light_edge_cases_warn():
    st, _ = _light_stage(intensity=0.0)
    sc = load_scene(st)
    assert sc.lights == [] and any("/L: light emits nothing" in w for w in sc.warnings)
    st, lt = _light_stage()
    lt.AddScaleOp().Set(Gf.Vec3f(0, 0, 0))
    sc = load_scene(st)
    assert sc.lights == [] and any("not invertible" in w for w in sc.warnings)
    st, lt = _light_stage()
    lt.AddTranslateOp().Set(Gf.Vec3d(NAN, 0, 0))
    with pytest.raises(StageError, match="/L: light world transform contains NaN"):
        load_scene(st)


def test_dome_texture_must_be_readable(tmp_path):
    for name, content in (("missing.exr", None), ("text.exr", b"This is not an image")):
        if content is not None:
            (tmp_path / name).write_bytes(content)
        layer = tmp_path / f"{name}.usda"
        st = _good_and(Usd.Stage.CreateNew(str(layer)))
        UsdLux.DomeLight.Define(st, "/Dome").CreateTextureFileAttr(Sdf.AssetPath(f"./{name}"))
        st.Save()
        with pytest.raises(StageError, match=f"/Dome: DomeLight texture:file ./{name}"):
            load_scene(st)


def test_dome_texture_nan_texels_replaced(tmp_path):
    import OpenImageIO as oiio

    img = np.ones((4, 8, 3), np.float32)
    img[0, 0] = np.nan
    img[1, 1] = -2.0
    out = oiio.ImageOutput.create(str(tmp_path / "sky.exr"))
    out.open(str(tmp_path / "sky.exr"), oiio.ImageSpec(8, 4, 3, "float"))
    out.write_image(img)
    out.close()
    st = _good_and(Usd.Stage.CreateNew(str(tmp_path / "s.usda")))
    UsdLux.DomeLight.Define(st, "/Dome").CreateTextureFileAttr(Sdf.AssetPath("./sky.exr"))
    st.Save()
    sc = load_scene(st)
    dome = sc.lights[0]
    assert np.isfinite(dome.image).all() and dome.image.min() >= 0
    assert any("NaN/Inf" in w and "sky.exr" in w for w in sc.warnings)


def _material(st, **inputs):
    mat = UsdShade.Material.Define(st, "/Looks/M")
    s = UsdShade.Shader.Define(st, "/Looks/M/s")
    s.CreateIdAttr("UsdPreviewSurface")
    for k, v in inputs.items():
        typ = Sdf.ValueTypeNames.Float if k == "opacity" else Sdf.ValueTypeNames.Color3f
        s.CreateInput(k, typ).Set(v)
    mat.CreateSurfaceOutput().ConnectToSource(s.ConnectableAPI(), "surface")
    m = st.GetPrimAtPath("/good")
    UsdShade.MaterialBindingAPI.Apply(m).Bind(mat)
    return st


def test_material_values():
    for inputs, pattern in [
        (dict(emissiveColor=Gf.Vec3f(NAN, 0, 0)), "inputs:emissiveColor is NaN"),
        (dict(emissiveColor=Gf.Vec3f(-1, 0, 0)), "inputs:emissiveColor (-1, 0, 0) must be"),
        (dict(diffuseColor=Gf.Vec3f(INF, 0, 0)), "inputs:diffuseColor is Inf"),
        (dict(opacity=NAN), "inputs:opacity is NaN"),
    ]:
        with pytest.raises(StageError, match="/Looks/M") as err:
            load_scene(_material(_good_and(new_stage()), **inputs))
        assert pattern in str(err.value)
    sc = load_scene(_material(_good_and(new_stage()), diffuseColor=Gf.Vec3f(1.5, -0.5, 0.5)))
    np.testing.assert_allclose(sc.materials[0].albedo, [1.0, 0.0, 0.5])
    assert any("/Looks/M: inputs:diffuseColor (1.5, -0.5, 0.5)" in w for w in sc.warnings)


@pytest.mark.skipif(not os.path.isdir(os.path.join(SCENES, "mcusd")), reason="no shared scenes")
def test_mcusd_loads_with_fallback_lights():
    sc = load_scene(os.path.join(SCENES, "mcusd", "McUsd.usda"))
    kinds = sorted(type(lt).__name__ for lt in sc.lights)
    assert "DomeLight" in kinds and "DistantLight" in kinds
    assert any(m.opacity_tex is not None or m.albedo_tex is not None for m in sc.materials)
