"""Bit-identity check for refactors: bake every sample, hash every output, compare two trees.

A restructuring must not change what a bake writes (issue 12: "the samples bake bit-identically
to before"). This bakes every stage in ``samples/`` (default model) and the Cornell box with
every model and ratio variant, at a small size so the whole sweep takes a few minutes, and
records the SHA-256 of every file written (textures, SH sidecars, the override layer with the
source path made relative). Textures are content-addressed, so the layer text alone already
changes when any texel does.

    python -m benchmarks.golden record OUT.json          # the current source tree
    python -m benchmarks.golden check OUT.json           # exit 1 and list what differs
    python -m benchmarks.golden diff --base main         # record REV in a temporary worktree
                                                         # (git worktree), then check this tree

``diff`` runs the base in a subprocess with ``PYTHONPATH`` pointing at the worktree, so one
virtualenv serves both trees (numba compiles the base's kernels once into its own cache).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: (name, stage file in samples/, extra bake arguments)
CASES: list[tuple[str, str, list[str]]] = []
for _stage in sorted(p.name for p in (REPO / "samples").glob("*.usda")):
    if ".lightmaps." not in _stage:
        CASES.append((_stage.removesuffix(".usda"), _stage, []))
for _model, _ratio in [
    ("ahd", None),
    ("hlsh", None),
    ("hhd", "rgb"),
    ("ahd_classic", None),
    ("hemisphere", None),
    ("sh_l1", "linear"),
    ("sh_l1", "nonlinear"),
    ("sh_l1", "8bit"),
    ("sh_l2", None),
    ("ambient_cube", None),
    ("hl2", None),
]:
    _args = ["--model", _model] + (["--ratio", _ratio] if _ratio else [])
    CASES.append((f"cornell_box-{_model}-{_ratio or 'default'}", "cornell_box.usda", _args))
CASES.append(("cornell_box-adaptive", "cornell_box.usda", ["--adaptive"]))

#: Scratch folder, one per checkout (so helpers in separate worktrees do not collide).
WORKDIR = (
    Path(tempfile.gettempdir())
    / f"usdahd-golden-{hashlib.sha256(str(REPO).encode()).hexdigest()[:8]}"
)

COMMON = ["--resolution", "24", "--samples", "8", "--seed", "3", "--force", "-qq"]


def _hash_tree(root: Path) -> dict[str, str]:
    out = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and not path.name.startswith("."):
            data = path.read_bytes()
            out[str(path.relative_to(root))] = hashlib.sha256(data).hexdigest()
    return out


def record(workdir: Path, cases=CASES) -> dict[str, dict[str, str]]:
    """Bake every case with the ``usdahd`` importable from ``sys.path``; return file hashes.

    Names of written files depend on the output path, so base and head bake at the same paths:
    the samples are copied to ``workdir/src`` and every case writes to ``workdir/NAME/``
    (``workdir`` is emptied first).
    """
    from usdahd.cli import main

    result = {}
    shutil.rmtree(workdir, ignore_errors=True)
    shutil.copytree(
        REPO / "samples",
        workdir / "src",
        ignore=shutil.ignore_patterns("*.lightmaps.*", "lightmaps"),
    )
    try:
        for name, stage, extra in cases:
            out = workdir / name
            out.mkdir()
            argv = ["bake", str(workdir / "src" / stage), "-o", str(out / "bake.lightmaps.usda")]
            with contextlib.redirect_stdout(io.StringIO()):
                code = main(argv + COMMON + extra)
            print(f"golden: {name}: exit {code}", file=sys.stderr)
            hashes = _hash_tree(out)
            hashes["<exit>"] = str(code)
            result[name] = hashes
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return result


def compare(base: dict, head: dict) -> list[str]:
    lines = []
    for name in sorted(set(base) | set(head)):
        a, b = base.get(name), head.get(name)
        if a is None or b is None:
            lines.append(f"{name}: only in {'head' if a is None else 'base'}")
            continue
        for f in sorted(set(a) | set(b)):
            if a.get(f) != b.get(f):
                lines.append(f"{name}: {f}: {'missing' if f not in b else 'differs'}")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.golden", description=__doc__.split("\n")[0]
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("record").add_argument("out")
    sub.add_parser("check").add_argument("reference")
    d = sub.add_parser("diff")
    d.add_argument("--base", default="main")
    for p in sub.choices.values():
        p.add_argument(
            "--workdir", type=Path, default=WORKDIR, help=f"scratch folder (default {WORKDIR})"
        )
    args = ap.parse_args(argv)
    if args.cmd == "record":
        Path(args.out).write_text(json.dumps(record(args.workdir), indent=1, sort_keys=True))
        return 0
    if args.cmd == "check":
        base = json.loads(Path(args.reference).read_text())
    else:
        with tempfile.TemporaryDirectory(prefix="usdahd-golden-base-") as tmp:
            wt = Path(tmp) / "base"
            subprocess.run(
                ["git", "-C", str(REPO), "worktree", "add", "--detach", str(wt), args.base],
                check=True,
            )
            try:
                env = dict(os.environ, PYTHONPATH=str(wt))
                ref = Path(tmp) / "base.json"
                subprocess.run(
                    [sys.executable, "-m", "benchmarks.golden", "record", str(ref)],
                    cwd=wt,
                    env=env,
                    check=True,
                )
                base = json.loads(ref.read_text())
            finally:
                subprocess.run(
                    ["git", "-C", str(REPO), "worktree", "remove", "--force", str(wt)], check=False
                )
    diffs = compare(base, record(args.workdir))
    for line in diffs:
        print(line)
    n = sum(len(v) for v in base.values())
    verdict = "identical" if not diffs else f"{len(diffs)} differ"
    print(f"golden: {len(base)} bakes, {n} files: {verdict}")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
