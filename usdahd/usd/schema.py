"""Typed access to the AhdLightmapAPI schema: apply it, read bake inputs, write and read results.

This is the only module that writes ``ahdLightmap:*`` properties; the baker and the validator go
through it. Property names, fallbacks and docs are defined in ``schema/schema.usda`` (see
``docs/schema.md``); the constants below mirror it and tests/test_schema.py keeps them in sync.

- :class:`BakeInputs` — what a TD authors before baking (every field has the schema fallback).
- :class:`BakeResults` — what a bake writes: one file per texture role (``models.base.ROLES``)
  plus the SH sidecar, resolution, decode factors, tangent frame, hashes, settings, version.
- :func:`apply`, :func:`has_api`, :func:`prims_with_api`, :func:`read_inputs`,
  :func:`write_inputs`, :func:`write_results`, :func:`read_results`, :func:`input_problems`,
  :func:`result_problems`.

Apply the API and write results in an override layer that sublayers the source scene (set that
layer as the stage's edit target); texture paths are authored relative to that layer
(``@./lightmaps/...@``) so the override layer and its ``lightmaps/`` folder move together.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from usdahd.errors import SchemaError
from usdahd.models import REGISTRY
from usdahd.models.base import ROLES
from usdahd.sidecar import CHANNELS
from usdahd.usd.plugin import API_NAME, SCHEMA_TYPE_NAME, register

register()  # idempotent; the schema must be known before any prim definition is queried

from pxr import Gf, Sdf, Usd  # noqa: E402

from usdahd.usd.atlas_records import (  # noqa: E402
    NO_ATLAS,
    crop_record,
    page_size,
    read_record_pixels,
    record_rect,
    rect_problem,
)

__all__ = [
    "API_NAME",
    "SCHEMA_TYPE_NAME",
    "NAMESPACE",
    "FORMAT_VERSION",
    "KNOWN_FORMAT_VERSIONS",
    "MODELS",
    "RATIOS",
    "TANGENT_FRAMES",
    "NORMALS_RULES",
    "SIDECAR_ROLE",
    "FILE_ROLES",
    "COLOR_SPACES",
    "FACTORS",
    "SH_SIDECAR_CHANNELS",
    "BakeInputs",
    "BakeResults",
    "apply",
    "has_api",
    "prims_with_api",
    "read_inputs",
    "write_inputs",
    "input_problems",
    "write_results",
    "read_results",
    "result_problems",
    "is_baked",
    "property_name",
    "file_property_name",
    "packing_property_name",
    "digest_property_name",
    "file_digest",
    "layout_packing",
    "OLD_FORMAT_VERSIONS",
    "INSTANCE_API_NAME",
    "INSTANCE_NAMESPACE",
    "instance_carrier",
    "instance_carriers",
    "instance_key",
    "instance_layout",
    "instance_property_name",
    "read_instance_records",
    "stage_records",
    "write_instance_records",
    "NO_ATLAS",
    "record_rect",
    "page_size",
    "read_record_pixels",
    "crop_record",
    "rect_problem",
    "INPUT_KEYS",
    "SETTING_KEYS",
    "SchemaError",
    "api_prims",
    "authored_input_fields",
    "edit_layer_dir",
    "json_text",
    "relative_asset_path",
]

#: Property namespace of every schema property.
NAMESPACE = "ahdLightmap"
#: Texture and property layout version this code writes (``ahdLightmap:baked:formatVersion``).
#: 2: every texture <= 4 channels, EXR half / PNG UNORM8 (signed values biased), one RGB texture
#: per basis function, per-texture packing and content digests (docs/schema.md "Versions").
FORMAT_VERSION = 2
#: Versions this code can read; 0 (the fallback) means "not baked".
KNOWN_FORMAT_VERSIONS = (2,)
#: Versions earlier usdahd releases wrote: valid bakes, but their textures need a re-bake.
OLD_FORMAT_VERSIONS = (1,)
#: allowedTokens of ``ahdLightmap:model`` / ``ahdLightmap:baked:model`` (= models.REGISTRY).
MODELS = tuple(REGISTRY)
#: allowedTokens of ``ahdLightmap:ratio`` / ``ahdLightmap:baked:ratio`` (IrradZ ratio types,
#: "none", and the sh_l1 variants, which models.sh_l1 takes in the ratio slot).
RATIOS = ("luminance", "rgb", "none", "linear", "nonlinear", "8bit")
#: allowedTokens of ``ahdLightmap:baked:tangentFrame``.
TANGENT_FRAMES = ("mikktspace_uv",)
#: allowedTokens of ``ahdLightmap:baked:normals`` (usdahd.usd.normals.RULES): where the
#: normals the bake used came from (authored by the scene, or computed by a rule and authored
#: by the bake in the override layer).
NORMALS_RULES = ("authored", "creaseAngle30", "smooth")
#: Role name of the radiance SH sidecar (``ahdLightmap:sidecar:sh``), next to the texture ROLES.
SIDECAR_ROLE = "sh"
#: Every file-valued role: texture roles of models.base.ROLES, then the sidecar.
FILE_ROLES = tuple(ROLES) + (SIDECAR_ROLE,)
#: colorSpace metadata (Gf.ColorSpaceNames) authored on each file property.
COLOR_SPACES = {
    "iz": "lin_rec709_scene",
    "direction": "raw",
    "ratio": "raw",
    "ambient": "lin_rec709_scene",
    "directional": "lin_rec709_scene",
    **{r: "raw" for r in ROLES if r.startswith("coefficients")},
    SIDECAR_ROLE: "raw",
}
#: Scalar decode factors (a model's ``encode`` returns them by these names) and their fallbacks.
FACTORS = {
    "izScale": 1.0,
    "ratioScale": 1.0,
    "ambientScale": 1.0,
    "directionalScale": 1.0,
    "coefficientsScale": 1.0,
    "l0Scale": 1.0,
}
#: Channel names of the SH sidecar EXR (float32): :data:`usdahd.sidecar.CHANNELS`, whose module
#: reads and writes the file.
SH_SIDECAR_CHANNELS = CHANNELS


def property_name(key: str) -> str:
    """Full property name of a schema key: ``"baked:izScale"`` -> ``ahdLightmap:baked:izScale``."""
    return f"{NAMESPACE}:{key}"


def packing_property_name(role: str) -> str:
    """``ahdLightmap:texture:<role>:packing``: the channel packing the bake wrote."""
    if role not in ROLES:
        raise SchemaError(f"unknown texture role {role!r}; roles are {', '.join(ROLES)}")
    return file_property_name(role) + ":packing"


def digest_property_name(role: str) -> str:
    """``<file property>:digest``: sha256 of the file the bake wrote (textures and sidecar)."""
    return file_property_name(role) + ":digest"


def file_digest(path: str | os.PathLike) -> str:
    """``sha256:<hex>`` of a file's bytes (what ``...:digest`` records); a resolved path
    inside a package (``a.usdz[lightmaps/b.png]``) is read through USD's asset resolver."""
    path = os.fspath(path)
    h = hashlib.sha256()
    if not os.path.isfile(path):  # e.g. an asset inside a usdz package: read it through Ar
        from usdahd.usd import assets

        h.update(assets.read_bytes(path))
        return "sha256:" + h.hexdigest()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return "sha256:" + h.hexdigest()


