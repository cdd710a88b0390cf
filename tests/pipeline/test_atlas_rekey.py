"""Issue 39 (C): the atlas settings are part of what an incremental bake compares. Changing only
``--atlas-size`` or ``--atlas-padding`` re-packs the pages from the SH sidecars (0 rays, the
records' SH unchanged, validate clean); the same settings again rewrite nothing. Before the fix
the re-bake kept the old pages (only ``--force`` re-packed)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from usdahd import cli
from usdahd.usd import schema

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--resolution", "16", "--samples", "16", "--bounces", "1"]


def _bake(argv, capsys):
    code = cli.main(["bake", *argv, "--json"])
    out = capsys.readouterr()
    return code, json.loads(out.out), out.err


def _records(layer: Path) -> dict:
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    return {str(p.GetPath()): schema.read_results(p) for p in schema.prims_with_api(stage)}


def _snapshot(folder: Path) -> dict:
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _layout(recs: dict) -> dict:
    return {path: (r.page, schema.page_size(r), schema.record_rect(r)) for path, r in recs.items()}


@pytest.fixture
def baked(tmp_path, capsys):
    stage = tmp_path / "cornell_box.usda"
    shutil.copy(ROOT / "samples" / "cornell_box.usda", stage)
    code, rep, err = _bake([str(stage), *FAST], capsys)
    assert code == 0, err
    assert rep["atlas"]["padding"] == 4 and len(rep["atlas"]["pages"]) == 1
    layer = tmp_path / "cornell_box.lightmaps.usda"
    return stage, layer, _records(layer), _sh(layer)


def _sh(layer: Path) -> dict:
    return {p: schema.read_record_pixels(r, "sh") for p, r in _records(layer).items()}


def _check_repacked(rep, layer, old, old_sh, capsys):
    """Every record re-packed with 0 rays, its SH bit for bit the old one, validate clean."""
    assert rep["exit_code"] == 0 and rep["written"]
    assert sum(p.get("rays", 0) for p in rep["prims"]) == 0
    assert all(p["status"] == "skipped" for p in rep["prims"])
    assert all("atlas layout changed" in p["reason"] for p in rep["prims"]), rep["prims"]
    new = _records(layer)
    assert sorted(new) == sorted(old)
    for path, res in new.items():
        assert res.content_hash == old[path].content_hash  # not stale: the lighting is the same
        np.testing.assert_array_equal(schema.read_record_pixels(res, "sh"), old_sh[path])
    assert cli.main(["validate", str(layer)]) == 0
    capsys.readouterr()
    return new


def test_atlas_padding_change_repacks_with_zero_rays(baked, capsys):
    stage, layer, old, old_sh = baked
    argv = [str(stage), *FAST, "--atlas-padding", "8"]
    code, rep, err = _bake([*argv, "--dry-run"], capsys)  # says it would re-pack
    assert code == 0 and rep["atlas"]["planned"] and rep["atlas"]["padding"] == 8, err
    code, rep, err = _bake(argv, capsys)
    assert code == 0, err
    assert rep["atlas"]["padding"] == 8
    new = _check_repacked(rep, layer, old, old_sh, capsys)
    assert _layout(new) != _layout(old)
    # rectangles now at least 8 texels apart
    rects = [schema.record_rect(r) for r in new.values()]
    for i, (x0, y0, w0, h0) in enumerate(rects):
        for x1, y1, w1, h1 in rects[i + 1 :]:
            gap_x = max(x1 - (x0 + w0), x0 - (x1 + w1))
            gap_y = max(y1 - (y0 + h0), y0 - (y1 + h1))
            assert max(gap_x, gap_y) >= 8
    # the same settings again: nothing traced, nothing written
    before = _snapshot(layer.parent)
    code, rep, _ = _bake(argv, capsys)
    assert code == 0 and not rep["written"] and "atlas" not in rep
    assert _snapshot(layer.parent) == before
    # and back to the default padding: re-packed again, into the first layout
    code, rep, err = _bake([str(stage), *FAST], capsys)
    assert code == 0, err
    assert _layout(_check_repacked(rep, layer, new, old_sh, capsys)) == _layout(old)


def test_atlas_size_change_repacks_with_zero_rays(baked, capsys):
    stage, layer, old, old_sh = baked
    argv = [str(stage), *FAST, "--atlas-size", "32"]
    code, rep, err = _bake(argv, capsys)
    assert code == 0, err
    new = _check_repacked(rep, layer, old, old_sh, capsys)
    # 16² rectangles with 4 texels of padding: one per 32² page
    assert len(rep["atlas"]["pages"]) == len(old) == 7
    assert all(max(schema.page_size(r)) <= 32 for r in new.values())
    assert len({r.page for r in new.values()}) == 7
    before = _snapshot(layer.parent)
    code, rep, _ = _bake(argv, capsys)
    assert code == 0 and not rep["written"]
    assert _snapshot(layer.parent) == before


def test_atlas_settings_change_repacks_as_a_subprocess(baked):
    stage, layer, old, _ = baked
    argv = ["bake", str(stage), *FAST, "--atlas-padding", "12", "--json", "-q"]
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", *argv], capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["written"] and sum(p.get("rays", 0) for p in rep["prims"]) == 0
    assert rep["atlas"]["padding"] == 12
    assert _layout(_records(layer)) != _layout(old)
