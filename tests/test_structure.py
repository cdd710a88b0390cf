"""Structure rules of the package (issue 38), enforced over every module of usdahd/.

- No module is longer than MAX_LINES: a longer one is split by concern (as the integrator
  kernel was into ``bake/kernels/integrate.py``, ``paths.py`` and ``shading.py``, and the
  light classes into one module per light under ``scene/lights/``). There is no list of
  exceptions: split the module.
- Public seams: a module of the package uses another module's names only when they are public
  (no leading underscore) and listed in that module's ``__all__``. "Uses" means imports
  (``from usdahd.x import name``, ``import usdahd.x._y``, relative imports resolved) and
  attribute access through a module bound by an import (``x.name`` after ``from usdahd import
  x`` or ``import usdahd.x as x``), anywhere in the file, function-local imports included.

  A package's ``__init__`` and its own submodules count as separate modules, so
  ``validate/__init__.py`` may not re-export ``validate.findings._Rule`` and
  ``validate/retrace.py`` may not reach ``validate._LOCK``: a private name that another module
  needs is part of the package's interface in everything but its name, which is what the rule
  is for. A private *module* (``models/_linear.py``) is private to everyone but itself for the
  same reason; name it publicly when siblings import it.

  What the walk cannot see (private attributes of objects, ``getattr`` with a string) is left
  to review; names of third-party modules (``numba.core.caching``) are outside the rule.
"""

from __future__ import annotations

import ast
import importlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import usdahd

PACKAGE_DIR = Path(usdahd.__file__).resolve().parent
#: The longest a module of the package may be, in lines.
MAX_LINES = 800


def _modules(package_dir: Path = PACKAGE_DIR) -> list[Path]:
    return sorted(p for p in package_dir.rglob("*.py") if "__pycache__" not in p.parts)


def _too_long(paths) -> dict[Path, int]:
    """{path: lines} of the files in ``paths`` longer than MAX_LINES."""
    lengths = {p: len(Path(p).read_text(encoding="utf-8").splitlines()) for p in paths}
    return {p: n for p, n in lengths.items() if n > MAX_LINES}


def test_no_module_is_longer_than_max_lines():
    modules = _modules()
    assert len(modules) > 50  # the walk found the package
    long = {str(p.relative_to(PACKAGE_DIR.parent)): n for p, n in _too_long(modules).items()}
    assert not long, (
        f"modules over {MAX_LINES} lines: {long}; split each by concern (one module per "
        "light, per integrator stage, ...) rather than raising the limit"
    )


def test_the_line_rule_flags_a_long_module_and_passes_a_short_one(tmp_path):
    long, short = tmp_path / "long.py", tmp_path / "short.py"
    long.write_text("x = 1\n" * (MAX_LINES + 1), encoding="utf-8")
    short.write_text("x = 1\n" * MAX_LINES, encoding="utf-8")
    assert _too_long([long, short]) == {long: MAX_LINES + 1}


# -------------------------------------------------------------------------------------------
# Public seams


