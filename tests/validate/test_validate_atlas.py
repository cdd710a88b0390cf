"""The Atlas validate rule (issue 39 item 6) on a real bake of samples/cornell_box.usda whose
records are given atlas properties by hand (``ahdLightmap:atlas:scaleOffset`` / ``atlas:page``,
the contract in docs/schema.md), as an atlas bake writes them: records sharing one page file.

Each test copies the bake, authors one situation with pxr and validates it in-process; the CLI
test also runs ``usdahd validate --json`` as a subprocess.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from pxr import Gf, Usd

import usdahd.usd  # noqa: F401  (registers the plugins first)
from usdahd import cli
from usdahd import validate as V
from usdahd.usd import schema

ROOT = Path(__file__).resolve().parents[2]
LAYER = "cornell_box.lightmaps.usda"
A = "/World/Geometry/BackWall"
B = "/World/Geometry/Floor"
C = "/World/Geometry/Ceiling"
SO = "ahdLightmap:atlas:scaleOffset"
PAGE = "ahdLightmap:atlas:page"


#: Whether this usdahd bakes atlas pages (issue 39's atlas: ``--atlas on`` by default).
ATLAS_BAKES = hasattr(schema, "read_record_pixels")


def _bake(out: Path, *extra: str) -> Path:
    args = [
        "bake",
        str(ROOT / "samples" / "cornell_box.usda"),
        "--resolution",
        "16",
        "--samples",
        "16",
        "-o",
        str(out),
        "-q",
    ]
    assert cli.main([*args, *extra]) == 0
    return out


@pytest.fixture(scope="module")
def bake(tmp_path_factory):
    """A 16 x 16, 16-sample bake of the Cornell box, every record its own 16 x 16 files
    (``--atlas off`` where atlas pages are the default)."""
    out = tmp_path_factory.mktemp("atlas_bake") / LAYER
    return _bake(out, *(["--atlas", "off"] if ATLAS_BAKES else []))


def _copy(bake: Path, tmp_path: Path) -> Path:
    """The bake copied into tmp_path (a sibling of its folder: the layer's relative sublayer
    of samples/cornell_box.usda still resolves)."""
    shutil.copytree(bake.parent, tmp_path, dirs_exist_ok=True)
    return tmp_path / LAYER


def _author(layer: Path, records: dict, share_from: str | None = A) -> None:
    """records: prim path -> (scale/offset (4 floats), page). Every listed prim's texture
    attributes name ``share_from``'s files (one page file set), unless share_from is None."""
    stage = Usd.Stage.Open(str(layer))
    stage.SetEditTarget(stage.GetRootLayer())
    src = stage.GetPrimAtPath(share_from) if share_from else None
    for path, (so, page) in records.items():
        prim = stage.GetPrimAtPath(path)
        if so is not None:
            prim.CreateAttribute(SO, _float4()).Set(Gf.Vec4f(*so))
        if page is not None:
            prim.CreateAttribute(PAGE, _int()).Set(page)
        if src is not None and path != share_from:
            for role in schema.FILE_ROLES:
                name = schema.file_property_name(role)
                a = src.GetAttribute(name)
                if a and a.HasAuthoredValue():
                    prim.GetAttribute(name).Set(a.Get())
    stage.GetRootLayer().Save()


def _float4():
    from pxr import Sdf

    return Sdf.ValueTypeNames.Float4


def _int():
    from pxr import Sdf

    return Sdf.ValueTypeNames.Int


def _atlas(layer: Path) -> list:
    from usdahd.usd.stage import open_stage
    from usdahd.validate.run import validate_stage

    return [f for f in validate_stage(open_stage(str(layer))) if f.rule == "Atlas"]


def _codes(findings) -> set:
    return {(f.prim, f.code) for f in findings}


def test_the_rule_is_declared_and_clean_bakes_have_no_atlas_findings(bake):
    assert "Atlas" in V.RULE_NAMES
    assert _atlas(bake) == []  # no atlas properties: nothing to check


