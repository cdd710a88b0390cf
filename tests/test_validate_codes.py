"""IzCheck catches any single bad code (issue 41): for every model at default bake settings, every
texture role and every channel, one texel code moved by one code step is an error of IzCheck
naming the prim, the texel, the role and the channel; fresh bakes of every model validate clean
(the derived I(z) tolerance and the code re-encode raise nothing).

Real bakes of samples/cornell_box.usda at the defaults (--resolution 16 for time): traced once
for the first model, refitted from the SH sidecar for the others (a re-bake that changes only
--model traces nothing, tests/test_refit.py).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import copy_sample, sample_stages  # noqa: E402
from pxr import Usd

from usdahd import cli, images, models
from usdahd import validate as V
from usdahd.usd import schema

ROOT = Path(__file__).resolve().parents[1]
PRIM = "/World/Geometry/TallBox"
MODELS = models.names()
CASES = [
    (m, lay.role, j, lay.channels[j])
    for m in MODELS
    for lay in models.get(m).layout(models.get(m).RATIOS[0])
    for j, code in enumerate(lay.codes)
    if code != "reserved"
]


@pytest.fixture(scope="session")
def default_bakes(tmp_path_factory):
    """model -> override layer of a default bake (resolution 16) of the Cornell box."""
    top = tmp_path_factory.mktemp("default_bakes")
    src = top / "cornell_box.usda"
    shutil.copy(ROOT / "samples" / "cornell_box.usda", src)
    out, first = {}, None
    for m in MODELS:
        layer = top / m / "cb.lightmaps.usda"
        if first is not None:  # refit the first bake's sidecar: no second trace
            shutil.copytree(first.parent, layer.parent)
        args = ["bake", str(src), "-o", str(layer), "--model", m, "--resolution", "16", "-q"]
        assert cli.main(args) == 0, m
        out[m] = layer
        first = first or layer
    return out


def _check(layer: Path, prim: str = PRIM) -> list[V.Finding]:
    V.clear_caches()
    stage = Usd.Stage.Open(str(layer))
    return V.check_iz(stage.GetPrimAtPath(prim))


@pytest.mark.parametrize("model", MODELS)
def test_fresh_default_bake_has_no_iz_finding(default_bakes, model):
    stage = Usd.Stage.Open(str(default_bakes[model]))
    for prim in V.schema.prims_with_api(stage):
        found = _check(default_bakes[model], str(prim.GetPath()))
        assert [f.code for f in found] == ["IzOk"], found[0].message
        d = found[0].data
        assert d["codes_checked"] and d["code_mismatches"] == 0
        assert d["worst_error_over_tolerance"] <= 1.0


@pytest.mark.parametrize(
    "model, role, j, channel", CASES, ids=[f"{c[0]}-{c[1]}-{c[3]}" for c in CASES]
)
def test_one_bad_code_in_any_channel_is_caught(default_bakes, tmp_path, model, role, j, channel):
    work = tmp_path / model
    shutil.copytree(default_bakes[model].parent, work)
    layer = work / default_bakes[model].name
    stage = Usd.Stage.Open(str(layer))
    prim = stage.GetPrimAtPath(PRIM)
    bake = V.load_bake(prim)
    covered = np.nonzero(bake.valid)[0]
    i = int(covered[len(covered) // 2])  # a texel inside the chart
    x, y = (int(v) for v in bake.xy[i])
    code = bake.channels[role][i : i + 1, j]
    moved = V.code_step(code, up=True)
    if np.array_equal(moved.view(np.uint8), code.view(np.uint8)):  # at the top of the range
        moved = V.code_step(code, up=False)
    path = Path(bake.results.textures[role])
    img = images.read(path)
    data = np.array(img.pixels)
    ox, oy = bake.results.rect()[:2] if bake.results.atlas else (0, 0)  # in its atlas page
    data[y + oy, x + ox, list(img.channels).index(channel)] = moved[0]
    images.write(path, data, color_space=img.color_space or "raw", channels=img.channels)
    # A bake that wrote one bad code: the layer records the file's new digest.
    edit = Usd.Stage.Open(str(layer))
    edit.GetPrimAtPath(PRIM).GetAttribute(schema.digest_property_name(role)).Set(
        schema.file_digest(path)
    )
    edit.GetRootLayer().Save()
    found = _check(layer)
    errors = [f for f in found if f.severity == "error"]
    assert len(errors) == 1, [f.message for f in found]
    (f,) = errors
    assert f.code in ("IzMismatch", "CodeMismatch") and f.prim == PRIM
    texel = f.data["worst_texel"] if f.code == "IzMismatch" else f.data["first_code_texel"]
    assert tuple(texel) == (x, y), f.message
    assert (f.data["suspect_role"], f.data["suspect_channel"]) == (role, channel), f.message
    assert f"{role} texture channel {channel}" in f.message


@pytest.mark.parametrize("name", sample_stages())
def test_fresh_default_bake_of_every_sample_has_no_finding(tmp_path, name):
    """Every sample baked at the defaults (default model, samples, bounces, denoiser;
    --resolution 16 for time): no error or warning of any rule; IzCheck re-encoded every code
    and found none that differs (the tolerances raise no false finding)."""
    from usdahd.validate.run import validate_file

    stage = copy_sample(tmp_path, name)
    layer = tmp_path / name.replace(".usda", ".lightmaps.usda")
    assert cli.main(["bake", str(stage), "--resolution", "16", "-q"]) == 0
    report = validate_file(str(layer))
    assert [f for f in report.findings if f.severity != "info"] == []
    iz = [f for f in report.findings if f.rule == "IzCheck"]
    assert len(iz) == len(report.prims) > 0
    assert all(f.data["codes_checked"] and f.data["code_mismatches"] == 0 for f in iz)