def layout_packing(model: str, ratio: str) -> dict[str, str]:
    """role -> packing string of the textures ``model`` writes with ``ratio`` (the writer's
    table, usdahd.models.base.TextureLayout.packing)."""
    from usdahd.models import get

    return {t.role: t.packing for t in get(model).layout(ratio)}


def file_property_name(role: str) -> str:
    """Asset-valued property of a file role (``ahdLightmap:texture:<role>`` or the sidecar)."""
    if role == SIDECAR_ROLE:
        return property_name("sidecar:sh")
    if role not in ROLES:
        raise SchemaError(f"unknown texture role {role!r}; roles are {', '.join(FILE_ROLES)}")
    return property_name(f"texture:{role}")


# --------------------------------------------------------------------------------------- inputs


@dataclass(frozen=True)
class BakeInputs:
    """Bake settings of one prim (``ahdLightmap:*`` inputs); defaults are the schema fallbacks.

    bake : whether the prim gets a lightmap; model : a name in MODELS; ratio : one of RATIOS
    (models without an ambient ratio treat it as "none"); solver : "" for the model's default;
    uv_primvar : lightmap UV primvar name; resolution : texels per side (0: from
    texel_density); texel_density : texels per metre; samples : paths per texel; bounces :
    cap on reflections per path (Russian roulette ends paths earlier).
    """

    bake: bool = True
    model: str = "hhd"
    ratio: str = "luminance"
    solver: str = ""
    uv_primvar: str = "st"
    resolution: int = 0
    texel_density: float = 16.0
    samples: int = 256
    bounces: int = 64

    def replace(self, **changes) -> BakeInputs:
        """A copy with some fields changed (e.g. command-line overrides)."""
        return replace(self, **changes)


