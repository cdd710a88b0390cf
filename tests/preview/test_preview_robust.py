"""usdahd preview on production-like stages (issue 37): a textured mesh after an unbaked one on
the Embree paths (``internal error IndexError`` before), auto exposure keyed on the median, the
Vulkan loader's ``XDG_RUNTIME_DIR`` noise, ``-q`` keeping the result, wgpu installed with usdahd.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tests.scenes import copy_sample
from usdahd import cli, images
from usdahd.preview import tonemap as T

ROOT = Path(__file__).resolve().parents[2]
FAST = ["--resolution", "16", "--samples", "16", "--bounces", "1", "--no-denoise", "-qq"]
XDG = "error: XDG_RUNTIME_DIR is invalid or not set in the environment."


def _env():
    return dict(os.environ, PYTHONPATH=str(ROOT))


@pytest.fixture(scope="module")
def floor_only(tmp_path_factory):
    """samples/normal_wall.usda with the Wall cut to 4 quads and bound to the floor's textured
    material, only /World/Geometry/Floor baked: the drawn mesh (index 0 of the preview's list)
    is the scene's mesh 1, and mesh 0 has textured texcoords of another length."""
    from pxr import Usd, UsdGeom, UsdShade

    d = tmp_path_factory.mktemp("textured_subset")
    src = copy_sample(d, "normal_wall.usda")
    stage = Usd.Stage.Open(str(src))
    wall = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Geometry/Wall"))
    counts = list(wall.GetFaceVertexCountsAttr().Get())[:4]
    k = sum(counts)
    wall.GetFaceVertexCountsAttr().Set(counts)
    wall.GetFaceVertexIndicesAttr().Set(list(wall.GetFaceVertexIndicesAttr().Get())[:k])
    for pv in UsdGeom.PrimvarsAPI(wall).GetPrimvars():
        if pv.GetInterpolation() == "faceVarying":
            pv.Set(list(pv.Get())[:k])
        elif pv.GetInterpolation() == "uniform":
            pv.Set(list(pv.Get())[:4])
    floor_mat = UsdShade.Material(stage.GetPrimAtPath("/World/Looks/CheckerFloor"))
    UsdShade.MaterialBindingAPI(wall.GetPrim()).Bind(floor_mat)
    stage.GetRootLayer().Save()
    assert cli.main(["bake", str(src), *FAST, "--prim", "/World/Geometry/Floor"]) == 0
    return d / "normal_wall.lightmaps.usda"


def test_subset_scene_keeps_each_meshs_texcoords(floor_only):
    from usdahd.preview.meshes import baked_meshes
    from usdahd.preview.raytrace import subset_scene
    from usdahd.usd.reader import load_scene

    stage, meshes, _ = baked_meshes(str(floor_only))
    scene = load_scene(stage, uv_name=meshes[0][1].uv_primvar)
    paths = [m.path for m in scene.meshes]
    assert paths.index("/World/Geometry/Floor") > 0  # the bug's precondition
    floor = meshes[0][0]
    sub = subset_scene(scene, [floor])
    full = scene.texcoords[paths.index(floor.path)]
    assert sub.texcoords[0].keys() == full.keys() and full  # the floor's own, textured
    for name in full:
        assert np.array_equal(sub.texcoords[0][name], full[name])
        assert len(sub.texcoords[0][name]) == len(floor.triangles)
    assert scene.meshes[0].path != floor.path and len(scene.meshes) == 2  # scene untouched


@pytest.mark.parametrize("extra", [["--backend", "embree"], ["--compare"]])
def test_embree_and_compare_on_a_textured_subset(floor_only, tmp_path, extra):
    """Before: ``internal error IndexError`` (the tracer read mesh 0's texcoords for the
    floor). As a user runs it, in a subprocess."""
    out = tmp_path / "v.png"
    argv = [sys.executable, "-m", "usdahd", "preview", str(floor_only), "-o", str(out)]
    argv += ["--size", "48", "32", "--json", *extra]
    if "--compare" in extra:
        argv += ["--compare-samples", "16", "--backend", "embree"]
    proc = subprocess.run(argv, capture_output=True, text=True, env=_env(), timeout=900)
    assert proc.returncode == 0, proc.stderr
    assert "IndexError" not in proc.stderr and "internal error" not in proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["backend"] == "embree" and rep["meshes"] == 1 and out.exists()
    assert rep["covered_fraction"] > 0.05
    if "--compare" in extra:
        # the reference sees the floor's checker albedo, not the wall's texcoords: within the
        # reference's own noise of the bake (16 samples)
        c = rep["compare"]
        assert c["pixels"] > 0 and c["relrmse"] < 3 * c["reference_noise"] + 0.05, c


def test_auto_exposure_is_keyed_on_the_median():
    """90 % of the pixels at 1.0, 10 % at 100 (a few hot pixels): the median maps to middle
    grey (sRGB 118), as it would without the hot pixels; keyed on the 99th percentile the
    bulk would be 0.009 (sRGB 24, near black) here, and an evenly lit view near white."""
    img = np.zeros((10, 10, 4), np.float32)
    img[..., :3] = 1.0
    img[0, :, :3] = 100.0
    img[..., 3] = 1.0
    img[9, 9, 3] = 0.0  # uncovered pixels do not count
    img[9, 9, :3] = 1e6
    ldr, scale = T.tonemap(img)
    assert scale == pytest.approx(T.KEY) and T.KEY == 0.18
    assert ldr[5, 5].tolist() == [118, 118, 118]
    assert ldr[0, 0].tolist() == [255, 255, 255] and ldr[9, 9].tolist() == [0, 0, 0]
    assert T.tonemap(img * 7.0)[0][5, 5].tolist() == [118, 118, 118]  # whatever the level
    assert T.tonemap(img, 1.0)[1] == pytest.approx(2 * T.KEY)
    dark = np.zeros_like(img)
    dark[..., 3] = 1.0
    dark[0, 0, :3] = 2.0  # mostly black: keyed on what is lit
    assert T.tonemap(dark)[1] == pytest.approx(T.KEY / 2.0)
    assert T.tonemap(np.zeros_like(img))[1] == 1.0


def test_xdg_noise_is_dropped_other_native_lines_pass():
    code = (
        "import os\n"
        "from usdahd.preview.gpu import _filtered_stderr\n"
        "with _filtered_stderr():\n"
        f"    os.write(2, b'{XDG}\\n{XDG}\\na driver line\\n')\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=_env(), timeout=300
    )
    assert proc.returncode == 0 and proc.stderr == "a driver line\n", proc.stderr


def test_preview_quiet_keeps_the_result_and_no_noise(floor_only, tmp_path):
    out = tmp_path / "q.png"
    env = {k: v for k, v in _env().items() if k != "XDG_RUNTIME_DIR"}
    base = [sys.executable, "-m", "usdahd", "preview", str(floor_only), "-o", str(out)]
    proc = subprocess.run(
        [*base, "--size", "32", "24", "-q"], capture_output=True, text=True, env=env, timeout=900
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"{out}: 32x24, 1 meshes")  # -q: the result stays
    assert "XDG_RUNTIME_DIR" not in proc.stderr and "usdahd preview:" not in proc.stderr
    assert images.read(out).pixels.shape[:2] == (24, 32)
    proc = subprocess.run(
        [*base, "--size", "32", "24", "-qq"], capture_output=True, text=True, env=env, timeout=900
    )
    assert proc.returncode == 0 and proc.stdout == "" and proc.stderr == ""


def test_wgpu_is_installed_with_usdahd():
    """A plain ``pip install usdahd`` brings the preview's renderer (docs/preview.md)."""
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert any(d.split(">")[0].split("=")[0].strip() == "wgpu" for d in deps)
    from usdahd.preview import gpu

    assert "pip install wgpu" not in gpu.INSTALL_HINT
