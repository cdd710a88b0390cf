"""(Re)write the project's sample stages deterministically.

Usage::

    /work/venv/bin/python samples/make_samples.py [--out DIR]

Writes ``cornell_box.usda``, ``pillar_room.usda``, ``normal_wall.usda``, ``open_plane.usda``
and ``textures/*`` into ``DIR`` (default: the folder of this script). Running it twice gives
byte-identical ``.usda`` files (no dates, no random numbers, fixed float formatting).

Conventions shared by every sample (see samples/README.md):

- ``upAxis = "Y"``, ``metersPerUnit = 1``; the default prim is ``/World``.
- Geometry is built from planar rectangular *charts* (a wall, a box face), each a regular grid
  of quads. Points are welded within a mesh, so UV seams sit on shared 3-D edges.
- ``normals`` are authored (flat per chart); ``subdivisionScheme = "none"``.
- The lightmap UV set is the primvar ``st``: every chart is packed without rotation into
  ``[0, 1]^2`` at one texel density per mesh, with ``GUTTER_TEXELS`` texels between charts
  and ``BORDER_TEXELS`` to the image border at ``PACK_RESOLUTION``. Chart orientation is kept
  (u along the chart's first edge, v along its second), so UV triangles are counter-clockwise.
- Lights are UsdLux prims with explicit intensity, exposure, colour and normalize.
- Materials are UsdPreviewSurface networks bound with UsdShade.MaterialBindingAPI.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

# Lightmap packing parameters. Gutter 2.5 texels (> the required 2) so that a conservative
# rasteriser at 64x64 never touches one texel from two charts; border 1.25 texels so that a
# chart never touches the image edge (wrap or clamp filtering stays inside the gutter).
PACK_RESOLUTION = 64
GUTTER_TEXELS = 2.5
BORDER_TEXELS = 1.25
# Decimal places kept for authored floats: keeps the .usda readable and diffs stable.
DECIMALS = 6

HERE = Path(__file__).resolve().parent


# --------------------------------------------------------------------------------------------
# Geometry: charts, packing, meshes
# --------------------------------------------------------------------------------------------


@dataclass
class Chart:
    """A planar rectangle ``origin + s*a + t*b`` (s, t in [0, 1]) split into ``na x nb`` quads.

    The front side faces ``cross(a, b)`` (counter-clockwise, USD's rightHanded orientation).
    ``group`` names the material subset the chart's faces belong to.
    """

    origin: tuple[float, float, float]
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    na: int
    nb: int
    group: str = "default"

    @property
    def size(self) -> tuple[float, float]:
        return float(np.linalg.norm(self.a)), float(np.linalg.norm(self.b))


def box_charts(
    size: tuple[float, float, float],
    subdiv: tuple[int, int, int],
    inward: bool = False,
    faces: tuple[str, ...] = ("+x", "-x", "+y", "-y", "+z", "-z"),
    group: str = "default",
) -> list[Chart]:
    """Charts of an axis-aligned box ``[-sx/2, sx/2] x [0, sy] x [-sz/2, sz/2]``.

    ``faces`` picks which sides exist (e.g. drop "-y", the bottom, for a box on the floor).
    ``inward`` flips every face to look into the box (a room).
    """
    sx, sy, sz = size
    nx, ny, nz = subdiv
    x0, x1, y0, y1, z0, z1 = -sx / 2, sx / 2, 0.0, sy, -sz / 2, sz / 2
    # Outward-facing definitions: cross(a, b) points out of the box.
    outward = {
        "+x": Chart((x1, y0, z1), (0, 0, -sz), (0, sy, 0), nz, ny),
        "-x": Chart((x0, y0, z0), (0, 0, sz), (0, sy, 0), nz, ny),
        "+y": Chart((x0, y1, z1), (sx, 0, 0), (0, 0, -sz), nx, nz),
        "-y": Chart((x0, y0, z0), (sx, 0, 0), (0, 0, sz), nx, nz),
        "+z": Chart((x0, y0, z1), (sx, 0, 0), (0, sy, 0), nx, ny),
        "-z": Chart((x1, y0, z0), (-sx, 0, 0), (0, sy, 0), nx, ny),
    }
    charts = []
    for name in faces:
        c = outward[name]
        if inward:  # mirror the first edge: same rectangle, opposite facing, still CCW in UV
            o = np.add(c.origin, c.a)
            c = Chart(tuple(o), tuple(-np.asarray(c.a)), c.b, c.na, c.nb)
        charts.append(Chart(c.origin, c.a, c.b, c.na, c.nb, group))
    return charts


def pack_charts(sizes: list[tuple[float, float]]) -> tuple[float, np.ndarray]:
    """Shelf-pack rectangles (world sizes, metres) into [0, 1]^2 at one common scale.

    Returns ``(scale, offsets)``: UV = offset + scale * (s_metres, t_metres);
    ``offsets : (n, 2) float64``. Charts are never rotated (so u, v keep the directions of
    the chart edges). The scale is the largest (bisection, 60 steps) for which the shelves fit
    with the gutter and border of this module.
    """
    gutter = GUTTER_TEXELS / PACK_RESOLUTION
    border = BORDER_TEXELS / PACK_RESOLUTION
    order = sorted(range(len(sizes)), key=lambda i: (-sizes[i][1], -sizes[i][0], i))

    def place(scale: float) -> np.ndarray | None:
        offsets = np.zeros((len(sizes), 2))
        x, y, row = border, border, 0.0
        for i in order:
            w, h = sizes[i][0] * scale, sizes[i][1] * scale
            if x + w > 1.0 - border and x > border:
                x, y, row = border, y + row + gutter, 0.0
            if x + w > 1.0 - border or y + h > 1.0 - border:
                return None
            offsets[i] = (x, y)
            x += w + gutter
            row = max(row, h)
        return offsets

    lo, hi = 0.0, 1.0 / max(max(s) for s in sizes)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if place(mid) is not None else (lo, mid)
    return lo, place(lo)


@dataclass
class MeshArrays:
    """Flat mesh arrays before authoring (local space)."""

    points: np.ndarray  # (v, 3) float64, welded
    counts: np.ndarray  # (f,) int32, all 4
    indices: np.ndarray  # (4f,) int32
    normals: np.ndarray  # (4f, 3) float64, faceVarying
    st: np.ndarray  # (4f, 2) float64, faceVarying lightmap UVs
    uv: np.ndarray  # (4f, 2) float64, faceVarying texture UVs (metres along a, b)
    groups: dict[str, list[int]]  # material group -> face indices
    corner_chart: np.ndarray  # (4f,) int32 chart of each face-vertex


def build_mesh(charts: list[Chart], stretch: list[tuple[float, float]] | None = None) -> MeshArrays:
    """Grid every chart into quads, weld points, pack the lightmap UVs.

    ``stretch`` (one (su, sv) per chart) scales each chart's lightmap UVs anisotropically
    before packing (a chart with non-uniform texel density); default: no stretch.
    """
    stretch = stretch or [(1.0, 1.0)] * len(charts)
    sizes = [(c.size[0] * su, c.size[1] * sv) for c, (su, sv) in zip(charts, stretch)]
    scale, offsets = pack_charts(sizes)
    pts, st, uv, nrm, chart_of = [], [], [], [], []
    groups: dict[str, list[int]] = {}
    face = 0
    for ci, c in enumerate(charts):
        o, a, b = np.asarray(c.origin, float), np.asarray(c.a, float), np.asarray(c.b, float)
        n = np.cross(a, b)
        n /= np.linalg.norm(n)
        la, lb = c.size
        su, sv = stretch[ci]
        for j in range(c.nb):
            for i in range(c.na):
                for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):  # CCW around cross(a, b)
                    s, t = (i + di) / c.na, (j + dj) / c.nb
                    pts.append(o + s * a + t * b)
                    uv.append((s * la, t * lb))
                    st.append(offsets[ci] + scale * np.array([s * la * su, t * lb * sv]))
                    nrm.append(n)
                    chart_of.append(ci)
                groups.setdefault(c.group, []).append(face)
                face += 1
    pts = np.round(np.asarray(pts), DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0
    unique, first, inverse = np.unique(pts, axis=0, return_index=True, return_inverse=True)
    # Keep first-appearance order so point ids follow the chart order (readable files).
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    points = np.empty_like(unique)
    points[rank] = unique
    indices = rank[inverse.reshape(-1)].astype(np.int32)
    return MeshArrays(
        points=points,
        counts=np.full(face, 4, np.int32),
        indices=indices,
        normals=np.round(np.asarray(nrm), DECIMALS) + 0.0,
        st=np.round(np.asarray(st), DECIMALS),
        uv=np.round(np.asarray(uv), DECIMALS),
        groups=groups,
        corner_chart=np.asarray(chart_of, np.int32),
    )


# --------------------------------------------------------------------------------------------
# Authoring helpers
# --------------------------------------------------------------------------------------------


def new_stage(doc: str) -> tuple[Usd.Stage, Usd.Prim]:
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World").GetPrim()
    Usd.ModelAPI(world).SetKind(Kind.Tokens.component)
    stage.SetDefaultPrim(world)
    layer.documentation = doc
    UsdGeom.Xform.Define(stage, "/World/Geometry")
    UsdGeom.Xform.Define(stage, "/World/Lights")
    UsdGeom.Scope.Define(stage, "/World/Looks")
    return stage, world


def save(stage: Usd.Stage, path: Path) -> None:
    text = stage.GetRootLayer().ExportToString()
    path.write_text(text, encoding="utf-8")


def _r(v) -> float:
    return round(float(v), DECIMALS) + 0.0


def set_xform(prim: Usd.Prim, translate=None, rotate_xyz=None, scale=None) -> None:
    x = UsdGeom.Xformable(prim)
    if translate is not None:
        x.AddTranslateOp().Set(Gf.Vec3d(*map(_r, translate)))
    if rotate_xyz is not None:
        x.AddRotateXYZOp().Set(Gf.Vec3f(*map(_r, rotate_xyz)))
    if scale is not None:
        x.AddScaleOp().Set(Gf.Vec3f(*map(_r, scale)))


def author_mesh(
    stage: Usd.Stage,
    path: str,
    m: MeshArrays,
    *,
    st_mode: str = "faceVarying",
    texture_uv: bool = False,
    normals: bool = True,
) -> UsdGeom.Mesh:
    """Author a mesh. ``st_mode``: "faceVarying", "indexed" (faceVarying + indices) or
    "vertex" (only valid when every welded point has one UV, e.g. a single grid chart)."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    pts = Vt.Vec3fArray.FromNumpy(m.points.astype(np.float32))
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(m.counts))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(m.indices))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(pts))
    pv_api = UsdGeom.PrimvarsAPI(mesh)
    st_type = Sdf.ValueTypeNames.TexCoord2fArray
    if st_mode == "vertex":
        st_v = np.zeros((len(m.points), 2))
        st_v[m.indices] = m.st
        assert np.allclose(st_v[m.indices], m.st), "vertex st needs one UV per point"
        pv = pv_api.CreatePrimvar("st", st_type, UsdGeom.Tokens.vertex)
        pv.Set(Vt.Vec2fArray.FromNumpy(st_v.astype(np.float32)))
        n_v = np.zeros((len(m.points), 3))
        n_v[m.indices] = m.normals
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(n_v.astype(np.float32)))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    else:
        pv = pv_api.CreatePrimvar("st", st_type, UsdGeom.Tokens.faceVarying)
        if st_mode == "indexed":
            values, index = np.unique(m.st, axis=0, return_inverse=True)
            pv.Set(Vt.Vec2fArray.FromNumpy(values.astype(np.float32)))
            pv.SetIndices(Vt.IntArray.FromNumpy(index.reshape(-1).astype(np.int32)))
        else:
            pv.Set(Vt.Vec2fArray.FromNumpy(m.st.astype(np.float32)))
        if normals:
            mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(m.normals.astype(np.float32)))
            mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    if texture_uv:
        tv = pv_api.CreatePrimvar("uv", st_type, UsdGeom.Tokens.faceVarying)
        tv.Set(Vt.Vec2fArray.FromNumpy(m.uv.astype(np.float32)))
    return mesh


