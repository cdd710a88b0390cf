"""Register usdahd's USD plugins (the AhdLightmapAPI schema, the validators) with Plug.

``import usdahd.usd`` calls :func:`register` before anything creates a stage: USD reads schema
plugins when its schema registry is first built (by the first ``Usd.Stage`` or
``Usd.SchemaRegistry()``), and a plugin registered later has a TfType of kind Invalid, so
``ApplyAPI`` fails with "Cannot find a valid schema". :func:`register` checks that the schema
is usable afterwards and raises :class:`usdahd.errors.SchemaError` with what to do otherwise.

Other USD tools (usdview, UsdValidation runs, engine importers) see the schema without importing
usdahd when ``PXR_PLUGINPATH_NAME`` holds :func:`plugin_path` (an absolute path: USD silently
ignores relative entries). ``usdahd plugin-path`` prints it.

Where the plugins are: an installed wheel carries them in ``usdahd/_resources/plugins`` (see
setup.py); a source checkout or an editable install uses the repository's ``plugins/``. That
directory's plugInfo.json ``Includes`` every plugin below it.
"""

from __future__ import annotations

from pathlib import Path

from usdahd.errors import SchemaError

__all__ = ["API_NAME", "SCHEMA_TYPE_NAME", "plugin_path", "register"]

#: Plug plugin name of the codeless schema (plugins/usdAhd/resources/plugInfo.json).
PLUGIN_NAME = "usdAhd"
#: Directory name of the validator plugin (issue 6), registered too when present.
VALIDATORS_DIR = "usdAhdValidators"
#: Schema identifier and TfType name (the generator prefixes the library name).
API_NAME = "AhdLightmapAPI"
SCHEMA_TYPE_NAME = "UsdAhdAhdLightmapAPI"

_PACKAGE_DIR = Path(__file__).resolve().parent.parent  # .../usdahd


def candidate_dirs() -> list[Path]:
    """Plugin directories in search order: the installed copy, then the source checkout's."""
    return [_PACKAGE_DIR / "_resources" / "plugins", _PACKAGE_DIR.parent / "plugins"]


def plugin_dir() -> Path:
    """Absolute directory whose plugInfo.json includes every usdahd plugin.

    Raises SchemaError when neither the installed nor the source-checkout copy exists.
    """
    for d in candidate_dirs():
        if (d / "plugInfo.json").is_file() and (d / PLUGIN_NAME).is_dir():
            return d.resolve()
    looked = ", ".join(str(d) for d in candidate_dirs())
    raise SchemaError(
        f"the usdahd USD plugins are missing (looked in {looked}); reinstall usdahd with "
        "'pip install usdahd' (the wheel ships them in usdahd/_resources/plugins) or run from a "
        "source checkout that has plugins/"
    )


def plugin_path() -> str:
    """The absolute path to put in ``PXR_PLUGINPATH_NAME`` so USD tools see the schema."""
    return str(plugin_dir())


def _registered_under(directory: Path) -> bool:
    from pxr import Plug

    top = directory.resolve()
    return any(
        p.path and Path(p.path).resolve().is_relative_to(top)
        for p in Plug.Registry().GetAllPlugins()
    )


def register() -> Path:
    """Register the usdahd plugins with USD (idempotent) and check the schema is usable.

    Registers :func:`plugin_dir` unless a plugin named ``usdAhd`` is already known (e.g. from
    ``PXR_PLUGINPATH_NAME``), and ``plugins/usdAhdValidators`` if it exists and is not yet
    registered. Returns the plugin directory. Raises SchemaError when the schema is unknown or
    invalid afterwards, typically because a stage was created before usdahd.usd was imported.
    """
    from pxr import Plug

    directory = plugin_dir()
    registry = Plug.Registry()
    if registry.GetPluginWithName(PLUGIN_NAME) is None:
        registry.RegisterPlugins([str(directory)])
    validators = directory / VALIDATORS_DIR
    if validators.is_dir() and not _registered_under(validators):
        registry.RegisterPlugins([str(validators)])
    check()
    return directory


def check() -> None:
    """Raise SchemaError unless AhdLightmapAPI is a valid single-apply API schema."""
    from pxr import Plug, Usd

    if Plug.Registry().GetPluginWithName(PLUGIN_NAME) is None:
        raise SchemaError(
            f"USD plugin {PLUGIN_NAME!r} is not registered; import usdahd.usd first or set "
            f"PXR_PLUGINPATH_NAME={plugin_path()}"
        )
    info = Usd.SchemaRegistry.FindSchemaInfo(API_NAME)
    if info is None or info.kind != Usd.SchemaKind.SingleApplyAPI:
        raise SchemaError(
            f"USD schema {API_NAME} is registered but not usable (kind "
            f"{getattr(info, 'kind', 'unknown')}): USD built its schema registry before usdahd "
            "registered its plugin. Import usdahd.usd before creating any Usd.Stage or "
            f"Usd.SchemaRegistry, or set PXR_PLUGINPATH_NAME={plugin_path()} before starting "
            "Python"
        )
