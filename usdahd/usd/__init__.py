"""USD stage access, the only pxr user: plugin, schema, scene extraction, authoring, rules.

Importing ``usdahd.usd`` (or any module below it) registers usdahd's USD plugins — the
AhdLightmapAPI schema and the validators — once, before anything in the package can create a
stage: USD reads schema plugins when its schema registry is first built. Everything pxr-facing
in usdahd goes through this package, so ``import usdahd`` and the numerics never need pxr.
Raises :class:`usdahd.errors.SchemaError` if the schema ends up unusable (see
:mod:`usdahd.usd.plugin`).
"""

from usdahd.usd import plugin as _plugin

_plugin.register()
