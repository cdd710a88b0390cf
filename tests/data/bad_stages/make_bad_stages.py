"""(Re)write the bad-input stage corpus and its manifest ``cases.json`` deterministically.

Usage::

    /work/venv/bin/python tests/data/bad_stages/make_bad_stages.py [--out DIR]

Each case is a tiny stage with exactly one defect; everything else is valid. Unless the defect
is about the whole file or stage, a case contains

- ``/World/Good``: a valid 1 x 1 m plane (y = 0, facing +y) with a lightmap UV set ``st`` and a
  UsdPreviewSurface material, which must bake;
- ``/World/Lights/Key``: a valid DistantLight shining down (normalize on, intensity 2);
- the defect, usually on ``/World/Bad`` (a second plane at x = 2) or ``/World/Lights/Bad``.

So a prim-level defect leaves one good prim and one failing prim (exit code 1, "some prims
failed"), a stage-level defect (unreadable file, broken lights, no meshes) makes the input
unusable (exit code 2), and defects the baker must tolerate give exit code 0 plus a warning.

Manifest format (``cases.json``): ``{"format": 1, "matching": ..., "generator": ...,
"cases": [case, ...]}`` where each case has

- ``id``: unique name; ``file``: the stage to pass to ``usdahd bake`` (relative to this folder);
- ``description``: the defect in one line;
- ``exit_code``: 0 (handled, maybe with a warning), 1 (some prims failed), 2 (unusable input);
- ``severity``: "error", "warning" or "none" (no message required);
- ``message``: a substring the error/warning text must contain (case-insensitive), or null;
- ``prim``: a prim path the message must also name, or null;
- ``args``: extra ``usdahd bake`` arguments for this case (usually empty);
- ``exists``: false only for the deliberately missing file; ``opens``: whether
  ``Usd.Stage.Open`` succeeds on it (composition errors are warnings, so cycles open);
- ``aux``: other files of this folder the case uses (referenced layers, fake textures);
- ``check``: an extra property the bake test must assert, or null:
  "distinct_texture_names" (every baked prim gets its own texture file, also on a
  case-insensitive file system), "texture_names_fit" (every file name <= 255 bytes),
  "inside_output_dir" (every written file lies under the output directory),
  "no_warning" (valid input: must bake cleanly);
- ``setup``: what the test does to the copied case before baking, for defects a committed
  file cannot hold, or null: "lightmaps_file" (a file named ``lightmaps`` beside the stage),
  "lightmaps_dangling_symlink", "readonly_lightmaps" (the lightmaps folder read-only, a
  read-only tmpfs mount as root), "output_is_directory" (a folder where the output layer
  goes), "readonly_layer" (an existing output layer without write permission), "fifo_texture"
  (``pipe.png`` beside the stage is a FIFO), "non_utf8_name" (the stage copied to a file name
  with a Latin-1 byte).

The lead aligns the implementation with these codes and keywords; change them here (and
regenerate) rather than in the JSON.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

HERE = Path(__file__).resolve().parent
NAN = float("nan")
INF = float("inf")

# --------------------------------------------------------------------------------------------
# Valid building blocks
# --------------------------------------------------------------------------------------------


def new_stage(doc: str, *, up_axis: str = "Y", meters_per_unit: float = 1.0) -> Usd.Stage:
    stage = Usd.Stage.Open(Sdf.Layer.CreateAnonymous(".usda"))
    stage.SetMetadata("upAxis", up_axis)
    stage.SetMetadata("metersPerUnit", meters_per_unit)
    stage.GetRootLayer().documentation = doc
    world = UsdGeom.Xform.Define(stage, "/World").GetPrim()
    stage.SetDefaultPrim(world)
    UsdGeom.Xform.Define(stage, "/World/Lights")
    UsdGeom.Scope.Define(stage, "/World/Looks")
    return stage


def material(stage: Usd.Stage, name: str = "Grey", diffuse=(0.5, 0.5, 0.5)) -> UsdShade.Shader:
    """A UsdPreviewSurface material; returns its surface shader (for adding inputs)."""
    path = f"/World/Looks/{name}"
    if stage.GetPrimAtPath(path):
        return UsdShade.Shader(stage.GetPrimAtPath(f"{path}/PreviewSurface"))
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return shader


def plane(
    stage: Usd.Stage,
    path: str,
    x: float = 0.0,
    size: float = 1.0,
    n: int = 2,
    look: str = "Grey",
    st: bool = True,
) -> UsdGeom.Mesh:
    """A valid ``size`` x ``size`` plane of n x n quads at (x, 0, 0) facing +y, with a
    faceVarying lightmap UV set ``st`` (one chart, 2 texels of border at 64x64)."""
    for i in range(1, path.count("/")):
        parent = "/".join(path.split("/")[: i + 1])
        if not stage.GetPrimAtPath(parent):
            UsdGeom.Xform.Define(stage, parent)
    mesh = UsdGeom.Mesh.Define(stage, path)
    g = np.linspace(0.0, 1.0, n + 1)
    pts = [(x + (u - 0.5) * size, 0.0, (0.5 - v) * size) for v in g for u in g]
    idx, uvs = [], []
    border = 2.0 / 64.0
    for j in range(n):
        for i in range(n):
            for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                idx.append((j + dj) * (n + 1) + i + di)
                uvs.append(tuple(border + (1 - 2 * border) * np.array([g[i + di], g[j + dj]])))
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4] * (n * n)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 1, 0)] * len(idx)))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    if st:
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
        )
        pv.Set(Vt.Vec2fArray([Gf.Vec2f(*map(float, t)) for t in uvs]))
    material(stage, look)
    api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    api.Bind(UsdShade.Material(stage.GetPrimAtPath(f"/World/Looks/{look}")))
    return mesh


def key_light(stage: Usd.Stage, intensity: float = 2.0) -> UsdLux.DistantLight:
    light = UsdLux.DistantLight.Define(stage, "/World/Lights/Key")
    light.CreateIntensityAttr(intensity)
    light.CreateExposureAttr(0.0)
    light.CreateColorAttr(Gf.Vec3f(1, 1, 1))
    light.CreateNormalizeAttr(True)
    UsdGeom.Xformable(light).AddRotateXYZOp().Set(Gf.Vec3f(-90, 0, 0))  # emits -Y
    return light


def sphere_light(stage: Usd.Stage, path: str = "/World/Lights/Bad", **inputs) -> UsdLux.SphereLight:
    light = UsdLux.SphereLight.Define(stage, path)
    light.CreateRadiusAttr(0.1)
    values = {"intensity": 5.0, "exposure": 0.0, "color": (1.0, 1.0, 1.0)} | inputs
    light.CreateIntensityAttr(values["intensity"])
    light.CreateExposureAttr(values["exposure"])
    light.CreateColorAttr(Gf.Vec3f(*values["color"]))
    light.CreateNormalizeAttr(False)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 1.5, 0))
    return light


def base(doc: str, **kw) -> Usd.Stage:
    """Stage with the good plane and the key light."""
    stage = new_stage(doc, **kw)
    plane(stage, "/World/Good")
    key_light(stage)
    return stage


def with_bad_plane(doc: str, **plane_kw) -> tuple[Usd.Stage, UsdGeom.Mesh]:
    stage = base(doc)
    return stage, plane(stage, "/World/Bad", x=2.0, **plane_kw)


def text(stage: Usd.Stage) -> bytes:
    """The root layer as .usda bytes, after authoring extents on meshes with finite points."""
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            pts = UsdGeom.Mesh(prim).GetPointsAttr().Get()
            if pts is not None and len(pts) and np.isfinite(np.array(pts)).all():
                UsdGeom.Mesh(prim).CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(pts))
    return stage.GetRootLayer().ExportToString().encode("utf-8")


def edit_layer(data: bytes, edit: Callable[[Sdf.Layer], None]) -> bytes:
    """Apply an Sdf-level edit to .usda bytes with no stage attached (so arcs to files that do
    not exist yet, or cycles, are not composed while generating)."""
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.ImportFromString(data.decode("utf-8"))
    edit(layer)
    return layer.ExportToString().encode("utf-8")


def add_reference(data: bytes, path: str, asset: str) -> bytes:
    def edit(layer: Sdf.Layer) -> None:
        spec = layer.GetPrimAtPath(path) or Sdf.CreatePrimInLayer(layer, path)
        if not spec.typeName:
            spec.specifier, spec.typeName = Sdf.SpecifierDef, "Xform"
        spec.referenceList.Prepend(Sdf.Reference(asset))

    return edit_layer(data, edit)


def valid_text() -> bytes:
    return text(base("A valid stage: the good plane and the key light."))


# --------------------------------------------------------------------------------------------
# Cases. Each builder returns {file name: bytes} (the case file first, then aux files).
# --------------------------------------------------------------------------------------------

CASES: list[dict] = []


def case(
    id: str,
    description: str,
    exit_code: int,
    message: str | None,
    *,
    prim: str | None = None,
    severity: str | None = None,
    ext: str = ".usda",
    opens: bool = True,
    exists: bool = True,
    args: list[str] | None = None,
    check: str | None = None,
    setup: str | None = None,
    file: str | None = None,
):
    """Register a builder ``() -> {name: bytes}``; its first entry is the case file."""
    if severity is None:
        severity = {2: "error", 1: "error", 0: "warning" if message else "none"}[exit_code]

    def register(build: Callable[[], dict[str, bytes]] | None):
        CASES.append(
            {
                "id": id,
                "file": file or id + ext,
                "description": description,
                "exit_code": exit_code,
                "severity": severity,
                "message": message,
                "prim": prim,
                "args": args or [],
                "exists": exists,
                "opens": opens,
                "aux": [],
                "check": check,
                "setup": setup,
                "_build": build,
            }
        )
        return build

    return register


# ---- the file itself is unusable (exit 2, the message names the file) ----------------------


case("missing_file", "The stage file does not exist.", 2, "missing_file.usda",
     opens=False, exists=False)(None)  # fmt: skip


@case("empty_file", "A zero-byte .usda file.", 2, "empty_file.usda", opens=False)
def _():
    return {"empty_file.usda": b""}


@case("truncated_text", "A valid .usda cut off in the middle of a prim.", 2,
      "truncated_text.usda", opens=False)  # fmt: skip
def _():
    data = valid_text()
    return {"truncated_text.usda": data[: int(len(data) * 0.6)]}


@case("truncated_crate", "A valid binary .usdc cut to half its length.", 2,
      "truncated_crate.usdc", ext=".usdc", opens=False)  # fmt: skip
def _():
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "full.usdc"
        layer = Sdf.Layer.CreateNew(str(path))
        layer.ImportFromString(valid_text().decode())
        layer.Save()
        data = path.read_bytes()
    return {"truncated_crate.usdc": data[: len(data) // 2]}


@case("not_usd_png", "A PNG image renamed to .usda.", 2, "not_usd_png.usda", opens=False)
def _():
    return {"not_usd_png.usda": png_bytes()}


@case("random_bytes", "512 bytes of random binary data named .usda.", 2, "random_bytes.usda",
      opens=False)  # fmt: skip
def _():
    return {"random_bytes.usda": np.random.default_rng(20250607).bytes(512)}


@case("syntax_error", "A .usda with a valid header and a syntax error in a prim body.", 2,
      "syntax_error.usda", opens=False)  # fmt: skip
def _():
    data = valid_text().decode()
    data = data.replace('def Mesh "Good"', 'def Mesh "Good" {{ oops = = ]', 1)
    return {"syntax_error.usda": data.encode()}


@case("bad_version_header", "A .usda whose header claims version 99.0.", 2,
      "bad_version_header.usda", opens=False)  # fmt: skip
def _():
    data = valid_text().decode().replace("#usda 1.0", "#usda 99.0", 1)
    return {"bad_version_header.usda": data.encode()}


# ---- the stage opens but nothing can be baked from it (exit 2) ------------------------------


@case("no_meshes", "Lights, an Xform and a Sphere gprim, but no UsdGeom.Mesh.", 2, "no mesh")
def _():
    stage = new_stage("No meshes: a Sphere gprim is not a mesh.")
    UsdGeom.Sphere.Define(stage, "/World/Ball").CreateRadiusAttr(0.5)
    key_light(stage)
    return {"no_meshes.usda": text(stage)}


@case("meters_per_unit_zero", "Stage metadata metersPerUnit = 0.", 2, "metersPerUnit")
def _():
    return {"meters_per_unit_zero.usda": text(base("metersPerUnit 0.", meters_per_unit=0.0))}


@case("negative_intensity", "A SphereLight with inputs:intensity = -5.", 2, "intensity",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("Negative light intensity.")
    sphere_light(stage, intensity=-5.0)
    return {"negative_intensity.usda": text(stage)}


@case("nan_intensity", "A SphereLight with inputs:intensity = NaN.", 2, "NaN",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("NaN light intensity.")
    sphere_light(stage, intensity=NAN)
    return {"nan_intensity.usda": text(stage)}


@case("inf_intensity", "A SphereLight with inputs:intensity = +Inf.", 2, "Inf",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("Infinite light intensity.")
    sphere_light(stage, intensity=INF)
    return {"inf_intensity.usda": text(stage)}


@case("huge_exposure", "A SphereLight with inputs:exposure = 200 (2^200 overflows float32).", 2,
      "exposure", prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("Exposure 200.")
    sphere_light(stage, exposure=200.0)
    return {"huge_exposure.usda": text(stage)}


@case("nan_light_color", "A SphereLight with inputs:color = (NaN, 1, 1).", 2, "color",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("NaN light colour.")
    sphere_light(stage, color=(NAN, 1.0, 1.0))
    return {"nan_light_color.usda": text(stage)}


@case("dome_texture_missing", "A DomeLight whose texture:file does not exist.", 2,
      "no_such_sky.exr", prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("DomeLight texture missing.")
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Bad")
    dome.CreateTextureFileAttr(Sdf.AssetPath("./no_such_sky.exr"))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)
    return {"dome_texture_missing.usda": text(stage)}


@case("dome_texture_not_image", "A DomeLight whose texture:file is a text file named .exr.", 2,
      "not_an_image.exr", prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("DomeLight texture is not an image.")
    dome = UsdLux.DomeLight.Define(stage, "/World/Lights/Bad")
    dome.CreateTextureFileAttr(Sdf.AssetPath("./not_an_image.exr"))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)
    return {
        "dome_texture_not_image.usda": text(stage),
        "not_an_image.exr": b"This is not an OpenEXR file, only text with an .exr name.\n",
    }


@case("nan_emissive", "A material with emissiveColor = (NaN, 0, 0) bound to the good plane.", 2,
      "emissiveColor", prim="/World/Looks/Glow")  # fmt: skip
def _():
    stage = new_stage("NaN emission: emissive surfaces are light sources.")
    shader = material(stage, "Glow")
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(NAN, 0, 0))
    plane(stage, "/World/Good", look="Glow")
    key_light(stage)
    return {"nan_emissive.usda": text(stage)}


# ---- one prim is broken, the good plane still bakes (exit 1) -------------------------------


@case("nan_points", "/World/Bad has a NaN coordinate in its points.", 1, "NaN", prim="/World/Bad")
def _():
    stage, mesh = with_bad_plane("NaN points.")
    pts = np.array(mesh.GetPointsAttr().Get())
    pts[4, 1] = NAN
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts))
    return {"nan_points.usda": text(stage)}


@case("inf_points", "/World/Bad has a +Inf coordinate in its points.", 1, "Inf",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Inf points.")
    pts = np.array(mesh.GetPointsAttr().Get())
    pts[0, 0] = INF
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts))
    return {"inf_points.usda": text(stage)}


@case("zero_area_mesh", "/World/Bad: every point on one line, so every triangle has zero area.",
      1, "area", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Zero-area mesh.")
    pts = np.array(mesh.GetPointsAttr().Get())
    pts[:, 2] = 0.0  # all on the line z = 0, y = 0
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pts))
    return {"zero_area_mesh.usda": text(stage)}


@case("fvc_mismatch", "/World/Bad: sum(faceVertexCounts) = 15 but 16 faceVertexIndices.", 1,
      "faceVertexCounts", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("faceVertexCounts do not match faceVertexIndices.")
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray([4, 4, 4, 3]))
    return {"fvc_mismatch.usda": text(stage)}


@case("face_with_two_vertices", "/World/Bad: two extra faces with faceVertexCounts 2 (fewer than "
      "3): skip those faces with a warning, as Hydra does, and bake the rest.", 0, "vertices",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("A two-vertex face.")
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray([4, 4, 4, 2, 2]))
    return {"face_with_two_vertices.usda": text(stage)}


@case("indices_out_of_range", "/World/Bad: a faceVertexIndices entry 99 >= the 9 points.", 1,
      "faceVertexIndices", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Index out of range.")
    idx = list(mesh.GetFaceVertexIndicesAttr().Get())
    idx[5] = 99
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray(idx))
    return {"indices_out_of_range.usda": text(stage)}


@case("negative_index", "/World/Bad: a faceVertexIndices entry -1.", 1, "faceVertexIndices",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Negative index.")
    idx = list(mesh.GetFaceVertexIndicesAttr().Get())
    idx[2] = -1
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray(idx))
    return {"negative_index.usda": text(stage)}


def _retype_st(mesh: UsdGeom.Mesh, type_name, value, interpolation="faceVarying"):
    mesh.GetPrim().RemoveProperty("primvars:st")
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", type_name, interpolation)
    pv.Set(value)
    return pv


@case("uv_float3", "/World/Bad: primvars:st authored as float3[] instead of texCoord2f[].", 1,
      "float3", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("UV primvar of type float3[].")
    _retype_st(mesh, Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray([Gf.Vec3f(0.5)] * 16))
    return {"uv_float3.usda": text(stage)}


@case("uv_string", "/World/Bad: primvars:st authored as string[].", 1, "string",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("UV primvar of type string[].")
    _retype_st(mesh, Sdf.ValueTypeNames.StringArray, Vt.StringArray(["0.5 0.5"] * 16))
    return {"uv_string.usda": text(stage)}


@case("uv_wrong_length", "/World/Bad: faceVarying primvars:st with 5 values for 16 face-vertices.",
      1, "primvars:st", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("UV primvar too short.")
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    st.Set(Vt.Vec2fArray(list(st.Get())[:5]))
    return {"uv_wrong_length.usda": text(stage)}


@case("uv_uniform", "/World/Bad: primvars:st with uniform (one per face) interpolation.", 1,
      "uniform", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("UV primvar with uniform interpolation.")
    uv = [Gf.Vec2f(0.2, 0.2), Gf.Vec2f(0.7, 0.2), Gf.Vec2f(0.7, 0.7), Gf.Vec2f(0.2, 0.7)]
    _retype_st(mesh, Sdf.ValueTypeNames.TexCoord2fArray, Vt.Vec2fArray(uv), "uniform")
    return {"uv_uniform.usda": text(stage)}


@case("uv_constant", "/World/Bad: primvars:st with constant interpolation (one UV).", 1,
      "constant", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("UV primvar with constant interpolation.")
    _retype_st(mesh, Sdf.ValueTypeNames.TexCoord2fArray, Vt.Vec2fArray([Gf.Vec2f(0.5)]), "constant")
    return {"uv_constant.usda": text(stage)}


@case("uv_nan", "/World/Bad: one lightmap UV is (NaN, 0.5).", 1, "NaN", prim="/World/Bad")
def _():
    stage, mesh = with_bad_plane("NaN UV.")
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    uv = np.array(st.Get())
    uv[3, 0] = NAN
    st.Set(Vt.Vec2fArray.FromNumpy(uv))
    return {"uv_nan.usda": text(stage)}


@case("uv_indices_out_of_range", "/World/Bad: indexed primvars:st whose indices reach past its "
      "values.", 1, "primvars:st", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Indexed UVs with an index out of range.")
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    values = list(st.Get())
    st.Set(Vt.Vec2fArray(values[:8]))
    st.SetIndices(Vt.IntArray([i % 8 for i in range(15)] + [40]))
    return {"uv_indices_out_of_range.usda": text(stage)}


@case("zero_scale", "/World/Bad has xformOp:scale = (0, 0, 0): a non-invertible transform.", 1,
      "transform", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Zero scale.")
    UsdGeom.Xformable(mesh).AddScaleOp().Set(Gf.Vec3f(0, 0, 0))
    return {"zero_scale.usda": text(stage)}


@case("singular_matrix", "/World/Bad has an xformOp:transform of rank 2 (projects onto a line "
      "in the plane), so the world-space mesh has zero area.", 1, "transform",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Singular transform matrix.")
    m = Gf.Matrix4d(1, 0, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1)  # z -> x: rank 2 in 3-D
    UsdGeom.Xformable(mesh).AddTransformOp().Set(m)
    return {"singular_matrix.usda": text(stage)}


@case("nan_transform", "/World/Bad has xformOp:translate = (NaN, 0, 0).", 1, "NaN",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("NaN translation.")
    UsdGeom.Xformable(mesh).AddTranslateOp().Set(Gf.Vec3d(NAN, 0, 0))
    return {"nan_transform.usda": text(stage)}


@case("huge_coordinates", "/World/Bad translated to x = 1e9 m: beyond float32 ray-tracing "
      "precision (ulp 64 m there).", 1, "precision", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Enormous coordinates.")
    UsdGeom.Xformable(mesh).AddTranslateOp().Set(Gf.Vec3d(1e9, 0, 0))
    return {"huge_coordinates.usda": text(stage)}


def with_resolution(doc: str, resolution: int, **plane_kw) -> Usd.Stage:
    """The good and bad planes carry AhdLightmapAPI (schema inputs are only read on prims with
    the API; the bake then selects exactly these two); /World/Bad authors the resolution."""
    stage, mesh = with_bad_plane(doc, **plane_kw)
    for path in ("/World/Good", "/World/Bad"):
        stage.GetPrimAtPath(path).AddAppliedSchema("AhdLightmapAPI")
    # As the schema declares it (the same text whether or not the usdahd plugin is loaded).
    attr = mesh.GetPrim().CreateAttribute(
        "ahdLightmap:resolution", Sdf.ValueTypeNames.Int, False, Sdf.VariabilityUniform
    )
    attr.Set(resolution)
    return stage


@case("huge_resolution", "/World/Bad requests ahdLightmap:resolution = 1000000 (10^12 texels): "
      "refuse instead of exhausting memory.", 1, "resolution", prim="/World/Bad")  # fmt: skip
def _():
    return {"huge_resolution.usda": text(with_resolution("Huge requested resolution.", 10**6))}


@case("huge_resolution_unwrap", "/World/Bad has no UV set (so it is unwrapped) and requests "
      "ahdLightmap:resolution = 1000000: refuse before unwrapping.", 1, "resolution",
      prim="/World/Bad")  # fmt: skip
def _():
    stage = with_resolution("Huge requested resolution on a mesh to unwrap.", 10**6, st=False)
    return {"huge_resolution_unwrap.usda": text(stage)}


@case("negative_resolution", "/World/Bad requests ahdLightmap:resolution = -5 (the schema "
      "requires >= 0).", 1, "resolution", prim="/World/Bad")  # fmt: skip
def _():
    return {"negative_resolution.usda": text(with_resolution("Negative resolution.", -5))}


@case("zero_resolution", "/World/Bad authors ahdLightmap:resolution = 0, which the schema "
      "defines as 'derive from texelDensity' (docs/schema.md): valid, bakes.", 0, None)  # fmt: skip
def _():
    return {"zero_resolution.usda": text(with_resolution("Zero requested resolution.", 0))}


# ---- must be handled gracefully (exit 0, a warning naming the problem) ---------------------


@case("missing_uv", "/World/Bad has no primvars:st: unwrap it (xatlas) and say so.", 0, "unwrap",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, _ = with_bad_plane("No lightmap UV set on /World/Bad.", st=False)
    return {"missing_uv.usda": text(stage)}


# Same file as missing_uv, with unwrapping switched off: now the prim cannot be baked.
case("missing_uv_no_unwrap", "/World/Bad has no primvars:st and unwrapping is switched off.", 1,
     "UV", prim="/World/Bad", file="missing_uv.usda", args=["--no-unwrap"])(None)  # fmt: skip


@case("uv_out_of_range", "/World/Bad: primvars:st spans [-0.5, 1.5] (tiling texture UVs): warn "
      "and unwrap a separate lightmap set.", 0, "outside", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("UVs outside [0, 1].")
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    st.Set(Vt.Vec2fArray.FromNumpy(np.array(st.Get()) * 2.0 - 0.5))
    return {"uv_out_of_range.usda": text(stage)}


@case("uv_overlap", "/World/Bad: all four quads map onto the same UV square: warn and unwrap "
      "a separate lightmap set.", 0, "overlap", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Overlapping UVs.")
    quad = [Gf.Vec2f(0.1, 0.1), Gf.Vec2f(0.9, 0.1), Gf.Vec2f(0.9, 0.9), Gf.Vec2f(0.1, 0.9)]
    UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Set(Vt.Vec2fArray(quad * 4))
    return {"uv_overlap.usda": text(stage)}


@case("empty_mesh", "/World/Empty is a Mesh with no points and no faces: skip it.", 0, "empty",
      prim="/World/Empty")  # fmt: skip
def _():
    stage = base("An empty mesh.")
    UsdGeom.Mesh.Define(stage, "/World/Empty")
    return {"empty_mesh.usda": text(stage)}


@case("points_without_faces", "/World/Bad has points but empty faceVertexCounts: skip it.", 0,
      "faces", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Points but no faces.")
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray())
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray())
    mesh.GetPrim().RemoveProperty("primvars:st")
    mesh.GetPrim().RemoveProperty("normals")
    return {"points_without_faces.usda": text(stage)}


@case("degenerate_triangles", "/World/Bad: a valid plane plus two degenerate faces (a repeated "
      "vertex, three collinear points): drop them with a warning.", 0, "degenerate",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Some degenerate triangles.")
    counts = list(mesh.GetFaceVertexCountsAttr().Get()) + [3, 3]
    idx = list(mesh.GetFaceVertexIndicesAttr().Get()) + [0, 0, 4, 0, 1, 2]  # 0,1,2 collinear
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray(counts))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray(idx))
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    st.Set(Vt.Vec2fArray(list(st.Get()) + [Gf.Vec2f(0.01, 0.01)] * 6))
    mesh.GetNormalsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0, 1, 0)] * len(idx)))
    return {"degenerate_triangles.usda": text(stage)}


@case("tiny_coordinates", "/World/Bad is a 1e-9 m plane standing at the origin (ray offsets "
      "and texel density must scale): bake with a warning, never NaN.", 0, "small",
      prim="/World/Bad")  # fmt: skip
def _():
    # At the origin, so float32 resolves it (at x = 2 it would collapse: see tiny_far).
    stage = base("A nanometre-sized mesh.")
    mesh = plane(stage, "/World/Bad", x=0.0, size=1e-9)
    UsdGeom.Xformable(mesh).AddRotateZOp().Set(90.0)  # stand up: not coplanar with Good
    return {"tiny_coordinates.usda": text(stage)}


@case("tiny_far", "/World/Bad is a 1e-9 m plane at x = 2, where the float32 ulp is 2.4e-7: "
      "beyond ray-tracing precision, the prim fails.", 1, "precision",
      prim="/World/Bad")  # fmt: skip
def _():
    stage, _ = with_bad_plane("A nanometre-sized mesh away from the origin.", size=1e-9)
    return {"tiny_far.usda": text(stage)}


@case("zero_intensity", "The only light has inputs:intensity = 0: bakes black, with a warning.",
      0, "intensity", prim="/World/Lights/Key")  # fmt: skip
def _():
    stage = new_stage("Zero light intensity.")
    plane(stage, "/World/Good")
    key_light(stage, intensity=0.0)
    return {"zero_intensity.usda": text(stage)}


@case("material_texture_missing", "The good plane's diffuseColor texture file does not exist: "
      "use the fallback diffuseColor, with a warning.", 0, "does_not_exist.png")  # fmt: skip
def _():
    stage = base("Material texture missing.")
    shader = material(stage)
    looks = "/World/Looks/Grey"
    reader = UsdShade.Shader.Define(stage, f"{looks}/TexCoordReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, f"{looks}/DiffuseTexture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./does_not_exist.png"))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.ConnectableAPI(), "result"
    )
    out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    shader.GetInput("diffuseColor").ConnectToSource(out)
    return {"material_texture_missing.usda": text(stage)}


@case("albedo_above_one", "/World/Hot has diffuseColor (1.5, 1.5, 1.5): non-physical, energy "
      "would grow with every bounce; clamp below 1 with a warning.", 0, "diffuseColor",
      prim="/World/Looks/Hot")  # fmt: skip
def _():
    stage = base("Albedo above one.")
    material(stage, "Hot", (1.5, 1.5, 1.5))
    plane(stage, "/World/Hot", x=2.0, look="Hot")
    return {"albedo_above_one.usda": text(stage)}


@case("light_shaping_ies", "A SphereLight with UsdLuxShapingAPI (cone 30 deg) and an IES "
      "profile: unsupported, warn and ignore the shaping.", 0, "shaping",
      prim="/World/Lights/Spot")  # fmt: skip
def _():
    stage = base("Light with shaping and IES.")
    light = sphere_light(stage, "/World/Lights/Spot", intensity=20.0)
    shaping = UsdLux.ShapingAPI.Apply(light.GetPrim())
    shaping.CreateShapingConeAngleAttr(30.0)
    shaping.CreateShapingConeSoftnessAttr(0.2)
    shaping.CreateShapingIesFileAttr(Sdf.AssetPath("./spot.ies"))
    return {"light_shaping_ies.usda": text(stage), "spot.ies": IES}


@case("geometry_light", "A GeometryLight (unsupported light type) next to the key light: warn "
      "and ignore it.", 0, "GeometryLight", prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("Unsupported light type.")
    light = UsdLux.GeometryLight.Define(stage, "/World/Lights/Bad")
    light.CreateIntensityAttr(3.0)
    light.CreateGeometryRel().SetTargets([Sdf.Path("/World/Good")])
    return {"geometry_light.usda": text(stage)}


@case("animated_points", "/World/Bad has time-sampled points only (no default value): bake one "
      "time (the start time code) and warn.", 0, "time sample", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Animated points.")
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(2)
    attr = mesh.GetPointsAttr()
    pts = np.array(attr.Get())
    attr.Clear()
    attr.Set(Vt.Vec3fArray.FromNumpy(pts), 1.0)
    attr.Set(Vt.Vec3fArray.FromNumpy(pts + np.float32([0, 0.5, 0])), 2.0)
    return {"animated_points.usda": text(stage)}


@case("nan_normals", "/World/Bad has authored normals containing NaN: ignore them and compute "
      "normals, with a warning.", 0, "normals", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("NaN normals.")
    n = np.array(mesh.GetNormalsAttr().Get())
    n[2] = NAN
    mesh.GetNormalsAttr().Set(Vt.Vec3fArray.FromNumpy(n))
    return {"nan_normals.usda": text(stage)}


@case("up_axis_invalid", "Stage metadata upAxis = \"X\" (only Y or Z are valid): warn, assume Y.",
      0, "upAxis")  # fmt: skip
def _():
    return {"up_axis_invalid.usda": text(base("upAxis X.", up_axis="X"))}


@case("reference_cycle", "reference_cycle.usda references cycle_b.usda, which references "
      "reference_cycle.usda back: USD drops the cyclic arc; an authoring bug, refuse naming it.",
      2, "cycle")  # fmt: skip
def _():
    main_layer = add_reference(text(base("A cycle of references.")), "/World/Ref", "./cycle_b.usda")
    other = text(new_stage("The other half of the reference cycle."))
    other = add_reference(other, "/World", "./reference_cycle.usda")
    return {"reference_cycle.usda": main_layer, "cycle_b.usda": other}


@case("sublayer_cycle", "The root layer lists itself as a sublayer: USD reports the cycle; "
      "refuse naming it, like any composition cycle.", 2, "cycle")  # fmt: skip
def _():
    data = text(base("A layer that sublayers itself."))
    data = edit_layer(data, lambda layer: layer.subLayerPaths.append("./sublayer_cycle.usda"))
    return {"sublayer_cycle.usda": data}


@case("missing_reference", "/World/Ref references a layer that does not exist: warn and bake the "
      "rest.", 0, "nowhere.usda")  # fmt: skip
def _():
    data = add_reference(text(base("A missing reference.")), "/World/Ref", "./nowhere.usda")
    return {"missing_reference.usda": data}


# ---- hostile names: texture file naming must stay inside the output dir and unique ----------
# USD prim names are identifiers (letters, digits, '_', and since 24.x UTF-8 XID characters),
# so a prim path itself can never contain '.', '..' or an extra '/'. What a file naming
# scheme based on prim paths CAN be tricked by: (1) joining components with '_' makes
# /World/A/B_C, /World/A_B/C and /World/A_B_C collide; (2) names that differ only in case
# collide on macOS/Windows file systems; (3) long names (USD has no length limit) exceed the
# 255-byte file-name limit, also as UTF-8 multi-byte text; (4) schemes that prefer
# displayName / assetInfo / customData strings can be fed '../' from there.


@case("name_collision", "Meshes /World/A/B_C, /World/A_B/C and /World/A_B_C: a '/'->'_' naming "
      "scheme gives them one texture name.", 0, None, check="distinct_texture_names")  # fmt: skip
def _():
    stage = base("Prim paths that collide after '/' -> '_' sanitization.")
    for i, path in enumerate(("/World/A/B_C", "/World/A_B/C", "/World/A_B_C")):
        plane(stage, path, x=2.0 * (i + 1))
    return {"name_collision.usda": text(stage)}


@case("case_collision", "Meshes /World/Wall and /World/wall: distinct on Linux, one file on "
      "macOS/Windows.", 0, None, check="distinct_texture_names")  # fmt: skip
def _():
    stage = base("Prim names that differ only in case.")
    plane(stage, "/World/Wall", x=2.0)
    plane(stage, "/World/wall", x=4.0)
    return {"case_collision.usda": text(stage)}


@case("long_names", "A mesh under three nested 200-character prim names (path > 600 chars).", 0,
      None, check="texture_names_fit")  # fmt: skip
def _():
    stage = base("Very long prim names.")
    names = ["L" * 199 + "1", "L" * 199 + "2", "M" * 200]
    plane(stage, "/World/" + "/".join(names), x=2.0)
    return {"long_names.usda": text(stage)}


@case("unicode_names", "UTF-8 prim names: /World/Stüdio_墙 and a 100-character name of '墙' "
      "(300 bytes in UTF-8).", 0, None, check="texture_names_fit")  # fmt: skip
def _():
    stage = base("UTF-8 prim names.")
    plane(stage, "/World/Stüdio_墙", x=2.0)
    plane(stage, "/World/" + "墙" * 100, x=4.0)
    return {"unicode_names.usda": text(stage)}


@case("display_name_escape", "/World/Evil has displayName, assetInfo:name and customData "
      "strings of '../../../../tmp/usdahd_escape': must not reach any file path.", 0, None,
      check="inside_output_dir")  # fmt: skip
def _():
    stage = base("Path-like metadata on a prim.")
    prim = plane(stage, "/World/Evil", x=2.0).GetPrim()
    evil = "../../../../tmp/usdahd_escape"
    prim.SetDisplayName(evil)
    Usd.ModelAPI(prim).SetAssetName(evil)
    prim.SetCustomDataByKey("name", evil)
    return {"display_name_escape.usda": text(stage)}


# ---- valid but easy to get wrong: must bake cleanly -----------------------------------------


@case("mirrored_transform", "/World/Bad has xformOp:scale = (-1, 1, 1): winding flips; valid, "
      "must bake without warnings.", 0, None, check="no_warning")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Mirrored transform.")
    UsdGeom.Xformable(mesh).AddScaleOp().Set(Gf.Vec3f(-1, 1, 1))
    return {"mirrored_transform.usda": text(stage)}


@case("left_handed", "/World/Bad has orientation = leftHanded with reversed winding; valid, "
      "must bake without warnings.", 0, None, check="no_warning")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("leftHanded orientation.")
    counts = list(mesh.GetFaceVertexCountsAttr().Get())
    idx = np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 4)[:, ::-1]
    st = np.array(UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Get()).reshape(-1, 4, 2)[:, ::-1]
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(idx.reshape(-1).astype(np.int32)))
    UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").Set(Vt.Vec2fArray.FromNumpy(st.reshape(-1, 2)))
    mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    assert counts == [4] * 4
    return {"left_handed.usda": text(stage)}


# ---- issue 18: more kinds of bad input ------------------------------------------------------


def _area_light(stage, kind: str, **attrs):
    cls = {"rect": UsdLux.RectLight, "disk": UsdLux.DiskLight, "sphere": UsdLux.SphereLight}[kind]
    light = cls.Define(stage, "/World/Lights/Bad")
    light.CreateIntensityAttr(5.0)
    light.CreateExposureAttr(0.0)
    light.CreateColorAttr(Gf.Vec3f(1, 1, 1))
    light.CreateNormalizeAttr(False)
    for name, value in attrs.items():
        getattr(light, f"Create{name}Attr")(value)
    UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 1.5, 0))
    UsdGeom.Xformable(light).AddRotateXYZOp().Set(Gf.Vec3f(-90, 0, 0))
    return light


@case("nan_sphere_radius", "A SphereLight with inputs:radius = NaN.", 2, "radius",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("NaN sphere radius.")
    _area_light(stage, "sphere", Radius=NAN)
    return {"nan_sphere_radius.usda": text(stage)}


@case("nan_rect_width", "A RectLight with inputs:width = NaN.", 2, "width",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("NaN rect width.")
    _area_light(stage, "rect", Width=NAN, Height=0.5)
    return {"nan_rect_width.usda": text(stage)}


@case("inf_disk_radius", "A DiskLight with inputs:radius = +Inf.", 2, "radius",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("Inf disk radius.")
    _area_light(stage, "disk", Radius=INF)
    return {"inf_disk_radius.usda": text(stage)}


@case("negative_rect_height", "A RectLight with inputs:height = -1.", 2, "height",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("Negative rect height.")
    _area_light(stage, "rect", Width=0.5, Height=-1.0)
    return {"negative_rect_height.usda": text(stage)}


@case("exposure_minus_1000", "A SphereLight with inputs:exposure = -1000 (2^-1000 is 0 in "
      "float32): it emits nothing; bake with a warning naming exposure.", 0, "exposure",
      prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("Exposure -1000.")
    sphere_light(stage, exposure=-1000.0)
    return {"exposure_minus_1000.usda": text(stage)}


@case("string_light_input", "A SphereLight whose inputs:intensity is authored as a string.",
      2, "intensity", prim="/World/Lights/Bad")  # fmt: skip
def _():
    stage = base("String-typed light input.")
    sphere_light(stage, intensity=5.0)
    data = text(stage)
    assert data.count(b"float inputs:intensity = 5") == 1
    return {
        "string_light_input.usda": data.replace(
            b"float inputs:intensity = 5", b'string inputs:intensity = "bright"'
        )
    }


@case("negative_emissive_scale", "The good plane's emissiveColor comes from a texture with "
      "inputs:scale = (-1, -1, -1, 1): negative emission; refuse naming the shader.", 2,
      "scale", prim="/World/Looks/Grey")  # fmt: skip
def _():
    stage = base("Negative emissive texture scale.")
    shader = material(stage)
    looks = "/World/Looks/Grey"
    tex = UsdShade.Shader.Define(stage, f"{looks}/GlowTexture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./glow.png"))
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 1))
    out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(out)
    return {"negative_emissive_scale.usda": text(stage), "glow.png": png_bytes()}


@case("binding_missing_material", "/World/Bad's material:binding targets "
      "/World/Looks/Nope, which does not exist: bake with the default material and a "
      "warning.", 0, "material", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Binding to a missing material.")
    mesh.GetPrim().GetRelationship("material:binding").SetTargets(["/World/Looks/Nope"])
    return {"binding_missing_material.usda": text(stage)}


@case("binding_to_non_material", "/World/Bad's material:binding targets an Xform: bake with "
      "the default material and a warning.", 0, "material", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Binding to a prim that is not a Material.")
    UsdGeom.Xform.Define(stage, "/World/Looks/NotAMaterial")
    mesh.GetPrim().GetRelationship("material:binding").SetTargets(["/World/Looks/NotAMaterial"])
    return {"binding_to_non_material.usda": text(stage)}


@case("uv_element_size_2", "/World/Bad's st primvar has elementSize 2 (two UVs per corner).",
      1, "elementSize", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("UV primvar with elementSize 2.")
    UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").SetElementSize(2)
    return {"uv_element_size_2.usda": text(stage)}


@case("faces_with_holes", "/World/Bad authors holeIndices = [0]: the hole is not baked, with "
      "a warning.", 0, "hole", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Faces with holes.")
    mesh.CreateHoleIndicesAttr(Vt.IntArray([0]))
    return {"faces_with_holes.usda": text(stage)}


@case("huge_meters_per_unit", "metersPerUnit = 1e15 and /World/Bad authors "
      "ahdLightmap:texelDensity = 16 (per metre): its lightmap would have ~1e32 texels; the "
      "message names metersPerUnit.", 1, "metersPerUnit", prim="/World/Bad")  # fmt: skip
def _():
    stage, mesh = with_bad_plane("Huge metersPerUnit.")
    stage.SetMetadata("metersPerUnit", 1e15)
    for path in ("/World/Good", "/World/Bad"):
        stage.GetPrimAtPath(path).AddAppliedSchema("AhdLightmapAPI")
    attr = mesh.GetPrim().CreateAttribute(
        "ahdLightmap:texelDensity", Sdf.ValueTypeNames.Float, False, Sdf.VariabilityUniform
    )
    attr.Set(16.0)
    return {"huge_meters_per_unit.usda": text(stage)}


@case("api_on_xform", "AhdLightmapAPI applied (by hand) to the Xform /World and to no mesh.",
      2, "not a Mesh", prim="/World")  # fmt: skip
def _():
    stage = base("AhdLightmapAPI on an Xform.")
    stage.GetPrimAtPath("/World").AddAppliedSchema("AhdLightmapAPI")
    return {"api_on_xform.usda": text(stage)}


@case("output_layer_as_input", "An override layer written by usdahd bake passed as the stage "
      "(x.lightmaps.usda): refuse instead of writing x.lightmaps.lightmaps.usda.", 2,
      "output layer")  # fmt: skip
def _():
    data = edit_layer(
        valid_text(),
        lambda layer: setattr(
            layer,
            "documentation",
            "Directional lightmaps baked by usdahd 0.0 for x.usda; regenerate with usdahd bake.",
        ),
    )
    # (not named *.lightmaps.usda: git ignores those; the refusal reads the layer's doc)
    return {"output_layer_as_input.usda": data}


@case("non_utf8_string", "A string attribute and the layer doc hold bytes that are not "
      "UTF-8 (Latin-1 'caf\\xe9'): USD cannot read it; one message naming the line.", 2,
      "UTF-8", opens=False)  # fmt: skip
def _():
    stage = base("Non-UTF-8 string values: PLACEHOLDER.")
    stage.GetPrimAtPath("/World/Good").CreateAttribute("userNote", Sdf.ValueTypeNames.String).Set(
        "PLACEHOLDER"
    )
    return {"non_utf8_string.usda": text(stage).replace(b"PLACEHOLDER", b"caf\xe9")}


@case("non_utf8_prim_name", "A prim name with a byte that is not UTF-8 (\\xff).", 2,
      "UTF-8", opens=False)  # fmt: skip
def _():
    data = valid_text().replace(b'def Mesh "Good"', b'def Mesh "Go\xffod"', 1)
    return {"non_utf8_prim_name.usda": data}


@case("texture_is_directory", "The good plane's diffuseColor texture path names a directory: "
      "use the fallback diffuseColor, with a warning.", 0, "not a regular file")  # fmt: skip
def _():
    stage = base("Material texture is a directory.")
    shader = material(stage)
    looks = "/World/Looks/Grey"
    tex = UsdShade.Shader.Define(stage, f"{looks}/DiffuseTexture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./"))
    out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    shader.GetInput("diffuseColor").ConnectToSource(out)
    return {"texture_is_directory.usda": text(stage)}


# ---- issue 18: defects of the surroundings (see ``setup``) -----------------------------------


for _id, _setup, _code, _msg, _desc in [
    ("lightmaps_is_file", "lightmaps_file", 2, "a file where the lightmaps folder goes",
     "A regular file named lightmaps where the textures folder goes."),
    ("lightmaps_dangling_symlink", "lightmaps_dangling_symlink", 2, "dangling",
     "lightmaps is a symbolic link to a folder that does not exist."),
    ("readonly_lightmaps", "readonly_lightmaps", 2, "writable",
     "The lightmaps folder is read-only (a read-only mount)."),
    ("output_is_directory", "output_is_directory", 2, "is a directory",
     "A folder sits where the output layer goes."),
    ("readonly_layer", "readonly_layer", 2, "read-only",
     "The existing output layer has no write permission."),
    ("non_utf8_name", "non_utf8_name", 2, "not valid UTF-8",
     "The stage's file name holds a byte that is not UTF-8."),
]:  # fmt: skip
    case(_id, _desc + " Refused before tracing.", _code, _msg, setup=_setup)(
        lambda _id=_id: {f"{_id}.usda": valid_text()}
    )


@case("fifo_texture", "The good plane's diffuseColor texture pipe.png is a FIFO (created by "
      "the test): refused as not a regular file instead of blocking the bake.", 0,
      "not a regular file", setup="fifo_texture")  # fmt: skip
def _():
    stage = base("Material texture is a FIFO.")
    shader = material(stage)
    tex = UsdShade.Shader.Define(stage, "/World/Looks/Grey/DiffuseTexture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./pipe.png"))
    out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    shader.GetInput("diffuseColor").ConnectToSource(out)
    return {"fifo_texture.usda": text(stage)}


# --------------------------------------------------------------------------------------------
# Aux data
# --------------------------------------------------------------------------------------------

IES = b"""IESNA:LM-63-2002
[TEST] usdahd bad-stage corpus: a small valid photometric file
TILT=NONE
1 1000 1 3 1 1 2 0.1 0.1 0
1 1 100
0 45 90
0
1000 500 0
"""


def png_bytes() -> bytes:
    """A valid 4x4 RGB PNG written by OpenImageIO (deterministic for one OIIO version)."""
    import tempfile

    import OpenImageIO as oiio

    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "x.png")
        out = oiio.ImageOutput.create(path)
        out.open(path, oiio.ImageSpec(4, 4, 3, "uint8"))
        out.write_image(np.full((4, 4, 3), 200, np.uint8))
        out.close()
        return Path(path).read_bytes()


# --------------------------------------------------------------------------------------------
# Self-check and manifest
# --------------------------------------------------------------------------------------------


def opens(path: Path) -> bool:
    try:
        return bool(Usd.Stage.Open(str(path)))
    except Exception:  # pxr raises Tf.ErrorException for unreadable layers
        return False


def write_all(out: Path) -> list[dict]:
    out.mkdir(parents=True, exist_ok=True)
    by_file: dict[str, dict] = {}
    manifest = []
    for c in CASES:
        entry = {k: v for k, v in c.items() if not k.startswith("_")}
        build = c["_build"]
        files = build() if build else {}
        if files:
            names = list(files)
            assert names[0] == entry["file"], (names[0], entry["file"])
            entry["aux"] = names[1:]
            for name, data in files.items():
                (out / name).write_bytes(data)
            by_file[entry["file"]] = entry
        elif entry["file"] in by_file:  # a case that reuses another case's file
            entry["aux"] = by_file[entry["file"]]["aux"]
        manifest.append(entry)
    for entry in manifest:  # verify the claims the manifest makes
        path = out / entry["file"]
        assert path.exists() == entry["exists"], entry["id"]
        if entry["exists"]:
            assert opens(path) == entry["opens"], (entry["id"], "opens")
    return manifest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE, help="output folder (default: here)")
    args = parser.parse_args(argv)
    cases = write_all(args.out)
    doc = {
        "format": 1,
        "matching": "message and prim are case-insensitive substrings of the bake's stderr "
        "(or of the --json report's errors/warnings); exit_code is the process status",
        "generator": "tests/data/bad_stages/make_bad_stages.py",
        "cases": cases,
    }
    text = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
    (args.out / "cases.json").write_text(text, encoding="utf-8")
    print(f"wrote {len(cases)} cases to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
