"""Checks a bake runs before it reads a scene or traces a ray: the source is a readable stage
file, the output path and its folders are usable and writable, the options' dependencies are
installed (:func:`preflight`), the opened stage is not one of our output layers and every
``--prim`` exists (:func:`check_stage_inputs`), and authored values are valid
(:func:`check_stage_values`).
"""

from __future__ import annotations

import importlib.util
import os
import tempfile
from pathlib import Path

from usdahd.errors import InputError, StageError, UsageError
from usdahd.pipeline.outputs import LIGHTMAPS_DIR
from usdahd.pipeline.settings import BakeOptions

__all__ = ["check_stage_inputs", "check_stage_values", "default_output", "files_exist", "preflight"]


def default_output(stage_path: Path, scenario: str | None = None) -> Path:
    """``dir/name.usda`` -> ``dir/name.lightmaps.usda`` (``dir/name.NAME.lightmaps.usda`` for
    ``--scenario NAME``, ``SET=NAME`` or ``/Prim{SET=NAME}``)."""
    from usdahd.usd import scenarios

    return scenarios.default_output(stage_path, scenarios.name_of(scenario) if scenario else None)


def _probe_writable(folder: Path, what: str) -> None:
    """Create and remove a file in ``folder``: the real test (root ignores permission bits,
    read-only mounts ignore them too). Raises OutputError naming the folder and the fix."""
    from usdahd.errors import OutputError

    try:
        fd, name = tempfile.mkstemp(prefix=".usdahd-probe.", dir=folder)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise OutputError(
            f"{folder}: cannot write the {what} there ({exc.strerror}); make the folder "
            "writable or choose another output with -o"
        ) from None


def preflight(stage_path, opts: BakeOptions) -> tuple[Path, Path]:
    """Checks that need no scene: the source is a readable regular file, the output path is
    usable and its folders writable, and the options' dependencies are installed.
    returns (source path, output layer path). Writes nothing (a probe file is removed)."""
    from usdahd.errors import OutputError

    src = Path(stage_path)
    for what, path in (("stage", src), ("-o", Path(opts.output or "."))):
        try:
            os.fsencode(path.resolve()).decode("utf-8")
        except UnicodeDecodeError:
            shown = os.fsencode(path).decode("utf-8", errors="backslashreplace")
            raise InputError(
                f"{shown}: the {what} path is not valid UTF-8; USD needs UTF-8 file names: "
                "rename the file or folder"
            ) from None
    if src.is_dir():
        raise InputError(f"{stage_path}: is a directory; give a USD stage file (.usda/.usdc/.usd)")
    if not src.exists():
        raise InputError(f"{stage_path}: no such file")
    if not src.is_file():
        raise InputError(f"{stage_path}: not a regular file (a FIFO or device?); give a stage file")
    try:
        with open(src, "rb") as f:
            f.read(1)
    except OSError as exc:
        raise InputError(f"{stage_path}: cannot read the stage ({exc.strerror})") from None
    out = Path(opts.output) if opts.output else default_output(src, opts.scenario)
    if out.suffix not in (".usda", ".usdc", ".usd"):
        raise UsageError(f"-o {out}: the output layer must end in .usda, .usdc or .usd")
    if out.is_dir():
        raise UsageError(f"-o {out}: is a directory; give the output layer's file name")
    if out.exists() and not out.is_file():
        raise UsageError(f"-o {out}: not a regular file; give the output layer's file name")
    if out.resolve() == src.resolve():
        raise UsageError(f"-o {out}: refusing to overwrite the source layer; choose another path")
    if opts.denoise and importlib.util.find_spec("pyoidn") is None:
        raise UsageError(
            "denoising (the default) needs Intel Open Image Denoise: pip install pyoidn, "
            "or bake with --no-denoise"
        )
    parent = out.parent
    existing = parent
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"{existing}: not a folder, so {out} cannot be written; check -o")
    folder = parent / LIGHTMAPS_DIR
    if folder.is_symlink() and not folder.exists():
        raise OutputError(
            f"{folder}: a dangling symbolic link where the lightmaps folder goes; remove it "
            "or choose another output with -o"
        )
    if folder.exists() and not folder.is_dir():
        raise OutputError(
            f"{folder}: a file where the lightmaps folder goes; move it away or choose another "
            "output with -o"
        )
    if folder.is_symlink():
        raise OutputError(
            f"{folder}: is a symbolic link; the lightmaps folder must be a real folder inside "
            "the output folder (remove the link or choose another output with -o)"
        )
    _probe_writable(existing, "output layer")
    if folder.is_dir():
        _probe_writable(folder, "lightmap textures")
    if out.is_file() and not out.stat().st_mode & 0o222:
        raise OutputError(
            f"{out}: the output layer is read-only (no write permission bits); make it "
            "writable (chmod u+w) or choose another output with -o"
        )
    return src, out


def check_stage_inputs(src: Path, stage, opts: BakeOptions) -> None:
    """Checks on the opened stage before any scene is read: not an output layer of ours
    (``usdahd bake x.lightmaps.usda`` by mistake), every ``--prim`` exists."""
    from usdahd.usd import author
    from usdahd.usd import stage as usd_stage

    if author.is_output_layer(stage) and not opts.output:
        raise UsageError(
            f"{src}: this is an output layer of usdahd bake (it would bake into "
            f"{default_output(src).name} and re-bake everything); bake its source stage "
            "instead, or pass -o to bake this layer on purpose"
        )
    for p in opts.prims or []:
        if not usd_stage.is_prim_path(p):
            raise UsageError(f"--prim {p!r}: not an absolute prim path (like /World/Floor)")
        if usd_stage.prim_at(stage, p) is None:
            raise UsageError(
                f"--prim {p}: no such prim on {src.name}; list the meshes with "
                "usdahd bake --dry-run, or check the spelling"
            )


def check_stage_values(src: Path, stage, uv_name: str):
    """Authored light/material/primvar values (:mod:`usdahd.usd.checks`); a stage-level error
    raises StageError (the first one, with how many more)."""
    from usdahd.usd import checks

    found = checks.check_stage(stage, uv_name)
    if found.errors:
        more = len(found.errors) - 1
        raise StageError(found.errors[0] + (f" (and {more} more problem(s))" if more else ""))
    return found


def files_exist(res) -> bool:
    return bool(res.textures) and all(Path(p).is_file() for p in res.textures.values())
