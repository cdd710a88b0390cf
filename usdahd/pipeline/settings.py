"""Bake settings: built-in defaults, the command-line options, and how a prim's settings are
resolved (built-in defaults < CLI flags < per-prim schema inputs), with the usage checks that
hold for every prim.
"""

from __future__ import annotations

from dataclasses import dataclass

from usdahd import models
from usdahd.errors import UsageError

__all__ = [
    "BakeOptions",
    "DEFAULTS",
    "DEFAULT_TEXEL_BUDGET",
    "DENSITY_AUTO_MAX",
    "DENSITY_LADDER",
    "DENSITY_MAX_RESOLUTION",
    "MAX_RESOLUTION",
    "MIN_RESOLUTION",
    "RESOLUTION_MULTIPLE",
    "TINY_RESOLUTION",
    "UV_DEGENERATE_LIMIT",
    "UV_OUTSIDE_LIMIT",
    "authored_inputs",
    "check_options",
    "record_time",
    "resolve_settings",
]

#: Built-in defaults; CLI flags override them, per-prim schema inputs override both.
DEFAULTS = {
    "model": "hhd",
    "ratio": None,  # the model's first ratio type (luminance for IrradZ models)
    "solver": None,  # the model's default solver
    "uv": "st",
    "resolution": None,  # None: from texel_density
    "texel_density": "auto",  # texels per metre; "auto": from the scene's texel budget
    "samples": 256,
    "bounces": 64,  # a safety cap: paths end by Russian roulette (integrate.DEFAULT_BOUNCES)
    "padding": 4,
    "container": "files",  # "ktx2" / "ktx2-bc": also write KTX2 engine containers (usdahd.ktx2)
}
#: Largest lightmap side we agree to allocate (memory: 16k^2 x 27 float32 = 27 GiB).
MAX_RESOLUTION = 8192
#: Largest side a *texel density* may ask for without an explicit --resolution: a 221 m ground
#: quad at 16 texels/m would otherwise take most of the bake; clamped with a warning.
DENSITY_MAX_RESOLUTION = 1024
#: A UV set is unusable as a lightmap (and gets unwrapped into a new primvar) when more than
#: numerics.raster.UV_OVERLAP_LIMIT of its covered texels overlap, or more than this fraction
#: of its UVs lie outside [0, 1].
UV_OUTSIDE_LIMIT = 0.001
#: ... or when zero-area UV triangles cover more than this fraction of the mesh's surface.
UV_DEGENERATE_LIMIT = 0.01
#: How a --ratio / --solver the model does not offer is reported (models.choice_problem).
FLAG_TEXT = {
    "ratio": "model {model!r} supports --ratio {allowed}, not {value!r}",
    "solver": "model {model!r} has --solver {allowed}, not {value!r}",
}
#: Largest ``--atlas-padding`` (texels between two rectangles of a page).
MAX_ATLAS_PADDING = 64
#: A density-derived lightmap smaller than this on its longer side gets a warning (wrong units?).
TINY_RESOLUTION = 8

# -- The automatic texel density (docs/texels.md "Texel density and resolution"): used when no
# --texel-density / --resolution flag and no ahdLightmap:texelDensity / resolution input is
# given. One density for the whole stage (so every prim of an atlas page has the same texel
# size), the largest step of DENSITY_LADDER at or below DENSITY_AUTO_MAX whose maps fit the
# texel budget; each map at least MIN_RESOLUTION per side, at most DENSITY_MAX_RESOLUTION.

#: Texels (sum of w x h over the prims on the automatic density) a stage gets by default: one
#: 1024^2 page, Unity's default Max Lightmap Size (LightingSettings.lightmapMaxSize = 1024).
DEFAULT_TEXEL_BUDGET = 1 << 20
#: Density ceiling (texels per metre, 6.25 cm texels): the former fixed default, between
#: Godot's import default (generate_lightmap_uv2_texel_size 0.2 m = 5 texels/m) and Unity's
#: Lightmap Resolution (40 texels per unit); stages of 8 m and more keep it, smaller ones start
#: higher (density.STAGE_MIN_TEXELS: the floor by stage size).
DENSITY_AUTO_MAX = 16.0
#: Steps of the automatic density: DENSITY_AUTO_MAX * 2^(-k/4), so a small edit of one prim
#: rarely moves the stage's density (which would re-bake every prim).
DENSITY_LADDER = 2.0 ** (-1 / 4)
#: Smallest side of a map on the automatic density (a prop 20 cm across still gets ~8 texels
#: over each face of a box); Unreal's default per-mesh Light Map Resolution and Datasmith's
#: min_lightmap_resolution are 64, for 4x4-block-compressed pages of 2 lightmap rows per texel.
MIN_RESOLUTION = 32
#: Sides from the automatic density are rounded up to a multiple of this (atlas pages pack
#: rectangles on 4x4 texel blocks, the BC block size); an explicit density is not rounded.
RESOLUTION_MULTIPLE = 4


