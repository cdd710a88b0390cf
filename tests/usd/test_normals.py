"""Normals of meshes without authored normals (issue 17 item 1): the crease-angle rule, smooth
normals for subdivision surfaces, authored normals winning, and the normals a bake computes
authored into its override layer (an interchange fact, checked by validate)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from tests.scenes import BOX_QUADS, box_points, define_mesh, new_stage
from usdahd import cli
from usdahd.usd import normals as N
from usdahd.usd.reader import load_scene

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--resolution", "64", "--samples", "16", "--bounces", "0", "--quiet"]

# A unit box with shared points (every corner is used by three faces), outward CCW quads.
BOX_P = box_points((0, 0, 0), (1, 1, 1))
BOX_Q = list(BOX_QUADS)


def _cylinder(n=32, r=1.0, h=2.0, caps=True):
    """n-segment cylinder about z: side quads + two n-gon caps (shared points)."""
    phi = 2 * np.pi * np.arange(n) / n
    ring = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    pts = [(x, y, 0.0) for x, y in ring] + [(x, y, h) for x, y in ring]
    faces = [(j, (j + 1) % n, n + (j + 1) % n, n + j) for j in range(n)]
    if caps:
        faces.append(tuple(range(n - 1, -1, -1)))  # bottom, facing -z
        faces.append(tuple(range(n, 2 * n)))  # top, facing +z
    return np.array(pts), faces


def _box_normals_by_triangle(md):
    """(t, 3, 3) corner normals of each triangle and the geometric unit normal (t, 3)."""
    p = md.points[md.triangles]
    g = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return md.normals.astype(np.float64), g / np.linalg.norm(g, axis=1, keepdims=True)


# ------------------------------------------------------------------------------ the rule


def test_box_is_exactly_flat_per_face():
    st = new_stage()
    define_mesh(st, "/Box", BOX_P, BOX_Q)
    sc = load_scene(st)
    md = sc.meshes[0]
    n, g = _box_normals_by_triangle(md)
    # every corner of every triangle carries its face's normal, both triangles of a quad alike
    np.testing.assert_allclose(n, np.repeat(g[:, None], 3, axis=1), atol=1e-7)
    for f in range(6):
        tris = np.flatnonzero(md.face == f)
        assert len(tris) == 2
        np.testing.assert_array_equal(n[tris[0]], n[tris[1]])
        assert np.all(n[tris[0]] == n[tris[0], 0])  # bit-identical across the quad
    assert sc.computed_normals["/Box"].rule == N.RULE_CREASE


def test_box_flat_under_rotation_nonuniform_scale_and_mirror():
    st = new_stage()
    m = define_mesh(st, "/Box", BOX_P, BOX_Q)
    m.AddRotateXYZOp().Set(Gf.Vec3f(20, 35, -50))
    m.AddScaleOp().Set(Gf.Vec3f(3.0, 0.5, -1.5))  # mirrored: the winding is flipped back
    md = load_scene(st).meshes[0]
    n, g = _box_normals_by_triangle(md)
    np.testing.assert_allclose(n, np.repeat(g[:, None], 3, axis=1), atol=1e-6)
    c = md.points.mean(axis=0)  # outward: the box is convex
    cen = md.points[md.triangles].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", g, cen - c) > 0)


def test_32_segment_cylinder_is_smooth_and_its_caps_flat():
    pts, faces = _cylinder(32)
    st = new_stage()
    define_mesh(st, "/Cyl", pts, faces)
    md = load_scene(st).meshes[0]
    side = md.face < 32
    p = md.points[md.triangles[side]]
    radial = p.copy()
    radial[..., 2] = 0
    radial /= np.linalg.norm(radial, axis=-1, keepdims=True)
    # each side corner averages its two neighbours (11.25 degrees apart): exactly radial
    np.testing.assert_allclose(md.normals[side], radial, atol=2e-6)
    cap_n = md.normals[~side].reshape(-1, 3)
    np.testing.assert_allclose(np.abs(cap_n[:, 2]), 1.0, atol=1e-7)  # 90 degree rim: flat caps


@pytest.mark.parametrize("segments, smooth", [(6, False), (8, False), (12, True), (13, True)])
def test_crease_angle_threshold(segments, smooth):
    pts, faces = _cylinder(segments, caps=False)
    fv = N.compute_normals(pts, [4] * segments, np.ravel(faces))
    fv = fv.reshape(segments, 4, 3)
    face_n = np.cross(pts[faces[0][1]] - pts[faces[0][0]], pts[faces[0][3]] - pts[faces[0][0]])
    face_n /= np.linalg.norm(face_n)
    corner0 = fv[0, 0]  # shared with the previous face
    if smooth:
        want = pts[faces[0][0]] / np.linalg.norm(pts[faces[0][0]])
        np.testing.assert_allclose(corner0, want, atol=1e-6)
    else:
        np.testing.assert_allclose(corner0, face_n, atol=1e-6)


def _brute_force_crease(points, faces, crease_deg):
    """Independent per-corner loop with trimesh's face normals and angles (triangles only)."""
    tm = trimesh.Trimesh(points, faces, process=False)
    fn = tm.face_normals
    ang = tm.face_angles  # (t, 3) interior angles
    cos_lim = math.cos(math.radians(crease_deg))
    around = {}
    for g, tri in enumerate(faces):
        for v in tri:
            around.setdefault(int(v), []).append(g)
    out = np.zeros((len(faces), 3, 3))
    for f, tri in enumerate(faces):
        for k, v in enumerate(tri):
            acc = np.zeros(3)
            for g in around[int(v)]:
                if fn[f] @ fn[g] >= cos_lim:
                    acc += ang[g][list(faces[g]).index(v)] * fn[g]
            out[f, k] = acc / np.linalg.norm(acc)
    return out


