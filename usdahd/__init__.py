"""usdahd: directional lightmaps baked from OpenUSD stages and described by a USD schema.

Public API (kept small; see README and docs/):

- :func:`usdahd.fit` — fit a lighting model to tangent-space radiance SH.
- :func:`usdahd.models.get` — the model registry.
- :mod:`usdahd.sh` — the SH basis and constants (an alias of :mod:`usdahd.numerics.sh`).

``import usdahd`` imports nothing heavy (``usdahd.fit`` loads the models, numpy and numba, on
first use); pxr and OpenImageIO are imported by the modules that use them. The USD plugins
(schema and validators) are registered when :mod:`usdahd.usd` is first imported — by the baker,
the validator and the CLI before they open a stage; Python code that creates stages with the
AhdLightmapAPI schema itself imports ``usdahd.usd`` first.
"""

from usdahd.version import __version__

__all__ = ["__version__", "fit"]


def __getattr__(name):
    # ``usdahd.fit`` and the subpackages load on first use: ``import usdahd`` (which the
    # ``usdahd`` console script does before it can catch Ctrl-C) stays instant (issue 40).
    import importlib

    if name == "fit":
        from usdahd.models import fit

        return fit
    try:
        return importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
