"""``usdahd fit SH.npy``: fit a lighting model to radiance SH stored in a .npy/.npz file."""

from __future__ import annotations

import os
import sys
import zipfile
from pathlib import Path

import numpy as np

from usdahd import budget, models
from usdahd.commands.output import emit
from usdahd.errors import InputError, UsageError
from usdahd.numerics import sh as shmod
from usdahd.numerics.stats import rmse_over_mean_abs


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


#: Texels fitted per chunk: memory stays bounded whatever the file size (measured peak about
#: 140 MB at 4096 texels for sh_l1, most of it the models' evaluation at 256 directions).
CHUNK = 4096
#: Largest array accepted (elements); a bigger one is refused before anything is read.
MAX_ELEMENTS = 2**34


def _read_header(fh):
    """(shape, fortran_order, dtype) of an .npy stream, with numpy's public readers."""
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version == (1, 0):
        return fmt.read_array_header_1_0(fh)
    if version == (2, 0):
        return fmt.read_array_header_2_0(fh)
    raise ValueError(f"unsupported .npy format version {version[0]}.{version[1]}")


class ShSource:
    """(n, 3, 9) radiance SH read in chunks from a .npy (memory-mapped) or the 'sh' array of
    an .npz (streamed from the zip member), never loaded whole.

    shape : the file's full shape (..., 3, 9); n : texels; dtype : its numpy dtype.
    ``chunks(size)`` yields (start, (k, 3, 9) float64) and checks every value is finite.
    """

    def __init__(self, path: str):
        self.path = path
        f = Path(path)
        if f.is_dir():
            raise InputError(f"{path}: is a directory; give a .npy or .npz file")
        if not f.exists():
            raise InputError(f"{path}: no such file")
        if not f.is_file():
            raise InputError(f"{path}: not a regular file; give a .npy or .npz file")
        self._zip = None
        try:
            if zipfile.is_zipfile(f):
                self._open_npz(f)
            else:
                self._open_npy(f)
        except InputError:
            raise
        except ValueError as exc:
            if "pickle" in str(exc).lower() or "object" in str(exc).lower():
                raise self._pickle_error() from None
            raise InputError(f"{path}: not a readable .npy/.npz file ({exc})") from None
        except Exception as exc:  # numpy raises several types for corrupt files
            raise InputError(f"{path}: not a readable .npy/.npz file ({exc})") from None
        self._check()

    def _pickle_error(self) -> InputError:
        return InputError(
            f"{self.path}: holds Python objects (a pickle); usdahd fit reads numeric arrays "
            "only, never pickles: save the SH with np.save(path, np.asarray(sh, np.float32))"
        )

    def _open_npy(self, f: Path) -> None:
        with open(f, "rb") as fh:
            shape, fortran, dtype = _read_header(fh)
        self.shape, self.dtype = tuple(shape), np.dtype(dtype)
        self._check_dtype()
        self._fortran = fortran
        self._inflated = None
        self._check_shape()  # before mapping: np.load checks the size against the file
        self._array = np.load(f, mmap_mode="r", allow_pickle=False)

    def _open_npz(self, f: Path) -> None:
        self._zip = zipfile.ZipFile(f)
        names = self._zip.namelist()
        if "sh.npy" not in names:
            found = [n[:-4] if n.endswith(".npy") else n for n in names]
            raise InputError(f"{self.path}: .npz has no array named 'sh' (has {found})")
        info = self._zip.getinfo("sh.npy")
        # Only the member's header is inflated here (a few hundred bytes); its declared size and
        # the array's are checked against the memory budget (_check) before any data is read.
        with self._zip.open("sh.npy") as fh:
            shape, fortran, dtype = _read_header(fh)
            self._offset = fh.tell()
        self.shape, self.dtype, self._fortran = tuple(shape), np.dtype(dtype), fortran
        self._inflated = int(info.file_size)
        self._check_dtype()
        self._array = None

    def _check_dtype(self) -> None:
        if self.dtype.hasobject:
            raise self._pickle_error()
        if self.dtype.kind == "c":
            raise InputError(
                f"{self.path}: complex values (dtype {self.dtype}); radiance SH are real: "
                "save the real part"
            )
        if self.dtype.kind not in "fiu":
            raise InputError(
                f"{self.path}: dtype {self.dtype} is not numeric; save float32 or float64 SH"
            )

    def _check(self) -> None:
        self._check_shape()

    def _check_shape(self) -> None:
        if len(self.shape) < 2 or self.shape[-2:] != (3, 9):
            raise InputError(
                f"{self.path}: expected shape (..., 3, 9) (RGB x 9 SH coefficients), got "
                f"{self.shape}"
            )
        self.n = int(np.prod(self.shape[:-2], dtype=np.int64))
        if self.n == 0:
            raise InputError(
                f"{self.path}: the array is empty (shape {self.shape}); nothing to fit"
            )
        if self.n * 27 > MAX_ELEMENTS:
            raise InputError(
                f"{self.path}: {self.n} texels is above the limit of {MAX_ELEMENTS // 27}; "
                "split the file"
            )
        # The memory budget (usdahd.budget), checked on the sizes the file declares before
        # anything is inflated or allocated: the fit holds up to the array's float64 size (the
        # fitted parameters with -o; the whole array for Fortran order), and an .npz member is
        # inflated up to its declared size.
        member = "the 'sh' array" if self._inflated is not None else "the array"
        member += f" (shape {self.shape}, {self.dtype})"
        need = self.n * 27 * max(8, self.dtype.itemsize)
        what = f"{member} needs"
        if self._inflated is not None and self._inflated >= need:
            need, what = self._inflated, f"{member} inflates to"
        budget.check(
            need,
            f"{self.path}: {what}",
            "split the file (usdahd fit streams each file in chunks) or raise the budget",
        )
        if self._inflated is not None:
            stored = self.n * 27 * self.dtype.itemsize + self._offset
            if self._inflated < stored:
                raise InputError(
                    f"{self.path}: the 'sh' array is truncated ({self._inflated} bytes in the "
                    f"archive, its header declares {stored}); re-save the file"
                )

    def chunks(self, size: int | None = None):
        """Yield (start, (k, 3, 9) float64) over the texels (``size`` each, default
        :data:`CHUNK`); InputError on NaN/Inf."""
        size = int(size or CHUNK)
        row = 27 * self.dtype.itemsize
        fh = None
        if self._zip is not None:
            fh = self._zip.open("sh.npy")
            fh.read(self._offset)
        if self._fortran and self.n > 1 and len(self.shape) > 2:
            # Fortran order: texels are not contiguous, so the array is converted once to C
            # order (float64, within the budget _check verified).
            if self._array is None:
                data = fh.read(self.n * row)
                if len(data) != self.n * row:
                    fh.close()
                    raise InputError(f"{self.path}: the 'sh' array is truncated")
                fh.close()
                fh = None
                arr = np.frombuffer(data, self.dtype).reshape(self.shape, order="F")
            else:
                arr = self._array
            flat = np.ascontiguousarray(arr, dtype=np.float64).reshape(-1, 3, 9)
        else:
            flat = None if self._array is None else np.asarray(self._array).reshape(-1, 3, 9)
        try:
            for start in range(0, self.n, size):
                k = min(size, self.n - start)
                if flat is not None:
                    block = np.asarray(flat[start : start + k], dtype=np.float64)
                else:
                    data = fh.read(k * row)
                    if len(data) != k * row:
                        raise InputError(f"{self.path}: the 'sh' array is truncated")
                    block = np.frombuffer(data, self.dtype).reshape(k, 3, 9).astype(np.float64)
                bad = ~np.isfinite(block)
                if bad.any():
                    first = start + int(np.argwhere(bad.any(axis=(1, 2)))[0, 0])
                    raise InputError(
                        f"{self.path}: {int(bad.sum())} non-finite SH values (NaN or Inf) in "
                        f"texels {start}..{start + k - 1}, first at texel {first}; fix or drop "
                        "those texels"
                    )
                yield start, block
        finally:
            if fh is not None:
                fh.close()