#: BakeInputs field -> schema key.
INPUT_KEYS = {
    "bake": "bake",
    "model": "model",
    "ratio": "ratio",
    "solver": "solver",
    "uv_primvar": "uvPrimvar",
    "resolution": "resolution",
    "texel_density": "texelDensity",
    "samples": "samples",
    "bounces": "bounces",
}
#: BakeInputs field -> key of the bake settings record (``pipeline.settings.resolve_settings``,
#: stored in ``baked:settings``): the one map, used by the baker to apply authored inputs and by
#: the validator's Staleness rule to compare them with the record. ``bake`` is no setting.
SETTING_KEYS = {
    "model": "model",
    "ratio": "ratio",
    "solver": "solver",
    "uv_primvar": "uv",
    "samples": "samples",
    "bounces": "bounces",
    "resolution": "resolution",
    "texel_density": "texel_density",
}
_INPUT_TYPES = {
    "bake": bool,
    "model": str,
    "ratio": str,
    "solver": str,
    "uv_primvar": str,
    "resolution": int,
    "texel_density": float,
    "samples": int,
    "bounces": int,
}


def input_problems(inputs: BakeInputs) -> list[str]:
    """Every reason these inputs cannot be baked, one sentence each (empty list: fine)."""
    out = []
    for f in fields(BakeInputs):
        v = getattr(inputs, f.name)
        want = _INPUT_TYPES[f.name]
        ok = isinstance(v, want) or (want is float and isinstance(v, int))
        if not ok or (want is int and isinstance(v, bool)):
            out.append(f"{property_name(INPUT_KEYS[f.name])} must be {want.__name__}, got {v!r}")
    if out:
        return out
    if inputs.model not in MODELS:
        out.append(f"{property_name('model')} = {inputs.model!r} is not one of {', '.join(MODELS)}")
    if inputs.ratio not in RATIOS:
        out.append(f"{property_name('ratio')} = {inputs.ratio!r} is not one of {', '.join(RATIOS)}")
    if not inputs.uv_primvar or any(c.isspace() for c in inputs.uv_primvar):
        out.append(f"{property_name('uvPrimvar')} = {inputs.uv_primvar!r} is not a primvar name")
    if inputs.resolution < 0:
        out.append(f"{property_name('resolution')} = {inputs.resolution} must be >= 0")
    if not (math.isfinite(inputs.texel_density) and inputs.texel_density > 0):
        out.append(f"{property_name('texelDensity')} = {inputs.texel_density} must be > 0")
    if inputs.samples < 1:
        out.append(f"{property_name('samples')} = {inputs.samples} must be >= 1")
    if inputs.bounces < 0:
        out.append(f"{property_name('bounces')} = {inputs.bounces} must be >= 0")
    return out


