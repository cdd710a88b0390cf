"""Calibrate the reference on analytic cases: exporter + Cycles against closed forms.

Usage (project environment; a bpy interpreter from --bpy-python or $USDAHD_BPY_PYTHON)::

    python -m benchmarks.reference calibrate [--spp 4096] [--json]

Each case is a small USD stage written here with pxr: a 2 x 2 cm plane (y = 0, facing +y,
albedo 0, so nothing bounces) baked at 4 x 4 texels, under one light. The whole harness path
runs (USD -> export.py -> cycles_bake.py -> per-texel I_z) and every covered texel is compared
with the exact normalized irradiance at its centre (texels are 5 mm and lights >= 0.5 m
away, so the variation across the ~half-texel jitter of Cycles' bake is < 1e-5):

- sphere light (radius R, centre c, fully above the horizon): I = L (R/d)^2 cos(theta);
- point light (treatAsPoint) of intensity I0 = L pi R^2: I = I0 cos(theta) / (pi d^2);
- rect light and emissive quads: Lambert's polygon formula
  I = L/(2 pi) sum_edges angle_i (n . unit(v_i x v_i+1));
- disk light: the same formula on a 4096-gon (area error 4e-7);
- distant light (cap of half-angle a above the horizon): I = E cos(theta) / pi;
- uniform dome: I = L; a dome texture varying with elevation as a + b sin(elev):
  I = a + 2 b / 3.

Reported per case: mean of Cycles / exact - 1 over the texels and its standard error.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

PLANE = 0.02  # metres
RES = 4


def _plane_stage(path: Path, build_light) -> None:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    h = PLANE / 2
    mesh = UsdGeom.Mesh.Define(stage, "/World/Plane")
    mesh.CreatePointsAttr(Vt.Vec3fArray([(-h, 0, h), (h, 0, h), (h, 0, -h), (-h, 0, -h)]))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
    mesh.CreateSubdivisionSchemeAttr("none")
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
    )
    st.Set(Vt.Vec2fArray([(0, 0), (1, 0), (1, 1), (0, 1)]))
    mat = UsdShade.Material.Define(stage, "/World/Black")
    sh = UsdShade.Shader.Define(stage, "/World/Black/S")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    build_light(stage, path.parent)
    stage.GetRootLayer().Save()


def texel_points() -> np.ndarray:
    """World positions (RES*RES, 3) of the texel centres, row-major with row 0 at the top."""
    h = PLANE / 2
    ys, xs = np.mgrid[0:RES, 0:RES]
    u = (xs.ravel() + 0.5) / RES
    v = 1 - (ys.ravel() + 0.5) / RES
    return np.stack([-h + u * PLANE, np.zeros_like(u), h - v * PLANE], -1)


def polygon_irradiance(p: np.ndarray, verts: np.ndarray, n=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Normalized irradiance (per unit radiance) at points p (k, 3) with normal n from a
    uniform polygon ``verts`` (m, 3) (Lambert's formula; the polygon fully above the
    horizon). returns (k,)."""
    n = np.asarray(n, float)
    a = verts[None, :, :] - p[:, None, :]
    b = np.roll(a, -1, axis=1)
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    cr = np.cross(a, b)
    ang = np.arccos(np.clip((a * b).sum(-1), -1, 1))
    cr /= np.linalg.norm(cr, axis=-1, keepdims=True)
    return np.abs((ang * (cr @ n)).sum(-1)) / (2 * math.pi)


def _xf(prim, translate=(0, 0, 0), rotate=(0, 0, 0)):
    from pxr import Gf, UsdGeom

    x = UsdGeom.Xformable(prim)
    x.AddTranslateOp().Set(Gf.Vec3d(*translate))
    x.AddRotateXYZOp().Set(Gf.Vec3f(*rotate))


def _common(api, intensity, exposure=0.0, color=(1, 1, 1), normalize=False):
    from pxr import Gf

    api.CreateIntensityAttr(float(intensity))
    api.CreateExposureAttr(float(exposure))
    api.CreateColorAttr(Gf.Vec3f(*color))
    api.CreateNormalizeAttr(bool(normalize))


