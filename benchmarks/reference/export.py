"""Export a USD stage into a self-contained scene file for the Cycles reference bake.

Runs in the project environment (pxr, numpy, OpenImageIO); the Cycles side
(``cycles_bake.py``) reads only numpy and json. Everything the reference needs is read here
with pxr directly, **independently of the ``usdahd/usd/`` readers**, so the reference does not
share the baker's interpretation of UsdLux and UsdPreviewSurface:

- geometry: every visible, active ``UsdGeom.Mesh`` (render/default purpose, instance proxies
  included), triangulated as fans, in world space, wound counter-clockwise about its front
  (``orientation`` and mirroring transforms taken into account);
  coincident opposite-facing faces (a doubled sheet) moved 0.5 mm apart, which Cycles needs
  to shade them (``twins.py``);
- normals per corner: ``primvars:normals`` or ``normals`` (any interpolation) transformed by
  the inverse transpose; without authored normals, ``subdivisionScheme = "none"`` meshes get
  a crease-angle rule decided per pair of faces (a corner averages, weighted by corner angle,
  the faces around its point whose normal is within ``crease_deg`` of its own face's), other
  schemes (including the catmullClark fallback) a full smooth average;
- lightmap UVs (the named primvar, any interpolation, indexed or not) and resolution for each
  baked mesh;
- materials: UsdPreviewSurface ``diffuseColor`` (constant or a ``UsdUVTexture`` read through a
  ``UsdPrimvarReader_float2``) and ``emissiveColor``; ``displayColor`` or 0.18 grey without a
  material; ``doubleSided`` (emission is one-sided unless it is set);
- lights in radiometric terms (radiance L in W/(m^2 sr) per RGB channel):
  ``L = intensity * 2^exposure * color`` (times blackbody colour when enabled);
  ``normalize`` divides area lights by their world-space area (sphere 4 pi r^2, rect w h, disk
  pi r^2) and makes a DistantLight's intensity its illuminance at normal incidence;
  an unnormalized DistantLight of angular radius a has illuminance ``L pi sin^2 a``;
  ``treatAsPoint`` / zero radius SphereLights become point lights of radiant intensity
  ``I = L pi r^2`` (``I = L`` for radius 0); DomeLight colour or latlong texture (resampled
  into Blender's equirectangular convention here, so the Cycles side needs no image I/O).

The scene file is one ``.npz`` (arrays + a ``meta`` JSON string); see :func:`save_scene`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.reference.npzio import save_npz
from benchmarks.reference.twins import TWIN_GAP, separate_twins

#: Crease angle (degrees) for meshes without authored normals and subdivisionScheme "none".
CREASE_DEG = 30.0
#: UsdPreviewSurface fallback diffuseColor (also used without any material).
DEFAULT_ALBEDO = (0.18, 0.18, 0.18)
#: Rows of the resampled equirectangular dome map (width = 2 x rows).
DOME_ROWS = 256
#: Scene file format version (bump when the layout changes; part of the cache key).
FORMAT = 1


class ExportError(Exception):
    """The stage cannot be exported for the reference (message names prim/file and the fix)."""


@dataclass
class Scene:
    """A stage flattened for Cycles.

    tri_p : (t, 3, 3) float64 world-space corners (counter-clockwise about the front);
    tri_n : (t, 3, 3) float64 unit shading normals per corner;
    tri_uv : (t, 3, 2) float64 lightmap UVs (NaN on meshes that are not baked);
    tri_tuv : (t, 3, 2) float64 texture UVs of the material's texture (0 when untextured);
    tri_mesh : (t,) int32 mesh index; tri_mat : (t,) int32 material index.
    meshes : [{"path", "baked", "resolution": [w, h], "uv"}]; materials : [{"name", "albedo",
    "emission", "texture", "texture_srgb", "double_sided"}]; lights : [{"type", "path", ...}];
    dome : (rows, 2 rows, 3) float32 Blender-convention equirect map or None; dome_color :
    [r, g, b] or None. warnings : [str].
    """

    tri_p: np.ndarray
    tri_n: np.ndarray
    tri_uv: np.ndarray
    tri_tuv: np.ndarray
    tri_mesh: np.ndarray
    tri_mat: np.ndarray
    meshes: list
    materials: list
    lights: list
    dome: np.ndarray | None = None
    dome_color: list | None = None
    warnings: list = field(default_factory=list)
    source: str = ""

    def meta(self) -> dict:
        return {
            "format": FORMAT,
            "meshes": self.meshes,
            "materials": self.materials,
            "lights": self.lights,
            "dome_color": self.dome_color,
            "has_dome_map": self.dome is not None,
            "warnings": self.warnings,
            "source": self.source,
        }

    def digest(self) -> str:
        """sha256 of everything Cycles sees (not the source path or warnings)."""
        h = hashlib.sha256()
        for a in (self.tri_p, self.tri_n, self.tri_uv, self.tri_tuv, self.tri_mesh, self.tri_mat):
            h.update(np.ascontiguousarray(a).tobytes())
        if self.dome is not None:
            h.update(np.ascontiguousarray(self.dome).tobytes())
        meta = self.meta()
        meta.pop("warnings")
        meta.pop("source")
        for m in meta["materials"]:  # a texture's content, not its path
            for key in ("texture", "opacity_texture", "metallic_texture", "emission_texture"):
                if m.get(key):
                    h.update(Path(m[key]).read_bytes())
        h.update(json.dumps(meta, sort_keys=True).encode())
        return h.hexdigest()


# ------------------------------------------------------------------------------ helpers


def _get(attr, default=None, time=None):
    from pxr import Usd

    if not attr or not attr.HasValue():
        return default
    v = attr.Get(Usd.TimeCode.Default() if time is None else time)
    return default if v is None else v


def _corner_values(pv_values, interp: str, fv_index, face_of_fv, n_points, what: str):
    """Values per face-vertex (n_fv, k) from a primvar of any interpolation."""
    vals = np.asarray(pv_values, np.float64)
    if vals.ndim == 1:
        vals = vals[:, None]
    n_fv = len(fv_index)
    if interp == "constant":
        if len(vals) < 1:
            raise ExportError(f"{what}: constant primvar has no value")
        return np.broadcast_to(vals[:1], (n_fv, vals.shape[1])).copy()
    if interp == "uniform":
        need, idx = face_of_fv.max() + 1 if n_fv else 0, face_of_fv
    elif interp in ("vertex", "varying"):
        need, idx = n_points, fv_index
    elif interp == "faceVarying":
        need, idx = n_fv, np.arange(n_fv)
    else:
        raise ExportError(f"{what}: unknown interpolation {interp!r}")
    if len(vals) < need:
        raise ExportError(
            f"{what}: {interp} primvar has {len(vals)} values, needs {need}; fix the primvar"
        )
    return vals[idx]


def _primvar_corners(pv, fv_index, face_of_fv, n_points, what, time=None):
    from pxr import Usd

    vals = pv.ComputeFlattened(Usd.TimeCode.Default() if time is None else time)
    if vals is None:
        return None
    return _corner_values(vals, pv.GetInterpolation(), fv_index, face_of_fv, n_points, what)


def _tri_normal(p: np.ndarray) -> np.ndarray:
    """(t, 3, 3) corners -> (t, 3) unnormalized counter-clockwise normals (2 x area)."""
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 0, v / np.where(n > 0, n, 1), 0.0)


def computed_normals(
    points: np.ndarray, counts: np.ndarray, fv_index: np.ndarray, crease_deg: float
) -> np.ndarray:
    """Per face-vertex unit normals of a polygon mesh without authored normals.

    points : (v, 3) world-space; counts : (f,); fv_index : (n_fv,) point ids, faces
    counter-clockwise about the front. A corner of face f at point p averages the normals of
    the faces around p whose normal is within ``crease_deg`` of face f's, weighted by their
    corner angle at p (180: a full smooth average; 0: flat faces).
    returns : (n_fv, 3) float64.
    """
    points = np.asarray(points, np.float64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    face_of = np.repeat(np.arange(len(counts)), counts)
    # Newell normal per polygon (robust for non-planar quads).
    nxt = np.arange(len(fv_index)) + 1
    last = starts + counts - 1
    nxt[last] = starts
    prv = np.arange(len(fv_index)) - 1
    prv[starts] = last
    a, b = points[fv_index], points[fv_index[nxt]]
    cr = np.cross(a, b)
    fn = np.zeros((len(counts), 3))
    np.add.at(fn, face_of, cr)
    fn = _unit(fn)
    # Corner angle of each face-vertex.
    e1 = _unit(points[fv_index[nxt]] - a)
    e2 = _unit(points[fv_index[prv]] - a)
    ang = np.arccos(np.clip((e1 * e2).sum(-1), -1, 1))
    cos_c = math.cos(math.radians(min(max(crease_deg, 0.0), 180.0))) - 1e-9
    out = np.zeros((len(fv_index), 3))
    order = np.argsort(fv_index, kind="stable")
    bounds = np.flatnonzero(np.diff(fv_index[order])) + 1
    for group in np.split(order, bounds):
        fnorm = fn[face_of[group]]
        w = ang[group][:, None] * fnorm
        close = fnorm @ fnorm.T >= cos_c  # (k, k): faces within the crease of each other
        out[group] = close.astype(np.float64) @ w
    bad = np.linalg.norm(out, axis=1) == 0
    out[bad] = fn[face_of[bad]]
    return _unit(out)


# ----------------------------------------------------------------------------- materials


def _input_source(inp):
    """(shader prim, output name) feeding a UsdShade input, or None."""
    if not inp or not inp.HasConnectedSource():
        return None
    src = inp.GetConnectedSource()
    if not src:
        return None
    return src[0].GetPrim(), str(src[1])


def _uv_texture(tex) -> tuple[str, bool, str]:
    """(resolved file, sRGB?, UV primvar name) of a UsdUVTexture shader; ExportError when the
    file does not resolve or its ``st`` is not read from a named primvar."""
    from pxr import Sdf, UsdShade

    f = tex.GetInput("file")
    asset = f.Get() if f else None
    path = asset.resolvedPath if isinstance(asset, Sdf.AssetPath) else ""
    if not path or not os.path.isfile(path):
        raise ExportError(
            f"{tex.GetPath()}: texture file {asset} does not resolve; fix inputs:file"
        )
    cs = tex.GetInput("sourceColorSpace")
    cs = str(cs.Get()) if cs and cs.Get() else "auto"
    srgb = cs == "sRGB" or (cs == "auto" and Path(path).suffix.lower() in (".png", ".jpg"))
    st = _input_source(tex.GetInput("st"))
    varname = None
    if st is not None:
        reader = UsdShade.Shader(st[0])
        vn = reader.GetInput("varname") if reader else None
        varname = str(vn.Get()) if vn and vn.Get() is not None else None
    if varname is None:
        raise ExportError(
            f"{tex.GetPath()}: inputs:st is not fed by a UsdPrimvarReader_float2 with a "
            "varname; the reference needs the texture's UV primvar"
        )
    return path, bool(srgb), varname


def _channel_texture(inp, out: dict, name: str, what: str, warn):
    """(file, channel, sRGB?) of a UsdUVTexture output feeding ``inp``, or None (with a
    warning naming ``what`` when it cannot be used: not a UsdUVTexture, or another UV primvar
    than the material's other textures, since the reference has one texture UV per material)."""
    from pxr import UsdShade

    src = _input_source(inp)
    if src is None:
        return None
    tex = UsdShade.Shader(src[0])
    channel = str(src[1])
    if not (tex and tex.GetIdAttr().Get() == "UsdUVTexture") or channel not in (
        "r",
        "g",
        "b",
        "a",
        "rgb",
    ):
        warn(f"{name}: {what} is fed by {src[0].GetPath()}.{channel}, not a UsdUVTexture "
             "output; ignored by the reference")  # fmt: skip
        return None
    path, srgb, varname = _uv_texture(tex)
    if out["texture_uv"] not in (None, varname):
        warn(f"{name}: {what} texture reads primvar {varname!r}, another texture of the "
             f"material {out['texture_uv']!r}; {what} ignored by the reference")  # fmt: skip
        return None
    out["texture_uv"] = varname
    return path, channel, srgb


def _read_opacity(shader, out: dict, name: str, warn) -> None:
    """UsdPreviewSurface ``opacity`` / ``opacityThreshold`` into ``out`` as usdahd reads them
    (usdahd/bake/kernels/trace.py ``nb_transmits``): with a threshold > 0 a hit whose opacity
    is below it is a cut-out (rays pass), else a hit transmits with probability 1 - opacity."""
    thr = shader.GetInput("opacityThreshold")
    out["opacity_threshold"] = float(thr.Get()) if thr and thr.Get() is not None else 0.0
    op = shader.GetInput("opacity")
    if _input_source(op) is None:
        if op and op.Get() is not None:
            out["opacity"] = min(max(float(op.Get()), 0.0), 1.0)
        return
    got = _channel_texture(op, out, name, "opacity", warn)
    if got is not None:
        out.update(opacity_texture=got[0], opacity_channel=got[1])


def _read_metallic(shader, out: dict, name: str, warn) -> None:
    """The metallic workflow has no diffuse lobe on metal: the diffuse albedo is
    diffuseColor x (1 - metallic), as usdahd reads it (docs/usd-semantics.md), constant or
    textured. The reference renders the same diffuse transport; the specular bounce off
    metal is in neither."""
    spec = shader.GetInput("useSpecularWorkflow")
    met = shader.GetInput("metallic")
    if (spec and spec.Get()) or not met:
        return
    if _input_source(met) is not None:
        got = _channel_texture(met, out, name, "metallic", warn)
        if got is not None:
            out.update(metallic_texture=got[0], metallic_channel=got[1], metallic_srgb=got[2])
    elif met.Get() is not None and float(met.Get()) != 0.0:
        m = min(max(float(met.Get()), 0.0), 1.0)
        if out["texture"] is not None:
            out["albedo_scale"] = 1.0 - m  # applied to the texture in the Cycles material
        else:
            out["albedo"] = [a * (1.0 - m) for a in out["albedo"]]


def _read_material(material, name: str, warn) -> dict:
    """UsdPreviewSurface parameters of a material as plain data."""
    from pxr import UsdShade

    out = {
        "name": name,
        "albedo": list(DEFAULT_ALBEDO),
        "emission": [0.0, 0.0, 0.0],
        "texture": None,
        "texture_srgb": True,
        "texture_uv": None,
        "double_sided": False,
        "opacity": 1.0,
        "opacity_texture": None,
        "opacity_channel": "a",
        "opacity_threshold": 0.0,
    }
    surface = material.ComputeSurfaceSource()
    shader = surface[0] if surface else None
    if not shader:
        warn(f"{name}: no surface shader; albedo {DEFAULT_ALBEDO}")
        return out
    sid = shader.GetIdAttr().Get() if shader.GetIdAttr() else None
    if sid != "UsdPreviewSurface":
        warn(f"{name}: surface shader {sid!r} is not UsdPreviewSurface; albedo {DEFAULT_ALBEDO}")
        return out
    dc = shader.GetInput("diffuseColor")
    src = _input_source(dc)
    if src is not None:
        tex = UsdShade.Shader(src[0])
        if tex and tex.GetIdAttr().Get() == "UsdUVTexture":
            path, srgb, varname = _uv_texture(tex)
            for k in ("scale", "bias"):
                i = tex.GetInput(k)
                if (
                    i
                    and i.Get() is not None
                    and tuple(i.Get())[:3] != ((1, 1, 1), (0, 0, 0))[k == "bias"]
                ):
                    warn(f"{tex.GetPath()}: inputs:{k} on a diffuse texture ignored")
            out.update(texture=path, texture_srgb=bool(srgb), texture_uv=varname)
        else:
            warn(f"{name}: diffuseColor is fed by a non-UsdUVTexture shader; fallback used")
    elif dc and dc.Get() is not None:
        out["albedo"] = [float(x) for x in dc.Get()]
    _read_metallic(shader, out, name, warn)
    _read_opacity(shader, out, name, warn)
    ec = shader.GetInput("emissiveColor")
    if _input_source(ec) is not None:
        got = _channel_texture(ec, out, name, "emissiveColor", warn)
        if got is not None and got[1] != "rgb":
            warn(f"{name}: emissiveColor fed by a single channel ({got[1]}); ignored by the "
                 "reference")  # fmt: skip
        elif got is not None:
            out.update(emission_texture=got[0], emission_srgb=got[2])
    elif ec and ec.Get() is not None:
        out["emission"] = [float(x) for x in ec.Get()]
    return out


# ------------------------------------------------------------------------------- lights


def _light_radiance(prim, warn) -> np.ndarray | None:
    """``intensity * 2^exposure * color`` (x blackbody) of a light, (3,) float64, or None."""
    from pxr import UsdLux

    api = UsdLux.LightAPI(prim)
    intensity = float(_get(api.GetIntensityAttr(), 1.0))
    exposure = float(_get(api.GetExposureAttr(), 0.0))
    color = np.array(_get(api.GetColorAttr(), (1.0, 1.0, 1.0)), np.float64)
    rad = intensity * 2.0**exposure * color
    if _get(api.GetEnableColorTemperatureAttr(), False):
        t = float(_get(api.GetColorTemperatureAttr(), 6500.0))
        rad = rad * np.array(UsdLux.BlackbodyTemperatureAsRgb(t), np.float64)
    diffuse = float(_get(api.GetDiffuseAttr(), 1.0))
    if diffuse != 1.0:
        rad = rad * diffuse
    if not np.all(np.isfinite(rad)) or np.any(rad < 0):
        raise ExportError(f"{prim.GetPath()}: light radiance {rad.tolist()} is not finite/>= 0")
    if prim.HasAPI(UsdLux.ShapingAPI):
        sh = UsdLux.ShapingAPI(prim)
        if float(_get(sh.GetShapingConeAngleAttr(), 90.0)) < 90.0 or _get(
            sh.GetShapingFocusAttr(), 0.0
        ):
            warn(f"{prim.GetPath()}: ShapingAPI cone/focus ignored by the reference")
    return rad if np.any(rad > 0) else None


def _frame(m4: np.ndarray):
    """World rotation (3, 3) rows = unit local axes, their lengths, translation, from a USD
    row-vector matrix (p_world = p_local @ m3 + t)."""
    m3, t = m4[:3, :3], m4[3, :3]
    lengths = np.linalg.norm(m3, axis=1)
    if np.any(lengths <= 0):
        return None, lengths, t
    return m3 / lengths[:, None], lengths, t


def _lights(stage, xf, warn) -> tuple[list, np.ndarray | None, list | None]:
    from pxr import Usd, UsdGeom, UsdLux

    lights, dome_map, dome_color = [], None, None
    up = str(UsdGeom.GetStageUpAxis(stage))
    for prim in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies()):
        if not prim.HasAPI(UsdLux.LightAPI):
            continue
        img = UsdGeom.Imageable(prim)
        if img and img.ComputeVisibility() == UsdGeom.Tokens.invisible:
            continue
        path = str(prim.GetPath())
        rad = _light_radiance(prim, warn)
        if rad is None:
            continue
        api = UsdLux.LightAPI(prim)
        normalize = bool(_get(api.GetNormalizeAttr(), False))
        m4 = np.array(xf.GetLocalToWorldTransform(prim), np.float64)
        rot, lengths, t = _frame(m4)
        if rot is None:
            warn(f"{path}: zero scale; light ignored")
            continue
        if prim.IsA(UsdLux.SphereLight):
            lt = UsdLux.SphereLight(prim)
            r = float(_get(lt.GetRadiusAttr(), 0.5)) * float(lengths.mean())
            if normalize and r > 0:
                rad = rad / (4 * math.pi * r * r)
            if _get(lt.GetTreatAsPointAttr(), False) or r <= 0:
                inten = rad * math.pi * r * r if r > 0 else rad
                lights.append({"type": "point", "path": path, "position": t.tolist(),
                               "intensity": inten.tolist()})  # fmt: skip
            else:
                lights.append({"type": "sphere", "path": path, "position": t.tolist(),
                               "radius": r, "radiance": rad.tolist()})  # fmt: skip
        elif prim.IsA(UsdLux.RectLight) or prim.IsA(UsdLux.DiskLight):
            if prim.IsA(UsdLux.RectLight):
                lt = UsdLux.RectLight(prim)
                w = float(_get(lt.GetWidthAttr(), 1.0)) * lengths[0]
                h = float(_get(lt.GetHeightAttr(), 1.0)) * lengths[1]
                area, kind = w * h, "rect"
                if _get(lt.GetTextureFileAttr()):
                    warn(f"{path}: RectLight texture ignored by the reference (uniform)")
            else:
                lt = UsdLux.DiskLight(prim)
                r = float(_get(lt.GetRadiusAttr(), 0.5))
                w, h = 2 * r * lengths[0], 2 * r * lengths[1]
                area, kind = math.pi * w * h / 4, "disk"
                if abs(w - h) > 1e-6 * max(w, h):
                    warn(f"{path}: non-uniform scale on a DiskLight (an ellipse); kept")
            if area <= 0:
                warn(f"{path}: zero-area light ignored")
                continue
            if normalize:
                rad = rad / area
            # Blender's area light emits along its local -Z, sizes along local X, Y: as UsdLux.
            lights.append({"type": kind, "path": path, "position": t.tolist(),
                           "rotation": rot.tolist(), "size": [w, h], "area": area,
                           "radiance": rad.tolist()})  # fmt: skip
        elif prim.IsA(UsdLux.DistantLight):
            lt = UsdLux.DistantLight(prim)
            angle = float(_get(lt.GetAngleAttr(), 0.53))
            half = math.radians(min(max(angle, 0.0), 180.0)) / 2
            if normalize or half == 0:
                if half == 0 and not normalize:
                    warn(f"{path}: DistantLight angle 0 without normalize: intensity taken as "
                         "illuminance")  # fmt: skip
                illum = rad
            else:
                illum = rad * math.pi * math.sin(half) ** 2
            lights.append({"type": "distant", "path": path, "rotation": rot.tolist(),
                           "direction": (-rot[2]).tolist(), "angle": 2 * half,
                           "illuminance": illum.tolist()})  # fmt: skip
        elif prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
            if dome_map is not None or dome_color is not None:
                warn(f"{path}: a second DomeLight is ignored by the reference")
                continue
            lt = UsdLux.DomeLight(prim) if prim.IsA(UsdLux.DomeLight) else UsdLux.DomeLight_1(prim)
            pole = "Y"
            if prim.IsA(UsdLux.DomeLight_1):
                pa = str(_get(lt.GetPoleAxisAttr(), "scene"))
                pole = up if pa == "scene" else pa
            tex = _get(lt.GetTextureFileAttr())
            if tex is not None and tex.path:
                if not tex.resolvedPath or not os.path.isfile(tex.resolvedPath):
                    raise ExportError(f"{path}: dome texture {tex.path} does not resolve")
                fmt = str(_get(lt.GetTextureFormatAttr(), "automatic"))
                if fmt not in ("automatic", "latlong"):
                    raise ExportError(f"{path}: dome texture format {fmt!r} not supported by "
                                      "the reference (latlong only)")  # fmt: skip
                dome_map = dome_to_blender(_read_image(tex.resolvedPath), rot, pole) * rad
                dome_map = dome_map.astype(np.float32)
            else:
                dome_color = rad.tolist()
        else:
            warn(f"{path}: light type {prim.GetTypeName()} not supported by the reference")
    return lights, dome_map, dome_color