def test_crease_rule_matches_a_brute_force_loop_on_a_bumpy_sphere():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(3)
    pts = sphere.vertices * (1 + 0.15 * rng.standard_normal((len(sphere.vertices), 1)))
    faces = sphere.faces
    got = N.compute_normals(pts, [3] * len(faces), faces.ravel()).reshape(-1, 3, 3)
    want = _brute_force_crease(pts, faces, N.CREASE_ANGLE_DEG + N.CREASE_MARGIN_DEG)
    np.testing.assert_allclose(got, want, atol=2e-6)
    # the bumps make some corners crease and others smooth: the test exercises both branches
    fn = trimesh.Trimesh(pts, faces, process=False).face_normals
    own = np.einsum("tcj,tj->tc", got, fn)
    assert (own > 1 - 1e-6).mean() > 0.01 and (own < 0.999).mean() > 0.3


def test_chunked_pairs_match_unchunked(monkeypatch):
    # a fan: one apex shared by 400 triangles (160k corner pairs), chunked at 1000 pairs
    n = 400
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pts = np.concatenate([[[0, 0, 0.3]], np.stack([np.cos(phi), np.sin(phi), 0 * phi], 1)])
    faces = np.array([(0, 1 + j, 1 + (j + 1) % n) for j in range(n)])
    whole = N.compute_normals(pts, [3] * n, faces.ravel())
    monkeypatch.setattr(N, "_CHUNK_PAIRS", 1000)
    np.testing.assert_array_equal(N.compute_normals(pts, [3] * n, faces.ravel()), whole)


def test_subdivision_surfaces_get_smooth_normals_equal_to_trimesh():
    sphere = trimesh.creation.icosphere(subdivisions=1)
    pts, faces = sphere.vertices, sphere.faces
    st = new_stage()
    define_mesh(st, "/Loop", pts, faces, scheme="loop")
    sc = load_scene(st)
    md = sc.meshes[0]
    assert sc.computed_normals["/Loop"].rule == N.RULE_SMOOTH
    # trimesh's vertex normals are angle-weighted too: an independent implementation
    want = sphere.vertex_normals[faces]
    np.testing.assert_allclose(md.normals, want, atol=2e-6)
    # a catmullClark box is smooth: corners lean diagonally (1, 1, 1) / sqrt 3
    st = new_stage()
    define_mesh(st, "/Box", BOX_P, BOX_Q, scheme="catmullClark")
    md = load_scene(st).meshes[0]
    d = md.points[md.triangles] - 0.5
    np.testing.assert_allclose(md.normals, d / np.linalg.norm(d, axis=-1, keepdims=True), atol=1e-6)


def test_unauthored_scheme_uses_the_crease_rule_and_warns_once():
    st = new_stage()
    define_mesh(st, "/A", BOX_P, BOX_Q, scheme=None)
    m = define_mesh(st, "/B", BOX_P, BOX_Q, scheme=None)
    m.AddTranslateOp().Set(Gf.Vec3d(3, 0, 0))
    sc = load_scene(st)
    n, g = _box_normals_by_triangle(sc.meshes[0])
    np.testing.assert_allclose(n, np.repeat(g[:, None], 3, axis=1), atol=1e-7)
    scheme = [w for w in sc.warnings if "leave subdivisionScheme unauthored" in w]
    assert len(scheme) == 1 and "catmullClark" in scheme[0] and "/A, /B" in scheme[0]
    computed = [w for w in sc.warnings if "author no normals" in w]
    assert len(computed) == 1 and computed[0].startswith("2 meshes")