@dataclass
class BakeOptions:
    """Command-line level options; ``None`` means "not given" (fall back to defaults)."""

    output: str | None = None
    prims: list[str] | None = None
    model: str | None = None
    ratio: str | None = None
    solver: str | None = None
    uv: str | None = None
    resolution: int | None = None
    texel_density: float | None = None
    #: texels the automatic density may spend on the stage (None: DEFAULT_TEXEL_BUDGET)
    texel_budget: int | None = None
    samples: int | None = None
    bounces: int | None = None
    seed: int = 0
    padding: int | None = None
    adaptive: bool = False
    denoise: bool = True
    container: str | None = None
    unwrap: bool = True
    force: bool = False
    dry_run: bool = False
    quiet: bool = False
    time: float | str | None = None  # None: automatic (usd.time.resolve_time); "default"
    #: A lighting scenario (usdahd.usd.scenarios): as given, then the canonical /Prim{set=v}.
    scenario: str | None = None
    #: Trace in tiles on a Dask cluster (usdahd.pipeline.distributed): a LocalCluster of this
    #: many worker processes, or the existing cluster at this scheduler address. Outputs are
    #: identical to a plain bake, so neither is a bake setting (not in the content hash).
    workers: int | None = None
    scheduler: str | None = None
    #: Seconds to wait for another bake of the same output (None: the default,
    #: usdahd.pipeline.outputs.DEFAULT_LOCK_TIMEOUT); not a bake setting either.
    lock_timeout: float | None = None
    #: Atlas pages (usdahd.pipeline.atlas): records share power-of-two pages of at most
    #: ``atlas_size`` (None: numerics.atlas.DEFAULT_SIZE) with ``atlas_padding`` texels between
    #: rectangles (None: ``padding``, else 4). Not bake settings (not in the content hash): a
    #: page layout changes where a record's texels are stored, never their values.
    atlas: bool = True
    atlas_size: int | None = None
    atlas_padding: int | None = None


def authored_inputs(prim) -> dict:
    """Bake inputs authored on ``prim`` (per-prim overrides), as BakeOptions field names."""
    from usdahd.usd import schema

    if not prim or not schema.has_api(prim):
        return {}
    inputs = schema.read_inputs(prim)  # validates every value; SchemaError names the prim
    authored = schema.authored_input_fields(prim)
    keys = schema.SETTING_KEYS
    out = {keys[n]: getattr(inputs, n) for n in schema.INPUT_KEYS if n in keys and n in authored}
    if out.get("resolution") == 0:
        del out["resolution"]  # 0 means "from texel density"
    return out


def resolve_settings(
    opts: BakeOptions, authored: dict, meters_per_unit: float = 1.0, auto_density=None
) -> dict:
    """Built-in defaults < CLI flags < per-prim authored schema inputs.

    auto_density : the stage's automatic texel density (texels per metre,
        :func:`usdahd.pipeline.density.auto_texel_density`), used when neither a resolution nor a
        density is given; then ``min_resolution`` is recorded too (it decides the map size;
        the budget itself is not a setting, only the density it gives is, so a new budget that
        gives the same density re-bakes nothing). None: DENSITY_AUTO_MAX.
    """
    s = dict(DEFAULTS)
    for k in DEFAULTS:
        v = getattr(opts, k, None)
        if v is not None:
            s[k] = v
    if opts.texel_density is not None:
        s["resolution"] = None
    if opts.resolution is not None:
        s["texel_density"] = None
    for k, v in authored.items():
        s[k] = v
        if k == "texel_density" and "resolution" not in authored:
            s["resolution"] = None
        if k == "resolution":
            s["texel_density"] = None
    if s["texel_density"] == "auto":
        s["texel_density"] = float(auto_density or DENSITY_AUTO_MAX)
        s["min_resolution"] = MIN_RESOLUTION
        # an explicit density keeps its exact size, ceil(T * extent), as before
        s["resolution_multiple"] = RESOLUTION_MULTIPLE
    mod = models.get(s["model"])
    problem = models.choice_problem(s["model"], "ratio", s["ratio"], mod.RATIOS, FLAG_TEXT["ratio"])
    if problem is not None:
        if opts.ratio is not None and "ratio" not in authored:
            raise UsageError(problem)
        s["ratio"] = mod.RATIOS[0]  # e.g. the schema fallback "luminance" on an SH model
    if s["solver"] in (None, ""):
        s["solver"] = mod.DEFAULT_SOLVER
    models.check_choice(s["model"], "solver", s["solver"], mod.SOLVERS, error=UsageError)
    s["seed"] = opts.seed
    s["meters_per_unit"] = meters_per_unit
    s["adaptive"] = bool(opts.adaptive)
    s["denoise"] = bool(opts.denoise)
    if opts.scenario:  # only then: plain bakes keep their settings (and hashes) unchanged
        s["scenario"] = opts.scenario
    return s


