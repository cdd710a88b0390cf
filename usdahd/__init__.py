"""usdahd: directional lightmaps baked from OpenUSD stages and described by a USD schema.

Public API (kept small; see README and docs/):

- :func:`usdahd.fit` — fit a lighting model to tangent-space radiance SH.
- :func:`usdahd.models.get` — the model registry.

Importing the package registers the USD plugins (schema and validators) before any stage is
created; numerics (``usdahd.sh``, ``usdahd.models``) do not need pxr.
"""

from usdahd._version import __version__
from usdahd.models import fit

__all__ = ["__version__", "fit"]