def _prim_label(prim) -> str:
    return f"<{prim.GetPath()}>"


def apply(prim: Usd.Prim) -> None:
    """Apply AhdLightmapAPI to a mesh prim in the current edit target (idempotent).

    Raises SchemaError naming the prim when it is not a Mesh (or is invalid).
    """
    if not prim or not prim.IsValid():
        raise SchemaError(f"cannot apply {API_NAME}: invalid prim {prim}")
    if prim.HasAPI(API_NAME):
        return
    ok = prim.CanApplyAPI(API_NAME)
    if not ok:
        why = getattr(ok, "whyNot", "") or "see docs/schema.md"
        raise SchemaError(f"cannot apply {API_NAME} to {_prim_label(prim)}: {why}")
    if not prim.ApplyAPI(API_NAME):
        raise SchemaError(f"ApplyAPI({API_NAME}) failed on {_prim_label(prim)}")


def has_api(prim: Usd.Prim) -> bool:
    """Whether AhdLightmapAPI is applied to ``prim``."""
    return bool(prim) and prim.HasAPI(API_NAME)


def prims_with_api(stage: Usd.Stage) -> list[Usd.Prim]:
    """Every prim of ``stage`` (instance proxies included) with AhdLightmapAPI applied."""
    rng = Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate))
    return [p for p in rng if p.HasAPI(API_NAME)]


def api_prims(stage: Usd.Stage) -> dict[str, Usd.Prim]:
    """:func:`prims_with_api` by prim path (str)."""
    return {str(p.GetPath()): p for p in prims_with_api(stage)}


def authored_input_fields(prim: Usd.Prim) -> set[str]:
    """The :class:`BakeInputs` fields (:data:`INPUT_KEYS`) ``prim`` authors a value for."""
    out = set()
    for field_name, key in INPUT_KEYS.items():
        attr = prim.GetAttribute(property_name(key))
        if attr and attr.HasAuthoredValue():
            out.add(field_name)
    return out


def _attr(prim, key: str) -> Usd.Attribute:
    name = property_name(key)
    attr = prim.GetAttribute(name)
    if not attr:
        raise SchemaError(
            f"{_prim_label(prim)} has no {name}: apply {API_NAME} first (usdahd.usd.schema.apply)"
        )
    return attr


def _get(prim, key: str):
    return _attr(prim, key).Get()


def _require_api(prim) -> None:
    if not has_api(prim):
        raise SchemaError(
            f"{_prim_label(prim)} does not have {API_NAME} applied; apply it in an override "
            "layer (usdahd.usd.schema.apply) or bake the prim with usdahd bake"
        )


def read_inputs(prim: Usd.Prim, *, validate: bool = True) -> BakeInputs:
    """The prim's bake inputs (authored values, else schema fallbacks).

    With ``validate`` (default) invalid values raise SchemaError listing every problem; the
    validator passes ``validate=False`` and reports :func:`input_problems` itself.
    """
    _require_api(prim)
    values = {}
    for fname, key in INPUT_KEYS.items():
        v = _get(prim, key)
        want = _INPUT_TYPES[fname]
        values[fname] = want(v) if v is not None else getattr(BakeInputs, fname)
    inputs = BakeInputs(**values)
    if validate:
        problems = input_problems(inputs)
        if problems:
            raise SchemaError(f"{_prim_label(prim)}: " + "; ".join(problems))
    return inputs


