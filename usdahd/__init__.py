"""usdahd: directional lightmaps baked from OpenUSD stages and described by a USD schema.

Public API (kept small; see README and docs/):

- :func:`usdahd.fit` — fit a lighting model to tangent-space radiance SH.
- :func:`usdahd.models.get` — the model registry.

Importing the package registers the USD plugins (schema and validators) before any stage is
created; numerics (``usdahd.sh``, ``usdahd.models``) do not need pxr.
"""

from usdahd._version import __version__
from usdahd.usd import plugin as _plugin

# Before anything else can create a stage: USD reads schema plugins once, when its schema
# registry is first built. Raises usdahd.errors.SchemaError if the schema ends up unusable.
_plugin.register()

from usdahd.models import fit  # noqa: E402

__all__ = ["__version__", "fit"]