def cases() -> list[dict]:
    """Analytic cases: name, a light builder (stage, folder) and the exact I per texel."""
    from pxr import Sdf, UsdLux

    p = texel_points()
    out = []

    def sphere(c, R, L):
        d = np.asarray(c) - p
        dist = np.linalg.norm(d, axis=1)
        return ((R / dist) ** 2 * (d[:, 1] / dist))[:, None] * np.asarray(L)[None]

    c1, r1 = (0.3, 0.8, -0.2), 0.15
    col1 = np.array([1.0, 0.7, 0.4])

    def b_sphere(stage, _):
        lt = UsdLux.SphereLight.Define(stage, "/World/L")
        lt.CreateRadiusAttr(r1)
        _common(lt, 5.0, 1.0, col1)
        _xf(lt.GetPrim(), c1)

    out.append({"name": "sphere r=0.15 (exposure 1)", "build": b_sphere,
                "exact": sphere(c1, r1, 10.0 * col1)})  # fmt: skip

    def b_sphere_norm(stage, _):
        lt = UsdLux.SphereLight.Define(stage, "/World/L")
        lt.CreateRadiusAttr(0.1)
        _common(lt, 4 * math.pi * 0.01 * 3.0, 0.0, (1, 1, 1), normalize=True)
        _xf(lt.GetPrim(), (0, 0.6, 0))

    out.append({"name": "sphere normalize", "build": b_sphere_norm,
                "exact": sphere((0, 0.6, 0), 0.1, [3.0, 3.0, 3.0])})  # fmt: skip

    def b_point(stage, _):
        lt = UsdLux.SphereLight.Define(stage, "/World/L")
        lt.CreateRadiusAttr(0.05)
        lt.CreateTreatAsPointAttr(True)
        _common(lt, 40.0, 0.0, (0.5, 1.0, 0.8))
        _xf(lt.GetPrim(), (-0.4, 0.7, 0.1))

    d = np.array([-0.4, 0.7, 0.1]) - p
    dist = np.linalg.norm(d, axis=1)
    i0 = 40.0 * math.pi * 0.05**2 * np.array([0.5, 1.0, 0.8])
    out.append({"name": "point (treatAsPoint)", "build": b_point,
                "exact": (d[:, 1] / dist**3 / math.pi)[:, None] * i0[None]})  # fmt: skip

    def rect_verts(c, w, h):  # a rect facing -y at height c (rotate X by 90 deg)
        cx, cy, cz = c
        return np.array(
            [
                (cx - w / 2, cy, cz - h / 2),
                (cx + w / 2, cy, cz - h / 2),
                (cx + w / 2, cy, cz + h / 2),
                (cx - w / 2, cy, cz + h / 2),
            ]  # fmt: skip
        )

    def b_rect(stage, _):
        lt = UsdLux.RectLight.Define(stage, "/World/L")
        lt.CreateWidthAttr(0.8)
        lt.CreateHeightAttr(0.4)
        _common(lt, 6.0, 0.0, (1.0, 0.9, 0.5))
        _xf(lt.GetPrim(), (0.2, 0.7, 0.1), (-90, 0, 0))  # local -Z -> world -Y

    col = np.array([1.0, 0.9, 0.5])
    out.append({"name": "rect 0.8x0.4 offset", "build": b_rect,
                "exact": polygon_irradiance(p, rect_verts((0.2, 0.7, 0.1), 0.8, 0.4))[:, None]
                * 6.0 * col[None]})  # fmt: skip

    def b_rect_norm(stage, _):
        lt = UsdLux.RectLight.Define(stage, "/World/L")
        lt.CreateWidthAttr(0.5)
        lt.CreateHeightAttr(0.5)
        _common(lt, 2.0 * 0.25, 0.0, (1, 1, 1), normalize=True)
        _xf(lt.GetPrim(), (0.0, 0.5, 0.0), (-90, 0, 0))

    out.append({"name": "rect normalize", "build": b_rect_norm,
                "exact": np.repeat(polygon_irradiance(p, rect_verts((0, 0.5, 0), 0.5, 0.5))[:, None]
                                   * 2.0, 3, 1)})  # fmt: skip

    def b_disk(stage, _):
        lt = UsdLux.DiskLight.Define(stage, "/World/L")
        lt.CreateRadiusAttr(0.3)
        _common(lt, 3.0, -1.0, (0.6, 0.8, 1.0))
        _xf(lt.GetPrim(), (-0.1, 0.6, 0.2), (-90, 0, 0))

    t = np.linspace(0, 2 * math.pi, 4096, endpoint=False)
    disk = np.stack([-0.1 + 0.3 * np.cos(t), np.full_like(t, 0.6), 0.2 + 0.3 * np.sin(t)], -1)
    out.append(
        {
            "name": "disk r=0.3 (exposure -1)",
            "build": b_disk,
            "exact": polygon_irradiance(p, disk)[:, None] * 1.5 * np.array([0.6, 0.8, 1.0]),
        }
    )

    sun_dir = np.array([0.3, -0.8, -0.4])
    sun_dir /= np.linalg.norm(sun_dir)

    def b_sun(normalize, intensity, angle):
        def build(stage, _):
            from pxr import Gf, UsdGeom

            lt = UsdLux.DistantLight.Define(stage, "/World/L")
            lt.CreateAngleAttr(angle)
            _common(lt, intensity, 0.0, (1.0, 0.95, 0.85), normalize=normalize)
            # Orient local -Z along sun_dir with an explicit matrix (rows = local axes).
            z = -sun_dir
            x = np.cross([0, 1, 0], z)
            x /= np.linalg.norm(x)
            y = np.cross(z, x)
            m = Gf.Matrix4d(1)
            for i, row in enumerate((x, y, z)):
                m.SetRow(i, Gf.Vec4d(*row, 0))
            UsdGeom.Xformable(lt.GetPrim()).AddTransformOp().Set(m)

        return build

    cos_t = -sun_dir[1]
    col_s = np.array([1.0, 0.95, 0.85])
    out.append({"name": "distant normalize (E=3)", "build": b_sun(True, 3.0, 0.53),
                "exact": np.tile(3.0 * cos_t / math.pi * col_s, (len(p), 1))})  # fmt: skip
    half = math.radians(2.0) / 2
    e_un = 5000.0 * math.pi * math.sin(half) ** 2
    out.append({"name": "distant 2 deg, not normalized", "build": b_sun(False, 5000.0, 2.0),
                "exact": np.tile(e_un * cos_t / math.pi * col_s, (len(p), 1))})  # fmt: skip

    def b_dome(stage, _):
        lt = UsdLux.DomeLight.Define(stage, "/World/L")
        _common(lt, 0.8, 0.0, (0.5, 0.75, 1.0))

    out.append({"name": "uniform dome", "build": b_dome,
                "exact": np.tile(0.8 * np.array([0.5, 0.75, 1.0]), (len(p), 1))})  # fmt: skip

    a, b = np.array([0.3, 0.4, 0.5]), np.array([0.2, 0.5, 1.0])

    def b_dome_tex(stage, folder):
        import OpenImageIO as oiio

        rows, cols = 128, 256
        elev = (0.5 - (np.arange(rows) + 0.5) / rows) * math.pi
        sky = a[None] + b[None] * np.maximum(np.sin(elev), 0)[:, None]
        sky[elev < 0] = (5.0, 5.0, 5.0)  # bright ground: must not be seen from the plane
        img = np.repeat(sky[:, None, :], cols, 1).astype(np.float32)
        f = folder / "sky.exr"
        spec = oiio.ImageSpec(cols, rows, 3, "float")
        o = oiio.ImageOutput.create(str(f))
        o.open(str(f), spec)
        o.write_image(img)
        o.close()
        lt = UsdLux.DomeLight.Define(stage, "/World/L")
        lt.CreateTextureFileAttr(Sdf.AssetPath("./sky.exr"))
        lt.CreateTextureFormatAttr("latlong")
        _common(lt, 1.0)

    # The map is piecewise linear in sin(elev) between rows, so the exact value of the
    # resampled map differs from a + 2b/3 by the sin() curvature inside one row (<1e-4).
    out.append({"name": "dome texture (elevation)", "build": b_dome_tex,
                "exact": np.tile(a + 2 * b / 3, (len(p), 1))})  # fmt: skip

    def b_emissive(facing_down: bool):
        def build(stage, _):
            from pxr import Gf, UsdGeom, UsdShade, Vt

            q = rect_verts((0.1, 0.5, -0.1), 0.6, 0.6)  # counter-clockwise about -y
            if not facing_down:
                q = q[::-1]
            m = UsdGeom.Mesh.Define(stage, "/World/Emitter")
            m.CreatePointsAttr(Vt.Vec3fArray([tuple(float(c) for c in v) for v in q]))
            m.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
            m.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
            m.CreateSubdivisionSchemeAttr("none")
            mat = UsdShade.Material.Define(stage, "/World/Glow")
            sh = UsdShade.Shader.Define(stage, "/World/Glow/S")
            sh.CreateIdAttr("UsdPreviewSurface")
            sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
            sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(4, 2, 1))
            mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
            UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(mat)

        return build

    q = rect_verts((0.1, 0.5, -0.1), 0.6, 0.6)
    out.append(
        {
            "name": "emissive quad (front down)",
            "build": b_emissive(True),
            "exact": polygon_irradiance(p, q)[:, None] * np.array([4.0, 2.0, 1.0]),
        }
    )
    out.append({"name": "emissive quad (back down)", "build": b_emissive(False),
                "exact": np.zeros((len(p), 3))})  # fmt: skip
    return out


