"""Assets through USD's asset resolver (Ar): textures inside usdz packages, studio resolvers.

OpenImageIO opens files by name, but a resolved asset path need not be a file: inside a usdz
package it reads ``/abs/scene.usdz[textures/a.png]``, and a studio resolver may return a URI.
:func:`local_file` yields a path OpenImageIO can open: the path itself when it is a plain file,
else a temporary copy of the asset's bytes read through ``Ar.GetResolver().OpenAsset`` (deleted
on exit). :func:`exists` and :func:`stamp` answer "is it there" and "did it change" the same way,
so nothing that reads assets calls ``os.path.isfile`` on a package path.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager

from pxr import Ar

__all__ = ["exists", "extension", "local_file", "read_bytes", "stamp"]


def _is_plain_file(path: str) -> bool:
    return bool(path) and not Ar.IsPackageRelativePath(path) and os.path.isfile(path)


def extension(path: str) -> str:
    """File extension of the innermost asset (``a.usdz[t/b.png]`` -> ``.png``), lower case."""
    inner = path
    while Ar.IsPackageRelativePath(inner):
        inner = Ar.SplitPackageRelativePathInner(inner)[1]
    return os.path.splitext(inner)[1].lower()


def read_bytes(path: str) -> bytes:
    """The asset's content through Ar. Raises OSError naming the path when it cannot be opened."""
    if _is_plain_file(path):
        with open(path, "rb") as f:
            return f.read()
    asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(path)) if path else None
    if asset is None:
        raise OSError(f"the USD asset resolver cannot open {path or '(empty path)'}")
    return bytes(asset.GetBuffer())


def exists(path: str) -> bool:
    """Whether the resolved asset path can be opened (a file, or an asset inside a package)."""
    if not path:
        return False
    if _is_plain_file(path):
        return True
    if not Ar.IsPackageRelativePath(path) and os.path.isabs(path):
        return False  # an absolute file path that is not there
    try:
        return Ar.GetResolver().OpenAsset(Ar.ResolvedPath(path)) is not None
    except Exception:  # a resolver may raise for malformed identifiers
        return False


def stamp(path: str):
    """(size, mtime) identifying a version of the asset, for caches; None when unknown."""
    outer = path
    while Ar.IsPackageRelativePath(outer):
        outer = Ar.SplitPackageRelativePathOuter(outer)[0]
    try:
        st = os.stat(outer)
    except OSError:
        return None
    return (os.path.realpath(outer), path, st.st_size, st.st_mtime_ns)


@contextmanager
def local_file(path: str):
    """A filesystem path with the asset's content (see the module docstring); raises OSError."""
    if _is_plain_file(path):
        yield path
        return
    data = read_bytes(path)
    fd, tmp = tempfile.mkstemp(prefix="usdahd-asset-", suffix=extension(path))
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        yield tmp
    finally:
        try:
            os.unlink(tmp)
        except OSError:
            pass
