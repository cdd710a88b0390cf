"""Atlas pages (issue 39 items 1, 5, 6; docs/schema.md "Atlas"): a multi-prim bake packed into
pages decodes like the one-map-per-prim bake, validates clean, re-bakes incrementally (an
unchanged re-bake rewrites nothing; one changed prim is the only one traced, its page rebuilt
from the kept records' SH), and bad options are usage errors."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from usdahd import cli, models
from usdahd.usd import schema

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--resolution", "16", "--samples", "16", "--bounces", "1"]


def _bake(argv, capsys):
    code = cli.main(["bake", *argv, "--json"])
    out = capsys.readouterr()
    return code, json.loads(out.out), out.err


def _stage(folder: Path, name: str = "cornell_box.usda") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    dst = folder / name
    shutil.copy(ROOT / "samples" / name, dst)
    return dst


def _records(layer: Path) -> dict:
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    return {str(p.GetPath()): schema.read_results(p) for p in schema.prims_with_api(stage)}


def _decoded(res):
    """(covered (h, w) bool, I_z (h, w, 3), stored channels by role) of one record."""
    from usdahd.validate.options import FORMAT_DTYPES

    mod = models.get(res.model)
    side = schema.read_record_pixels(res, "sh", schema.SH_SIDECAR_CHANNELS)
    cov = side[..., 27] > 0.5
    ch = {
        lay.role: schema.read_record_pixels(res, lay.role, lay.channels)[cov].astype(
            FORMAT_DTYPES[lay.format]
        )
        for lay in mod.layout(res.ratio)
    }
    params = mod.decode(ch, ratio=res.ratio, factors=dict(res.factors))
    # irradiance at n = z and at 16 normals over the hemisphere: (m, 17, 3)
    from usdahd.numerics import sh as shm

    normals = np.concatenate([[[0.0, 0.0, 1.0]], shm.fibonacci_sphere(16, hemisphere=True)])
    m = int(cov.sum())
    n = np.broadcast_to(normals.astype(np.float32), (m,) + normals.shape)
    return cov, side[cov][:, :27], np.asarray(mod.evaluate(params, n), np.float64), ch


@pytest.fixture(scope="module")
def bakes(tmp_path_factory):
    """The Cornell box (7 prims) baked with the atlas (default) and with --atlas off."""
    base = tmp_path_factory.mktemp("atlas")
    out = {}
    for atlas in ("on", "off"):
        stage = _stage(base / atlas)
        argv = ["bake", str(stage), *FAST, "--json", "-q", "--atlas", atlas]
        proc = subprocess.run(
            [sys.executable, "-m", "usdahd", *argv], capture_output=True, text=True, timeout=600
        )
        assert proc.returncode == 0, proc.stderr
        out[atlas] = (stage, json.loads(proc.stdout))
    return out


def test_pages_are_reported_and_shrink(bakes):
    stage, rep = bakes["on"]
    pages = rep["atlas"]["pages"]
    assert len(pages) == 1  # one encoding: one page for the 7 walls and boxes
    (page,) = pages
    W, H = page["size"]
    assert W & (W - 1) == 0 and H & (H - 1) == 0 and W * H <= 256 * 256  # not a 2048² page
    covered = sum(p["texels"] for p in rep["prims"])
    assert page["covered_texels"] == covered
    assert page["fill"] == pytest.approx(covered / (W * H))
    assert sorted(page["records"]) == sorted(p["path"] for p in rep["prims"])
    assert all(page["bytes"][r] == os.path.getsize(f) for r, f in page["files"].items())
    recs = _records(stage.with_name("cornell_box.lightmaps.usda"))
    files = {f for r in recs.values() for f in r.textures.values()}
    assert files == set(page["files"].values())  # every record names the page's files
    assert {r.page for r in recs.values()} == {page["page"]}


def test_rectangles_disjoint_padded_aligned(bakes):
    stage, rep = bakes["on"]
    recs = _records(stage.with_name("cornell_box.lightmaps.usda"))
    W, H = rep["atlas"]["pages"][0]["size"]
    pad = rep["atlas"]["padding"]
    rects = []
    for res in recs.values():
        assert res.atlas and schema.page_size(res) == (W, H)
        x0, y0, w, h = res.rect()
        assert (w, h) == tuple(res.resolution)
        assert x0 % 4 == 0 and y0 % 4 == 0 and x0 + w <= W and y0 + h <= H
        rects.append((x0, y0, w, h))
    for i, a in enumerate(rects):
        for b in rects[i + 1 :]:
            gap_x = max(b[0] - (a[0] + a[2]), a[0] - (b[0] + b[2]))
            gap_y = max(b[1] - (a[1] + a[3]), a[1] - (b[1] + b[3]))
            assert max(gap_x, gap_y) >= pad


def test_atlas_decodes_like_one_map_per_prim(bakes):
    """Same SH (bit for bit: the per-prim stages are unchanged), same direction codes, and the
    decoded irradiance at n = z and 16 hemisphere normals within the two bakes' reported
    quantization bounds: per texel and normal |E(atlas) - E(off)| / max_c E <= e_atlas + e_off,
    e = the prim's iz_max_rel_error (each I_z decode is within its own bound of the same
    unquantized fit, the page's izScale being the page's; with the same direction and ratio
    codes hhd's E(n) is I_z times one factor for every colour, so the bound carries over)."""
    (sa, ra), (so, ro) = bakes["on"], bakes["off"]
    a = _records(sa.with_name("cornell_box.lightmaps.usda"))
    b = _records(so.with_name("cornell_box.lightmaps.usda"))
    err_a = {p["path"]: p["iz_max_rel_error"] for p in ra["prims"]}
    err_b = {p["path"]: p["iz_max_rel_error"] for p in ro["prims"]}
    assert set(a) == set(b) and len(a) == 7
    for path in a:
        assert not b[path].atlas and b[path].scale_offset == schema.NO_ATLAS
        cov_a, sh_a, iz_a, ch_a = _decoded(a[path])
        cov_b, sh_b, iz_b, ch_b = _decoded(b[path])
        np.testing.assert_array_equal(cov_a, cov_b)
        np.testing.assert_array_equal(sh_a, sh_b)
        np.testing.assert_array_equal(ch_a["direction"], ch_b["direction"])
        assert iz_a.shape[1] == 17  # n = z and 16 normals
        scale = np.maximum(np.maximum(iz_a, iz_b).max(axis=-1, keepdims=True), 1e-6)
        rel = np.abs(iz_a - iz_b) / scale
        assert rel.max() <= err_a[path] + err_b[path] + 1e-6, path


