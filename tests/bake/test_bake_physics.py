"""Pipeline-level physics behaviour of `usdahd bake` (issue 17): what the report says about
texels the integrator could not trust."""

from __future__ import annotations

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

from usdahd.pipeline import BakeOptions, bake

_TC = Sdf.ValueTypeNames.TexCoord2fArray


def _quad(st, path, corners):
    m = UsdGeom.Mesh.Define(st, path)
    m.CreatePointsAttr([Gf.Vec3f(*c) for c in corners])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    m.CreateSubdivisionSchemeAttr("none")
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", _TC, UsdGeom.Tokens.vertex)
    pv.Set([Gf.Vec2f(0.05, 0.05), Gf.Vec2f(0.95, 0.05), Gf.Vec2f(0.95, 0.95), Gf.Vec2f(0.05, 0.95)])
    return m


def _box(st, path, lo, hi):
    """A closed box with outward faces (six quads), UVs in a 3 x 2 grid of charts."""
    m = UsdGeom.Mesh.Define(st, path)
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    p = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
         (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]  # fmt: skip
    quads = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    m.CreatePointsAttr([Gf.Vec3f(*c) for c in p])
    m.CreateFaceVertexCountsAttr([4] * 6)
    m.CreateFaceVertexIndicesAttr([i for q in quads for i in q])
    m.CreateSubdivisionSchemeAttr("none")
    uv = []
    for k in range(6):
        cx, cy = (k % 3) / 3.0, (k // 3) / 2.0
        a, b = 0.02, 0.31
        uv += [(cx + a, cy + a), (cx + b, cy + a), (cx + b, cy + 0.48), (cx + a, cy + 0.48)]
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", _TC, UsdGeom.Tokens.faceVarying)
    pv.Set([Gf.Vec2f(*t) for t in uv])


def test_enclosed_faces_are_named_in_the_warning(tmp_path):
    """A quad sealed inside a box sees only back faces: its texels are invalid, no valid
    neighbour can fill them, and the warning names the prim's faces (not just a count)."""
    st = Usd.Stage.CreateNew(str(tmp_path / "sealed.usda"))
    UsdGeom.SetStageUpAxis(st, "Z")
    UsdGeom.SetStageMetersPerUnit(st, 1.0)
    _box(st, "/World/Box", (-1, -1, 0), (1, 1, 2))
    _quad(st, "/World/Inside", [(-0.5, -0.5, 1), (0.5, -0.5, 1), (0.5, 0.5, 1), (-0.5, 0.5, 1)])
    UsdLux.DomeLight.Define(st, "/World/Sky")
    st.GetRootLayer().Save()
    rep = bake(
        tmp_path / "sealed.usda",
        BakeOptions(prims=["/World/Inside"], resolution=8, samples=16, bounces=1, quiet=True),
    )
    inside = next(p for p in rep["prims"] if p["path"] == "/World/Inside")
    msg = [w for w in inside["warnings"] if "back faces" in w]
    assert msg, inside["warnings"]
    assert "face(s) 0" in msg[0] and "no valid neighbour" in msg[0]
