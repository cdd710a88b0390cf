"""(Re)write ``ngon_stage.usda``: polygon meshes (n-gons and quads, no lightmap UVs) that the
baker must unwrap into a UV set a faceVarying primvar can hold (issue 37, row 1).

Usage::

    python tests/data/production/make_ngon.py [--out DIR]

Deterministic: running it twice gives byte-identical files (no dates, no random numbers,
fixed float formatting). ``upAxis = "Y"``, ``metersPerUnit = 1``, default prim ``/World``,
``subdivisionScheme = "none"``, no normals and no ``st`` authored (the baker computes the
normals and unwraps every mesh). The meshes:

- ``Disk``: one planar 12-gon.
- ``Cylinder``: 16 quad sides and two 16-gon caps.
- ``Dodecahedron``: 12 pentagons.
- ``Box``: a box whose six sides are 3 x 3 grids of quads, bulged outwards so the quads are
  not planar (xatlas then cuts charts along curved regions).
- ``Torus``: 24 x 10 curved (non-planar) quads.
- ``HexTerrain``: a field of hexagons with the corners at random-free, smoothly varying
  heights (non-planar hexagons).
- ``Ground``: one quad; lit by a DomeLight and a DistantLight.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

DECIMALS = 6
HERE = Path(__file__).resolve().parent


def _r(v) -> np.ndarray:
    out = np.round(np.asarray(v, dtype=np.float64), DECIMALS)
    out[out == 0] = 0.0  # no "-0"
    return out


def disk(n=12, r=0.6):
    a = 2 * math.pi * np.arange(n) / n
    pts = np.stack([r * np.cos(a), np.zeros(n), -r * np.sin(a)], axis=1)
    return pts, [n], list(range(n))


def cylinder(n=16, r=0.4, h=1.0):
    a = 2 * math.pi * np.arange(n) / n
    ring = np.stack([r * np.cos(a), np.zeros(n), -r * np.sin(a)], axis=1)
    pts = np.concatenate([ring, ring + [0, h, 0]])
    counts, idx = [], []
    for i in range(n):
        j = (i + 1) % n
        counts.append(4)
        idx += [i, j, n + j, n + i]
    counts.append(n)  # bottom cap, facing -y
    idx += list(range(n))[::-1]
    counts.append(n)  # top cap, facing +y
    idx += list(range(n, 2 * n))
    return pts, counts, idx


def dodecahedron(r=0.45):
    phi = (1 + 5**0.5) / 2
    pts = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                pts.append((sx, sy, sz))
    for s1 in (-1, 1):
        for s2 in (-1, 1):
            pts.append((0, s1 / phi, s2 * phi))
            pts.append((s1 / phi, s2 * phi, 0))
            pts.append((s1 * phi, 0, s2 / phi))
    pts = np.array(pts, dtype=np.float64)
    # faces: the 12 sets of 5 points nearest to each face centre (icosahedron vertices)
    ico = []
    for s1 in (-1, 1):
        for s2 in (-1, 1):
            ico += [(0, s1, s2 * phi), (s1, s2 * phi, 0), (s2 * phi, 0, s1)]
    counts, idx = [], []
    for c in np.array(ico, dtype=np.float64):
        c = c / np.linalg.norm(c)
        d = pts @ c
        ring = np.argsort(-d)[:5]
        # order counter-clockwise seen from outside
        u = np.cross(c, [0.0, 0.0, 1.0] if abs(c[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(c, u)
        ang = np.arctan2((pts[ring] @ v), (pts[ring] @ u))
        ring = ring[np.argsort(ang)]
        counts.append(5)
        idx += [int(i) for i in ring]
    pts = pts / np.linalg.norm(pts[0]) * r
    return pts, counts, idx


def bulged_box(n=3, half=0.5, bulge=0.12):
    """Six n x n quad grids on the faces of a cube, pushed out towards a sphere."""
    pts, counts, idx = [], [], []
    key = {}

    def vid(p):
        k = tuple(np.round(p, 9))
        if k not in key:
            key[k] = len(pts)
            pts.append(p)
        return key[k]

    for axis in range(3):
        for sign in (-1, 1):
            u_ax, v_ax = (axis + 1) % 3, (axis + 2) % 3
            if sign < 0:
                u_ax, v_ax = v_ax, u_ax
            grid = np.empty((n + 1, n + 1), dtype=np.int64)
            for i in range(n + 1):
                for j in range(n + 1):
                    p = np.zeros(3)
                    p[axis] = sign * half
                    p[u_ax] = -half + 2 * half * i / n
                    p[v_ax] = -half + 2 * half * j / n
                    grid[i, j] = vid(p)
            for i in range(n):
                for j in range(n):
                    counts.append(4)
                    idx += [grid[i, j], grid[i + 1, j], grid[i + 1, j + 1], grid[i, j + 1]]
    pts = np.array(pts, dtype=np.float64)
    rad = np.linalg.norm(pts, axis=1, keepdims=True)
    sphere = pts / rad * half * 3**0.5
    pts = pts + bulge / (half * (3**0.5 - 1)) * (sphere - pts) * 0.5
    return pts, counts, [int(i) for i in idx]


def torus(nu=24, nv=10, big=0.45, small=0.15):
    pts = []
    for i in range(nu):
        a = 2 * math.pi * i / nu
        for j in range(nv):
            b = 2 * math.pi * j / nv
            rr = big + small * math.cos(b)
            pts.append((rr * math.cos(a), small * math.sin(b), -rr * math.sin(a)))
    counts, idx = [], []
    for i in range(nu):
        for j in range(nv):
            i1, j1 = (i + 1) % nu, (j + 1) % nv
            counts.append(4)
            idx += [i * nv + j, i * nv + j1, i1 * nv + j1, i1 * nv + j]
    return np.array(pts), counts, idx


def hex_terrain(rings=3, size=0.18):
    """Flat-topped hexagons in axial coordinates; shared corners welded; heights vary."""
    pts, counts, idx = [], [], []
    key = {}
    for q in range(-rings, rings + 1):
        for r in range(max(-rings, -q - rings), min(rings, -q + rings) + 1):
            cx = size * 1.5 * q
            cz = size * 3**0.5 * (r + q / 2)
            ring = []
            for k in range(6):
                a = math.pi / 3 * k
                x, z = cx + size * math.cos(a), cz - size * math.sin(a)
                kk = (round(x, 6), round(z, 6))
                if kk not in key:
                    key[kk] = len(pts)
                    pts.append((x, 0.12 * math.sin(3.1 * x) * math.cos(2.3 * z), z))
                ring.append(key[kk])
            counts.append(6)
            idx += ring
    return np.array(pts), counts, idx


MESHES = {
    "Disk": (disk, (-1.6, 0.02, -1.2)),
    "Cylinder": (cylinder, (0.0, 0.0, -1.2)),
    "Dodecahedron": (dodecahedron, (1.5, 0.45, -1.2)),
    "Box": (bulged_box, (-1.5, 0.6, 0.4)),
    "Torus": (torus, (0.0, 0.15, 0.4)),
    "HexTerrain": (hex_terrain, (1.5, 0.15, 0.6)),
}


def _mesh(stage, path, pts, counts, idx, offset, material):
    m = UsdGeom.Mesh.Define(stage, path)
    p = _r(np.asarray(pts) + np.asarray(offset))
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, q)) for q in p]))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in counts]))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in idx]))
    lo, hi = p.min(axis=0), p.max(axis=0)
    m.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(material)
    return m


def _material(stage, path, rgb):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*rgb))
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def write(out: Path) -> Path:
    path = out / "ngon_stage.usda"
    stage = Usd.Stage.CreateInMemory()
    root = stage.GetRootLayer()
    root.documentation = (
        "Polygon meshes for issue 37 row 1: a 12-gon disk, a cylinder with 16-gon caps, a "
        "dodecahedron, a bulged quad box, a quad torus and non-planar hexagons, with no "
        "lightmap UVs (usdahd bake unwraps them). Written by tests/data/production/make_ngon.py."
    )
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Xform.Define(stage, "/World/Geometry")
    grey = _material(stage, "/World/Looks/Grey", (0.5, 0.5, 0.5))
    orange = _material(stage, "/World/Looks/Orange", (0.8, 0.4, 0.1))
    _mesh(
        stage,
        "/World/Geometry/Ground",
        [(-3, 0, 2), (3, 0, 2), (3, 0, -2.5), (-3, 0, -2.5)],
        [4],
        [0, 1, 2, 3],
        (0, 0, 0),
        grey,
    )
    for name, (fn, offset) in MESHES.items():
        pts, counts, idx = fn()
        _mesh(stage, f"/World/Geometry/{name}", pts, counts, idx, offset, orange)
    UsdGeom.Xform.Define(stage, "/World/Lights")
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    dome.CreateIntensityAttr(0.5)
    dome.CreateExposureAttr(0.0)
    dome.CreateColorAttr(Gf.Vec3f(0.8, 0.9, 1.0))
    dome.CreateNormalizeAttr(False)
    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.CreateIntensityAttr(3.0)
    sun.CreateExposureAttr(0.0)
    sun.CreateColorAttr(Gf.Vec3f(1.0, 0.95, 0.85))
    sun.CreateAngleAttr(1.0)
    sun.CreateNormalizeAttr(True)  # intensity is the illuminance (lux-like units)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-50.0, 30.0, 0.0))
    text = root.ExportToString()
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE)
    print(write(ap.parse_args().out))


if __name__ == "__main__":
    main()
