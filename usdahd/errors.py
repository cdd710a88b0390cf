"""One flat module of exceptions. The CLI maps them to exit codes.

Every message should name what is wrong (a prim path, a file, a flag) and what to do.
"""

__all__ = [
    "BakeError",
    "ImageError",
    "InputError",
    "ModelError",
    "OutputError",
    "SchemaError",
    "StageError",
    "UsageError",
    "UsdAhdError",
]


class UsdAhdError(Exception):
    """Base class of every error usdahd raises on purpose."""

    exit_code = 1


class UsageError(UsdAhdError):
    """Bad command-line flags or API arguments (exit 2)."""

    exit_code = 2


class InputError(UsdAhdError):
    """The input (stage, file, array) cannot be used as given (exit 2)."""

    exit_code = 2


class StageError(InputError):
    """A USD stage could not be opened or contains nothing usable (exit 2)."""


class SchemaError(UsdAhdError):
    """The AhdLightmapAPI plugin is missing, or a schema value is invalid."""

    exit_code = 2


class ModelError(UsageError):
    """Unknown lighting model, ratio type or solver."""


class BakeError(UsdAhdError):
    """A prim failed to bake (exit 1; other prims may still succeed)."""

    exit_code = 1


class ImageError(UsdAhdError):
    """A texture could not be read or written."""

    exit_code = 1


class OutputError(UsdAhdError):
    """The output (layer, lightmaps folder) cannot be written: read-only, full, not a folder,
    locked (exit 2). The previous bake is left as it was."""

    exit_code = 2
