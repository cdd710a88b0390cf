"""Build the clean and one-defect-each baked stages that tests/validate/test_validate.py validates.

A synthetic bake (no path tracing): a 4 x 4-quad mesh with a lightmap UV set and a distant
light, random but plausible hemispherical radiance SH at every covered texel (a sky term plus a
few cosine-power lobes, projected exactly over the upper hemisphere), fitted with
``usdahd.fit``, encoded with the model's ``encode``, written as the textures and SH sidecar the
schema declares, and recorded with ``usdahd.usd.schema.write_results`` in an override layer
that sublayers the source, with the content hash of ``usdahd.scene.hashing.content_hash``.

Nothing binary is committed: ``python tests/data/validate/make_assets.py OUT_DIR`` writes
``OUT_DIR/clean/`` and ``OUT_DIR/bad/<defect>/`` for inspection; the tests build the same
assets in a temporary directory. :data:`DEFECTS` maps each defect to the one rule it breaks.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt  # noqa: E402,I001

import usdahd.usd  # noqa: E402,F401  (registers the plugins before any stage exists)
from usdahd import images, models  # noqa: E402
from usdahd.numerics import sh as shm  # noqa: E402
from usdahd.usd import schema  # noqa: E402

RESOLUTION = (16, 16)
GRID = 4  # quads per side
SOURCE = "source.usda"
LAYER = "scene.lightmaps.usda"
PRIM = "/World/Quad"
LIGHT = "/World/Sun"


# --------------------------------------------------------------------------------- geometry


def grid_uvs(overlap: bool = False, outside: bool = False) -> np.ndarray:
    """faceVarying UVs (GRID*GRID*4, 2): each quad's own cell of [0.02, 0.98]^2.

    overlap: quad 1 reuses quad 0's cell; outside: the last column is shifted past u = 1.
    """
    lo, hi = 0.02, 0.98
    step = (hi - lo) / GRID
    out = []
    for j in range(GRID):
        for i in range(GRID):
            ci = 0 if (overlap and j == 0 and i == 1) else i
            u0, v0 = lo + ci * step, lo + j * step
            if outside and i == GRID - 1:
                u0 += 0.5
            out += [(u0, v0), (u0 + step, v0), (u0 + step, v0 + step), (u0, v0 + step)]
    return np.array(out, np.float32)


def write_source(directory: Path, uvs: np.ndarray) -> Path:
    """The source layer: /World/Quad (2 x 2 units in XZ, facing +Y) and a distant light."""
    path = directory / SOURCE
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, PRIM)
    xs = np.linspace(-1.0, 1.0, GRID + 1)
    pts = [(x, 0.0, -z) for z in xs for x in xs]
    idx = []
    for j in range(GRID):
        for i in range(GRID):
            a = j * (GRID + 1) + i
            idx += [a, a + 1, a + GRID + 2, a + GRID + 1]
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    mesh.CreateFaceVertexCountsAttr([4] * (GRID * GRID))
    mesh.CreateFaceVertexIndicesAttr(idx)
    mesh.CreateExtentAttr([(-1, 0, -1), (1, 0, 1)])
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
    )
    pv.Set(Vt.Vec2fArray.FromNumpy(uvs))
    sun = UsdLux.DistantLight.Define(stage, LIGHT)
    sun.CreateIntensityAttr(3.0)
    UsdGeom.XformCommonAPI(sun).SetRotate(Gf.Vec3f(-50.0, 30.0, 0.0))
    stage.GetRootLayer().Save()
    return path


# ------------------------------------------------------------------------------- radiance SH


def hemispherical_sh(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3, 9) float64 radiance SH of positive radiance that is zero below the horizon.

    L(w) = sky + sum_k c_k max(0, w . l_k)^p_k over the upper hemisphere, projected with the
    exact Gauss-Legendre hemisphere rule (usdahd.sh.hemisphere_quadrature).
    """
    dirs, wts = shm.hemisphere_quadrature(24)
    basis = shm.basis(dirs) * wts[:, None]  # (q, 9)
    out = np.empty((n, 3, 9))
    for t in range(n):
        rad = np.tile(rng.uniform(0.05, 0.3, 3), (len(dirs), 1))
        for _ in range(2):
            lz = rng.uniform(0.3, 0.9)
            phi = rng.uniform(0, 2 * np.pi)
            lobe = np.array(
                [np.sqrt(1 - lz * lz) * np.cos(phi), np.sqrt(1 - lz * lz) * np.sin(phi), lz]
            )
            power = rng.uniform(4.0, 16.0)
            rad += rng.uniform(1.0, 4.0, 3) * np.maximum(dirs @ lobe, 0.0)[:, None] ** power
        out[t] = rad.T @ basis
    return out


