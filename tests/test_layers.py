"""Import layers of the package (issue 12), enforced by an AST walk over usdahd/.

Each package says what it may import (:data:`RULES`); every ``import``/``from ... import`` in a
module counts, at module level or inside a function (a lazy import is still a dependency).
Violations that exist today and that another part of issue 12 removes are listed in
:data:`ALLOWLIST` with the part that removes them. The test fails on a violation that is not
listed, and on a listed entry that no longer occurs: the list only shrinks — delete an entry
when your change removes its violation.

A second test imports the numerics and the models in a child Python in which pxr and
OpenImageIO cannot be imported at all.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import usdahd

PACKAGE_DIR = Path(usdahd.__file__).resolve().parent
STDLIB = frozenset(sys.stdlib_module_names)
#: Third-party packages the numerics may use.
NUMERIC = frozenset({"numpy", "numba"})


@dataclass(frozen=True)
class Rule:
    """Modules under one of ``scope`` (package prefixes, minus ``exempt``) may import only
    ``allow`` (prefixes; stdlib with ``stdlib``) when it is given, and never ``forbid``."""

    name: str
    why: str
    scope: tuple[str, ...]
    allow: frozenset[str] | None = None
    stdlib: bool = True
    forbid: frozenset[str] = frozenset()
    exempt: tuple[str, ...] = ()
    #: Forbid private modules (a ``_name`` part) of other packages.
    private: bool = False

    def applies(self, module: str) -> bool:
        return _under(module, self.scope) and not _under(module, self.exempt)

    def violates(self, imported: str, module: str = "") -> bool:
        if _under(imported, tuple(self.forbid)):
            return True
        if self.private and _foreign_private(imported, module):
            return True
        if self.allow is None:
            return False
        if self.stdlib and imported.split(".")[0] in STDLIB:
            return False
        return not _under(imported, tuple(self.allow))


def _under(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def _foreign_private(imported: str, module: str) -> bool:
    """``usdahd.a._b`` imported from outside ``usdahd.a``."""
    parts = imported.split(".")
    for k, part in enumerate(parts):
        if part.startswith("_") and not part.startswith("__"):
            return not _under(module, (".".join(parts[:k]),))
    return False


RULES = (
    Rule(
        "numerics",
        "numerics are I/O-free array code: numpy, numba, stdlib, usdahd.errors",
        scope=("usdahd.numerics", "usdahd.sh"),
        allow=NUMERIC | {"usdahd.numerics", "usdahd.errors"},
    ),
    Rule(
        "models",
        "lighting models build on the numerics only",
        scope=("usdahd.models",),
        allow=NUMERIC | {"usdahd.numerics", "usdahd.errors", "usdahd.models"},
    ),
    Rule(
        "scene",
        "the scene description is pxr-free numpy data",
        scope=("usdahd.scene",),
        allow=NUMERIC | {"usdahd.numerics", "usdahd.errors", "usdahd.scene"},
    ),
    Rule(
        "bake",
        "the baker (numpy, numba, Embree, xatlas, OIDN) never reads USD or images itself",
        scope=("usdahd.bake",),
        forbid=frozenset(
            {
                "pxr",
                "OpenImageIO",
                "usdahd.usd",
                "usdahd.images",
                "usdahd.pipeline",
                "usdahd.validate",
                "usdahd.commands",
                "usdahd.cli",
            }
        ),
    ),
    Rule(
        "usd",
        "USD readers return scene/ types; usd/ never imports the baker (which loads Embree)",
        scope=("usdahd.usd",),
        forbid=frozenset({"usdahd.bake", "usdahd.pipeline", "usdahd.validate", "usdahd.commands"}),
    ),
    Rule(
        "pxr",
        "pxr only under usdahd/usd/ (so commands/, cli, pipeline, validate use usdahd.usd)",
        scope=("usdahd",),
        exempt=("usdahd.usd",),
        forbid=frozenset({"pxr"}),
    ),
    Rule(
        "oiio",
        "OpenImageIO only in usdahd/images.py",
        scope=("usdahd",),
        exempt=("usdahd.images",),
        forbid=frozenset({"OpenImageIO"}),
    ),
    Rule(
        "validate",
        "the validator reads scene/ and numerics/, never the orchestrator",
        scope=("usdahd.validate",),
        forbid=frozenset({"usdahd.pipeline"}),
    ),
    Rule(
        "dask",
        "Dask is optional (usdahd[distributed]): only usdahd/pipeline/distributed.py imports it",
        scope=("usdahd",),
        exempt=("usdahd.pipeline.distributed",),
        forbid=frozenset({"dask", "distributed"}),
    ),
    Rule(
        "private",
        "a private module (usdahd.x._y) is used only inside its package; others use public API",
        scope=("usdahd",),
        private=True,
    ),
)

#: Known violations: (rule, importing module or package prefix, imported prefix) -> the part of
#: issue 12 that removes it. Prefixes match submodules too, so a module split into a package
#: (pipeline.py -> pipeline/) keeps its entries. Never add an entry except for a violation
#: another part is removing; delete entries as they go.
ALLOWLIST: dict[tuple[str, str, str], str] = {}


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_module(name: str) -> bool:
    """Whether ``name`` (dotted, under usdahd) is a module or package of this package."""
    rel = PACKAGE_DIR.parent.joinpath(*name.split("."))
    return rel.with_suffix(".py").is_file() or (rel / "__init__.py").is_file()


def imports_of(path: Path) -> set[str]:
    """Dotted names a module imports (``from a import b`` gives ``a.b`` when that is a module
    of usdahd, else ``a``)."""
    mod = module_name(path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            for a in node.names:
                full = f"{base}.{a.name}"
                out.add(full if base.startswith("usdahd") and _is_module(full) else base)
    return out


def violations() -> set[tuple[str, str, str]]:
    """(rule, module, imported name) for every import a rule forbids."""
    found = set()
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        mod = module_name(path)
        imported = imports_of(path)
        for rule in RULES:
            if not rule.applies(mod):
                continue
            for imp in imported:
                if rule.violates(imp, mod):
                    found.add((rule.name, mod, imp))
    return found


def _allowed_by(v: tuple[str, str, str]) -> tuple[str, str, str] | None:
    rule, mod, imp = v
    for key in ALLOWLIST:
        if key[0] == rule and _under(mod, (key[1],)) and _under(imp, (key[2],)):
            return key
    return None


def test_walk_sees_lazy_relative_and_from_imports(tmp_path, monkeypatch):
    pkg = tmp_path / "usdahd"
    (pkg / "numerics").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "errors.py").write_text("")
    (pkg / "numerics" / "__init__.py").write_text("")
    src = pkg / "numerics" / "x.py"
    src.write_text(
        textwrap.dedent(
            """
            import numpy as np
            from . import y
            from ..errors import InputError
            def f():
                from pxr import Usd
                import OpenImageIO.foo
            """
        )
    )
    (pkg / "numerics" / "y.py").write_text("")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE_DIR", pkg)
    assert imports_of(src) == {
        "numpy",
        "usdahd.numerics.y",
        "usdahd.errors",
        "pxr",
        "OpenImageIO.foo",
    }
    rule = RULES[0]
    assert [i for i in sorted(imports_of(src)) if rule.violates(i)] == ["OpenImageIO.foo", "pxr"]


def test_import_layers():
    found = violations()
    new = sorted(v for v in found if _allowed_by(v) is None)
    used = {_allowed_by(v) for v in found}
    stale = sorted(k for k in ALLOWLIST if k not in used)
    why = {r.name: r.why for r in RULES}
    msg = [f"{m} imports {i}: rule {r!r} ({why[r]})" for r, m, i in new]
    msg += [
        f"ALLOWLIST entry {k} ({ALLOWLIST[k]}) no longer occurs: delete it (tests/test_layers.py)"
        for k in stale
    ]
    assert not msg, "\n".join(msg)


def test_allowlist_names_the_part_that_removes_each_entry():
    parts = {"pipeline", "usdread", "kernels", "validate", "models"}
    rules = {r.name for r in RULES}
    for key, part in ALLOWLIST.items():
        assert key[0] in rules, key
        assert part.split(":")[0] in parts, (key, part)


BLOCKER = """
import importlib.abc, sys

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("pxr", "OpenImageIO"):
            raise ModuleNotFoundError(f"blocked for the test: {name}", name=name)
        return None

sys.meta_path.insert(0, Block())
"""


def test_numerics_and_models_import_without_pxr_and_oiio():
    code = BLOCKER + textwrap.dedent(
        """
        import numpy as np

        import usdahd, usdahd.sh, usdahd.models, usdahd.numerics
        import usdahd.numerics.sh, usdahd.numerics.hemi, usdahd.numerics.sampling
        import usdahd.numerics.encoding, usdahd.numerics.raster
        from usdahd import sh

        assert sh is usdahd.numerics.sh and usdahd.sh.basis is usdahd.numerics.sh.basis
        try:
            import pxr  # noqa: F401
        except ModuleNotFoundError:
            pass
        else:
            raise SystemExit("the blocker does not block pxr")
        rng = np.random.default_rng(0)
        radiance = rng.normal(size=(16, 3, 9)).astype(np.float32)
        radiance[..., 0] = 2.0
        fit = usdahd.models.fit(radiance, model="hhd")
        assert np.isfinite(fit.evaluate(np.array([0.0, 0.0, 1.0]))).all()
        assert not any(m.split(".")[0] in ("pxr", "OpenImageIO") for m in sys.modules)
        print("ok")
        """
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=PACKAGE_DIR.parent,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"
