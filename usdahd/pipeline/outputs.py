"""Output files of a bake: where textures go and what they are called (content-addressed
names under ``lightmaps/``), committing them (rename + fsync), removing files no layer references,
the per-output lock, and the fault-injection points the fault tests kill a bake at.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from usdahd.pipeline.plan import PrimJob
from usdahd.pipeline.settings import BakeOptions
from usdahd.usd.author import layer_assets, referenced_assets

__all__ = [
    "FAULT_POINTS",
    "LIGHTMAPS_DIR",
    "author_layer",
    "cleanup_outputs",
    "commit_textures",
    "fault_point",
    "inside_lightmaps",
    "layer_prefix",
    "output_lock",
    "remove_legacy",
    "sanitize",
    "texture_path",
    "write_role_texture",
]

#: Folder beside the output layer that holds its textures.
LIGHTMAPS_DIR = "lightmaps"
#: Hex digits of the content hash in a texture's file name.
DIGEST_CHARS = 16


def sanitize(prim_path: str) -> str:
    """A file-name stem for a prim path that cannot escape the output directory.

    ``/World/Geo/wall_1`` -> ``World_Geo_wall_1-<hash8>``; the hash of the full path keeps
    paths distinct that would collide after replacing separators (``/A/B_C`` vs ``/A_B/C``).
    """
    stem = re.sub(r"[^A-Za-z0-9_]+", "_", prim_path.strip("/"))[:80] or "root"
    digest = hashlib.sha1(prim_path.encode()).hexdigest()[:8]
    return f"{stem}-{digest}"


def inside_lightmaps(path: Path, out: Path) -> bool:
    """``path`` is a regular file (no symlink) directly inside ``out``'s lightmaps folder."""
    folder = (out.parent / LIGHTMAPS_DIR).resolve()
    try:
        return (
            not path.is_symlink()
            and path.resolve().parent == folder
            and path.is_file()
            and path.resolve().is_relative_to(folder)
        )
    except OSError:
        return False


def layer_prefix(out: Path) -> str:
    """The file-name prefix of every texture written for the output layer ``out``.

    ``day.lightmaps.usda`` -> ``day_lightmaps-<hash6>``: layers sharing a folder never share
    (or clean up) each other's textures; the hash of the exact file name separates names that
    only differ in punctuation.
    """
    clean = re.sub(r"[^A-Za-z0-9_]+", "_", out.stem)[:48] or "layer"
    return f"{clean}-{hashlib.sha1(out.name.encode()).hexdigest()[:6]}"


def texture_path(out: Path, prim_path: str, role: str, ext: str) -> Path:
    """Where a new texture of ``prim_path`` is first written (a hidden staging name).

    The one place that names output files: :func:`commit_textures` renames the staged file
    to ``<layer prefix>.<prim stem>.<role>.<content hash><ext>`` (:func:`output_name`), so a
    new bake never overwrites a file the current layer references.
    """
    return out.parent / LIGHTMAPS_DIR / f".{layer_prefix(out)}.{sanitize(prim_path)}.{role}{ext}"


def output_name(out: Path, staged: Path, digest: str) -> str:
    """Content-addressed name of a staged texture (see :func:`texture_path`)."""
    stem = staged.name[1 + len(layer_prefix(out)) + 1 :]  # "<prim stem>.<role><ext>"
    base, ext = os.path.splitext(stem)
    return f"{layer_prefix(out)}.{base}.{digest[:DIGEST_CHARS]}{ext}"


def _owned_pattern(out: Path) -> re.Pattern:
    """Final texture names this layer owns (written by :func:`commit_textures`)."""
    return re.compile(
        re.escape(layer_prefix(out))
        + r"\.[A-Za-z0-9_]+-[0-9a-f]{8}\.[A-Za-z0-9_]+\.[0-9a-f]{"
        + str(DIGEST_CHARS)
        + r"}\.(exr|png|tif|tiff|ktx2)$"
    )


