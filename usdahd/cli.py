"""The ``usdahd`` command line: one subcommand per module in ``usdahd/commands/``.

Results go to stdout, progress and status to stderr. Exit status: 0 ok, 1 findings or a
failed prim, 2 usage or input error (argparse's own errors also exit 2).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from usdahd._version import __version__
from usdahd.errors import UsdAhdError

#: subcommand name -> module in usdahd.commands defining ``add_parser(subparsers)`` and
#: ``run(args) -> int``.
COMMANDS = {
    "bake": "usdahd.commands.bake",
    "validate": "usdahd.commands.validate",
    "fit": "usdahd.commands.fit",
    "bench": "usdahd.commands.bench",
    "plugin-path": "usdahd.commands.plugin_path",
    "preview": "usdahd.commands.preview",
}


def _available():
    for name, path in COMMANDS.items():
        try:
            yield name, importlib.import_module(path)
        except ModuleNotFoundError as exc:
            if exc.name != path:
                raise


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="usdahd",
        description=(
            "Bake directional lightmaps (IrradZ AHD/HHD/HLSH, SH, ambient cube) from an OpenUSD "
            "stage, describe them with the AhdLightmapAPI schema, and validate them in asset CI."
        ),
    )
    parser.add_argument("--version", action="version", version=f"usdahd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for _name, mod in _available():
        mod.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UsdAhdError as exc:
        print(f"usdahd {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"usdahd {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