def _read_image(path: str) -> np.ndarray:
    """(h, w, 3) float32 linear pixels, row 0 at the top (OpenImageIO).

    A DomeLight texture has no colour-space input: Hydra's rule (HioImage) decides, so an
    8-bit image with 3 or 4 channels is sRGB and decoded here with the sRGB transfer
    function (IEC 61966-2-1); 1-2 channel, 16-bit and float images are linear. (McUsd's
    8-bit PNG sky was read as linear values before: 2-3x too bright a sky.)"""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(path)
    px = buf.get_pixels(oiio.FLOAT)
    if px is None or px.size == 0:
        raise ExportError(f"{path}: cannot read image ({oiio.geterror()})")
    px = np.asarray(px, np.float32)
    spec = buf.spec()
    if spec.format == oiio.UINT8 and spec.nchannels in (3, 4):
        c = px[..., :3]
        px = px.copy()
        px[..., :3] = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    if px.ndim == 2:
        px = px[..., None]
    if px.shape[-1] == 1:
        px = np.repeat(px, 3, -1)
    return px[..., :3]


def latlong_lookup(img: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a UsdLux latlong image at dome-local directions (Y up).

    Storm's convention: u = (atan2(z, x) + pi/2) / 2 pi, v = acos(y) / pi with row 0 at +Y.
    img : (h, w, 3); d : (n, 3) unit. returns (n, 3) float64.
    """
    h, w = img.shape[:2]
    u = (np.arctan2(d[:, 2], d[:, 0]) + 0.5 * math.pi) / (2 * math.pi)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / math.pi
    x = u * w - 0.5
    y = np.clip(v * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    y1 = np.minimum(y0 + 1, h - 1)
    x0w, x1w = x0 % w, (x0 + 1) % w
    top = img[y0, x0w] * (1 - fx) + img[y0, x1w] * fx
    bot = img[y1, x0w] * (1 - fx) + img[y1, x1w] * fx
    return top * (1 - fy) + bot * fy


def blender_equirect_dirs(rows: int) -> np.ndarray:
    """World directions (rows, 2 rows, 3) of the pixel centres of a Blender equirect image,
    row 0 = the image's **first stored row** (Blender stores bottom-up: v = 0 is -Z).

    Cycles: u = 0.5 - atan2(y, x) / 2 pi, v = 0.5 + asin(z) / pi (z up in Blender's world).
    """
    cols = 2 * rows
    u = (np.arange(cols) + 0.5) / cols
    v = (np.arange(rows) + 0.5) / rows
    phi = (0.5 - u) * 2 * math.pi
    theta = (v - 0.5) * math.pi  # elevation
    ph, th = np.meshgrid(phi, theta)
    return np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), np.sin(th)], -1)


def dome_to_blender(img: np.ndarray, rot: np.ndarray, pole: str, rows: int = DOME_ROWS):
    """Resample a UsdLux latlong dome (row 0 top) into Blender's equirect layout (bottom-up
    rows), for the scene's world axes used unchanged as Blender's. rot : (3, 3) dome's world
    rotation (rows = local axes). returns (rows, 2 rows, 3) float64."""
    d = blender_equirect_dirs(rows).reshape(-1, 3)
    local = d @ rot.T  # world -> dome local (rot is orthonormal)
    if pole == "Z":  # the latlong's +Y is the dome's +Z
        local = np.stack([local[:, 0], local[:, 2], -local[:, 1]], -1)
    return latlong_lookup(img, local).reshape(rows, 2 * rows, 3)


# ------------------------------------------------------------------------------- export


def _material_faces(prim, n_faces: int):
    """[(face indices, UsdShade.Material or None)] covering every face (subsets first)."""
    from pxr import UsdShade

    bound = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
    owner = np.full(n_faces, -1, np.int64)
    mats = [bound if bound else None]
    subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
    for s in subsets:
        m = UsdShade.MaterialBindingAPI(s.GetPrim()).ComputeBoundMaterial()[0]
        idx = np.asarray(s.GetIndicesAttr().Get() or [], np.int64)
        idx = idx[(idx >= 0) & (idx < n_faces)]
        mats.append(m if m else None)
        owner[idx] = len(mats) - 1
    owner[owner < 0] = 0
    return owner, mats


def export_stage(
    stage_path,
    *,
    baked: dict | None = None,
    uv: str = "st",
    resolution: int | None = None,
    crease_deg: float = CREASE_DEG,
) -> Scene:
    """Flatten a stage for the reference bake.

    baked : {prim path: {"uv": primvar name, "resolution": (w, h)}} (e.g. from a usdahd bake's
    results); None: every mesh carrying primvar ``uv`` is baked at ``resolution``.
    """
    from pxr import Usd, UsdGeom

    stage_path = Path(stage_path)
    if not stage_path.is_file():
        raise ExportError(f"{stage_path}: no such file")
    stage = Usd.Stage.Open(str(stage_path))
    if stage is None:
        raise ExportError(f"{stage_path}: not a readable USD stage")
    if baked is None and not resolution:
        raise ExportError("give --resolution (or bake with usdahd first and pass its results)")
    warnings: list[str] = []
    warn = warnings.append
    xf = UsdGeom.XformCache(Usd.TimeCode.Default())
    tri_p, tri_n, tri_uv, tri_tuv, tri_mesh, tri_mat = [], [], [], [], [], []
    meshes, materials, mat_index = [], [], {}

    def material_id(mat, prim) -> int:
        if mat is None:
            dc = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
            col = DEFAULT_ALBEDO
            if dc and dc.HasValue():
                v = np.asarray(dc.ComputeFlattened(), np.float64).reshape(-1, 3)
                if len(v):
                    col = tuple(float(x) for x in v.mean(axis=0))
            key = f"<displayColor {np.round(col, 6).tolist()}>"
            if key not in mat_index:
                mat_index[key] = len(materials)
                materials.append({"name": key, "albedo": list(col), "emission": [0.0] * 3,
                                  "texture": None, "texture_srgb": True, "texture_uv": None,
                                  "double_sided": False})  # fmt: skip
            return mat_index[key]
        key = str(mat.GetPath())
        if key not in mat_index:
            mat_index[key] = len(materials)
            materials.append(_read_material(mat, key, warn))
        return mat_index[key]

    for prim in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdGeom.Mesh):
            if prim.IsA(UsdGeom.Gprim) and not prim.IsA(UsdGeom.Mesh):
                warn(f"{prim.GetPath()}: {prim.GetTypeName()} gprims are not exported")
            continue
        img = UsdGeom.Imageable(prim)
        if img.ComputeVisibility() == UsdGeom.Tokens.invisible:
            continue
        if img.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
            continue
        path = str(prim.GetPath())
        mesh = UsdGeom.Mesh(prim)
        points = np.asarray(_get(mesh.GetPointsAttr(), []), np.float64).reshape(-1, 3)
        counts = np.asarray(_get(mesh.GetFaceVertexCountsAttr(), []), np.int64)
        fv = np.asarray(_get(mesh.GetFaceVertexIndicesAttr(), []), np.int64)
        if len(points) == 0 or len(counts) == 0:
            continue
        if counts.sum() != len(fv) or (fv.size and (fv.min() < 0 or fv.max() >= len(points))):
            raise ExportError(f"{path}: inconsistent faceVertexCounts/Indices; fix the mesh")
        m4 = np.array(xf.GetLocalToWorldTransform(prim), np.float64)
        m3 = m4[:3, :3]
        wp = points @ m3 + m4[3, :3]
        left = str(_get(mesh.GetOrientationAttr(), "rightHanded")) == "leftHanded"
        flip = left != (np.linalg.det(m3) < 0)
        face_of = np.repeat(np.arange(len(counts)), counts)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        # Fan triangulation: corners (s, s+i, s+i+1), reversed when the front is clockwise.
        good = counts >= 3
        k = np.concatenate([np.arange(1, c - 1) for c in counts[good]]) if good.any() else []
        f_t = np.repeat(np.flatnonzero(good), counts[good] - 2)
        s_t = starts[f_t]
        corners = np.stack([s_t, s_t + k, s_t + k + 1], 1).astype(np.int64)
        if flip:
            corners = corners[:, [0, 2, 1]]
        # Normals (authored win; primvars:normals over the normals attribute).
        pv_api = UsdGeom.PrimvarsAPI(prim)
        nv = None
        pvn = pv_api.GetPrimvar("normals")
        if pvn and pvn.HasValue():
            nv = _primvar_corners(pvn, fv, face_of, len(points), f"{path} primvars:normals")
        elif mesh.GetNormalsAttr().HasValue():
            vals = np.asarray(mesh.GetNormalsAttr().Get(), np.float64)
            interp = str(mesh.GetNormalsInterpolation())
            nv = _corner_values(vals, interp, fv, face_of, len(points), f"{path} normals")
        if nv is not None:
            nv = _unit(nv @ np.linalg.inv(m3).T)
        else:
            crease = crease_deg if _scheme(mesh) else 180.0
            # Wind every polygon counter-clockwise about its front (reversed when flipped).
            order = np.arange(len(fv))
            if flip:
                order = np.concatenate([s + np.arange(c)[::-1] for s, c in zip(starts, counts)])
            nv = np.empty((len(fv), 3))
            nv[order] = computed_normals(wp, counts, fv[order], crease)
        p_t = wp[fv[corners]]
        area2 = np.linalg.norm(_tri_normal(p_t), axis=1)
        keep = area2 > 1e-12 * max(float(np.ptp(wp, axis=0).max()), 1e-30) ** 2
        corners, p_t = corners[keep], p_t[keep]
        info = (baked or {}).get(path) if baked is not None else None
        uvname = (info or {}).get("uv", uv)
        st = pv_api.GetPrimvar(uvname)
        is_baked = (info is not None) if baked is not None else bool(st and st.HasValue())
        if is_baked:
            if not (st and st.HasValue()):
                raise ExportError(
                    f"{path}: lightmap UV primvar {uvname!r} not found; pass the baked stage "
                    "(X.lightmaps.usda) so UVs the bake unwrapped are read"
                )
            uvc = _primvar_corners(st, fv, face_of, len(points), f"{path} primvars:{uvname}")
            t_uv = uvc[corners][..., :2]
            res = list((info or {}).get("resolution") or (resolution, resolution))
        else:
            t_uv = np.full((len(corners), 3, 2), np.nan)
            res = [0, 0]
        owner, mats = _material_faces(prim, len(counts))
        ids = np.array([material_id(m, prim) for m in mats], np.int32)
        t_mat = ids[owner[face_of[corners[:, 0]]]]
        t_tuv = np.zeros((len(corners), 3, 2))
        for mi in np.unique(t_mat):
            tex_uv = materials[mi].get("texture_uv")
            if tex_uv:
                tp = pv_api.GetPrimvar(tex_uv)
                if not (tp and tp.HasValue()):
                    raise ExportError(f"{path}: texture primvar {tex_uv!r} missing")
                tc = _primvar_corners(tp, fv, face_of, len(points), f"{path} {tex_uv}")
                sel = t_mat == mi
                t_tuv[sel] = tc[corners[sel]][..., :2]
        ds = _get(mesh.GetDoubleSidedAttr(), False)
        if ds:
            for mi in np.unique(t_mat):
                if any(materials[mi]["emission"]) and not materials[mi]["double_sided"]:
                    materials[mi] = dict(materials[mi], double_sided=True)
        tri_p.append(p_t)
        tri_n.append(nv[corners])
        tri_uv.append(t_uv)
        tri_tuv.append(t_tuv)
        tri_mesh.append(np.full(len(corners), len(meshes), np.int32))
        tri_mat.append(t_mat)
        meshes.append({"path": path, "baked": bool(is_baked), "resolution": [int(r) for r in res],
                       "uv": uvname if is_baked else None})  # fmt: skip
    if not meshes:
        raise ExportError(f"{stage_path}: no mesh to export")
    if not any(m["baked"] for m in meshes):
        raise ExportError(
            f"{stage_path}: no mesh has the lightmap UV primvar {uv!r}; pass --uv or bake with "
            "usdahd first (the compare command does)"
        )
    lights, dome, dome_color = _lights(stage, xf, warn)
    all_p, twins = separate_twins(np.concatenate(tri_p))
    all_mesh = np.concatenate(tri_mesh)
    if twins.any():
        names = [meshes[k]["path"] for k in np.unique(all_mesh[twins])]
        warn(
            f"{int(twins.sum())} faces coincide with an opposite-facing face (a doubled sheet) "
            f"on {len(names)} meshes ({', '.join(names[:4])}{', ...' if len(names) > 4 else ''}): "
            f"moved {TWIN_GAP / 2 * 1000:g} mm toward their fronts for Cycles, which otherwise "
            "shadows both sides (benchmarks/reference/twins.py)"
        )
    return Scene(
        tri_p=all_p,
        tri_n=np.concatenate(tri_n),
        tri_uv=np.concatenate(tri_uv),
        tri_tuv=np.concatenate(tri_tuv),
        tri_mesh=all_mesh,
        tri_mat=np.concatenate(tri_mat),
        meshes=meshes,
        materials=materials,
        lights=lights,
        dome=dome,
        dome_color=dome_color,
        warnings=warnings,
        source=str(stage_path),
    )


def _scheme(mesh) -> bool:
    """True for subdivisionScheme "none" (crease rule), False for subdivision (smooth)."""
    return str(_get(mesh.GetSubdivisionSchemeAttr(), "catmullClark")) == "none"


def save_scene(scene: Scene, path) -> Path:
    """Write the scene file atomically: arrays of :class:`Scene` + ``meta`` (JSON string)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {
        "tri_p": scene.tri_p,
        "tri_n": scene.tri_n,
        "tri_uv": scene.tri_uv,
        "tri_tuv": scene.tri_tuv,
        "tri_mesh": scene.tri_mesh,
        "tri_mat": scene.tri_mat,
        "meta": np.array(json.dumps(scene.meta())),
    }
    if scene.dome is not None:
        arrays["dome"] = scene.dome
    save_npz(path, arrays, prefix=f".{path.stem}.")
    return path