def below_horizon_sh(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3, 9) radiance SH of a narrow lobe 17 degrees *below* the tangent plane plus a faint
    sky: light an IrradZ model (which stores max(I_z, 0)) decodes black."""
    dirs, wts = shm.sphere_quadrature(32)
    basis = shm.basis(dirs) * wts[:, None]
    out = np.empty((n, 3, 9))
    for t in range(n):
        phi = rng.uniform(0, 2 * np.pi)
        lz = -0.3
        d = np.array([np.sqrt(1 - lz * lz) * np.cos(phi), np.sqrt(1 - lz * lz) * np.sin(phi), lz])
        rad = np.full((len(dirs), 3), 0.01) + 3.0 * np.maximum(dirs @ d, 0.0)[:, None] ** 64
        out[t] = rad.T @ basis
    return out


# ------------------------------------------------------------------------------------ images


def write_image(path: Path, data: np.ndarray, *, channels=None, color_space: str = "") -> None:
    """Write (h, w, c) data in its own dtype (float16/float32 EXR, uint8 PNG, int8 TIFF)."""
    import OpenImageIO as oiio

    fmt = {np.float16: "half", np.float32: "float", np.uint8: "uint8", np.int8: "int8"}[
        data.dtype.type
    ]
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], fmt)
    if channels:
        spec.channelnames = tuple(channels)
    if color_space:
        spec.attribute("oiio:ColorSpace", color_space)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise OSError(oiio.geterror())
    ok = out.write_image(np.ascontiguousarray(data))
    out.close()
    if not ok:
        raise OSError(out.geterror())


# ------------------------------------------------------------------------------------- bake


def bake(
    directory: Path,
    *,
    model: str = "hhd",
    ratio: str | None = None,
    uvs=None,
    seed: int = 0,
    sh_fn=None,
) -> Path:
    """Write a synthetic, consistent bake into ``directory``; returns the override layer.

    sh_fn : ``(n, rng) -> (n, 3, 9)`` radiance SH of the covered texels (default
    :func:`hemispherical_sh`)."""
    from usdahd import pipeline
    from usdahd.numerics.raster import rasterize_uv
    from usdahd.scene.hashing import content_hash, scene_hash_parts
    from usdahd.usd.author import generator_id
    from usdahd.usd.reader import load_scene

    directory.mkdir(parents=True, exist_ok=True)
    uvs = grid_uvs() if uvs is None else uvs
    write_source(directory, uvs)
    w, h = RESOLUTION
    # Covered texels: centres inside a UV triangle (fan triangulation of the quads).
    quads = uvs.reshape(-1, 4, 2).astype(np.float64)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    ids = rasterize_uv(tris, RESOLUTION, conservative=False).ids
    ys, xs = ids // w, ids % w
    rng = np.random.default_rng(seed)
    # float32, as the baker fits it and stores it in the sidecar
    sh = (sh_fn or hemispherical_sh)(len(xs), rng).astype(np.float32)
    mod = models.get(model)
    ratio = ratio or mod.RATIOS[0]
    fitted = models.fit(sh, model, ratio=ratio)
    channels, factors = fitted.encode()
    lm = directory / "lightmaps"
    lm.mkdir(exist_ok=True)
    textures = {}
    for lay in mod.layout(ratio):
        vals = channels[lay.role]
        img = np.zeros((h, w, vals.shape[-1]), vals.dtype)
        img[ys, xs] = vals
        f = lm / f"quad.{lay.role}{lay.extension}"
        images.write(f, img, format=lay.format, color_space=lay.color_space, channels=lay.channels)
        textures[lay.role] = str(f)
    side = np.zeros((h, w, 28), np.float32)
    side[ys, xs, :27] = sh.reshape(-1, 27)
    side[ys, xs, 27] = 1.0
    f = lm / "quad.sh.exr"
    images.write(f, side, format="float", color_space="raw", channels=schema.SH_SIDECAR_CHANNELS)
    textures[schema.SIDECAR_ROLE] = str(f)
    digests = {role: schema.file_digest(path) for role, path in textures.items()}

    layer_path = directory / LAYER
    layer = Sdf.Layer.CreateNew(str(layer_path))
    layer.subLayerPaths.append(f"./{SOURCE}")
    layer.Save()
    stage = Usd.Stage.Open(str(layer_path))
    stage.SetEditTarget(stage.GetRootLayer())
    prim = stage.GetPrimAtPath(PRIM)
    schema.apply(prim)
    settings = pipeline.resolve_settings(pipeline.BakeOptions(model=model, ratio=ratio), {})
    settings["resolution"] = [w, h]
    settings = json.loads(json.dumps(settings, sort_keys=True, default=str))
    parts = scene_hash_parts(load_scene(stage, uv_name=settings["uv"]))
    digest, named = content_hash(parts, PRIM, settings, generator_id())
    results = schema.BakeResults(
        model=model,
        ratio=ratio,
        solver=fitted.solver,
        uv_primvar="st",
        resolution=(w, h),
        textures=textures,
        factors=dict(factors),
        content_hash=digest,
        part_hashes=named,
        settings=settings,
        generator=f"usdahd {usdahd.__version__}",
        digests=digests,
    )
    schema.write_results(prim, results)
    stage.GetRootLayer().Save()
    return layer_path


# ----------------------------------------------------------------------------------- defects


def _layer_stage(layer_path: Path):
    stage = Usd.Stage.Open(str(layer_path))
    stage.SetEditTarget(stage.GetRootLayer())
    return stage


def _edit_image(path: Path, fn, *, record: bool = True) -> None:
    """Rewrite a texture through ``fn(pixels)``. With ``record`` the layer's digest of that
    file is updated too, so the defect reads as a bake that wrote bad data (the rule under test
    fires alone); without it the file looks replaced behind the layer's back (Textures)."""
    img = images.read(path)
    data = fn(np.array(img.pixels))
    if data.dtype.kind == "f" and not np.isfinite(data).all():  # images.write refuses NaN
        write_image(path, data, channels=img.channels, color_space=img.color_space or "raw")
    else:
        images.write(path, data, color_space=img.color_space or "raw", channels=img.channels)
    if not record:
        return
    layer = path.parent.parent / LAYER
    stage = _layer_stage(layer)
    prim = stage.GetPrimAtPath(PRIM)
    for role, f in schema.read_results(prim, validate=False).textures.items():
        if Path(f).resolve() == path.resolve():
            prim.GetAttribute(schema.digest_property_name(role)).Set(schema.file_digest(path))
    stage.GetRootLayer().Save()


