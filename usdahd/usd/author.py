"""Authoring of the override layer ``usdahd bake`` writes (the only writer of baked USD).

The layer sublayers the source stage and holds, per baked prim, the unwrapped lightmap UVs
(faceVarying primvar), the normals the bake traced with and the ``AhdLightmapAPI`` results
(:func:`usdahd.usd.schema.write_results`). :mod:`usdahd.pipeline` decides what goes in and
commits the exported file atomically. The end of the module reads an existing output layer
back for the pipeline (is a stage one of ours, the UVs an earlier run unwrapped, the assets a
layer names), so the pipeline itself never calls pxr.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from usdahd.errors import OutputError
from usdahd.usd import normals, schema
from usdahd.version import __version__

__all__ = [
    "authored_default",
    "build_layer",
    "export_layer",
    "generator_id",
    "is_output_layer",
    "layer_assets",
    "previous_layer",
    "referenced_assets",
]

#: How the documentation of every override layer ``usdahd bake`` writes begins.
DOC_PREFIX = "Directional lightmaps baked by usdahd"


def generator_id() -> str:
    """The generator part of a bake's content hash: the usdahd version and the normals rule
    (a rule change re-bakes every prim)."""
    return f"usdahd {__version__}; {normals.RULE_VERSION}"


def relative_path(path: Path, start: Path) -> str:
    """``path`` relative to ``start`` as a USD asset path ("./x" or "../x", "/" separators)."""
    rel = os.path.relpath(path.resolve(), start.resolve()).replace(os.sep, "/")
    return rel if rel.startswith("../") else f"./{rel}"


def author_uvs(stage, job) -> str | None:
    """Author an unwrapped UV set as a faceVarying primvar; returns a warning or None."""
    prim = stage.GetPrimAtPath(job.path)
    mesh = UsdGeom.Mesh(prim)
    n_fv = len(mesh.GetFaceVertexIndicesAttr().Get() or [])
    corner = np.asarray(job.mesh.corner).reshape(-1)
    uv = np.asarray(job.uv_primvar_values, dtype=np.float32).reshape(-1, 2)
    values = np.zeros((n_fv, 2), dtype=np.float32)
    values[corner] = uv
    # A polygon's fan triangles share corners; xatlas may cut a polygon into two charts.
    mismatch = int((np.abs(values[corner] - uv).max(axis=1) > 1e-6).sum())
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(
        job.settings["uv"], Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
    )
    pv.Set(Vt.Vec2fArray.FromNumpy(values))
    if mismatch:
        return (
            f"{job.path}: {mismatch} unwrapped UV corners of split polygons could not be "
            "represented in the faceVarying primvar; author a lightmap UV set for this mesh"
        )
    return None


def author_normals(stage, job) -> str:
    """Author the normals the scene computed for a mesh (faceVarying, object space, float32:
    exactly the values the bake traced with), so renderers shade with them; returns the rule
    token for ``ahdLightmap:baked:normals`` ("authored" when the mesh had its own)."""
    comp = job.normals
    if comp is None:
        return "authored"
    prim = stage.GetPrimAtPath(job.path)
    values = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(comp.values, dtype=np.float32))
    if comp.attr == "primvars:normals":
        pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(
            "normals", Sdf.ValueTypeNames.Normal3fArray, UsdGeom.Tokens.faceVarying
        )
        pv.Set(values)
        pv.BlockIndices()
    else:
        mesh = UsdGeom.Mesh(prim)
        mesh.CreateNormalsAttr().Set(values)
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    return comp.rule


def build_layer(
    src: Path, out: Path, source_stage, jobs: list, scenario: str | None = None
) -> Sdf.Layer:
    """The override layer for ``out``, in memory (anonymous): sublayers ``src`` (by absolute
    path while authoring, by relative path in the returned layer), carries the source's
    defaultPrim / upAxis / metersPerUnit, and for every job with results (``results``,
    ``previous`` or ``fallback``) authors its unwrapped UVs, computed normals and the schema
    results. Kept prims (``mesh`` None) carry over the UV set and normals an earlier run
    authored in the existing ``out``. Warnings go to ``job.report["warnings"]``.

    jobs : pipeline ``PrimJob`` objects (``path``, ``mesh``, ``settings``, ``normals``,
        ``uv_primvar_values`` (F, 2) float32 or None, ``results``/``previous``/``fallback``,
        ``report``).
    scenario : canonical ``/Prim{set=variant}`` of ``--scenario``: the layer selects that
        variant itself (before anything is authored, so prims inside the variant exist) and
        records it (:func:`usdahd.usd.scenarios.author`).
    """
    layer = Sdf.Layer.CreateAnonymous(out.suffix if out.suffix != ".usd" else ".usdc")
    src_root = source_stage.GetRootLayer()
    layer.subLayerPaths.append(str(src.resolve()))
    layer.documentation = (
        f"{DOC_PREFIX} {__version__} for {src.name}; "
        "regenerate with usdahd bake, do not edit by hand."
    )
    for key in ("defaultPrim", "upAxis", "metersPerUnit"):
        if src_root.pseudoRoot.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, src_root.pseudoRoot.GetInfo(key))
    if scenario:
        from usdahd.usd import scenarios

        scenarios.author(layer, scenarios.resolve(source_stage, scenario))
    ostage = Usd.Stage.Open(layer)
    ostage.SetEditTarget(layer)
    if not src_root.pseudoRoot.HasInfo("upAxis"):
        UsdGeom.SetStageUpAxis(ostage, UsdGeom.GetStageUpAxis(source_stage))
    old_layer = previous_layer(out)
    instances: dict[str, dict] = {}  # carrier path -> {entry key: BakeResults}
    for job in sorted(jobs, key=lambda j: j.path):
        res = job.results or job.previous or job.fallback
        if res is None:
            continue
        carrier = instance_carrier(ostage, job)
        if carrier is not None:  # an instance copy: recorded on its carrier (below)
            if job.mesh is not None and job.mesh.instance is not None:
                res.normals = job.mesh.instance.normals
            instances.setdefault(carrier, {})[job.path] = res
            continue
        prim = ostage.GetPrimAtPath(job.path)
        if job.mesh is None and old_layer is not None:
            # A kept prim (not selected this time): carry over a UV set an earlier run
            # unwrapped and authored here, or its kept textures would lose their UVs.
            # Same for the normals it computed (baked:normals says which rule).
            names = [f"primvars:{res.uv_primvar}"]
            if res.normals != "authored":
                names += ["normals", "primvars:normals"]
            for name in names:
                spec_path = Sdf.Path(job.path).AppendProperty(name)
                if old_layer.GetAttributeAtPath(spec_path) is not None:
                    Sdf.CreatePrimInLayer(layer, Sdf.Path(job.path))
                    Sdf.CopySpec(old_layer, spec_path, layer, spec_path)
        if job.uv_primvar_values is not None:
            warning = author_uvs(ostage, job)
            if warning and warning not in job.report.setdefault("warnings", []):
                job.report["warnings"].append(warning)
        if job.mesh is not None:
            res.normals = author_normals(ostage, job)
        schema.write_results(prim, res, layer_dir=out.parent)
    author_instance_records(ostage, instances, out.parent)
    del ostage
    layer.subLayerPaths[0] = relative_path(src, out.parent)
    return layer


def instance_carrier(stage, job) -> str | None:
    """The carrier prim path of a job that bakes an instance copy (``job.mesh.instance``, or
    for a kept record its key: :func:`usdahd.usd.schema.instance_carrier`), else None."""
    ref = getattr(job.mesh, "instance", None) if job.mesh is not None else None
    if ref is not None:
        return ref.carrier
    return schema.instance_carrier(stage, job.path)


def author_instance_records(stage, instances: dict, layer_dir: Path) -> None:
    """Author instance entries ({carrier path: {key: BakeResults}}) on their carriers
    (:func:`usdahd.usd.schema.write_instance_records`): on the instanceable prim or the
    PointInstancer, outside every prototype, so nothing is de-instanced."""
    for carrier, records in sorted(instances.items()):
        prim = stage.GetPrimAtPath(carrier)
        schema.write_instance_records(prim, records, layer_dir=layer_dir)


def export_layer(layer: Sdf.Layer, tmp: str, out: Path) -> None:
    """Export ``layer`` to the file ``tmp`` (a temp file beside ``out``). Raises OutputError
    naming ``out`` when it cannot be written (disk full, read-only folder)."""
    try:
        ok = layer.Export(tmp)
    except Exception as exc:  # pxr raises Tf.ErrorException (e.g. no space left)
        ok = False
        text = " ".join(str(exc).split())
        if "No space left" in text:
            why = "no space left on device"
        else:
            why = re.sub(r"^.*?line \d+ in file \S+ : ", "", text).strip("'")[:200]
    else:
        why = ""
    if not ok or Path(tmp).stat().st_size == 0:
        raise OutputError(
            f"{out}: cannot write the output layer{f' ({why})' if why else ''}; is the "
            "disk full or the folder read-only? Free space and re-run (the previous bake "
            "is intact)"
        )


# ------------------------------------------------------------------- reading an output back


def is_output_layer(stage) -> bool:
    """Whether ``stage``'s root layer is an override layer ``usdahd bake`` wrote."""
    return (stage.GetRootLayer().documentation or "").startswith(DOC_PREFIX)