def run(spp: int = 4096, bpy: str | None = None, names=None, quiet=False,
        point: bool = False) -> list[dict]:  # fmt: skip
    """Bake every case (or those whose name contains one of ``names``); one row per case.
    ``point``: Cycles samples the texel centres through probes (probes.py)."""
    from benchmarks.reference import export, runner

    bpy = runner.find_bpy(bpy)
    rows = []
    with tempfile.TemporaryDirectory(prefix="usdahd-calib-") as tmp:
        for k, case in enumerate(cases()):
            if names and not any(n in case["name"] for n in names):
                continue
            folder = Path(tmp) / f"case{k}"
            folder.mkdir()
            stage = folder / "case.usda"
            _plane_stage(stage, case["build"])
            scene = export.export_stage(stage, resolution=RES)
            sf = export.save_scene(scene, folder / "scene.npz")
            info, images = runner.run_cycles(sf, spp, bpy=bpy, quiet=True, point=point)
            k_plane = [i for i, m in enumerate(scene.meshes) if m["path"] == "/World/Plane"][0]
            got = images[k_plane].reshape(-1, 3)
            exact = case["exact"]
            ok = np.isfinite(got[:, 0])
            row = {"case": case["name"], "texels": int(ok.sum()), "spp": spp,
                   "footprint": "point" if point else "box",
                   "seconds": info["wall_seconds"]}  # fmt: skip
            if np.all(exact[ok] == 0):
                row.update(mean_abs=float(np.abs(got[ok]).max()), ratio_m1=None, stderr=None)
            else:
                r = (got[ok] / exact[ok]).mean(axis=1) - 1  # per texel, mean over RGB
                row.update(
                    ratio_m1=float(r.mean()),
                    stderr=float(r.std(ddof=1) / math.sqrt(len(r))) if len(r) > 1 else None,
                    max_abs_m1=float(np.abs(r).max()),
                    exact_mean=float(exact[ok].mean()),
                )
            rows.append(row)
            if not quiet:
                print(_fmt_row(row), file=sys.stderr, flush=True)
    return rows