def test_left_handed_mesh_normals_face_its_front():
    st = new_stage()
    m = define_mesh(st, "/Q", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)])
    m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    sc = load_scene(st)
    np.testing.assert_allclose(sc.meshes[0].normals.reshape(-1, 3), [[0, 0, -1]] * 6)
    np.testing.assert_allclose(sc.computed_normals["/Q"].values, [[0, 0, -1]] * 4)


def test_degenerate_polygon_corners_get_a_unit_normal():
    pts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (2, 0, 0)]
    fv = N.compute_normals(np.array(pts, float), [3, 3], [0, 1, 2, 0, 1, 3])  # 2nd: collinear
    np.testing.assert_allclose(np.linalg.norm(fv, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(fv[:3], [[0, 0, 1]] * 3)
    with pytest.raises(ValueError, match="unknown normals rule"):
        N.compute_normals(np.array(pts, float), [3], [0, 1, 2], rule="bogus")


# ----------------------------------------------------------------------- authored normals win


@pytest.mark.parametrize("interp", ["faceVarying", "vertex", "uniform", "constant", "primvar"])
def test_authored_normals_win(interp):
    st = new_stage()
    m = define_mesh(st, "/Box", BOX_P, BOX_Q)
    tilt = np.array([0.3, -0.2, 0.9])
    tilt /= np.linalg.norm(tilt)
    n_fv = 24
    count = {"faceVarying": n_fv, "vertex": 8, "uniform": 6, "constant": 1, "primvar": n_fv}
    vals = Vt.Vec3fArray([Gf.Vec3f(*tilt)] * count[interp])
    if interp == "primvar":  # primvars:normals wins over normals too
        m.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(1, 0, 0)] * 8))
        m.SetNormalsInterpolation("vertex")
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            "normals", Sdf.ValueTypeNames.Normal3fArray, UsdGeom.Tokens.faceVarying
        )
        pv.Set(vals)
    else:
        m.CreateNormalsAttr(vals)
        m.SetNormalsInterpolation(interp)
    m.AddTranslateOp().Set(Gf.Vec3d(5, 0, 0))
    sc = load_scene(st)
    np.testing.assert_allclose(sc.meshes[0].normals.reshape(-1, 3), [tilt] * 36, atol=1e-6)
    assert "/Box" not in sc.computed_normals
    assert not any("author no normals" in w for w in sc.warnings)


# ------------------------------------------------------------ authored into the override layer


def _box_stage(tmp_path, scheme="none", name="box.usda"):
    st = Usd.Stage.CreateNew(str(tmp_path / name))
    UsdGeom.SetStageUpAxis(st, "Z")
    UsdGeom.SetStageMetersPerUnit(st, 1.0)
    pts, faces = _cylinder(12, r=0.5, h=1.0)
    m = define_mesh(st, "/World/Cyl", pts, faces, scheme=scheme)
    m.AddRotateXYZOp().Set(Gf.Vec3f(10, 20, 30))
    define_mesh(st, "/World/Box", BOX_P, BOX_Q, scheme=scheme)
    # mirrored and left-handed (clockwise quads: outward): still bit for bit after the trip
    lh = define_mesh(st, "/World/Mirrored", BOX_P, [q[::-1] for q in BOX_Q], scheme=scheme)
    lh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    lh.AddTranslateOp().Set(Gf.Vec3d(3, 0, 0))
    lh.AddScaleOp().Set(Gf.Vec3f(-1, 1, 2))
    from pxr import UsdLux

    sun = UsdLux.DistantLight.Define(st, "/World/Sun")
    sun.CreateIntensityAttr(2.0)
    sun.AddRotateXYZOp().Set(Gf.Vec3f(30, 20, 0))
    st.GetRootLayer().Save()
    return tmp_path / name