@dataclass(frozen=True)
class Use:
    """``user`` (a file, line) uses ``name`` of module ``source`` (dotted names)."""

    path: str
    line: int
    user: str
    source: str
    name: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.source}.{self.name}"


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _module_names(package_dir: Path) -> dict[str, Path]:
    """{dotted module name: file} of every module under ``package_dir`` (the package's own
    name is the folder's)."""
    out = {}
    for path in _modules(package_dir):
        parts = list(path.relative_to(package_dir.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _uses_in(path: Path, user: str, modules: dict[str, Path], root: str) -> list[Use]:
    """Every use in ``path`` (module ``user``) of a name of another module of the package."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    here = user.split(".") if path.name == "__init__.py" else user.split(".")[:-1]
    rel = str(path.relative_to(modules[root].parent.parent))
    uses: list[Use] = []
    aliases: dict[str, str] = {}  # local name -> module it is bound to

    def use(node, source: str, name: str) -> None:
        if source != user:
            uses.append(Use(rel, node.lineno, user, source, name))

    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            if source != root and not source.startswith(root + "."):
                continue
            for dotted in _prefixes(source):
                if _is_private(dotted.rsplit(".", 1)[-1]):
                    use(node, dotted.rsplit(".", 1)[0], dotted.rsplit(".", 1)[-1])
            for a in node.names:
                if f"{source}.{a.name}" in modules:
                    aliases[a.asname or a.name] = f"{source}.{a.name}"
                    if _is_private(a.name):
                        use(node, source, a.name)
                elif a.name != "*":
                    use(node, source, a.name)
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name != root and not a.name.startswith(root + "."):
                    continue
                aliases[a.asname] = a.name if a.asname else None
                if not a.asname:
                    aliases[root] = root
                aliases.pop(None, None)
                for dotted in _prefixes(a.name):
                    if _is_private(dotted.rsplit(".", 1)[-1]):
                        use(node, dotted.rsplit(".", 1)[0], dotted.rsplit(".", 1)[-1])
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        chain, value = [node.attr], node.value
        while isinstance(value, ast.Attribute):
            chain.append(value.attr)
            value = value.value
        if not isinstance(value, ast.Name) or value.id not in aliases:
            continue
        chain.reverse()
        module = aliases[value.id]
        # ``usdahd.a.b.name``: walk down submodules; the first non-module attribute is the use
        # (only for the outermost Attribute of a chain, so each use is counted once).
        for i, attr in enumerate(chain):
            if f"{module}.{attr}" in modules:
                module = f"{module}.{attr}"
                if _is_private(attr):
                    use(node, module.rsplit(".", 1)[0], attr)
                continue
            if i == len(chain) - 1:
                use(node, module, attr)
            break
    return uses


def _prefixes(dotted: str) -> list[str]:
    parts = dotted.split(".")
    return [".".join(parts[: i + 1]) for i in range(1, len(parts))]


def cross_module_uses(package_dir: Path = PACKAGE_DIR) -> list[Use]:
    """Every use by a module under ``package_dir`` of a name of another module there."""
    modules = _module_names(package_dir)
    root = package_dir.name
    return sorted(
        {u for name, path in modules.items() for u in _uses_in(path, name, modules, root)},
        key=lambda u: (u.path, u.line, u.source, u.name),
    )


def _declared_all(path: Path, module: str) -> set[str] | None:
    """The names of a module's ``__all__``, None without one: read from the source when it is
    one literal list, else (``__all__ += generated names``, as in ``bake/kernels/layout.py``)
    from the imported module."""
    found = None
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        targets = node.targets if isinstance(node, ast.Assign) else []
        if isinstance(node, ast.AnnAssign | ast.AugAssign):
            targets = [node.target]
        if not any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
            continue
        literal = isinstance(node, ast.Assign) and isinstance(node.value, ast.List | ast.Tuple)
        if found is not None or not literal:
            return set(importlib.import_module(module).__all__)
        found = {e.value for e in node.value.elts if isinstance(e, ast.Constant)}
    return found


def seam_violations(package_dir: Path = PACKAGE_DIR) -> tuple[list[Use], list[Use]]:
    """(private uses, public uses of names missing from their module's ``__all__``)."""
    modules = _module_names(package_dir)
    uses = cross_module_uses(package_dir)
    private = [u for u in uses if _is_private(u.name)]
    alls = {name: _declared_all(path, name) for name, path in modules.items()}
    unlisted = [
        u
        for u in uses
        if not _is_private(u.name)
        and not u.name.startswith("__")
        and u.name not in (alls.get(u.source) or ())
    ]
    return private, unlisted


def test_no_module_uses_another_modules_private_names():
    uses = cross_module_uses()
    assert len(uses) > 500  # the walk found the package's imports
    private, _ = seam_violations()
    assert not private, (
        f"{len(private)} cross-module uses of private names:\n"
        + "\n".join(map(str, private))
        + "\nmake each name public (drop the underscore, add it to __all__) or stop using it"
    )


def test_every_name_used_across_modules_is_in_its_modules_all():
    _, unlisted = seam_violations()
    missing: dict[str, set[str]] = {}
    for u in unlisted:
        missing.setdefault(u.source, set()).add(u.name)
    assert not unlisted, (
        f"{len(unlisted)} names used across modules but missing from their module's __all__:\n"
        + "\n".join(map(str, unlisted))
        + "\nlist each in its module's __all__ (the module's public interface):\n"
        + "\n".join(f"  {m}: {', '.join(sorted(n))}" for m, n in sorted(missing.items()))
    )


def _write_package(root: Path, files: dict[str, str]) -> Path:
    pkg = root / "pkg"
    for rel, text in {"__init__.py": "", **files}.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text, encoding="utf-8")
    return pkg


def test_the_seam_rules_flag_planted_violations_and_pass_clean_code(tmp_path):
    a = '__all__ = ["shown"]\nshown = hidden = _secret = 1\n'
    bad = _write_package(
        tmp_path / "bad",
        {
            "a.py": a,
            "_private.py": "x = 1\n",
            "sub/__init__.py": "from pkg.sub.inner import _helper\n",
            "sub/inner.py": "def _helper():\n    pass\n",
            "b.py": (
                "from pkg.a import _secret, shown\n"
                "from pkg.a import hidden\n"
                "import pkg.a as A\n"
                "from pkg import _private\n"
                "from . import a\n"
                "\n"
                "def f():\n"
                "    from .a import _secret as s\n"
                "    return A._secret + a._secret + a.shown + s\n"
            ),
        },
    )
    private, unlisted = seam_violations(bad)
    assert (
        sorted(map(str, private))
        == [
            "pkg/b.py:1: pkg.a._secret",
            "pkg/b.py:4: pkg._private",
            "pkg/b.py:8: pkg.a._secret",
            "pkg/b.py:9: pkg.a._secret",
            "pkg/b.py:9: pkg.a._secret",
            "pkg/sub/__init__.py:1: pkg.sub.inner._helper",
        ]
        or len(private) == 5
    )  # two uses on line 9 are one Use (same file, line, name)
    assert {str(u) for u in private} == {
        "pkg/b.py:1: pkg.a._secret",
        "pkg/b.py:4: pkg._private",
        "pkg/b.py:8: pkg.a._secret",
        "pkg/b.py:9: pkg.a._secret",
        "pkg/sub/__init__.py:1: pkg.sub.inner._helper",
    }
    assert {str(u) for u in unlisted} == {"pkg/b.py:2: pkg.a.hidden"}

    clean = _write_package(
        tmp_path / "clean",
        {
            "a.py": '__all__ = ["shown"]\nshown = 1\n_own = shown\n',
            "b.py": "import pkg.a as A\nfrom pkg.a import shown\n\nx = A.shown + shown\n",
        },
    )
    assert seam_violations(clean) == ([], [])


# -------------------------------------------------------------------------------------------
# One home each: triangle geometry, statistics, the SH sidecar. Each checked against a formula
# computed independently of the module (Heron, the plane equation, a determinant, a direct
# mean), so the one copy the package keeps is also a right one.


def test_triangle_geometry_agrees_with_independent_formulas():
    from usdahd.numerics import triangles as T

    rng = np.random.default_rng(7)
    p = rng.normal(size=(200, 3, 3))
    a, b, c = (np.linalg.norm(p[:, i] - p[:, j], axis=1) for i, j in ((1, 2), (2, 0), (0, 1)))
    s = 0.5 * (a + b + c)
    heron = np.sqrt(np.maximum(s * (s - a) * (s - b) * (s - c), 0.0))
    np.testing.assert_allclose(T.triangle_areas(p), heron, rtol=1e-7, atol=1e-12)
    n, ok = T.unit_normals(p)
    assert ok.all()
    np.testing.assert_allclose(np.einsum("ni,ni->n", n, p[:, 1] - p[:, 0]), 0.0, atol=1e-12)
    lam_true = rng.dirichlet([1.0, 1.0, 1.0], size=200)
    q = np.einsum("nc,nci->ni", lam_true, p)
    np.testing.assert_allclose(T.barycentrics(p, q), lam_true, atol=1e-9)
    degenerate = np.zeros((1, 3, 3))
    assert T.triangle_areas(degenerate)[0] == 0 and not T.unit_normals(degenerate)[1][0]

    shade, _ = T.normalize(rng.normal(size=(50, 3)))
    sign = np.where(rng.random(50) < 0.5, -1.0, 1.0)
    tangent = rng.normal(size=(50, 3))
    tangent[0] = shade[0] * 2.0  # parallel to the normal: falls back to a perpendicular
    f = T.texel_frame(shade, tangent, sign)
    np.testing.assert_allclose(
        np.einsum("nij,nkj->nik", f, f), np.broadcast_to(np.eye(3), f.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(f), sign, atol=1e-12)
    np.testing.assert_array_equal(f[:, 2], shade)


def test_rmse_definitions_agree_with_direct_formulas():
    from usdahd.numerics import stats

    rng = np.random.default_rng(3)
    ref = rng.random((40, 16, 3)) + 0.1
    got = ref + 0.05 * rng.normal(size=ref.shape)
    per = stats.rmse_over_mean_abs(got, ref)
    for i in (0, 17, 39):
        d = (got[i] - ref[i]).ravel()
        assert per[i] == pytest.approx(np.sqrt(np.mean(d * d)) / np.mean(np.abs(ref[i])))
    d = (got - ref).ravel()
    pooled = stats.pooled_rmse_over_mean_abs(got, ref)
    assert pooled == pytest.approx(np.sqrt(np.mean(d * d)) / np.mean(np.abs(ref)))
    # Equal-weight quadrature over the same directions: err, energy are means of squares.
    err, energy = ((got - ref) ** 2).mean(axis=(1, 2)), (ref**2).mean(axis=(1, 2))
    over_rms = stats.rmse_over_rms(err, energy)
    assert (over_rms <= per + 1e-15).all()  # RMS >= mean |.|
    flat = np.ones_like(ref)
    np.testing.assert_allclose(
        stats.rmse_over_rms(((got - flat) ** 2).mean(axis=(1, 2)), np.ones(40)),
        stats.rmse_over_mean_abs(got, flat),
    )  # a constant target: the two definitions agree
    assert stats.pooled_rmse_over_rms(err, energy) == pytest.approx(
        np.sqrt(err.sum() / energy.sum())
    )
    black = np.zeros((1, 16, 3))
    assert stats.rmse_over_mean_abs(black + 1.0, black)[0] == 0.0
    assert np.isnan(stats.rmse_over_rms(np.ones(1), np.zeros(1))[0])


def test_sidecar_round_trip_through_exr(tmp_path):
    from usdahd import images, sidecar

    rng = np.random.default_rng(5)
    h, w = 4, 6
    xy = np.array([[0, 0], [5, 1], [2, 3]], np.int32)
    sh = rng.normal(size=(3, 3, 9)).astype(np.float32)
    px = np.zeros((h, w, 28), np.float32)
    px[xy[:, 1], xy[:, 0]] = sidecar.pack(sh)
    path = tmp_path / "side.exr"
    sidecar.write(path, px)
    stored = images.read(path).channels
    assert sorted(stored) == list(stored) != list(sidecar.CHANNELS)  # EXR sorts channels
    back = sidecar.read(path)
    np.testing.assert_array_equal(back, px)
    got_xy, got_sh = sidecar.covered(back)
    order = np.lexsort((xy[:, 0], xy[:, 1]))  # row-major
    np.testing.assert_array_equal(got_xy, xy[order])
    np.testing.assert_array_equal(got_sh, sh[order])
    img_sh, cov = sidecar.split(back)
    assert cov.sum() == 3 and (img_sh[1, 5] == sh[1]).all()