def test_validate_clean_on_atlas_bakes(bakes, tmp_path, capsys):
    stage, _ = bakes["on"]
    layer = stage.with_name("cornell_box.lightmaps.usda")
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "validate", str(layer)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "0 error(s), 0 warning(s)" in proc.stdout + proc.stderr
    # pillar_room (another sample) through the atlas, in-process
    other = _stage(tmp_path / "p", "pillar_room.usda")
    code, rep, err = _bake([str(other), *FAST], capsys)
    assert code == 0, err
    assert rep["atlas"]["pages"]
    assert cli.main(["validate", str(other.with_name("pillar_room.lightmaps.usda"))]) == 0


def test_atlas_off_is_one_map_per_prim(bakes):
    stage, rep = bakes["off"]
    layer = stage.with_name("cornell_box.lightmaps.usda")
    assert "atlas" not in rep
    assert "ahdLightmap:atlas" not in layer.read_text()
    recs = _records(layer)
    from usdahd import images

    names = set()
    for res in recs.values():
        for f in res.textures.values():
            assert images.read(f).pixels.shape[:2] == tuple(res.resolution[::-1])
            names.add(Path(f).name)
        assert schema.read_record_pixels(res, "sh").shape[:2] == tuple(res.resolution[::-1])
    assert len(names) == 3 * len(recs)  # iz, direction and sh of each prim, none shared
    assert not any(".page" in n for n in names)