def test_baked_normals_round_trip_through_the_override_layer(tmp_path, capsys):
    src = _box_stage(tmp_path)
    before = src.read_bytes()
    code = cli.main(["bake", str(src), "--json", *FAST[:-1]])
    out = capsys.readouterr()
    assert code == 0, out.err
    report = json.loads(out.out)
    assert any("author no normals" in w for w in report["warnings"])
    assert src.read_bytes() == before  # the source layer is never modified
    scene = load_scene(str(src))
    layer = tmp_path / "box.lightmaps.usda"
    baked = Usd.Stage.Open(str(layer))
    for path in ("/World/Cyl", "/World/Box", "/World/Mirrored"):
        prim = baked.GetPrimAtPath(path)
        mesh = UsdGeom.Mesh(prim)
        assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.faceVarying
        got = np.asarray(mesh.GetNormalsAttr().Get(), np.float32)
        np.testing.assert_array_equal(got, scene.computed_normals[path].values)
        assert prim.GetAttribute("ahdLightmap:baked:normals").Get() == "creaseAngle30"
        # the opinion lives in the override layer, not in the source
        spec = Sdf.Layer.FindOrOpen(str(layer)).GetAttributeAtPath(f"{path}.normals")
        assert spec is not None and spec.default is not None
    # the baked stage reads them as authored: the same world normals, bit for bit
    again = load_scene(baked)
    assert not again.computed_normals
    by_path = {m.path: m for m in scene.meshes}
    for m in again.meshes:
        np.testing.assert_array_equal(m.normals, by_path[m.path].normals)
    # hence the validator's recomputed hash equals the bake's: validate is clean, re-bake skips
    code = cli.main(["validate", str(layer), "--strict", "--json"])
    out = capsys.readouterr()
    assert code == 0, out.out
    code = cli.main(["bake", str(src), "--json", *FAST[:-1]])
    report = json.loads(capsys.readouterr().out)
    assert {p["status"] for p in report["prims"]} == {"skipped"}


def test_authored_source_normals_are_not_overridden(tmp_path, capsys):
    src = _box_stage(tmp_path)
    st = Usd.Stage.Open(str(src))
    m = UsdGeom.Mesh(st.GetPrimAtPath("/World/Box"))
    m.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 0, 1)] * 24))
    m.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    st.GetRootLayer().Save()
    assert cli.main(["bake", str(src), *FAST]) == 0
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "box.lightmaps.usda"))
    assert layer.GetAttributeAtPath("/World/Box.normals") is None
    assert layer.GetAttributeAtPath("/World/Cyl.normals") is not None
    baked = Usd.Stage.Open(layer)
    assert baked.GetPrimAtPath("/World/Box").GetAttribute("ahdLightmap:baked:normals").Get() == (
        "authored"
    )


def test_normals_rule_change_changes_the_content_hash(monkeypatch):
    from usdahd.scene.hashing import content_hash
    from usdahd.usd import normals
    from usdahd.usd.author import generator_id

    parts = {"/m": "a", "shape:/m": "b", "lights": "", "materials": ""}
    h1, _ = content_hash(parts, "/m", {}, generator_id())
    monkeypatch.setattr(normals, "RULE_VERSION", "normals-99")
    h2, named = content_hash(parts, "/m", {}, generator_id())
    assert h1 != h2 and "generator" in named


def test_kept_prim_keeps_its_computed_normals(tmp_path, capsys):
    src = _box_stage(tmp_path)
    assert cli.main(["bake", str(src), *FAST]) == 0
    assert cli.main(["bake", str(src), *FAST, "--prim", "/World/Box", "--force"]) == 0
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "box.lightmaps.usda"))
    layer.Reload(force=True)
    assert layer.GetAttributeAtPath("/World/Cyl.normals") is not None
    baked = Usd.Stage.Open(layer)
    assert baked.GetPrimAtPath("/World/Cyl").GetAttribute("ahdLightmap:baked:normals").Get() == (
        "creaseAngle30"
    )
    capsys.readouterr()
    assert cli.main(["validate", str(tmp_path / "box.lightmaps.usda"), "--strict"]) == 0


# ------------------------------------------------------------------------- pillar_room physics


def _strip_pillar_normals(tmp_path) -> Path:
    dst = tmp_path / "pillar_room.usda"
    shutil.copy(ROOT / "samples" / "pillar_room.usda", dst)
    layer = Sdf.Layer.FindOrOpen(str(dst))
    layer.Reload(force=True)
    spec = layer.GetPrimAtPath("/World/Geometry/Pillar")
    spec.RemoveProperty(spec.properties["normals"])
    layer.Save()
    return dst


