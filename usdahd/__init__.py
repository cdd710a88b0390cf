"""usdahd: directional lightmaps baked from OpenUSD stages and described by a USD schema.

Public API (kept small; see README and docs/):

- :func:`usdahd.fit` — fit a lighting model to tangent-space radiance SH.
- :func:`usdahd.models.get` — the model registry.
- :mod:`usdahd.sh` — the SH basis and constants (an alias of :mod:`usdahd.numerics.sh`).

``import usdahd`` needs only numpy and numba: pxr and OpenImageIO are imported by the modules
that use them. The USD plugins (schema and validators) are registered when :mod:`usdahd.usd` is
first imported — by the baker, the validator and the CLI before they open a stage; Python code
that creates stages with the AhdLightmapAPI schema itself imports ``usdahd.usd`` first.
"""

from usdahd._version import __version__
from usdahd.models import fit

__all__ = ["__version__", "fit"]