def preview_material(
    stage: Usd.Stage,
    name: str,
    diffuse=(0.5, 0.5, 0.5),
    *,
    emissive=None,
    diffuse_texture: str | None = None,
    normal_texture: str | None = None,
    uv_primvar: str = "uv",
) -> UsdShade.Material:
    """A UsdPreviewSurface material (diffuse-only look: roughness 1, metallic 0)."""
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    shader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*map(_r, diffuse)))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    if emissive is not None:
        shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(
            Gf.Vec3f(*map(_r, emissive))
        )
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    if diffuse_texture or normal_texture:
        reader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/TexCoordReader")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set(uv_primvar)
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    for role, file in (("diffuse", diffuse_texture), ("normal", normal_texture)):
        if not file:
            continue
        tex = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/{role.capitalize()}Texture")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(file))
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
            reader.ConnectableAPI(), "result"
        )
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
        if role == "diffuse":
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
            out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
            shader.GetInput("diffuseColor").ConnectToSource(out)
        else:
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
            tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
            tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
            out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
            shader.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(out)
    return mat


def bind(prim_or_subset, material: UsdShade.Material) -> None:
    api = UsdShade.MaterialBindingAPI.Apply(prim_or_subset.GetPrim())
    api.Bind(material)


def bind_groups(mesh: UsdGeom.Mesh, m: MeshArrays, materials: dict[str, UsdShade.Material]):
    """One GeomSubset per material group (family materialBind, partition)."""
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    for name in sorted(m.groups):
        subset = UsdGeom.Subset.CreateGeomSubset(
            mesh,
            name,
            UsdGeom.Tokens.face,
            Vt.IntArray(m.groups[name]),
            UsdShade.Tokens.materialBind,
            UsdGeom.Tokens.partition,
        )
        bind(subset, materials[name])