def _fsync(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def commit_textures(jobs: list[PrimJob], out: Path) -> None:
    """Rename each job's staged textures to content-addressed names, check they read back
    whole, and fsync them (before the layer that references them is committed).

    Raises OutputError (the previous layer and its files are untouched) when a file cannot be
    read back, e.g. truncated by a full disk.
    """
    from usdahd import images
    from usdahd.errors import OutputError
    from usdahd.usd import schema

    folder = out.parent / LIGHTMAPS_DIR
    done: dict[Path, Path] = {}  # an atlas page is shared by the records on it
    for job in jobs:
        for role, staged in list(job.results.textures.items()):
            staged = Path(staged)
            if staged in done:
                job.results.textures[role] = str(done[staged])
                entry = job.report.get("ktx2", {}).get(role)
                if entry is not None:
                    entry["path"] = str(done[staged].with_suffix(".ktx2"))
                continue
            if not staged.name.startswith("."):
                continue  # already committed
            digest = hashlib.sha256(staged.read_bytes()).hexdigest()
            final = folder / output_name(out, staged, digest)
            size = schema.page_size(job.results) if job.results.atlas else job.results.resolution
            try:
                img = images.read(staged)
                ok = np.asarray(img.pixels).shape[:2] == tuple(size[::-1])
            except Exception as exc:  # a truncated or empty file
                import shutil

                free = shutil.disk_usage(folder).free
                why = (
                    f"the disk is full ({free / 1024:.0f} KiB free)"
                    if free < 4 * 2**20
                    else str(exc).splitlines()[0][:160]
                    if str(exc)
                    else type(exc).__name__
                )
                raise OutputError(
                    f"{job.path}: the new {role} texture in {folder} is truncated or unreadable "
                    f"after writing: {why}; free space and re-run (the previous bake is intact)"
                ) from None
            if not ok:
                raise OutputError(f"{job.path}: the new {role} texture came back truncated")
            _fsync(staged)
            # A KTX2 container written beside the texture (--container ktx2) follows its name.
            ktx, ktx_final = staged.with_suffix(".ktx2"), final.with_suffix(".ktx2")
            if ktx.is_file():
                _fsync(ktx)
                try:
                    os.replace(ktx, ktx_final)
                except OSError as exc:
                    raise _write_error(ktx_final, exc, "cannot commit the KTX2 container") from None
                entry = job.report.get("ktx2", {}).get(role)
                if entry is not None:
                    entry["path"] = str(ktx_final)
            try:
                if final.is_file() and not final.is_symlink():
                    staged.unlink()  # same content already there
                else:
                    os.replace(staged, final)
            except OSError as exc:
                raise _write_error(final, exc, f"cannot commit the new {role} texture") from None
            job.results.textures[role] = str(final)
            done[staged] = final
            fault_point("first_texture_committed")
    if jobs:
        _fsync(folder, directory=True)


def cleanup_outputs(out: Path, *, staged_only: bool = False) -> list[str]:
    """Remove files of this output layer that no layer references: textures it owns
    (:func:`_owned_pattern`) that ``out`` does not name, and temp/staging files a killed or
    failed bake left (only those with ``staged_only``). Only names this tool writes, only
    inside the output folder; call with the output lock held. returns the names removed."""
    removed = []
    folder = out.parent / LIGHTMAPS_DIR
    prefix = layer_prefix(out)
    refs = None if staged_only else _layer_refs(out)
    owned = _owned_pattern(out)
    layer_tmp = re.compile(
        r"\." + re.escape(out.stem) + r"\.[A-Za-z0-9_]{8}" + re.escape(out.suffix)
    )
    candidates = []
    if folder.is_dir() and not folder.is_symlink():
        for f in folder.iterdir():
            name = f.name
            staged = name.lstrip(".") != name and name.lstrip(".").startswith(prefix + ".")
            if staged:
                candidates.append(f)
            elif refs is not None and owned.match(name) and f.resolve() not in refs:
                # a .ktx2 is not in the layer: it stays while the texture it was made from does
                if f.suffix != ".ktx2" or not any(
                    r.parent == f.resolve().parent and r.stem == f.stem for r in refs
                ):
                    candidates.append(f)
    if out.parent.is_dir():
        candidates += [f for f in out.parent.iterdir() if layer_tmp.fullmatch(f.name)]
    for f in candidates:
        try:
            if f.is_file() or f.is_symlink():
                f.unlink()
                removed.append(f.name)
        except OSError:
            pass
    return removed


#: The assets of the layers this process committed, keyed by (path, inode, mtime, size): the
#: cleanup after a bake reads them from the layer it just built instead of re-parsing the file
#: (a text layer of millions of authored normals costs GBs to parse, issue 40).
_COMMITTED_REFS: dict[str, tuple[tuple, set[Path]]] = {}


def _stat_key(path: Path) -> tuple | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_mtime_ns, st.st_size)