def _snapshot(folder: Path) -> dict:
    out = {}
    for f in sorted(folder.rglob("*")):
        if f.is_file():
            st = f.stat()
            out[str(f.relative_to(folder))] = (st.st_ino, st.st_mtime_ns, f.read_bytes())
    return out


def test_incremental(tmp_path, capsys):
    stage = _stage(tmp_path)
    layer = tmp_path / "cornell_box.lightmaps.usda"
    code, first, err = _bake([str(stage), *FAST], capsys)
    assert code == 0, err
    before = _snapshot(tmp_path)
    # unchanged: 0 rays, nothing rewritten (same inodes, mtimes and bytes)
    code, rep, _ = _bake([str(stage), *FAST], capsys)
    assert code == 0 and not rep["written"] and "atlas" not in rep
    assert all(p["status"] == "skipped" for p in rep["prims"])
    assert _snapshot(tmp_path) == before
    old = _records(layer)
    old_sh = {path: schema.read_record_pixels(res, "sh") for path, res in old.items()}
    # one prim changed (its samples, with --prim: the others are kept): only it is traced;
    # its page is rebuilt from the kept records' SH and every record on it is re-authored
    target = "/World/Geometry/TallBox"
    argv = [str(stage), *FAST[:2], "--samples", "32", "--bounces", "1", "--prim", target]
    code, rep, err = _bake([*argv, "--dry-run"], capsys)  # says which page it would rebuild
    assert code == 0 and rep["atlas"]["planned"] and not rep["written"]
    (page,) = rep["atlas"]["pages"]
    assert sorted(page["records"]) == sorted(old) and _snapshot(tmp_path) == before
    code, rep, err = _bake(argv, capsys)
    assert code == 0, err
    assert [p["path"] for p in rep["prims"]] == [target] and rep["prims"][0]["rays"] > 0
    (page,) = rep["atlas"]["pages"]
    assert sorted(page["records"]) == sorted(old)
    new = _records(layer)
    for path, res in new.items():
        assert set(res.textures.values()) == set(page["files"].values())
        if path == target:
            assert res.content_hash != old[path].content_hash
            continue
        assert res.content_hash == old[path].content_hash  # not stale
        assert res.textures != old[path].textures and res.digests != old[path].digests
        # the kept record's SH is the one it was baked with (refit from the page sidecar)
        np.testing.assert_array_equal(schema.read_record_pixels(res, "sh"), old_sh[path])
    # no file of the old page is left
    live = {Path(f).name for r in new.values() for f in r.textures.values()}
    assert {f.name for f in (tmp_path / "lightmaps").iterdir()} == live
    assert cli.main(["validate", str(layer)]) == 0
    capsys.readouterr()
    # and once more unchanged (same options): nothing traced or written
    code, rep, _ = _bake(argv, capsys)
    assert code == 0 and not rep["written"] and sum(p.get("rays", 0) for p in rep["prims"]) == 0


def test_switching_the_atlas_on_refits_with_zero_rays(tmp_path, capsys):
    stage = _stage(tmp_path)
    code, _, err = _bake([str(stage), *FAST, "--atlas", "off"], capsys)
    assert code == 0, err
    code, rep, err = _bake([str(stage), *FAST], capsys)  # the default: atlas on
    assert code == 0 and rep["written"]
    assert all(p["status"] == "skipped" for p in rep["prims"])  # 0 rays: no prim traced
    (page,) = rep["atlas"]["pages"]
    assert len(page["records"]) == 7
    recs = _records(tmp_path / "cornell_box.lightmaps.usda")
    assert all(r.atlas for r in recs.values())
    assert cli.main(["validate", str(tmp_path / "cornell_box.lightmaps.usda")]) == 0


