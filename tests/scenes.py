"""Shared scene builders of the test suite: the sample stages (samples/) and small stages built
with pxr (quads, boxes, meshes, UsdPreviewSurface materials, lights), one definition each.

Test modules import what they use (``from tests.scenes import define_quad, new_stage``);
``tests/conftest.py`` builds its fixtures on the sample helpers here. Every builder returns the
prim it defined (or the stage), so a test can author more on it.

Conventions: stages are Z-up in memory unless a path is given; a mesh's ``scheme`` defaults to
``"none"`` (what a bake of flat geometry wants: a Mesh without the attribute is a Catmull-Clark
subdivision surface by USD's fallback, which the bake refines); ``scheme=None`` authors nothing.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"

#: The six faces of an axis-aligned box over the corners ``(x, y, z) for x in (lo, hi) for y in
#: (lo, hi) for z in (lo, hi)`` (see :func:`box_points`), each quad wound outward.
BOX_QUADS = ((0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3))


# --- the sample stages ---------------------------------------------------------------------


def sample_stages() -> list[str]:
    """File names of the sample stages in samples/, sorted. Bake outputs a user wrote there
    (README command 1 writes samples/cornell_box.lightmaps.usda) are not samples."""
    return sorted(p.name for p in SAMPLES.glob("*.usda") if ".lightmaps." not in p.name)


def copy_sample(folder: Path, name: str) -> Path:
    """Copy samples/<name> and samples/textures/ (which some samples reference) into
    ``folder``; returns the copied stage. A bake then writes next to the copy, never into
    samples/."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    dst = folder / name
    shutil.copy(SAMPLES / name, dst)
    if (SAMPLES / "textures").is_dir():
        shutil.copytree(SAMPLES / "textures", folder / "textures", dirs_exist_ok=True)
    return dst


def baked_mean_iz(layer: Path) -> float:
    """Mean baked I_z (channel R) over the covered texels of the one baked prim of ``layer``,
    from its float SH sidecar (reloaded, so a re-bake in the same process is seen)."""
    import numpy as np
    from pxr import Sdf, Usd

    from usdahd.numerics import sh as shmod
    from usdahd.usd import schema

    Sdf.Layer.FindOrOpen(str(layer)).Reload(force=True)
    stage = Usd.Stage.Open(str(layer))
    (prim,) = schema.prims_with_api(stage)
    res = schema.read_results(prim)
    img = schema.read_record_pixels(res, schema.SIDECAR_ROLE, schema.SH_SIDECAR_CHANNELS)
    px = np.asarray(img, np.float64).reshape(-1, 28)
    covered = px[px[:, 27] > 0, :27].reshape(-1, 3, 9)
    return float(shmod.iz(covered)[:, 0].mean())


# --- small stages built with pxr -----------------------------------------------------------


def new_stage(up: str = "Z", meters_per_unit: float | None = None, path: Path | None = None):
    """A stage with ``up`` as its up axis (and ``metersPerUnit`` when given): in memory, or a
    new layer file at ``path`` (saved by the caller)."""
    from pxr import Usd, UsdGeom

    st = Usd.Stage.CreateNew(str(path)) if path is not None else Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, up)
    if meters_per_unit is not None:
        UsdGeom.SetStageMetersPerUnit(st, meters_per_unit)
    return st


def bind(prim, material) -> None:
    """Bind ``material`` (a UsdShade.Material) to ``prim`` (a prim or schema object)."""
    from pxr import UsdShade

    prim = prim.GetPrim() if hasattr(prim, "GetPrim") else prim
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)


def define_mesh(
    st,
    path: str,
    points,
    faces: Sequence[Sequence[int]] | None = None,
    uv=None,
    material=None,
    *,
    counts: Sequence[int] | None = None,
    indices: Sequence[int] | None = None,
    scheme: str | None = "none",
    uv_interpolation: str = "faceVarying",
    uv_name: str = "st",
):
    """A UsdGeom.Mesh at ``path``: ``points`` (any (x, y, z) sequence, stored as float32) and
    either ``faces`` (one index tuple per face) or raw ``counts``/``indices`` (authored as
    given, also when invalid: the bad-mesh tests need that). ``uv``: a TexCoord2f primvar
    ``uv_name`` with ``uv_interpolation``; ``material``: bound; ``scheme``: the subdivision
    scheme (None: not authored, i.e. USD's catmullClark fallback)."""
    from pxr import Gf, Sdf, UsdGeom

    if faces is not None:
        counts = [len(f) for f in faces]
        indices = [int(i) for f in faces for i in f]
    m = UsdGeom.Mesh.Define(st, path)
    m.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in points])
    m.CreateFaceVertexCountsAttr(list(counts))
    m.CreateFaceVertexIndicesAttr(list(indices))
    if scheme is not None:
        m.CreateSubdivisionSchemeAttr(scheme)
    if uv is not None:
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
            uv_name, Sdf.ValueTypeNames.TexCoord2fArray, uv_interpolation
        )
        pv.Set([Gf.Vec2f(*map(float, c)) for c in uv])
    if material is not None:
        bind(m, material)
    return m


def define_quad(st, path: str, corners, material=None, uv=None, *, scheme: str | None = None):
    """One quad face over the four ``corners`` (wound as given: counter-clockwise seen from
    the side it faces), ``uv`` per corner (vertex interpolation). ``scheme`` None by default:
    a single planar quad refines to itself."""
    return define_mesh(
        st, path, corners, [(0, 1, 2, 3)], uv, material, scheme=scheme, uv_interpolation="vertex"
    )


def square(z: float = 0.0, half: float = 0.5, down: bool = False) -> list[tuple]:
    """The corners of the square ``|x|, |y| <= half`` at height ``z``, facing +Z (``down``:
    facing -Z), in :func:`define_quad`'s order."""
    h = half
    c = [(-h, -h, z), (h, -h, z), (h, h, z), (-h, h, z)]
    return c[::-1] if down else c


def box_points(lo, hi) -> list[tuple]:
    """The eight corners of the box ``lo``..``hi`` in :data:`BOX_QUADS`' order."""
    return [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]


def define_box(st, path: str, lo, hi, material=None, *, inward: bool = False, scheme=None):
    """A closed box of six quads, faces outward (``inward``: reversed, for a room or a furnace
    seen from inside)."""
    quads = [q[::-1] for q in BOX_QUADS] if inward else BOX_QUADS
    return define_mesh(st, path, box_points(lo, hi), quads, None, material, scheme=scheme)


def preview_material(st, path: str, albedo=(0.5, 0.5, 0.5), emission=(0.0, 0.0, 0.0)):
    """A UsdShade.Material at ``path`` whose surface is a UsdPreviewSurface ``path/pbr`` with
    ``diffuseColor`` ``albedo`` and ``emissiveColor`` ``emission`` (None: not authored)."""
    from pxr import Gf, Sdf, UsdShade

    mat = UsdShade.Material.Define(st, path)
    s = UsdShade.Shader.Define(st, path + "/pbr")
    s.CreateIdAttr("UsdPreviewSurface")
    s.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*albedo))
    if emission is not None:
        s.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emission))
    mat.CreateSurfaceOutput().ConnectToSource(s.ConnectableAPI(), "surface")
    return mat


def distant_light(st, path: str = "/Sun", intensity: float = 1.0, angle: float = 0.0):
    """A UsdLux.DistantLight (pointing down -Z of its frame) of ``intensity`` and ``angle``."""
    from pxr import UsdLux

    sun = UsdLux.DistantLight.Define(st, path)
    sun.CreateIntensityAttr(intensity)
    sun.CreateAngleAttr(angle)
    return sun