def _covered(directory: Path) -> tuple[np.ndarray, np.ndarray]:
    from usdahd.validate import read_image

    side = read_image(str(directory / "lightmaps" / "quad.sh.exr"))
    return np.nonzero(side.channels(("A",))[..., 0] > 0.5)


def bogus_token(d: Path) -> None:
    stage = _layer_stage(d / LAYER)
    stage.GetPrimAtPath(PRIM).GetAttribute("ahdLightmap:ratio").Set("bogus")
    stage.GetRootLayer().Save()


def missing_file(d: Path) -> None:
    (d / "lightmaps" / "quad.direction.png").unlink()


def wrong_resolution(d: Path) -> None:
    _edit_image(d / "lightmaps" / "quad.direction.png", lambda a: np.ascontiguousarray(a[::2, ::2]))


def nan_texel(d: Path) -> None:
    ys, xs = _covered(d)

    def fn(a):
        a[ys[3], xs[3], 1] = np.nan
        return a

    _edit_image(d / "lightmaps" / "quad.iz.exr", fn)


def horizon_direction(d: Path) -> None:
    ys, xs = _covered(d)

    def fn(a):
        a[ys[5], xs[5], :2] = (255, 128)  # (u, v) = (1, 0) decodes to d_z = 0
        return a

    _edit_image(d / "lightmaps" / "quad.direction.png", fn)