def record_time(settings: dict, scene) -> None:
    """The bake time in ``baked:settings`` (so in the content hash): ``time`` is the time code
    or "default"; ``time_auto`` whether it was chosen from the stage (startTimeCode), so the
    validator can tell when a re-bake would read another time."""
    settings["time"] = scene.time_setting
    settings["time_auto"] = bool(scene.time_auto)


def check_options(opts: BakeOptions) -> None:
    """Flag combinations that are wrong for every prim: usage errors (exit 2) up front."""
    model = opts.model or DEFAULTS["model"]
    mod = models.get(model)
    for kind, value, allowed in (
        ("ratio", opts.ratio, mod.RATIOS),
        ("solver", opts.solver, mod.SOLVERS),
    ):
        if value is not None:
            models.check_choice(model, kind, value, allowed, FLAG_TEXT[kind], error=UsageError)
    if opts.resolution is not None and not 1 <= opts.resolution <= MAX_RESOLUTION:
        raise UsageError(f"--resolution must be in 1..{MAX_RESOLUTION}, got {opts.resolution}")
    if opts.texel_budget is not None and not opts.texel_budget >= MIN_RESOLUTION**2:
        raise UsageError(
            f"--texel-budget must be at least {MIN_RESOLUTION**2} texels (one "
            f"{MIN_RESOLUTION}x{MIN_RESOLUTION} map), got {opts.texel_budget}"
        )
    if opts.texel_budget is not None and (
        opts.texel_density is not None or opts.resolution is not None
    ):
        flag = "--texel-density" if opts.texel_density is not None else "--resolution"
        raise UsageError(
            f"--texel-budget sets the automatic texel density, which {flag} replaces for "
            f"every prim; pass one of them"
        )
    from usdahd.numerics import atlas

    if opts.atlas_size is not None and not (
        atlas.is_power_of_two(opts.atlas_size) and 16 <= opts.atlas_size <= MAX_RESOLUTION
    ):
        raise UsageError(
            f"--atlas-size must be a power of two in 16..{MAX_RESOLUTION} (pages are powers of "
            f"two), got {opts.atlas_size}; e.g. --atlas-size 1024"
        )
    if opts.atlas_padding is not None and not (
        atlas.MIN_PADDING <= opts.atlas_padding <= MAX_ATLAS_PADDING
    ):
        raise UsageError(
            f"--atlas-padding must be {atlas.MIN_PADDING}..{MAX_ATLAS_PADDING} texels (bilinear "
            f"filtering needs a gutter texel per neighbour), got {opts.atlas_padding}"
        )
    if opts.container not in (None, "files", "ktx2", "ktx2-bc"):
        raise UsageError(f"--container must be files, ktx2 or ktx2-bc, got {opts.container!r}")
    from usdahd.pipeline import distributed

    distributed.require(opts.workers, opts.scheduler)  # before anything is read or traced
    if opts.container == "ktx2-bc":
        try:
            import ispc_texcomp  # noqa: F401
        except ImportError:
            raise UsageError(
                "--container ktx2-bc needs ispc-texcomp (the BC6H/BC7 encoder): "
                "pip install 'usdahd[ktx2]'"
            ) from None
        try:
            import imagecodecs  # noqa: F401
        except ImportError:
            raise UsageError(
                "--container ktx2-bc needs imagecodecs (it checks each BC6H texture's error): "
                "pip install 'usdahd[ktx2]'"
            ) from None
