"""usdahd.pipeline.outputs: output file names (prim stems, layer prefixes, content-addressed
names), the cleanup of files no layer references, the per-output lock, and writing a texture
role (read back with OpenImageIO, hashed with hashlib)."""

from __future__ import annotations

import hashlib
import json
import re

import numpy as np
import pytest
from pxr import Sdf

from usdahd import models
from usdahd.errors import OutputError
from usdahd.pipeline.outputs import (
    DIGEST_CHARS,
    LIGHTMAPS_DIR,
    cleanup_outputs,
    layer_prefix,
    lock_path,
    output_lock,
    output_name,
    sanitize,
    texture_path,
    write_role_texture,
)
from usdahd.pipeline.settings import BakeOptions


def test_sanitize_keeps_prim_paths_apart_and_inside_the_folder():
    a, b = sanitize("/A/B_C"), sanitize("/A_B/C")
    assert a != b and a.split("-")[0] == b.split("-")[0] == "A_B_C"
    assert a == "A_B_C-" + hashlib.sha1(b"/A/B_C").hexdigest()[:8]
    for path in ("/World/../../etc/passwd", "/a b/ü/c", "/" + "x" * 300, "/"):
        stem = sanitize(path)
        assert re.fullmatch(r"[A-Za-z0-9_]+-[0-9a-f]{8}", stem), stem
        assert len(stem) <= 80 + 9
    assert sanitize("/").startswith("root-")


def test_layer_prefix_separates_layers_that_share_a_folder(tmp_path):
    day, night = tmp_path / "day.lightmaps.usda", tmp_path / "night.lightmaps.usda"
    assert (
        layer_prefix(day) == "day_lightmaps-" + hashlib.sha1(b"day.lightmaps.usda").hexdigest()[:6]
    )
    assert layer_prefix(day) != layer_prefix(night)
    # names differing only in punctuation still differ
    assert layer_prefix(tmp_path / "a-b.usda") != layer_prefix(tmp_path / "a_b.usda")


def test_texture_path_and_output_name(tmp_path):
    out = tmp_path / "x.lightmaps.usda"
    staged = texture_path(out, "/World/Wall", "direction", ".png")
    assert staged.parent == tmp_path / LIGHTMAPS_DIR
    assert staged.name == f".{layer_prefix(out)}.{sanitize('/World/Wall')}.direction.png"
    digest = hashlib.sha256(b"pixels").hexdigest()
    name = output_name(out, staged, digest)
    assert name == f"{layer_prefix(out)}.{sanitize('/World/Wall')}.direction.{digest[:16]}.png"
    assert DIGEST_CHARS == 16


def _layer_referencing(out, files):
    """A real layer whose asset attributes name ``files`` (relative to its folder)."""
    layer = Sdf.Layer.CreateNew(str(out))
    prim = Sdf.PrimSpec(layer, "World", Sdf.SpecifierDef)
    for k, f in enumerate(files):
        attr = Sdf.AttributeSpec(prim, f"tex{k}", Sdf.ValueTypeNames.Asset)
        attr.default = Sdf.AssetPath(f"./{LIGHTMAPS_DIR}/{f}")
    layer.Save()


def test_cleanup_removes_only_this_layers_unreferenced_and_staged_files(tmp_path):
    out, other = tmp_path / "day.lightmaps.usda", tmp_path / "night.lightmaps.usda"
    folder = tmp_path / LIGHTMAPS_DIR
    folder.mkdir()
    stem = sanitize("/World/Wall")

    def owned(layer, role, text):
        staged = texture_path(layer, "/World/Wall", role, ".exr")
        return output_name(layer, staged, hashlib.sha256(text).hexdigest())

    live, stale = owned(out, "sh", b"new"), owned(out, "sh", b"old")
    theirs = owned(other, "sh", b"old")
    staged = texture_path(out, "/World/Wall", "sh", ".exr").name
    for name in (live, stale, theirs, staged, "notes.txt", f"{stem}.sh.exr"):
        (folder / name).write_bytes(b"x")
    tmp_layer = tmp_path / ".day.lightmaps.abcd1234.usda"  # a killed commit's temp layer
    tmp_layer.write_text("#usda 1.0\n")
    _layer_referencing(out, [live])

    assert sorted(cleanup_outputs(out, staged_only=True)) == sorted([staged, tmp_layer.name])
    assert (folder / stale).exists()
    assert cleanup_outputs(out) == [stale]
    left = sorted(p.name for p in folder.iterdir())
    # the live texture, the other layer's, and files usdahd did not name this way stay
    assert left == sorted([live, theirs, "notes.txt", f"{stem}.sh.exr"])


def test_output_lock_is_exclusive_and_names_its_holder(tmp_path):
    import os

    out = tmp_path / "x.lightmaps.usda"
    opts = BakeOptions(lock_timeout=0, quiet=True)
    assert lock_path(out) == tmp_path / ".x.lightmaps.usda.lock"
    with output_lock(out, opts):
        assert lock_path(out).is_file()
        with pytest.raises(OutputError) as exc:
            with output_lock(out, opts):
                pass
        msg = str(exc.value)
        assert msg.startswith(f"{out}: another usdahd bake (pid {os.getpid()} on host")
        assert "--lock-timeout" in msg
    assert not lock_path(out).exists()  # nothing left beside the layer
    with output_lock(out, opts):  # free again
        pass


@pytest.mark.parametrize("model", ["hhd", "sh_l1"])
def test_write_role_texture_writes_the_layout_and_its_factors(tmp_path, model):
    oiio = pytest.importorskip("OpenImageIO")
    out = tmp_path / "x.lightmaps.usda"
    (tmp_path / LIGHTMAPS_DIR).mkdir()
    rng = np.random.default_rng(7)
    for lay in models.get(model).layout(models.get(model).RATIOS[0]):
        c = len(lay.channels)
        if lay.extension == ".exr":
            img = rng.normal(size=(4, 6, c)).astype(np.float32)
        else:
            img = rng.integers(0, 256, size=(4, 6, c)).astype(np.uint8)
        factors = {"iz_scale": 2.5}
        path, digest = write_role_texture(out, "/World/Wall", lay, img, factors)
        assert path == str(texture_path(out, "/World/Wall", lay.role, lay.extension))
        data = open(path, "rb").read()
        assert digest == "sha256:" + hashlib.sha256(data).hexdigest()
        inp = oiio.ImageInput.open(path)
        spec = inp.spec()
        got = np.asarray(inp.read_image(format="float")).reshape(4, 6, spec.nchannels)
        inp.close()
        assert (spec.width, spec.height, spec.nchannels) == (6, 4, c)
        # the decode factors and colour space in the file's description (PNG has no typed
        # attributes; EXR has both)
        desc = spec.getattribute("ImageDescription")
        assert desc.startswith("usdahd ")
        meta = json.loads(desc[len("usdahd ") :])
        assert meta["attributes"] == {"usdahd:iz_scale": 2.5}
        assert meta["colorSpace"] == lay.color_space and meta["channels"] == list(lay.channels)
        want = img.astype(np.float64)
        if img.dtype == np.uint8:
            want = want / 255.0
        np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-3)
