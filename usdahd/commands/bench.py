"""``usdahd bench``: regenerate docs/benchmarks.md and its plots (runs benchmarks/run.py).

The benchmark scripts and the sample stages they bake live in the source checkout
(``benchmarks/``, ``samples/``), not in the installed package, so this command works from a
checkout (``pip install -e '.[bench]'`` or ``PYTHONPATH=.``) and says so otherwise.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

from usdahd.commands.output import emit
from usdahd.errors import UsageError

#: benchmarks/run.py's sections, all run by default (its DEFAULT_SECTIONS; kept equal by a test).
SECTIONS = "bake,fit,encodings,skipping,soak,ktx2,reference"

#: The checkout's root, when usdahd is imported from one (``<root>/usdahd/commands/bench.py``).
CHECKOUT = Path(__file__).resolve().parents[2]


def _is_checkout(root: Path) -> bool:
    return (root / "benchmarks" / "run.py").is_file() and (root / "samples").is_dir()


def benchmarks_dir(root: Path | None = None) -> Path:
    """``<checkout>/benchmarks``: of ``root``, else of the checkout usdahd is imported from,
    else of the current directory (a clone with usdahd installed from it non-editably).
    UsageError when none has benchmarks/run.py and samples/."""
    candidates = [root] if root is not None else [CHECKOUT, Path.cwd()]
    for cand in candidates:
        if _is_checkout(cand):
            return cand / "benchmarks"
    raise UsageError(
        "usdahd bench needs the source checkout (benchmarks/run.py and samples/), but usdahd is "
        f"imported from {CHECKOUT / 'usdahd'} and the current directory "
        f"{candidates[-1]} is not a checkout either. Run it from a git clone: "
        "pip install '.[bench]' && usdahd bench (or: python benchmarks/run.py)"
    )


def load_runner(root: Path | None = None):
    """Import benchmarks/run.py of the checkout as a module."""
    bench = benchmarks_dir(root)
    if str(bench) not in sys.path:
        sys.path.insert(0, str(bench))
    name = "usdahd_benchmarks_run"
    spec = importlib.util.spec_from_file_location(name, bench / "run.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while executing it
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def add_parser(sub):
    p = sub.add_parser(
        "bench",
        help="regenerate docs/benchmarks.md and its plots (needs a source checkout)",
        description=(
            "Run the benchmarks (bake run time against error, fit speed and error per model and "
            "solver, encodings after quantization, skipping, soak, KTX2 containers, usdahd vs "
            "Blender Cycles) and write docs/benchmarks.md with PNG plots in docs/benchmarks/. "
            "Same as python benchmarks/run.py; needs matplotlib (pip install 'usdahd[bench]')."
        ),
    )
    p.add_argument("--quick", action="store_true", help="~2-3 minute run (fewer samples)")
    p.add_argument("--out", default=None, help="report path (default: docs/benchmarks.md)")
    p.add_argument(
        "--sections",
        default=SECTIONS,
        help=f"comma-separated subset of {SECTIONS} (reference: usdahd vs Blender Cycles; needs "
        "$USDAHD_BPY_PYTHON, see benchmarks/reference/README.md; reported as not run without it)",
    )
    p.add_argument(
        "--reference-stages",
        nargs="+",
        metavar="STAGE",
        help="the reference section's stages by file stem (default: every lit sample stage and "
        "the shared Cornell boxes)",
    )
    p.add_argument("--fresh", action="store_true", help="recompute cached reference bakes")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    runner = load_runner()
    ns = argparse.Namespace(
        quick=args.quick,
        out=args.out or str(CHECKOUT / "docs" / "benchmarks.md"),
        sections=args.sections,
        reference_stages=args.reference_stages,
        fresh=args.fresh,
        quiet=bool(args.quiet or args.json),
    )
    runner.check_args(ns)  # usage errors first
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise UsageError("usdahd bench needs matplotlib: pip install 'usdahd[bench]'") from None
    out = runner.run(ns)
    emit(args, {"report": str(out), "exit_code": 0}, lambda: print(out))
    return 0