def corrupted_iz(d: Path) -> None:
    ys, xs = _covered(d)

    def fn(a):
        a[ys[7], xs[7]] = (a[ys[7], xs[7]].astype(np.float32) * 1.01).astype(np.float16)
        return a

    _edit_image(d / "lightmaps" / "quad.iz.exr", fn)


def mirrored_directions(d: Path) -> None:
    def fn(a):
        a[..., :2] = 256 - a[..., :2].astype(np.int16)  # biased: d = (-x, -y, z), I_z unchanged
        return a

    _edit_image(d / "lightmaps" / "quad.direction.png", fn)


def replaced_texture(d: Path) -> None:
    def fn(a):
        a[0, 0, 0] ^= 1  # one code of a padding texel: no texel rule can see it
        return a

    _edit_image(d / "lightmaps" / "quad.direction.png", fn, record=False)


def moved_light(d: Path) -> None:
    stage = Usd.Stage.Open(str(d / SOURCE))
    UsdGeom.XformCommonAPI(stage.GetPrimAtPath(LIGHT)).SetRotate(Gf.Vec3f(-20.0, 30.0, 0.0))
    stage.GetRootLayer().Save()


#: defect -> (rule it breaks, how: a function editing a clean copy, or bake() keyword args).
DEFECTS = {
    "bogus_token": ("SchemaValues", bogus_token),
    "missing_file": ("Textures", missing_file),
    "wrong_resolution": ("Textures", wrong_resolution),
    "nan_texel": ("TexelValues", nan_texel),
    "horizon_direction": ("TexelValues", horizon_direction),
    "corrupted_iz": ("IzCheck", corrupted_iz),
    "mirrored_directions": ("IzCheck", mirrored_directions),
    "light_from_below": ("EncodingError", {"sh": "below"}),
    "moved_light": ("Staleness", moved_light),
    "replaced_texture": ("Textures", replaced_texture),
    "overlapping_uvs": ("UVSet", {"uvs": "overlap"}),
    "uvs_outside": ("UVSet", {"uvs": "outside"}),
}


def make_clean(directory: Path, **kw) -> Path:
    return bake(Path(directory), **kw)


def make_bad(directory: Path, defect: str, clean: Path | None = None) -> Path:
    """A one-defect copy: copies ``clean`` (a clean bake's directory) and breaks it, or bakes
    with broken inputs for defects that must be baked in (UVs)."""
    directory = Path(directory)
    _rule, how = DEFECTS[defect]
    if isinstance(how, dict) and "sh" in how:
        return bake(directory, sh_fn=below_horizon_sh)
    if isinstance(how, dict):
        uvs = grid_uvs(overlap=how["uvs"] == "overlap", outside=how["uvs"] == "outside")
        return bake(directory, uvs=uvs)
    if clean is None:
        clean = directory.parent / "clean"
        bake(clean)
    if directory.exists():
        shutil.rmtree(directory)
    shutil.copytree(clean, directory)
    how(directory)
    return directory / LAYER


if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "validate_assets")
    clean = out / "clean"
    make_clean(clean)
    print(clean / LAYER)
    for name in DEFECTS:
        print(make_bad(out / "bad" / name, name, clean))