def _layer_refs(out: Path) -> set[Path] | None:
    """:func:`referenced_assets` of ``out``, from the commit's record when the file is still
    the one this process wrote."""
    known = _COMMITTED_REFS.get(str(out))
    if known is not None and known[0] == _stat_key(out):
        return set(known[1])
    return referenced_assets(out)


def remove_legacy(out: Path, old_refs: set[Path]) -> list[str]:
    """Textures of an older usdahd (named ``<prim stem>.<role>.<ext>``, shared by every layer of
    a folder) that the previous version of ``out`` referenced and no layer in the folder
    references now: removed after the commit. returns the names removed."""
    folder = (out.parent / LIGHTMAPS_DIR).resolve()
    legacy = re.compile(r"[A-Za-z0-9_]+-[0-9a-f]{8}\.[A-Za-z0-9_]+\.(exr|png|tif|tiff)")
    candidates = {
        f for f in old_refs if f.parent == folder and legacy.fullmatch(f.name) and f.is_file()
    }
    if not candidates:
        return []
    in_use: set[Path] = set()
    for layer in out.parent.iterdir():
        if layer.suffix not in (".usda", ".usdc", ".usd") or not layer.is_file():
            continue
        if layer.suffix == ".usda":
            with open(layer, "rb") as f:
                if b"usdahd" not in f.read(4096):
                    continue  # not a layer usdahd wrote (its doc string names usdahd)
        refs = referenced_assets(layer, anonymous=True)
        if refs is None:
            return []  # a layer we cannot read may use them: keep everything
        in_use |= refs
    removed = []
    for f in sorted(candidates - in_use):
        try:
            f.unlink()
            removed.append(f.name)
        except OSError:
            pass
    return removed


#: Default of ``usdahd bake --lock-timeout`` (seconds a bake waits for another bake of the same
#: output to finish). One hour: the largest real scene measured here (sponza, 2 M triangles)
#: bakes in 20 min at the defaults (docs/scenes.md), so a healthy concurrent bake is waited for
#: with a 3x margin (then this one plans against its layer and skips what it baked), while a
#: holder that is hung or stopped frees the farm slot within the hour, with exit 2, instead of
#: blocking it for good. ``--lock-timeout 0`` gives up at once, ``inf`` waits as long as it takes.
DEFAULT_LOCK_TIMEOUT = 3600.0
#: Seconds between two attempts to take a busy lock.
_LOCK_POLL = 0.2


def lock_path(out: Path) -> Path:
    """The lock file of the output layer ``out`` (exists only while a bake holds it)."""
    return out.parent / f".{out.name}.lock"


def _holder(fd: int) -> dict:
    """Who holds the lock, as its holder wrote it (host, pid, since); {} when unreadable."""
    import json

    try:
        info = json.loads(os.pread(fd, 4096, 0).decode("utf-8", "replace") or "{}")
    except (OSError, ValueError):
        return {}
    return info if isinstance(info, dict) else {}