def light_common(light, intensity: float, exposure: float, color, normalize: bool = False):
    api = UsdLux.LightAPI(light)
    api.CreateIntensityAttr(_r(intensity))
    api.CreateExposureAttr(_r(exposure))
    api.CreateColorAttr(Gf.Vec3f(*map(_r, color)))
    api.CreateNormalizeAttr(normalize)
    return light


# --------------------------------------------------------------------------------------------
# Textures (OpenImageIO)
# --------------------------------------------------------------------------------------------


def write_image(path: Path, pixels: np.ndarray, fmt: str, attrs: dict | None = None) -> None:
    import OpenImageIO as oiio

    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    for k, v in (attrs or {}).items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise RuntimeError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(pixels)
    out.close()


def normal_bumps(size: int = 128, bumps: int = 4) -> np.ndarray:
    """Tangent-space normal map (OpenGL: +x right = +u, +y up = +v) of ``bumps^2`` domes.

    Returns ``(size, size, 3) uint8`` encoded as ``(n + 1) / 2``; row 0 is the top (v = 1).
    """
    x = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(x, 1.0 - x)  # image rows go down, v goes up
    cu = (np.floor(u * bumps) + 0.5) / bumps
    cv = (np.floor(v * bumps) + 0.5) / bumps
    radius = 0.42 / bumps
    du, dv = (u - cu) / radius, (v - cv) / radius
    r2 = du * du + dv * dv
    inside = r2 < 1.0
    # A low dome (height 0.35 * radius): slopes stay moderate, normals stay in the hemisphere.
    k = 0.35
    nx = np.where(inside, k * du, 0.0)
    ny = np.where(inside, k * dv, 0.0)
    n = np.stack([nx, ny, np.ones_like(nx)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.clip(np.round((n + 1.0) * 0.5 * 255.0), 0, 255).astype(np.uint8)


def checker_albedo(size: int = 32, checks: int = 4) -> np.ndarray:
    """sRGB-encoded ``(size, size, 3) uint8`` checker of two greys (linear 0.6 and 0.2)."""
    i = (np.arange(size) * checks // size) % 2
    mask = (i[:, None] ^ i[None, :]).astype(bool)
    lin = np.where(mask, 0.6, 0.2)

    def srgb(c):
        return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)

    g = np.round(srgb(lin) * 255.0).astype(np.uint8)
    return np.repeat(g[..., None], 3, -1)


def sky_latlong(width: int = 64, height: int = 32) -> np.ndarray:
    """``(height, width, 3) float32`` latlong sky that varies only with elevation (row).

    Row 0 is the zenith (+Y), the last row the nadir. Because it has no azimuthal variation,
    the latlong azimuth convention does not matter; only "+Y is up" does.
    """
    elev = (0.5 - (np.arange(height) + 0.5) / height) * math.pi  # +pi/2 at the top row
    zenith = np.array([0.25, 0.45, 0.9])
    horizon = np.array([0.9, 0.95, 1.0])
    ground = np.array([0.16, 0.13, 0.10])
    t = np.clip(np.sin(elev), 0.0, 1.0)[:, None]
    sky = horizon * (1 - t) + zenith * t
    rows = np.where((elev > 0)[:, None], sky, ground) * 0.8
    return np.repeat(rows[:, None, :], width, 1).astype(np.float32)


# --------------------------------------------------------------------------------------------
# The samples
# --------------------------------------------------------------------------------------------

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)


def cornell_box(out: Path) -> None:
    stage, _ = new_stage(
        "Cornell box, 2 m cube (x, z in [-1, 1], y in [0, 2]), open towards +z. "
        "Lit only by a 0.5 x 0.5 m RectLight 2 cm under the ceiling. "
        "Lightmap UVs: primvars:st, faceVarying. Written by samples/make_samples.py.",
    )
    looks = {
        "White": preview_material(stage, "White", WHITE),
        "Red": preview_material(stage, "Red", RED),
        "Green": preview_material(stage, "Green", GREEN),
    }
    room = box_charts((2, 2, 2), (4, 4, 4), inward=True, faces=("+y", "-y", "-z", "+x", "-x"))
    walls = [
        ("Ceiling", room[0], "White"),
        ("Floor", room[1], "White"),
        ("BackWall", room[2], "White"),
        ("RightWall", room[3], "Green"),
        ("LeftWall", room[4], "Red"),
    ]
    for name, chart, look in walls:
        mesh = author_mesh(stage, f"/World/Geometry/{name}", build_mesh([chart]))
        bind(mesh, looks[look])
    sides = ("+x", "-x", "+y", "+z", "-z")  # no bottom: it rests on the floor
    for name, size, subdiv, pos, rot in (
        ("TallBox", (0.6, 1.2, 0.6), (2, 4, 2), (-0.45, 0.0, -0.4), 17.0),
        ("ShortBox", (0.6, 0.6, 0.6), (2, 2, 2), (0.45, 0.0, 0.38), -17.0),
    ):
        mesh = author_mesh(
            stage, f"/World/Geometry/{name}", build_mesh(box_charts(size, subdiv, faces=sides))
        )
        set_xform(mesh.GetPrim(), translate=pos, rotate_xyz=(0, rot, 0))
        bind(mesh, looks["White"])
    light = UsdLux.RectLight.Define(stage, "/World/Lights/CeilingLight")
    light.CreateWidthAttr(0.5)
    light.CreateHeightAttr(0.5)
    light_common(light, intensity=8.0, exposure=1.0, color=(1.0, 0.85, 0.65))
    set_xform(light.GetPrim(), translate=(0, 1.98, 0), rotate_xyz=(-90, 0, 0))  # emits -Y
    save(stage, out / "cornell_box.usda")


def pillar_room(out: Path) -> None:
    stage, _ = new_stage(
        "The 2018 IrradZ paper's Figure 1 situation: a closed 8 x 3 x 6 m room, a pillar "
        "shadowing a SphereLight 25 cm above the floor, a high-albedo back wall bouncing light, "
        "and a 6 cm thin partition lit from behind by a DiskLight. The room shell is one mesh "
        "with materialBind GeomSubsets; lightmap UVs: primvars:st, faceVarying, indexed. "
        "Written by samples/make_samples.py.",
    )
    looks = {
        "Floor": preview_material(stage, "Concrete", (0.45, 0.45, 0.45)),
        "Walls": preview_material(stage, "Plaster", (0.5, 0.5, 0.5)),
        "BackWall": preview_material(stage, "BackWallPaint", (0.85, 0.8, 0.7)),
        "Ceiling": preview_material(stage, "Ceiling", (0.6, 0.6, 0.6)),
    }
    shell = box_charts((8, 3, 6), (1, 1, 1), inward=True)
    by_face = dict(zip(("+x", "-x", "+y", "-y", "+z", "-z"), shell))
    grids = {"+x": (6, 3), "-x": (6, 3), "+y": (4, 3), "-y": (8, 6), "+z": (8, 3), "-z": (8, 3)}
    groups = {"-y": "Floor", "+y": "Ceiling", "-z": "BackWall"}
    charts = []
    for face in ("-y", "-z", "+z", "+x", "-x", "+y"):
        c = by_face[face]
        na, nb = grids[face]
        charts.append(Chart(c.origin, c.a, c.b, na, nb, groups.get(face, "Walls")))
    shell_mesh = build_mesh(charts)
    room = author_mesh(stage, "/World/Geometry/Room", shell_mesh, st_mode="indexed")
    bind_groups(room, shell_mesh, looks)

    pillar = author_mesh(
        stage,
        "/World/Geometry/Pillar",
        build_mesh(box_charts((0.5, 3.0, 0.5), (1, 6, 1), faces=("+x", "-x", "+z", "-z"))),
        st_mode="indexed",
    )
    bind(pillar, looks["Walls"])
    partition = author_mesh(
        stage,
        "/World/Geometry/Partition",
        build_mesh(box_charts((0.06, 2.2, 2.0), (1, 4, 4), faces=("+x", "-x", "+y", "+z", "-z"))),
        st_mode="indexed",
    )
    set_xform(partition.GetPrim(), translate=(2.4, 0.0, 1.6))
    bind(partition, looks["Walls"])

    sign_mat = preview_material(stage, "ExitSign", (0.1, 0.1, 0.1), emissive=(0.2, 2.0, 0.4))
    sign = author_mesh(
        stage,
        "/World/Geometry/ExitSign",
        build_mesh([Chart((0.2, -0.1, 0.0), (-0.4, 0, 0), (0, 0.2, 0), 2, 1)]),  # faces -z
        st_mode="indexed",
    )
    set_xform(sign.GetPrim(), translate=(-2.0, 2.4, 2.99))
    bind(sign, sign_mat)

    lamp = UsdLux.SphereLight.Define(stage, "/World/Lights/FloorLamp")
    lamp.CreateRadiusAttr(0.1)
    light_common(lamp, intensity=30.0, exposure=2.0, color=(1.0, 0.75, 0.45))
    set_xform(lamp.GetPrim(), translate=(-1.5, 0.25, 0.0))
    back = UsdLux.DiskLight.Define(stage, "/World/Lights/BehindPartition")
    back.CreateRadiusAttr(0.3)
    light_common(back, intensity=10.0, exposure=0.0, color=(0.7, 0.85, 1.0))
    set_xform(back.GetPrim(), translate=(3.4, 1.1, 1.6), rotate_xyz=(0, 90, 0))  # emits -X
    save(stage, out / "pillar_room.usda")


def normal_wall(out: Path) -> None:
    tex = out / "textures"
    tex.mkdir(parents=True, exist_ok=True)
    write_image(tex / "bumps_normal.png", normal_bumps(), "uint8")
    write_image(tex / "checker_albedo.png", checker_albedo(), "uint8")
    write_image(
        tex / "sky_latlong.exr",
        sky_latlong(),
        "half",
        {"compression": "zip", "DateTime": "2025:01:01 00:00:00"},  # fixed: byte-stable file
    )

    stage, _ = new_stage(
        "A 4 x 2.5 m wall (z = 0, facing +z) with a tangent-space normal map of 4 x 4 domes per "
        "metre, over a checker floor. Texture UVs: primvars:uv (metres, tiling); lightmap UVs: "
        "primvars:st, faceVarying, same orientation as uv. Lit by a grazing DistantLight "
        "(normalize on: intensity = perpendicular irradiance) and a latlong sky DomeLight. "
        "Written by samples/make_samples.py.",
    )
    wall_mat = preview_material(
        stage, "BumpyPlaster", (0.7, 0.7, 0.7), normal_texture="./textures/bumps_normal.png"
    )
    floor_mat = preview_material(
        stage, "CheckerFloor", (0.4, 0.4, 0.4), diffuse_texture="./textures/checker_albedo.png"
    )
    wall = author_mesh(
        stage,
        "/World/Geometry/Wall",
        build_mesh([Chart((-2, 0, 0), (4, 0, 0), (0, 2.5, 0), 8, 5)]),
        texture_uv=True,
    )
    bind(wall, wall_mat)
    floor = author_mesh(
        stage,
        "/World/Geometry/Floor",
        build_mesh([Chart((-2, 0, 3), (4, 0, 0), (0, 0, -3), 8, 6)]),
        texture_uv=True,
    )
    bind(floor, floor_mat)

    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.CreateAngleAttr(0.53)
    light_common(sun, intensity=3.0, exposure=0.0, color=(1.0, 0.95, 0.85), normalize=True)
    set_xform(sun.GetPrim(), rotate_xyz=(-25.0, -60.0, 0.0))
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    dome.CreateTextureFileAttr(Sdf.AssetPath("./textures/sky_latlong.exr"))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    light_common(dome, intensity=1.0, exposure=0.0, color=(1.0, 1.0, 1.0))
    save(stage, out / "normal_wall.usda")


def open_plane(out: Path) -> None:
    stage, _ = new_stage(
        "The simplest analytic case: one 4 x 4 m plane (y = 0, facing +y) under a uniform "
        "DomeLight of radiance 1 (intensity 1, exposure 0, colour 1, normalize off, no texture). "
        "Nothing else is visible from the plane, so its normalized irradiance I_z = 1 in every "
        "texel for any number of bounces. Lightmap UVs: primvars:st, vertex interpolation. "
        "Written by samples/make_samples.py.",
    )
    look = preview_material(stage, "Grey", (0.5, 0.5, 0.5))
    plane = author_mesh(
        stage,
        "/World/Geometry/Plane",
        build_mesh([Chart((-2, 0, 2), (4, 0, 0), (0, 0, -4), 8, 8)]),
        st_mode="vertex",
    )
    bind(plane, look)
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/UniformSky")
    light_common(dome, intensity=1.0, exposure=0.0, color=(1.0, 1.0, 1.0))
    save(stage, out / "open_plane.usda")


# --------------------------------------------------------------------------------------------
# Stages for the Cycles reference (benchmarks/reference, issue 17): each exercises one thing
# the baker got wrong. Small (a few hundred triangles) so the default test run stays fast.
# --------------------------------------------------------------------------------------------


def _floor(stage, path: str, size: float, n: int, look) -> None:
    h = size / 2
    mesh = author_mesh(
        stage, path, build_mesh([Chart((-h, 0, h), (size, 0, 0), (0, 0, -size), n, n)])
    )
    bind(mesh, look)


def stretched_boxes(out: Path) -> None:
    stage, _ = new_stage(
        "Two boxes WITHOUT authored normals (subdivisionScheme none: faces are flat, creases "
        "sharp) whose lightmap charts are stretched (non-uniform texel density: u and v scaled "
        "differently per face), on a floor with normals. Lit by a 1 x 1 m RectLight 3 m up and "
        "a dim uniform DomeLight. Lightmap UVs: primvars:st, faceVarying. "
        "Written by samples/make_samples.py.",
    )
    floor = preview_material(stage, "Floor", (0.6, 0.6, 0.6))
    paint = preview_material(stage, "Paint", (0.7, 0.55, 0.4))
    _floor(stage, "/World/Geometry/Floor", 4.0, 8, floor)
    sides = ("+x", "-x", "+y", "+z", "-z")
    for name, size, subdiv, pos, rot, stretch in (
        ("TallBox", (0.8, 1.2, 0.8), (2, 3, 2), (-0.7, 0.0, -0.2), 20.0,
         [(2.0, 0.5), (0.5, 2.0), (3.0, 1.0), (1.0, 3.0), (2.0, 0.5)]),
        ("FlatBox", (1.0, 0.5, 0.6), (2, 1, 2), (0.9, 0.0, 0.5), -10.0,
         [(3.0, 1.0), (1.0, 3.0), (0.4, 1.0), (2.0, 2.0), (1.0, 0.4)]),
    ):  # fmt: skip
        charts = box_charts(size, subdiv, faces=sides)
        mesh = author_mesh(
            stage, f"/World/Geometry/{name}", build_mesh(charts, stretch), normals=False
        )
        set_xform(mesh.GetPrim(), translate=pos, rotate_xyz=(0, rot, 0))
        bind(mesh, paint)
    light = UsdLux.RectLight.Define(stage, "/World/Lights/Panel")
    light.CreateWidthAttr(1.0)
    light.CreateHeightAttr(1.0)
    light_common(light, intensity=10.0, exposure=0.0, color=(1.0, 0.95, 0.9))
    set_xform(light.GetPrim(), translate=(0, 3.0, 0), rotate_xyz=(-90, 0, 0))  # emits -Y
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Fill")
    light_common(dome, intensity=0.1, exposure=0.0, color=(0.8, 0.9, 1.0))
    save(stage, out / "stretched_boxes.usda")


def indirect_ceiling(out: Path) -> None:
    stage, _ = new_stage(
        "A closed 4 x 2.5 x 4 m room lit only by a one-sided 1 x 1 m RectLight 20 cm under the "
        "ceiling, emitting down: the ceiling (its own mesh) and the walls above the light get "
        "only indirect light. Lightmap UVs: primvars:st, faceVarying. "
        "Written by samples/make_samples.py.",
    )
    walls = preview_material(stage, "Walls", (0.7, 0.7, 0.7))
    ceiling = preview_material(stage, "Ceiling", (0.8, 0.8, 0.8))
    room = box_charts((4, 2.5, 4), (4, 3, 4), inward=True)
    by_face = dict(zip(("+x", "-x", "+y", "-y", "+z", "-z"), room))
    shell = author_mesh(
        stage,
        "/World/Geometry/Walls",
        build_mesh([by_face[f] for f in ("-y", "+x", "-x", "+z", "-z")]),
    )
    bind(shell, walls)
    top = author_mesh(stage, "/World/Geometry/Ceiling", build_mesh([by_face["+y"]]))
    bind(top, ceiling)
    light = UsdLux.RectLight.Define(stage, "/World/Lights/Panel")
    light.CreateWidthAttr(1.0)
    light.CreateHeightAttr(1.0)
    light_common(light, intensity=12.0, exposure=0.0, color=(1.0, 0.9, 0.8))
    set_xform(light.GetPrim(), translate=(0, 2.3, 0), rotate_xyz=(-90, 0, 0))  # emits -Y
    save(stage, out / "indirect_ceiling.usda")


def floor_lamp(out: Path) -> None:
    stage, _ = new_stage(
        "A small SphereLight (radius 5 cm) 15 cm above a 3 x 3 m floor, in front of a wall: a "
        "bright, sharp hotspot where a baker's light sampling shows its noise. "
        "Lightmap UVs: primvars:st, faceVarying. Written by samples/make_samples.py.",
    )
    look = preview_material(stage, "Grey", (0.5, 0.5, 0.5))
    _floor(stage, "/World/Geometry/Floor", 3.0, 6, look)
    wall = author_mesh(
        stage,
        "/World/Geometry/Wall",
        build_mesh([Chart((-1.5, 0, -1.5), (3, 0, 0), (0, 2, 0), 6, 4)]),
    )
    bind(wall, look)
    lamp = UsdLux.SphereLight.Define(stage, "/World/Lights/Lamp")
    lamp.CreateRadiusAttr(0.05)
    light_common(lamp, intensity=50.0, exposure=0.0, color=(1.0, 0.8, 0.6))
    set_xform(lamp.GetPrim(), translate=(0.3, 0.15, -0.4))
    save(stage, out / "floor_lamp.usda")


def emissive_only(out: Path) -> None:
    stage, _ = new_stage(
        "A closed 3 x 2.5 x 3 m room lit ONLY by an emissive 0.6 x 0.6 m ceiling panel (a mesh "
        "with UsdPreviewSurface emissiveColor, facing down, 1 cm under the ceiling; no UsdLux "
        "light), with a box on the floor. Lightmap UVs: primvars:st, faceVarying. "
        "Written by samples/make_samples.py.",
    )
    walls = preview_material(stage, "Walls", (0.7, 0.68, 0.65))
    glow = preview_material(stage, "Glow", (0.0, 0.0, 0.0), emissive=(12.0, 11.0, 9.0))
    room = author_mesh(
        stage, "/World/Geometry/Room", build_mesh(box_charts((3, 2.5, 3), (3, 2, 3), inward=True))
    )
    bind(room, walls)
    box = author_mesh(
        stage,
        "/World/Geometry/Box",
        build_mesh(box_charts((0.6, 0.6, 0.6), (1, 1, 1), faces=("+x", "-x", "+y", "+z", "-z"))),
    )
    set_xform(box.GetPrim(), translate=(0.5, 0.0, -0.3), rotate_xyz=(0, 30, 0))
    bind(box, walls)
    panel = author_mesh(
        stage,
        "/World/Geometry/Panel",
        build_mesh([Chart((-0.3, 2.49, -0.3), (0.6, 0, 0), (0, 0, 0.6), 1, 1)]),  # faces -y
    )
    bind(panel, glow)
    save(stage, out / "emissive_only.usda")


def exterior_sun_sky(out: Path) -> None:
    stage, _ = new_stage(
        "An exterior: a 6 x 6 m ground with two boxes and a wall under a sun (DistantLight, "
        "normalize on: intensity = illuminance 3, angle 0.53) and a uniform blue sky "
        "(DomeLight, radiance (0.3, 0.45, 0.7)). Lightmap UVs: primvars:st, faceVarying. "
        "Written by samples/make_samples.py.",
    )
    ground = preview_material(stage, "Ground", (0.35, 0.3, 0.25))
    stone = preview_material(stage, "Stone", (0.6, 0.58, 0.55))
    _floor(stage, "/World/Geometry/Ground", 6.0, 6, ground)
    sides = ("+x", "-x", "+y", "+z", "-z")
    for name, size, pos, rot in (
        ("BoxA", (1.0, 1.0, 1.0), (-1.2, 0.0, 0.4), 25.0),
        ("BoxB", (0.6, 1.6, 0.6), (1.0, 0.0, -0.6), -15.0),
        ("Wall", (3.0, 1.2, 0.15), (0.0, 0.0, -2.0), 0.0),
    ):
        mesh = author_mesh(
            stage, f"/World/Geometry/{name}", build_mesh(box_charts(size, (2, 2, 1), faces=sides))
        )
        set_xform(mesh.GetPrim(), translate=pos, rotate_xyz=(0, rot, 0))
        bind(mesh, stone)
    sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
    sun.CreateAngleAttr(0.53)
    light_common(sun, intensity=3.0, exposure=0.0, color=(1.0, 0.95, 0.85), normalize=True)
    set_xform(sun.GetPrim(), rotate_xyz=(-50.0, 30.0, 0.0))
    sky = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
    light_common(sky, intensity=1.0, exposure=0.0, color=(0.3, 0.45, 0.7))
    save(stage, out / "exterior_sun_sky.usda")


SAMPLES = {
    "cornell_box": cornell_box,
    "pillar_room": pillar_room,
    "normal_wall": normal_wall,
    "open_plane": open_plane,
    "stretched_boxes": stretched_boxes,
    "indirect_ceiling": indirect_ceiling,
    "floor_lamp": floor_lamp,
    "emissive_only": emissive_only,
    "exterior_sun_sky": exterior_sun_sky,
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE, help="output folder (default: here)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for name, make in SAMPLES.items():
        make(args.out)
        print(f"wrote {args.out / (name + '.usda')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