def test_pillar_without_normals_bakes_like_the_authored_flat_normals(tmp_path, capsys):
    """The pillar of samples/pillar_room.usda with its normals removed bakes the same Iz as
    with its authored (flat) normals: same seed, so the difference is the normals alone."""
    from usdahd.numerics import sh as shmod
    from usdahd.usd import schema

    args = ["--prim", "/World/Geometry/Pillar", "--resolution", "32", "--samples", "64"]
    args += ["--bounces", "1", "--quiet"]
    ref_dir = tmp_path / "ref"
    ref_dir.mkdir()
    ref_src = ref_dir / "pillar_room.usda"
    shutil.copy(ROOT / "samples" / "pillar_room.usda", ref_src)
    assert cli.main(["bake", str(ref_src), *args]) == 0
    src = _strip_pillar_normals(tmp_path)
    assert cli.main(["bake", str(src), *args]) == 0

    def iz(layer):
        st = Usd.Stage.Open(str(layer))
        res = schema.read_results(st.GetPrimAtPath("/World/Geometry/Pillar"))
        side = schema.read_record_pixels(res, "sh", schema.SH_SIDECAR_CHANNELS)
        cover = side[..., -1] > 0
        return shmod.iz(side[cover][:, :27].reshape(-1, 3, 9).astype(np.float64)), res

    want, _ = iz(ref_dir / "pillar_room.lightmaps.usda")
    got, res = iz(tmp_path / "pillar_room.lightmaps.usda")
    assert res.normals == "creaseAngle30"
    assert got.shape == want.shape
    # flat computed normals equal the authored ones to float32 rounding, so the paths agree
    scale = float(np.abs(want).max())
    assert np.abs(got - want).max() <= 1e-3 * scale


def test_broken_primvars_normals_are_recomputed_and_overridden_in_place(tmp_path, capsys):
    """primvars:normals wins over normals in USD, so a broken one (NaN) is replaced by the
    computed normals in primvars:normals itself (indices blocked), not in normals."""
    src = _box_stage(tmp_path)
    st = Usd.Stage.Open(str(src))
    m = UsdGeom.Mesh(st.GetPrimAtPath("/World/Box"))
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
        "normals", Sdf.ValueTypeNames.Normal3fArray, UsdGeom.Tokens.faceVarying
    )
    pv.Set(Vt.Vec3fArray([Gf.Vec3f(0, 0, 1), Gf.Vec3f(float("nan"), 0, 0)]))
    pv.SetIndices(Vt.IntArray([0, 1] * 12))
    st.GetRootLayer().Save()
    sc = load_scene(str(src))
    assert any("/World/Box: degenerate or NaN authored normals" in w for w in sc.warnings)
    assert sc.computed_normals["/World/Box"].attr == "primvars:normals"
    assert cli.main(["bake", str(src), *FAST]) == 0
    baked = Usd.Stage.Open(str(tmp_path / "box.lightmaps.usda"))
    got = UsdGeom.PrimvarsAPI(baked.GetPrimAtPath("/World/Box")).GetPrimvar("normals")
    assert not got.IsIndexed()
    np.testing.assert_array_equal(
        np.asarray(got.Get(), np.float32), sc.computed_normals["/World/Box"].values
    )
    capsys.readouterr()
    assert cli.main(["validate", str(tmp_path / "box.lightmaps.usda"), "--strict"]) == 0


def test_bogus_normals_rule_in_a_bake_record_is_reported():
    from usdahd.usd import schema

    res = schema.BakeResults("hhd", "luminance", "", "st", (4, 4), {}, normals="wobbly")
    assert any("normals rule 'wobbly' is not one of" in p for p in schema.result_problems(res))
    assert schema.NORMALS_RULES == N.RULES


def test_validate_names_stale_computed_normals_when_the_mesh_moves_under_them(tmp_path, capsys):
    src = _box_stage(tmp_path)
    assert cli.main(["bake", str(src), *FAST]) == 0
    st = Usd.Stage.Open(str(src))
    pts = st.GetPrimAtPath("/World/Box").GetAttribute("points")
    p = np.array(pts.Get())
    p[7] += (0.3, 0.2, 0.4)  # a corner pulled out: the crease normals change
    pts.Set(Vt.Vec3fArray.FromNumpy(p.astype(np.float32)))
    st.GetRootLayer().Save()
    capsys.readouterr()
    code = cli.main(["validate", str(tmp_path / "box.lightmaps.usda"), "--json"])
    findings = json.loads(capsys.readouterr().out)["findings"]
    assert code == 1
    stale = [f for f in findings if f["code"] == "Stale" and f["prim"] == "/World/Box"]
    assert stale
    assert "creaseAngle30 normals the bake authored no longer match" in stale[0]["message"]