def _describe_holder(info: dict) -> str:
    """``pid 123 on host farm7, since 2026-12-05 20:49:01 UTC (35 s ago), stopped``."""
    import socket

    pid, host = info.get("pid"), info.get("host")
    if not pid:
        return "holder unknown"
    text = f"pid {pid} on host {host or '?'}"
    since = info.get("unix")
    if isinstance(since, (int, float)):
        stamp = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(since))
        text += f", since {stamp} ({max(0.0, time.time() - since):.0f} s ago)"
    if host == socket.gethostname():
        try:
            with open(f"/proc/{int(pid)}/stat") as f:
                state = f.read().rsplit(")", 1)[1].split()[0]
            if state in ("T", "t"):
                text += ", stopped (SIGSTOP or Ctrl-Z: SIGCONT resumes it)"
        except (OSError, ValueError, IndexError):
            if not Path(f"/proc/{pid}").exists():
                text += ", no longer running (a process it started still holds the lock)"
    return text


def _same_file(fd: int, path: Path) -> bool:
    """The open lock ``fd`` is still the file at ``path`` (a finishing bake removes its lock
    file: a waiter that locked the removed file must start again on the new one)."""
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


@contextlib.contextmanager
def output_lock(out: Path, opts: BakeOptions):
    """Hold an exclusive lock on ``.<output name>.lock`` beside the output layer while baking.

    The lock is ``flock`` on that file: the kernel releases it when its holder exits, however
    it exits, so a dead holder never blocks. The holder writes its host, pid and start time
    into the file; a second bake of the same output prints them and waits up to
    ``opts.lock_timeout`` seconds (default :data:`DEFAULT_LOCK_TIMEOUT`), then gives up with
    OutputError (exit 2) naming the holder. When the bake ends the holder removes the file
    while still holding it (a waiter re-checks that the file it locked is still the one at the
    path, else starts again), so nothing is left beside the layer; a SIGKILLed bake leaves it
    until the next bake of that output.
    """
    import fcntl
    import json
    import socket

    from usdahd.errors import OutputError

    timeout = opts.lock_timeout if opts.lock_timeout is not None else DEFAULT_LOCK_TIMEOUT
    path = lock_path(out)
    t0 = time.monotonic()
    announced = False
    while True:
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as exc:
            raise OutputError(
                f"{path}: cannot create the bake lock ({exc.strerror}); make {out.parent} "
                "writable or choose another output with -o"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            who = _describe_holder(_holder(fd))
            os.close(fd)
            waited = time.monotonic() - t0
            if waited >= timeout:
                raise OutputError(
                    f"{out}: another usdahd bake ({who}) still holds the lock {path.name} after "
                    f"{waited:.0f} s (--lock-timeout {timeout:g}); wait for it to finish, stop "
                    "it if it is hung, or re-run with a longer --lock-timeout"
                ) from None
            if not announced:
                _warn(
                    opts,
                    f"another usdahd bake ({who}) is writing {out}; waiting for it to finish "
                    f"(giving up after {timeout:g} s, --lock-timeout)…",
                )
                announced = True
            time.sleep(min(_LOCK_POLL, max(0.0, timeout - waited)))
            continue
        except BaseException:
            os.close(fd)
            raise
        if not _same_file(fd, path):  # locked a file its holder removed: take the new one
            os.close(fd)
            continue
        break
    try:
        info = {
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "since": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "unix": round(time.time(), 3),
            "output": str(out),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        yield
    finally:
        try:
            if _same_file(fd, path):
                os.unlink(path)  # still holding it: waiters re-check and start again
        except OSError:
            pass  # a read-only folder: the file stays, harmless (the lock is the flock)
        finally:
            os.close(fd)


#: Fault-injection points of a bake, in order (tests/test_faults.py kills a bake at each).
FAULT_POINTS = (
    "traced",
    "textures_staged",
    "first_texture_committed",
    "textures_committed",
    "layer_exported",
    "layer_replaced",
)


def fault_point(point: str) -> None:
    """``USDAHD_FAULT=<point>`` sends this process ``USDAHD_FAULT_SIGNAL`` (default KILL) at
    ``point``: how the fault tests stop a bake at exact places. No effect otherwise."""
    if os.environ.get("USDAHD_FAULT") == point:
        import signal

        sig = getattr(signal, "SIG" + os.environ.get("USDAHD_FAULT_SIGNAL", "KILL"))
        os.kill(os.getpid(), sig)
        time.sleep(1.0)  # let a handled signal (SIGINT -> KeyboardInterrupt) arrive here


def _warn(opts: BakeOptions, msg: str) -> None:
    """A warning on stderr: shown with --quiet, hidden with -qq."""
    if int(opts.quiet or 0) < 2:
        from usdahd import progress

        progress.clear_line()
        print(f"warning: {msg}", file=sys.stderr)


def author_layer(
    src: Path, out: Path, source_stage, jobs: list[PrimJob], scenario: str | None = None
) -> bool:
    """Write the override layer; its atomic replace is the bake's single commit point.

    The layer is built in memory by :func:`usdahd.usd.author.build_layer`, exported to a fresh
    temp file beside ``out`` (created by mkstemp and kept, so no other process can take its
    name), fsynced, then renamed over ``out``. returns False when the content is unchanged
    (nothing replaced). Raises OutputError when the layer cannot be written (disk full,
    read-only); ``out`` is then untouched.
    """
    from usdahd.usd import author

    out.parent.mkdir(parents=True, exist_ok=True)
    layer = author.build_layer(src, out, source_stage, jobs, scenario)
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{out.stem}.", suffix=out.suffix, dir=out.parent)
    except OSError as exc:
        raise _write_error(out, exc, f"cannot create a file in {out.parent}") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        author.export_layer(layer, tmp_name, out)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        _fsync(tmp)
        fault_point("layer_exported")
        new = tmp.read_bytes()
        refs = layer_assets(layer, out.parent)
        if out.is_file() and out.read_bytes() == new:
            _COMMITTED_REFS[str(out)] = (_stat_key(out), refs)
            return False
        try:
            os.replace(tmp, out)  # the commit point
        except OSError as exc:
            raise _write_error(out, exc, "cannot replace the output layer") from None
        _fsync(out.parent, directory=True)
        _COMMITTED_REFS[str(out)] = (_stat_key(out), refs)
        return True
    finally:
        if tmp.exists():
            tmp.unlink()


def _write_error(path: Path, exc: OSError, what: str):
    """OutputError naming ``path`` (the file the user knows, never a temp name), why, and the
    fix, for an OSError writing it; the previous bake is intact when this is raised."""
    import errno

    from usdahd.errors import OutputError

    why = exc.strerror or str(exc)
    if exc.errno == errno.EPERM:
        fix = (
            f"{path.name} or its folder is protected against changes (an immutable file: "
            f"lsattr shows 'i'; `chattr -i {path}` as root clears it), or choose another "
            "output with -o"
        )
    elif exc.errno == errno.EACCES:
        fix = f"make {path.parent} writable or choose another output with -o"
    elif exc.errno == errno.EROFS:
        fix = f"{path.parent} is on a read-only file system: choose another output with -o"
    elif exc.errno == errno.ENOSPC:
        fix = "the disk is full: free space and re-run"
    else:
        fix = "check the folder and re-run, or choose another output with -o"
    return OutputError(f"{path}: {what} ({why}); {fix} (the previous bake is intact)")


def write_role_texture(out: Path, stem: str, lay, img, factors: dict) -> tuple[str, str]:
    """Write one texture role (``lay``: a model layout entry) of a prim or an atlas page: the
    image ``img (h, w, c)`` as the layout's format, colour space and channels, with the decode
    ``factors`` also in the file's metadata (the schema is authoritative). Returns (path,
    "sha256:<hex>" digest of the file as written)."""
    from usdahd import images
    from usdahd.usd import schema

    path = texture_path(out, stem, lay.role, lay.extension)
    images.write(
        path,
        img,
        format=lay.format,
        color_space=lay.color_space,
        channels=lay.channels,
        attributes={f"usdahd:{k}": float(v) for k, v in factors.items()},
    )
    return str(path), schema.file_digest(path)