def load_sh(path: str) -> np.ndarray:
    """Read (..., 3, 9) radiance SH from a .npy or .npz ('sh') file, with clear errors
    (validated like :class:`ShSource`; loads the whole array, as float64)."""
    src = ShSource(path)
    out = np.empty((src.n, 3, 9), np.float64)
    for start, block in src.chunks():
        out[start : start + len(block)] = block
    return out.reshape(src.shape)


def hemispherical_rmse(sh: np.ndarray, fitted, n_dirs: int = 256) -> np.ndarray:
    """Per-texel RMSE over the upper hemisphere of the fitted irradiance against the SH
    irradiance, relative to the texel's mean |target|
    (:func:`usdahd.numerics.stats.rmse_over_mean_abs`; 0 for a black texel).

    sh : (n, 3, 9); returns (n,).
    The target is a (n, d, 3) float64 product of the SH with a (9, d) irradiance basis
    (irradiance is linear in the SH), so no (n, d, 3, 9) temporary is built.
    """
    dirs = shmod.fibonacci_sphere(n_dirs, hemisphere=True)
    basis = shmod.basis(dirs) * shmod.COSINE_FACTORS  # (d, 9)
    target = np.einsum("nck,dk->ndc", sh, basis)  # (n, d, 3)
    got = fitted.evaluate(np.broadcast_to(dirs, (sh.shape[0],) + dirs.shape))
    return rmse_over_mean_abs(got, target)