def _fmt_row(row: dict) -> str:
    if row.get("ratio_m1") is None:
        return f"| {row['case']} | {row['texels']} | {row['spp']} | max |I| = {row['mean_abs']:.2e} (exact 0) | |"  # noqa: E501
    return (
        f"| {row['case']} | {row['texels']} | {row['spp']} | {100 * row['ratio_m1']:+.3f} % "
        f"± {100 * (row['stderr'] or 0):.3f} % | {100 * row['max_abs_m1']:.3f} % |"
    )


def table(rows: list[dict]) -> str:
    head = "| case | texels | spp | Cycles / exact - 1 (± s.e.) | max per-texel |"
    head += "\n" + "|---" * 5 + "|"
    return "\n".join([head] + [_fmt_row(r) for r in rows])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reference calibrate",
                                description=__doc__.splitlines()[0])  # fmt: skip
    p.add_argument("--spp", type=int, default=4096)
    p.add_argument("--bpy-python")
    p.add_argument("--case", action="append", help="only cases whose name contains this")
    p.add_argument("--point", action="store_true",
                   help="Cycles samples each texel's centre point (probes.py)")  # fmt: skip
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    from benchmarks.reference import runner

    try:
        rows = run(a.spp, a.bpy_python, a.case, point=a.point)
    except runner.ReferenceUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(rows, indent=1) if a.json else table(rows))
    return 0
