"""``usdahd bake``: stage -> scene -> texels -> SH -> fit -> textures -> schema.

The orchestration package; each step of the work lives in its own module (``usd/reader.py``,
``bake/texels.py``, ``bake/integrate.py``, ``bake/post.py``, ``models/``, ``images.py``,
``usd/author.py``). Here:

- ``settings.py``: :class:`BakeOptions`, defaults and the resolution of every setting;
- ``preflight.py``: the checks before any scene is read;
- ``plan.py``: the per-mesh plan (:class:`PrimJob`: settings, UVs, resolution, refit or trace);
- ``stages.py``: the per-prim work (trace, post-process, fit, encode, write);
- ``outputs.py``: output file names, commit, the override layer, cleanup and the output lock;
- ``run.py``: :func:`bake`, which runs them in order and decides what to skip.

Nothing is written until a prim's bake succeeded; every file is written atomically (temp file
+ rename) and the override layer last, so an interrupted bake leaves the previous outputs valid.
This module only re-exports the public names.
"""

from __future__ import annotations

from usdahd.pipeline.outputs import FAULT_POINTS, layer_prefix, sanitize
from usdahd.pipeline.plan import PrimJob
from usdahd.pipeline.preflight import default_output, preflight
from usdahd.pipeline.run import MAX_BAKE_BYTES, bake
from usdahd.pipeline.settings import DEFAULTS, MAX_RESOLUTION, BakeOptions, resolve_settings

__all__ = [
    "DEFAULTS",
    "FAULT_POINTS",
    "MAX_BAKE_BYTES",
    "MAX_RESOLUTION",
    "BakeOptions",
    "PrimJob",
    "bake",
    "default_output",
    "layer_prefix",
    "preflight",
    "resolve_settings",
    "sanitize",
]