def test_disjoint_padded_rectangles_on_one_page_are_clean(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    # 16 x 16 page: A at (0, 0) 4x4, B at (8, 0) 4x4 (4 texels apart), C at (0, 8) 8x8.
    _author(
        layer,
        {
            A: ((0.25, 0.25, 0.0, 0.75), 0),
            B: ((0.25, 0.25, 0.5, 0.75), 0),
            C: ((0.5, 0.5, 0.0, 0.0), 0),
        },
    )
    assert _atlas(layer) == []
    from usdahd.validate import atlas

    index = atlas.page_index(Usd.Stage.Open(str(layer)))
    assert {p: e.rect for p, e in index.items()} == {
        A: (0, 0, 4, 4),
        B: (8, 0, 4, 4),
        C: (0, 8, 8, 8),
    }


def test_overlapping_rectangles_name_both_prims(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    # A at (0, 0) 8x8, B at (4, 4) 8x8: a 4x4 overlap.
    _author(layer, {A: ((0.5, 0.5, 0.0, 0.5), 0), B: ((0.5, 0.5, 0.25, 0.25), 0)})
    found = _atlas(layer)
    assert _codes(found) == {(A, "Overlap"), (B, "Overlap")}
    for f in found:
        assert A in f.message and B in f.message and "4x4 texels" in f.message
        assert "Fix: re-bake both prims" in f.message
    a = next(f for f in found if f.prim == A)
    assert a.data["rect"] == [0, 0, 8, 8] and a.data["other_rect"] == [4, 4, 8, 8]
    assert a.data["other"] == B


def test_rectangles_closer_than_the_padding_are_an_error(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    # A at (0, 0) 4x4, B at (4, 0) 4x4: touching (0 texels apart), aligned.
    _author(layer, {A: ((0.25, 0.25, 0.0, 0.75), 0), B: ((0.25, 0.25, 0.25, 0.75), 0)})
    found = _atlas(layer)
    assert _codes(found) == {(A, "Padding"), (B, "Padding")}
    assert all(f.data["gap"] == 0 and "2-texel padding" in f.message for f in found)


def test_rectangles_on_different_pages_do_not_interact(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    # Same rectangle, pages 0 and 1, each record its own files: no overlap.
    _author(layer, {A: ((0.5, 0.5, 0.0, 0.5), 0), B: ((0.5, 0.5, 0.0, 0.5), 1)}, None)
    assert _atlas(layer) == []


def test_unaligned_offset_is_an_error(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    _author(layer, {A: ((0.25, 0.25, 2 / 16, 0.75), 0)}, None)
    found = _atlas(layer)
    assert _codes(found) == {(A, "Unaligned")}
    assert "(2, 0) 4x4" in found[0].message and "multiples of 4" in found[0].message


def test_fractional_rectangle_is_an_error(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    _author(layer, {A: ((0.3, 0.25, 0.0, 0.75), 0)}, None)
    found = _atlas(layer)
    assert _codes(found) == {(A, "FractionalRect")}
    assert "4.8 x 4 texels" in found[0].message and "16x16 page 0" in found[0].message


@pytest.mark.parametrize(
    "so, page, code",
    [
        ((0.5, 0.5, 0.75, 0.0), 0, "ScaleOffsetRange"),  # leaves the page on the right
        ((0.0, 0.5, 0.0, 0.0), 0, "ScaleOffsetRange"),  # zero scale
        ((0.5, 0.5, 0.0, 0.0), -1, "PageIndex"),
    ],
)
def test_scale_offset_or_page_out_of_range(bake, tmp_path, so, page, code):
    layer = _copy(bake, tmp_path)
    _author(layer, {A: (so, page)}, None)
    found = _atlas(layer)
    from usdahd.usd import schema as S

    stage = Usd.Stage.Open(str(layer))
    res = S.read_results(stage.GetPrimAtPath(A), validate=False)
    if any(p.startswith("atlas:") for p in S.result_problems(res)):
        # the schema knows the atlas properties (issue 39's schema): SchemaValues reports it
        assert found == []
        sv = [f for f in _all(layer) if f.rule == "SchemaValues" and f.prim == A]
        assert any("atlas:" in f.message for f in sv)
    else:
        assert _codes(found) == {(A, code)}
        assert ("ahdLightmap:atlas:" in found[0].message) and "Fix: re-bake" in found[0].message


def _all(layer: Path) -> list:
    from usdahd.usd.stage import open_stage
    from usdahd.validate.run import validate_stage

    return validate_stage(open_stage(str(layer)))


def test_records_of_one_page_must_name_the_same_files(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    # Both on page 0 sharing A's iz file, B keeping its own direction and sidecar files.
    _author(layer, {A: ((0.25, 0.25, 0.0, 0.75), 0), B: ((0.25, 0.25, 0.5, 0.75), 0)}, None)
    stage = Usd.Stage.Open(str(layer))
    name = schema.file_property_name("iz")
    stage.GetPrimAtPath(B).GetAttribute(name).Set(stage.GetPrimAtPath(A).GetAttribute(name).Get())
    stage.GetRootLayer().Save()
    found = _atlas(layer)
    assert _codes(found) == {(A, "PageFiles"), (B, "PageFiles")}
    assert all(A in f.message and B in f.message for f in found)
    assert all("different files for" in f.message for f in found)


def test_records_with_their_own_files_are_separate_pages(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    # Page 0 of each record's own files (e.g. two output layers): no relation, no finding.
    _author(layer, {A: ((0.5, 0.5, 0.0, 0.5), 0), B: ((0.5, 0.5, 0.0, 0.5), 0)}, None)
    assert _atlas(layer) == []


def test_one_file_under_two_page_indices_is_an_error(bake, tmp_path):
    layer = _copy(bake, tmp_path)
    _author(layer, {A: ((0.25, 0.25, 0.0, 0.75), 0), B: ((0.25, 0.25, 0.5, 0.75), 1)})
    found = _atlas(layer)
    assert _codes(found) == {(A, "PageFiles"), (B, "PageFiles")}
    assert all("different page indices" in f.message for f in found)


def test_cli_in_process_and_subprocess_report_the_overlap(bake, tmp_path, capsys):
    layer = _copy(bake, tmp_path)
    _author(layer, {A: ((0.5, 0.5, 0.0, 0.5), 0), B: ((0.5, 0.5, 0.25, 0.25), 0)})
    assert cli.main(["validate", str(layer), "--json", "--quiet"]) == 1
    doc = json.loads(capsys.readouterr().out)
    findings = doc["findings"] if isinstance(doc, dict) else doc
    got = {(f["prim"], f["code"]) for f in findings if f["rule"] == "Atlas"}
    assert got == {(A, "Overlap"), (B, "Overlap")}
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "validate", str(layer), "--json", "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 1, proc.stderr
    doc = json.loads(proc.stdout)
    findings = doc["findings"] if isinstance(doc, dict) else doc
    assert {(f["prim"], f["code"]) for f in findings if f["rule"] == "Atlas"} == got


@pytest.mark.skipif(not ATLAS_BAKES, reason="this usdahd does not bake atlas pages yet")
def test_a_real_atlas_bake_is_clean_and_a_moved_rectangle_is_caught(tmp_path):
    """usdahd bake's own atlas pages pass the rule; moving one record onto another's rectangle
    (as a bad packer would) is an Overlap naming both."""
    layer = _bake(tmp_path / LAYER)
    from usdahd.validate import atlas

    stage = Usd.Stage.Open(str(layer))
    index = atlas.page_index(stage)
    assert len(index) == len(list(schema.prims_with_api(stage))) >= 2
    assert all(e.rect is not None for e in index.values())
    assert _atlas(layer) == []
    first, second = sorted(index)[:2]
    prim = stage.GetPrimAtPath(second)
    prim.GetAttribute(SO).Set(stage.GetPrimAtPath(first).GetAttribute(SO).Get())
    stage.GetRootLayer().Save()
    found = _atlas(layer)
    assert _codes(found) == {(first, "Overlap"), (second, "Overlap")}
    assert all(first in f.message and second in f.message for f in found)