def write_inputs(prim: Usd.Prim, inputs: BakeInputs | None = None, **values) -> None:
    """Author bake inputs on a prim that has the API (in the current edit target).

    Either pass ``inputs`` (every field is authored) or keyword fields of BakeInputs (only
    those are authored), e.g. ``write_inputs(prim, model="ahd", resolution=256)``.
    Invalid values raise SchemaError before anything is authored.
    """
    _require_api(prim)
    unknown = set(values) - set(INPUT_KEYS)
    if unknown:
        raise SchemaError(
            f"unknown bake input(s) {', '.join(sorted(unknown))}; known: {', '.join(INPUT_KEYS)}"
        )
    if inputs is not None and values:
        raise SchemaError("pass either a BakeInputs or keyword values, not both")
    if inputs is not None:
        values = {f.name: getattr(inputs, f.name) for f in fields(BakeInputs)}
    merged = read_inputs(prim, validate=False).replace(**values)
    problems = input_problems(merged)
    if problems:
        raise SchemaError(f"{_prim_label(prim)}: " + "; ".join(problems))
    for fname in values:
        _set(prim, INPUT_KEYS[fname], getattr(merged, fname))


def _set(prim, key: str, value) -> None:
    attr = _attr(prim, key)
    if not attr.Set(value):
        raise SchemaError(f"could not author {attr.GetPath()} = {value!r}")


# -------------------------------------------------------------------------------------- results


@dataclass
class BakeResults:
    """What a bake wrote for one prim (the ``ahdLightmap:texture:*``, ``sidecar:sh`` and
    ``baked:*`` properties).

    model, ratio, solver : what the textures were encoded with (decoders use these).
    uv_primvar : the UV primvar the textures are laid out in.
    resolution : (width, height) of every texture.
    textures : role (FILE_ROLES) -> file. For :func:`write_results` a filesystem path
        (absolute, or relative to the current directory); from :func:`read_results` the
        resolved absolute path, or the authored asset path if it does not resolve.
    asset_paths : role -> asset path as authored (``./lightmaps/...``); filled by read_results.
    factors : decode factors by FACTORS name (missing ones are their fallbacks).
    tangent_frame : one of TANGENT_FRAMES.
    content_hash : "sha256:<hex>" over everything the bake depends on.
    part_hashes : part name (geometry, uv, lights, materials, settings, ...) -> hash.
    settings : every setting used (JSON-serialisable).
    generator : e.g. "usdahd 0.1.0".
    format_version : layout version (FORMAT_VERSION).
    normals : one of NORMALS_RULES (``baked:normals``).
    digests : role (FILE_ROLES) -> "sha256:<hex>" of the file as written (``...:digest``).
    packing : role -> channel packing as authored (filled by read_results; write_results
        authors the model layout's own packing).
    page : atlas page index (``atlas:page``; 0 without an atlas).
    scale_offset : (sx, sy, ox, oy) (``atlas:scaleOffset``): ``uv_page = uv * s + o``;
        :data:`NO_ATLAS` when the record's textures are its own (``--atlas off``).
    atlas : whether the record lives in an atlas page (the atlas properties are authored).
    """

    model: str
    ratio: str
    solver: str
    uv_primvar: str
    resolution: tuple[int, int]
    textures: dict[str, str]
    factors: dict[str, float] = field(default_factory=dict)
    tangent_frame: str = "mikktspace_uv"
    content_hash: str = ""
    part_hashes: dict[str, str] = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    generator: str = ""
    format_version: int = FORMAT_VERSION
    asset_paths: dict[str, str] = field(default_factory=dict)
    normals: str = "authored"
    digests: dict[str, str] = field(default_factory=dict)
    packing: dict[str, str] = field(default_factory=dict)
    page: int = 0
    scale_offset: tuple[float, float, float, float] = (1.0, 1.0, 0.0, 0.0)
    atlas: bool = False

    def rect(self, page: tuple[int, int] | None = None) -> tuple[int, int, int, int]:
        """(x0, y0, w, h): this record's pixel rectangle in its page (top-left origin, rows
        down), :func:`record_rect`."""
        return record_rect(self, page)

    def factor(self, name: str) -> float:
        """A decode factor, or its schema fallback when not set."""
        if name not in FACTORS:
            raise SchemaError(f"unknown decode factor {name!r}; known: {', '.join(FACTORS)}")
        return float(self.factors.get(name, FACTORS[name]))


