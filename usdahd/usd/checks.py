"""Pre-flight checks of authored stage values, before the scene reader runs (issue 18).

Every light, material and primvar value a bake depends on is checked for type and finiteness
here, with one warning or error each naming the prim and the attribute: the scene reader
(:mod:`usdahd.usd.reader`) can then assume well-typed, finite inputs. Called by
``usdahd.pipeline.bake`` (and its ``--dry-run``) right after the stage opens.

:func:`check_stage` returns a :class:`StageFindings`: ``errors`` that make the whole stage
unusable (a broken light spoils every prim: raise StageError), ``prim_errors`` that fail one
mesh (the rest still bakes) and ``warnings`` (baked anyway, the report says what was assumed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pxr import Usd, UsdGeom, UsdLux, UsdShade

__all__ = ["asset_problem", "check_stage", "no_mesh_message"]

#: Light inputs and the value type UsdLux declares for them.
LIGHT_INPUTS = {
    "inputs:intensity": "float",
    "inputs:exposure": "float",
    "inputs:diffuse": "float",
    "inputs:color": "color3f",
    "inputs:colorTemperature": "float",
    "inputs:radius": "float",
    "inputs:width": "float",
    "inputs:height": "float",
    "inputs:length": "float",
    "inputs:angle": "float",
}
#: Shape inputs: finite and >= 0.
SHAPE_INPUTS = ("inputs:radius", "inputs:width", "inputs:height", "inputs:length")
#: Below this exposure 2^exposure underflows float32: the light emits nothing at all.
MIN_EXPOSURE = -126.0
#: UsdPreviewSurface inputs whose value is a colour the baker uses directly.
COLOR_INPUTS = ("diffuseColor", "emissiveColor")


@dataclass
class StageFindings:
    errors: list[str] = field(default_factory=list)
    prim_errors: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _prims(stage):
    return Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))


def _values(v) -> list[float] | None:
    """Floats of a scalar or vector value, or None if it is not numeric."""
    if isinstance(v, bool):
        return [float(v)]
    if isinstance(v, (int, float)):
        return [float(v)]
    try:
        return [float(x) for x in v]
    except (TypeError, ValueError):
        return None


def _check_light(prim, out: StageFindings) -> None:
    path = str(prim.GetPath())
    for name, want in LIGHT_INPUTS.items():
        attr = prim.GetAttribute(name)
        if not attr or not attr.HasAuthoredValue():
            continue
        got = str(attr.GetTypeName())
        try:
            value = attr.Get()
        except Exception:  # a value USD cannot read back
            out.errors.append(f"{path}: light {name} cannot be read; re-author it as a {want}")
            continue
        nums = _values(value) if got == want or got in ("double", "half", "int") else None
        if isinstance(value, str):
            nums, got = None, "a string"
        if nums is None or (want == "color3f" and len(nums) != 3):
            shown = repr(value)[:40]
            out.errors.append(
                f"{path}: light {name} is authored as {got} ({shown}) but UsdLux declares "
                f"{want}; author a number (a broken light spoils every prim's bake)"
            )
            continue
        if name in SHAPE_INPUTS:
            bad = [x for x in nums if not math.isfinite(x)]
            if bad:
                kind = "NaN" if any(math.isnan(x) for x in bad) else "Inf"
                out.errors.append(
                    f"{path}: light {name} is {kind}; a light needs a finite size: fix it or "
                    "deactivate the light"
                )
            elif any(x < 0 for x in nums):
                out.errors.append(
                    f"{path}: light {name} is negative ({nums[0]:g}); a light's size must be "
                    ">= 0: fix it or deactivate the light"
                )
        if name == "inputs:exposure" and math.isfinite(nums[0]) and nums[0] < MIN_EXPOSURE:
            out.warnings.append(
                f"{path}: light inputs:exposure {nums[0]:g} scales its intensity by "
                f"2^{nums[0]:g}, below float32's range: the light emits nothing; check the "
                "exposure (stops, not a linear factor)"
            )


def _check_binding(prim, out: StageFindings) -> None:
    rel = prim.GetRelationship("material:binding")
    if not rel or not rel.HasAuthoredTargets():
        return
    stage = prim.GetStage()
    for target in rel.GetTargets():
        tp = stage.GetPrimAtPath(target)
        path = str(prim.GetPath())
        if not tp or not tp.IsA(UsdShade.Material):
            from usdahd.usd.materialx import find_mtlx  # the MaterialX library, lazily

            src = find_mtlx(stage, target)
            if src is not None:
                # A material from a .mtlx file USD could not compose (no usdMtlx in the
                # usd-core wheel): the material reader reads the file itself and reports it
                # once; only a file it cannot read either is a finding here, once per file.
                msg = (
                    f"{src.file}: MaterialX file could not be composed (USD: the usd-core "
                    f"wheel has no usdMtlx plugin; usdahd: {src.reason}); prims bound to its "
                    f"materials (e.g. {path} -> {target}) get the default material (grey "
                    f"0.18, no emission). Fix: the MaterialX file, or the reference to it in "
                    f"{src.layer}"
                )
                if src.reason and not any(w.startswith(f"{src.file}:") for w in out.warnings):
                    out.warnings.append(msg)
                continue
        if not tp:
            out.warnings.append(
                f"{path}: material:binding targets {target}, which does not exist: the "
                "default material (grey 0.18, no emission) is used; fix the binding"
            )
        elif not tp.IsA(UsdShade.Material):
            kind = tp.GetTypeName() or "an untyped prim"
            out.warnings.append(
                f"{path}: material:binding targets {target}, which is {kind}, not a Material: "
                "the default material is used; bind a UsdShade Material"
            )


def _check_mesh(prim, uv_name: str, out: StageFindings) -> None:
    path = str(prim.GetPath())
    mesh = UsdGeom.Mesh(prim)
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(uv_name)
    if pv and pv.HasAuthoredValue() and pv.GetElementSize() != 1:
        out.prim_errors[path] = (
            f"{path}: primvars:{uv_name} has elementSize {pv.GetElementSize()} (several UVs "
            "per element), which a lightmap UV set cannot be; author elementSize 1 or pick "
            "another set with --uv"
        )
    holes = mesh.GetHoleIndicesAttr()
    if holes and holes.HasAuthoredValue():
        h = holes.Get()
        if h is not None and len(h):
            out.warnings.append(
                f"{path}: holeIndices marks {len(h)} face(s) as holes; the baker ignores "
                "holes, so those faces are traced and lit as solid faces"
            )
    _check_binding(prim, out)


def _check_shader(prim, out: StageFindings) -> None:
    """UsdUVTexture feeding a colour input with a negative ``inputs:scale``."""
    shader = UsdShade.Shader(prim)
    if shader.GetIdAttr().Get() != "UsdUVTexture":
        return
    scale = shader.GetInput("scale")
    if not scale or not scale.GetAttr().HasAuthoredValue():
        return
    nums = _values(scale.Get())
    if nums is None:
        out.errors.append(f"{prim.GetPath()}: inputs:scale is not a float4; author one")
        return
    if all(math.isfinite(x) and x >= 0 for x in nums[:3]):
        return
    stage = prim.GetStage()
    for p in _prims(stage):
        if not p.IsA(UsdShade.Shader) or p == prim:
            continue
        for name in COLOR_INPUTS:
            inp = UsdShade.Shader(p).GetInput(name)
            if not inp:
                continue
            for src in inp.GetConnectedSources()[0]:
                if src.source.GetPrim() == prim:
                    owner = str(p.GetPath().GetParentPath())
                    out.errors.append(
                        f"{owner}: {name} comes from {prim.GetPath()} whose inputs:scale "
                        f"{tuple(nums)} is negative or not finite (negative "
                        f"{'emission' if name == 'emissiveColor' else 'albedo'}); use a "
                        "scale >= 0"
                    )


def check_stage(stage, uv_name: str = "st") -> StageFindings:
    """Check every light, mesh binding/primvar and texture scale of ``stage``."""
    out = StageFindings()
    for prim in _prims(stage):
        if prim.HasAPI(UsdLux.LightAPI) or prim.IsA(UsdLux.BoundableLightBase):
            _check_light(prim, out)
        elif prim.IsA(UsdLux.NonboundableLightBase):
            _check_light(prim, out)
        elif prim.IsA(UsdGeom.Mesh):
            _check_mesh(prim, uv_name, out)
        elif prim.IsA(UsdShade.Shader):
            _check_shader(prim, out)
    return out


#: Largest texture file read (bytes): a bigger file is refused before OpenImageIO opens it.
MAX_ASSET_BYTES = 2 * 2**30


def asset_problem(path) -> str | None:
    """Why the file ``path`` must not be opened as an asset, or None (also None when it does
    not exist: the caller reports that). A directory, FIFO, socket or device is refused (a
    FIFO would block the bake forever), and so is a file above MAX_ASSET_BYTES."""
    import os
    import stat

    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"cannot be examined ({exc.strerror})"
    if stat.S_ISDIR(st.st_mode):
        return "is a directory, not a regular file"
    if not stat.S_ISREG(st.st_mode):
        return "is not a regular file (a FIFO, socket or device)"
    if st.st_size > MAX_ASSET_BYTES:
        return f"is {st.st_size / 2**30:.1f} GiB, above the {MAX_ASSET_BYTES / 2**30:.0f} GiB limit"
    return None


def no_mesh_message(src, api_prims: dict) -> str:
    """Why a bake found nothing to bake: the AhdLightmapAPI prims (path -> prim) that are
    not meshes, or that every mesh is an occluder or has bake off."""
    not_mesh = [p for p, prim in sorted(api_prims.items()) if not prim.IsA(UsdGeom.Mesh)]
    if not_mesh:
        kinds = ", ".join(f"{p} ({api_prims[p].GetTypeName() or 'untyped'})" for p in not_mesh[:5])
        return (
            f"{src}: no mesh to bake: AhdLightmapAPI is applied to {kinds}, which is not a "
            "Mesh; apply it to the meshes to bake (or remove it to bake every visible mesh)"
        )
    return f"{src}: no mesh to bake (all meshes are occluders or have bake off)"
