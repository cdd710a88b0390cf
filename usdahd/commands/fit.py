"""``usdahd fit SH.npy``: fit a lighting model to radiance SH stored in a .npy/.npz file."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from usdahd import models
from usdahd import sh as shmod
from usdahd.errors import InputError


def add_parser(sub):
    p = sub.add_parser(
        "fit",
        help="fit a lighting model to tangent-space radiance SH in a .npy file",
        description=(
            "Fit a lighting model to tangent-space incident radiance SH of shape (..., 3, 9) "
            "(RGB x 9 coefficients, z = normal) read from a .npy file or the 'sh' array of an "
            ".npz, and report the hemispherical irradiance error. With -o, write the fitted "
            "parameters to an .npz."
        ),
    )
    p.add_argument("sh", help=".npy file, or .npz with an array named 'sh'")
    p.add_argument(
        "--model",
        default="hhd",
        help="lighting model (default hhd): %(choices)s",
        choices=list(models.REGISTRY),
    )
    p.add_argument("--ratio", default=None, help="luminance or rgb (IrradZ models)")
    p.add_argument("--solver", default=None, help="solver name (default: the model's)")
    p.add_argument(
        "--objective",
        choices=["luminance", "rgb"],
        help="ahd/hhd with --ratio luminance: fit the shared w_a to the luminance error "
        "(default) or to the summed RGB error",
    )
    p.add_argument("-o", "--output", help="write fitted parameters to this .npz")
    p.set_defaults(func=run)
    return p


def load_sh(path: str) -> np.ndarray:
    """Read (..., 3, 9) radiance SH from a .npy or .npz ('sh') file, with clear errors."""
    f = Path(path)
    if not f.is_file():
        raise InputError(f"{path}: no such file")
    try:
        data = np.load(f, allow_pickle=False)
    except Exception as exc:  # numpy raises several types for corrupt files
        raise InputError(f"{path}: not a readable .npy/.npz file ({exc})") from None
    if isinstance(data, np.lib.npyio.NpzFile):
        if "sh" not in data.files:
            raise InputError(f"{path}: .npz has no array named 'sh' (has {data.files})")
        data = data["sh"]
    if data.ndim < 2 or data.shape[-2:] != (3, 9):
        raise InputError(f"{path}: expected shape (..., 3, 9), got {data.shape}")
    return data


def hemispherical_rmse(sh: np.ndarray, fitted, n_dirs: int = 256) -> np.ndarray:
    """RMSE over the upper hemisphere of the fitted irradiance against the SH irradiance.

    sh : (n, 3, 9); returns (n,) relative to the mean target irradiance (luminance).
    """
    dirs = shmod.fibonacci_sphere(n_dirs, hemisphere=True)
    target = shmod.irradiance(sh[:, None], dirs[None])  # (n, d, 3)
    got = fitted.evaluate(np.broadcast_to(dirs, (sh.shape[0],) + dirs.shape))
    err = np.sqrt(((got - target) ** 2).mean(axis=(1, 2)))
    scale = np.abs(target).mean(axis=(1, 2))
    return err / np.where(scale > 0, scale, 1.0)


def run(args) -> int:
    data = load_sh(args.sh)
    options = {"objective": args.objective} if args.objective else {}
    flat = data.reshape(-1, 3, 9).astype(np.float64)
    fitted = models.fit(flat, args.model, ratio=args.ratio, solver=args.solver, **options)
    rel = hemispherical_rmse(flat, fitted)
    # Parameters keep the file's leading shape.
    lead = data.shape[:-2]
    fitted.params = {k: v.reshape(lead + v.shape[1:]) for k, v in fitted.params.items()}
    report = {
        "file": args.sh,
        "model": fitted.model,
        "ratio": fitted.ratio,
        "solver": fitted.solver,
        "texels": int(flat.shape[0]),
        "relative_rmse_mean": float(np.mean(rel)),
        "relative_rmse_max": float(np.max(rel)),
        "params": {k: list(v.shape) for k, v in fitted.params.items()},
    }
    if args.output:
        from usdahd.io_util import atomic_write_npz

        atomic_write_npz(args.output, **fitted.params)
        report["output"] = args.output
    if args.json:
        print(json.dumps(report, indent=2))
    elif not args.quiet:
        print(
            f"{report['texels']} texels  model={fitted.model} ratio={fitted.ratio} "
            f"solver={fitted.solver}  hemispherical relative RMSE mean "
            f"{report['relative_rmse_mean']:.4g} max {report['relative_rmse_max']:.4g}"
        )
        for k, v in fitted.params.items():
            print(f"  {k}: shape {v.shape}")
        if args.output:
            print(f"wrote {args.output}", file=sys.stderr)
    return 0