def result_problems(results: BakeResults) -> list[str]:
    """Every reason these results are not a valid bake record, one sentence each."""
    out = []
    if results.model not in MODELS:
        out.append(f"baked model {results.model!r} is not one of {', '.join(MODELS)}")
    if results.ratio not in RATIOS:
        out.append(f"baked ratio {results.ratio!r} is not one of {', '.join(RATIOS)}")
    if results.tangent_frame not in TANGENT_FRAMES:
        out.append(
            f"tangent frame {results.tangent_frame!r} is not one of {', '.join(TANGENT_FRAMES)}"
        )
    if results.normals not in NORMALS_RULES:
        out.append(f"normals rule {results.normals!r} is not one of {', '.join(NORMALS_RULES)}")
    res = tuple(results.resolution)
    if len(res) != 2 or any(not isinstance(r, int) or r <= 0 for r in res):
        out.append(f"resolution {results.resolution!r} must be two positive integers")
    if results.format_version in OLD_FORMAT_VERSIONS:
        out.append(
            f"format version {results.format_version} was written by an older usdahd: re-bake "
            f"needed (this usdahd reads {', '.join(map(str, KNOWN_FORMAT_VERSIONS))})"
        )
    elif results.format_version not in KNOWN_FORMAT_VERSIONS:
        out.append(
            f"format version {results.format_version} is not one of "
            f"{', '.join(map(str, KNOWN_FORMAT_VERSIONS))}"
        )
    if not results.uv_primvar:
        out.append("the UV primvar the textures use is empty")
    so = tuple(results.scale_offset)
    if len(so) != 4 or not all(isinstance(v, int | float) and math.isfinite(v) for v in so):
        out.append(f"atlas:scaleOffset {results.scale_offset!r} must be four finite numbers")
    elif not (0 < so[0] <= 1 and 0 < so[1] <= 1 and 0 <= so[2] and 0 <= so[3]) or (
        so[0] + so[2] > 1 + 1e-6 or so[1] + so[3] > 1 + 1e-6
    ):
        out.append(
            f"atlas:scaleOffset {so} puts the record outside its page (need 0 < s <= 1, "
            "o >= 0, s + o <= 1)"
        )
    if not isinstance(results.page, int) or results.page < 0:
        out.append(f"atlas:page {results.page!r} must be an integer >= 0")
    for role in results.textures:
        if role not in FILE_ROLES:
            out.append(f"unknown texture role {role!r}; roles are {', '.join(FILE_ROLES)}")
    for role, digest in results.digests.items():
        if role not in FILE_ROLES:
            out.append(f"digest of unknown texture role {role!r}")
        elif not (isinstance(digest, str) and digest.startswith("sha256:")):
            out.append(f"digest of {role} must be 'sha256:<hex>', got {digest!r}")
    for name, v in results.factors.items():
        if name not in FACTORS:
            out.append(
                f"decode factor {name!r} has no schema property (known: {', '.join(FACTORS)}); "
                "add it to schema/schema.usda"
            )
        elif not (isinstance(v, int | float) and math.isfinite(v)):
            out.append(f"decode factor {name} = {v!r} is not a finite number")
    for name in FACTORS:
        v = results.factors.get(name, FACTORS[name])
        if isinstance(v, int | float) and math.isfinite(v) and v <= 0:
            out.append(f"decode factor {name} = {v} must be > 0")
    return out


def edit_layer_dir(prim) -> Path:
    layer = prim.GetStage().GetEditTarget().GetLayer()
    if layer.anonymous or not layer.realPath:
        raise SchemaError(
            f"cannot author texture paths relative to anonymous layer {layer.identifier}; "
            "save the override layer first or pass layer_dir"
        )
    return Path(layer.realPath).resolve().parent


