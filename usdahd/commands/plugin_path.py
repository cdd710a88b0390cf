"""``usdahd plugin-path``: print the absolute path of usdahd's USD plugins.

Put it in ``PXR_PLUGINPATH_NAME`` so that USD tools which never import usdahd (usdview,
UsdValidation runs, engine importers) know the AhdLightmapAPI schema and the validators::

    eval "$(usdahd plugin-path --export)"
"""

from __future__ import annotations

import json
import os
import shlex


def add_parser(sub):
    p = sub.add_parser(
        "plugin-path",
        help="print the absolute path to put in PXR_PLUGINPATH_NAME",
        description=(
            "Print the absolute directory of usdahd's USD plugins (the AhdLightmapAPI schema "
            "and the validators). USD tools that do not import usdahd see the schema when this "
            "path is in PXR_PLUGINPATH_NAME (absolute paths only: USD ignores relative ones)."
        ),
    )
    p.add_argument(
        "--export",
        action="store_true",
        help="print a shell line 'export PXR_PLUGINPATH_NAME=...' that keeps existing entries",
    )
    p.set_defaults(func=run)
    return p


def export_line(path: str, existing: str | None) -> str:
    """``export PXR_PLUGINPATH_NAME=...`` with ``path`` first and other entries kept once."""
    entries = [path] + [e for e in (existing or "").split(os.pathsep) if e and e != path]
    return f"export PXR_PLUGINPATH_NAME={shlex.quote(os.pathsep.join(entries))}"


def run(args) -> int:
    from usdahd.usd import plugin  # loads pxr: here, not when the parser is built

    path = plugin.plugin_path()
    if getattr(args, "json", False):
        line = export_line(path, os.environ.get("PXR_PLUGINPATH_NAME"))
        print(json.dumps({"plugin_path": path, "export": line, "exit_code": 0}, indent=2))
    elif args.export:
        print(export_line(path, os.environ.get("PXR_PLUGINPATH_NAME")))
    else:
        print(path)
    return 0
