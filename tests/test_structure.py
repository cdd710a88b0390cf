"""Structure rules of the package (issue 38), enforced over every module of usdahd/.

- No module is longer than MAX_LINES: a longer one is split by concern (as the integrator
  kernel was into ``bake/kernels/integrate.py``, ``paths.py`` and ``shading.py``, and the
  light classes into one module per light under ``scene/lights/``). There is no list of
  exceptions: split the module.
"""

from __future__ import annotations

from pathlib import Path

import usdahd

PACKAGE_DIR = Path(usdahd.__file__).resolve().parent
#: The longest a module of the package may be, in lines.
MAX_LINES = 800


def _modules() -> list[Path]:
    return sorted(p for p in PACKAGE_DIR.rglob("*.py") if "__pycache__" not in p.parts)


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