def previous_layer(out: Path) -> Sdf.Layer | None:
    """The existing output layer ``out`` (the registry's copy), or None when there is none."""
    return Sdf.Layer.FindOrOpen(str(out)) if out.is_file() else None


def authored_default(layer: Sdf.Layer, prim_path: str, name: str):
    """The default value ``layer`` authors for the property ``name`` of ``prim_path`` (a Vt
    value), or None when it authors none."""
    spec = layer.GetAttributeAtPath(Sdf.Path(prim_path).AppendProperty(name))
    return None if spec is None else spec.default


def referenced_assets(out: Path, anonymous: bool = False) -> set[Path] | None:
    """Resolved paths of every asset the layer file ``out`` names (an empty set when there is
    no file, None when it is unreadable). ``anonymous``: read a private copy (leaves layers
    other stages use alone); else the registry's copy, reloaded from disk."""
    if not out.is_file():
        return set()
    try:
        if anonymous:
            layer = Sdf.Layer.OpenAsAnonymous(str(out))
        else:
            layer = Sdf.Layer.FindOrOpen(str(out))
            if layer is not None:
                layer.Reload(force=True)
        if layer is None:
            return None
    except Exception:
        return None
    return layer_assets(layer, out.parent)


def layer_assets(layer: Sdf.Layer, folder: Path) -> set[Path]:
    """Resolved paths (relative to ``folder``) of the assets ``layer``'s attributes name as
    default values. Only asset-typed values are read: converting a large array (a mesh's
    computed normals, millions of corners) to Python cost GBs for nothing (issue 40)."""
    found: set[Path] = set()
    asset_types = (Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray)

    def visit(path):
        spec = layer.GetObjectAtPath(path)
        if (
            isinstance(spec, Sdf.AttributeSpec)
            and spec.typeName in asset_types
            and spec.default is not None
        ):
            v = spec.default
            for a in v if hasattr(v, "__len__") and not isinstance(v, str) else [v]:
                if isinstance(a, Sdf.AssetPath) and a.path:
                    found.add((folder / a.path).resolve())

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found