def _check_output(path: str | None) -> None:
    if not path:
        return
    out = Path(path)
    if out.is_dir():
        raise UsageError(f"-o {path}: is a directory; give the .npz file to write")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise UsageError(f"-o {path}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise UsageError(f"-o {path}: the folder {parent} is not writable")


def run(args) -> int:
    src = ShSource(args.sh)
    _check_output(args.output)
    options = {"objective": args.objective} if args.objective else {}
    params: dict[str, np.ndarray] = {}
    rel_sum, rel_max, fitted = 0.0, 0.0, None
    for start, block in src.chunks():
        fitted = models.fit(block, args.model, ratio=args.ratio, solver=args.solver, **options)
        rel = hemispherical_rmse(block, fitted)
        rel_sum += float(rel.sum())
        rel_max = max(rel_max, float(rel.max()))
        if args.output:
            for k, v in fitted.params.items():
                if k not in params:
                    params[k] = np.empty((src.n,) + v.shape[1:], v.dtype)
                params[k][start : start + len(v)] = v
    shapes = {k: (src.n,) + v.shape[1:] for k, v in fitted.params.items()}
    # Parameters keep the file's leading shape.
    lead = src.shape[:-2]
    shapes = {k: lead + v[1:] for k, v in shapes.items()}
    params = {k: v.reshape(shapes[k]) for k, v in params.items()}
    report = {
        "file": args.sh,
        "model": fitted.model,
        "ratio": fitted.ratio,
        "solver": fitted.solver,
        "texels": int(src.n),
        "relative_rmse_mean": rel_sum / src.n,
        "relative_rmse_max": rel_max,
        # which of the RMSE definitions of usdahd.numerics.stats the two numbers above are
        "relative_rmse_definition": "rmse_over_mean_abs",
        "params": {k: list(v) for k, v in shapes.items()},
    }
    if args.output:
        from usdahd.io_util import atomic_write_npz

        atomic_write_npz(args.output, **params)
        report["output"] = args.output

    def human():
        print(
            f"{report['texels']} texels  model={fitted.model} ratio={fitted.ratio} "
            f"solver={fitted.solver}  per-texel hemispherical RMSE over mean |I| mean "
            f"{report['relative_rmse_mean']:.4g} max {report['relative_rmse_max']:.4g}"
        )
        for k, v in shapes.items():
            print(f"  {k}: shape {v}")
        if args.output:
            print(f"wrote {args.output}", file=sys.stderr)

    emit(args, report, human)
    return 0
