"""How every command prints its result: one JSON document on stdout with ``--json``, else
human-readable lines unless ``--quiet`` (progress and warnings go to stderr separately)."""

from __future__ import annotations

import json
from collections.abc import Callable


def emit(args, report: dict, human: Callable[[], None]) -> None:
    """Print ``report`` as indented JSON when ``args.json``; else call ``human()`` (which prints
    the lines a person reads) unless ``args.quiet``. ``args`` may lack either attribute."""
    if getattr(args, "json", False):
        print(json.dumps(report, indent=2))
    elif not getattr(args, "quiet", 0):
        human()