def relative_asset_path(path: str | os.PathLike, layer_dir: str | os.PathLike) -> str:
    """Asset path of ``path`` relative to ``layer_dir``: ``./lightmaps/a.exr`` or ``../x.exr``.

    Forward slashes on every platform; a path below the layer directory starts with ``./`` so
    USD anchors it to the layer rather than searching for it.
    """
    rel = os.path.relpath(Path(path).resolve(), Path(layer_dir).resolve()).replace(os.sep, "/")
    return rel if rel.startswith("../") else f"./{rel}"


def json_text(value, what: str) -> str:
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise SchemaError(f"{what} must be JSON-serialisable: {exc}") from None


def write_results(
    prim: Usd.Prim, results: BakeResults, layer_dir: str | os.PathLike | None = None
) -> None:
    """Author a bake's results on ``prim`` (applies the API if needed) in the edit target.

    Texture files are authored relative to ``layer_dir`` (default: the directory of the edit
    target layer) with their colorSpace metadata; roles not in ``results.textures`` are
    cleared (blocked if a weaker layer still has an opinion) so a re-bake with another model
    leaves no stale texture behind. Every ``baked:*`` property is authored explicitly so the
    layer is self-describing without the plugin. Raises SchemaError on invalid results.
    """
    problems = result_problems(results)
    if problems:
        raise SchemaError(f"{_prim_label(prim)}: invalid bake results: " + "; ".join(problems))
    layer_dir = Path(layer_dir) if layer_dir is not None else edit_layer_dir(prim)
    settings = json_text(results.settings, "bake settings")
    part_hashes = json_text(results.part_hashes, "part hashes")
    try:
        packing = layout_packing(results.model, results.ratio)
    except Exception:  # an unimplemented model: result_problems accepted its name
        packing = {}
    apply(prim)
    for role in FILE_ROLES:
        attr = prim.GetAttribute(file_property_name(role))
        extra = [prim.GetAttribute(digest_property_name(role))]
        if role != SIDECAR_ROLE:
            extra.append(prim.GetAttribute(packing_property_name(role)))
        if role in results.textures:
            asset = relative_asset_path(results.textures[role], layer_dir)
            if not attr.Set(Sdf.AssetPath(asset)):
                raise SchemaError(f"could not author {attr.GetPath()} = @{asset}@")
            attr.SetColorSpace(COLOR_SPACES[role])
            values = [results.digests.get(role, "")]
            if role != SIDECAR_ROLE:
                values.append(packing.get(role, ""))
            for a, v in zip(extra, values):
                if v:
                    if not a.Set(v):
                        raise SchemaError(f"could not author {a.GetPath()} = {v!r}")
                else:
                    a.Clear()
        else:
            for a in [attr] + extra:
                a.Clear()
                if a.HasAuthoredValue():
                    a.Block()
    _set(prim, "baked:resolution", Gf.Vec2i(*(int(r) for r in results.resolution)))
    _set(prim, "baked:model", results.model)
    _set(prim, "baked:ratio", results.ratio)
    _set(prim, "baked:solver", results.solver)
    _set(prim, "baked:uvPrimvar", results.uv_primvar)
    _set(prim, "baked:tangentFrame", results.tangent_frame)
    for name in FACTORS:
        _set(prim, f"baked:{name}", results.factor(name))
    _set(prim, "baked:contentHash", results.content_hash)
    _set(prim, "baked:partHashes", part_hashes)
    _set(prim, "baked:settings", settings)
    _set(prim, "baked:generator", results.generator)
    _set(prim, "baked:formatVersion", int(results.format_version))
    _set(prim, "baked:normals", results.normals)
    so_attr = prim.GetAttribute(property_name("atlas:scaleOffset"))
    page_attr = prim.GetAttribute(property_name("atlas:page"))
    if results.atlas:
        _set(prim, "atlas:scaleOffset", Gf.Vec4f(*(float(v) for v in results.scale_offset)))
        _set(prim, "atlas:page", int(results.page))
    else:
        for a in (so_attr, page_attr):
            a.Clear()
            if a.HasAuthoredValue():
                a.Block()


