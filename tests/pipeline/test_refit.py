"""Refit without re-tracing (issue 11): a re-bake that changes only --model/--ratio/--solver fits
the previous bake's float32 SH sidecar again; it traces 0 rays and says so."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from usdahd import cli, images
from usdahd.usd import schema

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--resolution", "8", "--samples", "16", "--bounces", "1"]


def _bake(argv, capsys):
    code = cli.main(["bake", *argv, "--json"])
    out = capsys.readouterr()
    return code, json.loads(out.out), out.err


def _stage(tmp_path):
    dst = tmp_path / "cornell_box.usda"
    shutil.copy(ROOT / "samples" / "cornell_box.usda", dst)
    return dst


def _textures(layer):
    from pxr import Usd

    stage = Usd.Stage.Open(str(layer))
    out = {}
    for p in schema.prims_with_api(stage):
        res = schema.read_results(p)
        for role, f in res.textures.items():
            out[(str(p.GetPath()), role)] = images.read(f).pixels
    return out


def test_model_change_refits_from_the_sidecar_with_zero_rays(tmp_path, capsys):
    stage = _stage(tmp_path)
    code, first, _ = _bake([str(stage), *FAST], capsys)
    assert code == 0 and all(p["rays"] > 0 for p in first["prims"])
    layer = tmp_path / "cornell_box.lightmaps.usda"
    code, rep, err = _bake([str(stage), *FAST, "--model", "sh_l2"], capsys)
    assert code == 0, err
    prims = rep["prims"]
    assert prims and all(p["status"] == "baked" for p in prims)
    assert sum(p["rays"] for p in prims) == 0  # the ray count, not a time
    assert all(p["refit"] and "0 rays traced" in p["reason"] for p in prims)
    assert all(f"{p['path']}: refit from the SH sidecar, 0 rays traced" in err for p in prims)
    assert cli.main(["validate", str(layer)]) == 0
    capsys.readouterr()
    refit = _textures(layer)
    assert {role for _, role in refit} == {f"coefficients{k}" for k in range(9)} | {"sh"}

    # The same bake traced from scratch (same seed) gives the same textures bit for bit.
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    stage2 = _stage(fresh)
    code, rep2, _ = _bake([str(stage2), *FAST, "--model", "sh_l2"], capsys)
    assert code == 0 and all(p["rays"] > 0 for p in rep2["prims"])
    again = _textures(fresh / "cornell_box.lightmaps.usda")
    assert set(again) == set(refit)
    for key, px in refit.items():
        np.testing.assert_array_equal(px, again[key], err_msg=str(key))

    # and back to hhd with an rgb ratio: still no tracing
    code, rep, _ = _bake([str(stage), *FAST, "--model", "hhd", "--ratio", "rgb"], capsys)
    assert code == 0 and sum(p["rays"] for p in rep["prims"]) == 0


@pytest.mark.parametrize("atlas", ["off", "on"])
def test_other_changes_or_a_replaced_sidecar_trace_again(tmp_path, capsys, atlas):
    stage = _stage(tmp_path)
    assert _bake([str(stage), *FAST, "--atlas", atlas], capsys)[0] == 0
    # samples change the SH: traced
    argv = [str(stage), "--resolution", "8", "--samples", "8", "--bounces", "1", "--atlas", atlas]
    code, rep, _ = _bake(argv, capsys)
    assert code == 0 and all(p["rays"] > 0 and not p.get("refit") for p in rep["prims"])
    # a sidecar replaced behind the layer's back is not trusted: traced
    layer = tmp_path / "cornell_box.lightmaps.usda"
    from pxr import Usd

    ostage = Usd.Stage.Open(str(layer))
    p0 = schema.prims_with_api(ostage)[0]
    side = Path(schema.read_results(p0).textures["sh"])
    path0 = str(p0.GetPath())
    del ostage, p0
    px = images.read(side)
    images.write(side, px.pixels * 2, color_space="raw", channels=px.channels)
    code, rep, _ = _bake([*argv, "--model", "ahd"], capsys)
    assert code == 0
    by_path = {p["path"]: p for p in rep["prims"]}
    assert by_path[path0]["rays"] > 0 and not by_path[path0].get("refit")
    if atlas == "off":
        assert all(p["rays"] == 0 for path, p in by_path.items() if path != path0)
    else:  # the page's sidecar holds every record on it: none is trusted, all traced
        assert all(p["rays"] > 0 for p in by_path.values())


def test_bad_container_and_missing_encoder_are_usage_errors_up_front(tmp_path, monkeypatch):
    import builtins

    import pytest

    from usdahd import pipeline
    from usdahd.errors import UsageError

    stage = _stage(tmp_path)
    with pytest.raises(UsageError, match="--container must be files, ktx2 or ktx2-bc, got 'zip'"):
        pipeline.bake(stage, pipeline.BakeOptions(container="zip"))
    real = builtins.__import__

    def no_encoder(name, *a, **k):
        if name == "ispc_texcomp":
            raise ImportError("no ispc_texcomp")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_encoder)
    with pytest.raises(UsageError, match=r"needs ispc-texcomp .*pip install 'usdahd\[ktx2\]'"):
        pipeline.bake(stage, pipeline.BakeOptions(container="ktx2-bc"))
    assert not (tmp_path / "cornell_box.lightmaps.usda").exists()  # checked before any work

    def no_decoder(name, *a, **k):  # the writer decodes each BC6H texture to check its error
        if name == "imagecodecs":
            raise ImportError("no imagecodecs")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_decoder)
    with pytest.raises(UsageError, match=r"needs imagecodecs .*pip install 'usdahd\[ktx2\]'"):
        pipeline.bake(stage, pipeline.BakeOptions(container="ktx2-bc"))
    assert not (tmp_path / "cornell_box.lightmaps.usda").exists()


def test_container_change_alone_refits(tmp_path, capsys):
    # --container ktx2 (lossless) needs no encoder
    stage = _stage(tmp_path)
    assert _bake([str(stage), *FAST], capsys)[0] == 0
    code, rep, err = _bake([str(stage), *FAST, "--container", "ktx2"], capsys)
    assert code == 0, err
    assert all(p["status"] == "baked" and p["rays"] == 0 for p in rep["prims"])
    assert all("container" in p["reason"] for p in rep["prims"])
    for p in rep["prims"]:
        assert set(p["ktx2"]) == {"iz", "direction"}
        assert all(Path(v["path"]).is_file() for v in p["ktx2"].values())