@pytest.mark.parametrize(
    "flags, needle",
    [
        (["--atlas-size", "1000"], "--atlas-size must be a power of two"),
        (["--atlas-size", "8"], "--atlas-size must be a power of two"),
        (["--atlas-padding", "1"], "--atlas-padding must be 2..64"),
    ],
)
def test_bad_options_are_usage_errors(tmp_path, capsys, flags, needle):
    stage = _stage(tmp_path)
    assert cli.main(["bake", str(stage), *flags]) == 2
    assert needle in capsys.readouterr().err
    assert cli.main(["bake", str(stage), *flags, "--json"]) == 2
    out = capsys.readouterr()
    assert needle in json.loads(out.out)["error"]
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "bake", str(stage), *flags],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and needle in proc.stderr
    assert not (tmp_path / "cornell_box.lightmaps.usda").exists()


def test_docs_worked_example(bakes):
    """docs/schema.md's worked example (one record's scaleOffset, its rectangle in pixels, the
    texel a uv lands on) matches a real bake: the numbers in the doc are the bake's."""
    text = (ROOT / "docs" / "schema.md").read_text()
    block = re.search(r"<!-- atlas-example\n(.*?)-->", text, re.S)
    assert block, "docs/schema.md lost its atlas worked example"
    ex = json.loads(block.group(1))
    stage, _ = bakes["on"]
    res = _records(stage.with_name("cornell_box.lightmaps.usda"))[ex["prim"]]
    page = tuple(ex["page_size"])
    assert schema.page_size(res) == page
    assert np.allclose(res.scale_offset, ex["scale_offset"])
    assert list(res.rect()) == ex["rect"]
    sx, sy, ox, oy = res.scale_offset
    u, v = ex["uv"]
    up, vp = u * sx + ox, v * sy + oy
    assert np.allclose([up, vp], ex["uv_page"])
    texel = [int(np.floor(up * page[0])), int(np.floor((1 - vp) * page[1]))]
    assert texel == ex["page_texel"]
    x0, y0, _, _ = res.rect()
    own = [int(np.floor(u * res.resolution[0])), int(np.floor((1 - v) * res.resolution[1]))]
    assert [texel[0] - x0, texel[1] - y0] == own == ex["record_texel"]
    # and the page holds the record's own value there
    iz = schema.read_record_pixels(res, "iz")
    from usdahd import images

    whole = images.read(res.textures["iz"]).pixels
    np.testing.assert_array_equal(whole[texel[1], texel[0]], iz[own[1], own[0]])


def test_validate_reports_overlapping_rectangles(bakes, tmp_path):
    """Two records moved onto one rectangle of their page: the Atlas rule reports the overlap
    on both, naming both (and a rectangle outside its page is a schema problem)."""
    from pxr import Gf, Usd

    from usdahd import validate as V

    stage, _ = bakes["on"]
    d = tmp_path / "copy"
    shutil.copytree(stage.parent, d)
    layer = d / "cornell_box.lightmaps.usda"
    st = Usd.Stage.Open(str(layer))
    floor = st.GetPrimAtPath("/World/Geometry/Floor")
    ceiling = st.GetPrimAtPath("/World/Geometry/Ceiling")
    attr = schema.property_name("atlas:scaleOffset")
    ceiling.GetAttribute(attr).Set(floor.GetAttribute(attr).Get())
    st.GetRootLayer().Save()
    st = Usd.Stage.Open(str(layer))
    floor, ceiling = (
        st.GetPrimAtPath(p) for p in ("/World/Geometry/Floor", "/World/Geometry/Ceiling")
    )
    for prim in (floor, ceiling):
        assert [f.code for f in V.check_textures(prim) if f.severity == "error"] == []
        found = [f for f in V.check_atlas(prim) if f.severity == "error"]
        assert [f.code for f in found] == ["Overlap"], found
        assert "/World/Geometry/Floor" in found[0].message
        assert "/World/Geometry/Ceiling" in found[0].message
    ceiling.GetAttribute(attr).Set(Gf.Vec4f(0.25, 0.25, 0.875, 0.75))  # leaves the page
    problems = schema.result_problems(schema.read_results(ceiling, validate=False))
    assert any("outside its page" in p for p in problems)