def is_baked(prim: Usd.Prim) -> bool:
    """Whether ``prim`` has the API and a bake record (formatVersion != 0)."""
    return has_api(prim) and int(_get(prim, "baked:formatVersion") or 0) != 0


def _parse_json(prim, key: str):
    text = _get(prim, key) or "{}"
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise SchemaError(f"{_prim_label(prim)}: {property_name(key)} is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise SchemaError(f"{_prim_label(prim)}: {property_name(key)} must be a JSON object")
    return value


def read_results(prim: Usd.Prim, *, validate: bool = True) -> BakeResults | None:
    """The prim's bake record, or None when it was never baked (formatVersion 0).

    ``textures`` holds resolved absolute paths (the authored asset path when it does not
    resolve, e.g. a missing file or a UDIM pattern); ``asset_paths`` the authored strings.
    With ``validate`` an invalid record raises SchemaError (see :func:`result_problems`).
    """
    _require_api(prim)
    if not is_baked(prim):
        return None
    textures, assets, digests, packing = {}, {}, {}, {}
    for role in FILE_ROLES:
        attr = prim.GetAttribute(file_property_name(role))
        if not attr.HasAuthoredValue():
            continue
        value = attr.Get()
        if value is None or not value.path:
            continue
        assets[role] = value.path
        textures[role] = value.resolvedPath or value.path
        d = prim.GetAttribute(digest_property_name(role))
        if d and d.HasAuthoredValue() and d.Get():
            digests[role] = str(d.Get())
        if role != SIDECAR_ROLE:
            pk = prim.GetAttribute(packing_property_name(role))
            if pk and pk.HasAuthoredValue() and pk.Get():
                packing[role] = str(pk.Get())
    factors = {name: float(_get(prim, f"baked:{name}")) for name in FACTORS}
    res = _get(prim, "baked:resolution")
    results = BakeResults(
        model=str(_get(prim, "baked:model")),
        ratio=str(_get(prim, "baked:ratio")),
        solver=str(_get(prim, "baked:solver")),
        uv_primvar=str(_get(prim, "baked:uvPrimvar")),
        resolution=(int(res[0]), int(res[1])),
        textures=textures,
        factors=factors,
        tangent_frame=str(_get(prim, "baked:tangentFrame")),
        content_hash=str(_get(prim, "baked:contentHash")),
        part_hashes=_parse_json(prim, "baked:partHashes"),
        settings=_parse_json(prim, "baked:settings"),
        generator=str(_get(prim, "baked:generator")),
        format_version=int(_get(prim, "baked:formatVersion")),
        asset_paths=assets,
        normals=str(_get(prim, "baked:normals")),
        digests=digests,
        packing=packing,
    )
    so_attr = prim.GetAttribute(property_name("atlas:scaleOffset"))
    if so_attr and so_attr.HasAuthoredValue() and so_attr.Get() is not None:
        so = so_attr.Get()
        page = prim.GetAttribute(property_name("atlas:page")).Get()
        results.scale_offset = tuple(float(v) for v in so)
        results.page = int(page or 0)
        results.atlas = True
    if validate:
        problems = result_problems(results)
        if problems:
            raise SchemaError(f"{_prim_label(prim)}: invalid bake record: " + "; ".join(problems))
    return results


# Instance records (AhdInstanceLightmapAPI) live in usdahd.usd.instance_records; the names are
# re-exported here so every record reader goes through this module.
from usdahd.usd.instance_records import (  # noqa: E402
    INSTANCE_API_NAME,
    INSTANCE_NAMESPACE,
    instance_carrier,
    instance_carriers,
    instance_key,
    instance_layout,
    instance_property_name,
    read_instance_records,
    stage_records,
    write_instance_records,
)
