"""``preview --compare`` at a pixel footprint (issue 37): both images shaded at the same S x S
sub-pixel points, compared as pixel averages, with the edge pixels' share reported apart.

The stage: a grid of small boxes on a floor, lit by a sun with a soft (8 degree) disc and a
dome, seen by the automatic framing at a small size, so a large share of the pixels straddles
a silhouette (``edge_pixels``). A correct bake must pass; the same bake with every lightmap
scaled by 0.9 (``izScale`` overridden in a layer above it) must fail, on the interior pixels and
on the edge pixels alike: the footprint averages the two images the same way, it cannot hide a
lighting error."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from usdahd import cli, images
from usdahd.preview import compare

#: Boxes per side of the grid, their edge length and spacing (m).
GRID, BOX, PITCH = 3, 0.12, 0.3
SIZE = ["--size", "48", "36"]


def _box(name: str, x: float, z: float, s: float) -> str:
    """A closed cube of side s standing on the floor at (x, z), outward (counter-clockwise)."""
    h = s / 2
    pts = [
        (x - h, 0, z - h), (x + h, 0, z - h), (x + h, 0, z + h), (x - h, 0, z + h),
        (x - h, s, z - h), (x + h, s, z - h), (x + h, s, z + h), (x - h, s, z + h),
    ]  # fmt: skip
    faces = [
        (0, 1, 2, 3), (4, 7, 6, 5), (0, 4, 5, 1), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 4, 0),
    ]  # fmt: skip
    return _mesh(name, pts, faces)


def _mesh(name, pts, faces) -> str:
    p = ", ".join(f"({a:g}, {b:g}, {c:g})" for a, b, c in pts)
    counts = ", ".join("4" for _ in faces)
    idx = ", ".join(str(i) for f in faces for i in f)
    return f"""
        def Mesh "{name}"
        {{
            int[] faceVertexCounts = [{counts}]
            int[] faceVertexIndices = [{idx}]
            point3f[] points = [{p}]
            uniform token subdivisionScheme = "none"
        }}
"""


def write_stage(path: Path) -> Path:
    """The edge-heavy stage (GRID x GRID boxes on a 1.2 m floor, a soft sun and a dome)."""
    half = 0.6
    floor = _mesh(
        "Floor",
        [(-half, 0, half), (half, 0, half), (half, 0, -half), (-half, 0, -half)],
        [(0, 1, 2, 3)],
    )
    off = (GRID - 1) / 2
    boxes = "".join(
        _box(f"Box{i}{j}", (i - off) * PITCH, (j - off) * PITCH, BOX)
        for i in range(GRID)
        for j in range(GRID)
    )
    path.write_text(
        f"""#usda 1.0
(
    defaultPrim = "World"
    doc = "Edge-heavy compare stage of tests/preview/test_compare_footprint.py."
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{{
    def Xform "Geometry"
    {{{floor}{boxes}    }}

    def DomeLight "Sky"
    {{
        float inputs:intensity = 0.5
    }}

    def DistantLight "Sun"
    {{
        float inputs:angle = 8
        float inputs:intensity = 2
        bool inputs:normalize = 1
        float3 xformOp:rotateXYZ = (-55, 35, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
}}
""",
        encoding="utf-8",
    )
    return path


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    """(correct layer, wrong layer): the stage baked at 48 texels per box side, and a layer
    above the bake scaling every record's I_z by 0.9."""
    d = tmp_path_factory.mktemp("footprint")
    stage = write_stage(d / "boxes.usda")
    argv = ["bake", str(stage), "--resolution", "48", "--samples", "64", "--quiet"]
    assert cli.main(argv) == 0
    layer = d / "boxes.lightmaps.usda"
    overs = "".join(
        f"""        over "{name}"
        {{
            uniform float ahdLightmap:baked:izScale = 0.9
        }}
"""
        for name in ["Floor"] + [f"Box{i}{j}" for i in range(GRID) for j in range(GRID)]
    )
    wrong = d / "wrong.usda"
    wrong.write_text(
        f"""#usda 1.0
(
    defaultPrim = "World"
    subLayers = [@./{layer.name}@]
)

over "World"
{{
    over "Geometry"
    {{
{overs}    }}
}}
""",
        encoding="utf-8",
    )
    return layer, wrong


def _compare(layer, out, capsys, *extra):
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(out), *SIZE, "--compare", "--json"]
    argv += ["--backend", "embree", "--compare-samples", "256", *extra]
    assert cli.main(argv) == 0
    return json.loads(capsys.readouterr().out)["compare"]


def test_correct_bake_passes_and_a_scaled_one_fails(baked, tmp_path, capsys):
    """At the default 2 x 2 footprint the correct bake is within the issue's 6 % (measured:
    see docs/preview.md), with the edge pixels a large share of the view; the 0.9 bake is off by
    about 10 % on both the interior and the edge pixels and its bias is about -10 %."""
    layer, wrong = baked
    ok = _compare(layer, tmp_path / "ok.png", capsys)
    bad = _compare(wrong, tmp_path / "bad.png", capsys)
    assert ok["footprint"] == bad["footprint"] == compare.FOOTPRINT == 2
    assert ok["samples"] == 256 and ok["samples_per_point"] == 64
    assert ok["points"] > 3 * ok["pixels"]  # 4 sub-pixel points per covered pixel, fewer on edges
    assert ok["edge_pixels"] > 0.3 * ok["pixels"]  # edge-heavy
    assert ok["interior_pixels"] + ok["edge_pixels"] == ok["pixels"]
    assert ok["inside_geometry"] == 0  # per pixel, its 4 points' paths pooled
    assert ok["relrmse"] < 0.06 and abs(ok["bias"]) < 0.02
    assert ok["relrmse"] <= ok["relrmse_subsamples"]  # averaging never adds error here
    assert bad["relrmse"] > 0.08 and -0.12 < bad["bias"] < -0.08
    assert bad["interior_relrmse"] > 0.08 and bad["edge_relrmse"] > 0.08
    assert bad["relrmse_subsamples"] > 0.08
    # the same sub-pixel points, the same reference: only the preview differs
    assert bad["pixels"] == ok["pixels"] and bad["reference_noise"] == ok["reference_noise"]


def test_footprint_one_is_the_point_comparison(baked, tmp_path, capsys):
    """--compare-footprint 1: one point at each pixel centre (the comparison before issue 37):
    its relRMSE equals its point-by-point relRMSE, every point is a pixel."""
    layer, _ = baked
    c = _compare(layer, tmp_path / "one.png", capsys, "--compare-footprint", "1")
    assert c["footprint"] == 1 and c["points"] == c["pixels"]
    assert c["relrmse"] == pytest.approx(c["relrmse_subsamples"], rel=1e-9)
    img = images.read(tmp_path / "one.png").pixels
    assert img.shape[:2] == (36, 3 * 48 + 2 * 4)


def test_footprint_stats_unit():
    """Hand-made 2 x 2 footprints: a pixel half covered compares the mean of its covered points;
    errors of opposite sign inside one pixel cancel in the pixel average (a shadow boundary
    drawn one sub-pixel off), a uniform 10 % error does not; the variance of a pixel mean is
    the sum of its points' variances over the count squared; the edge split."""
    s = 2
    h, w = 2, 3
    ref = np.zeros((h * s, w * s, 4), np.float32)
    ref[..., :3] = 1.0
    ref[..., 3] = 1.0
    ref[0, 0, 3] = 0.0  # one point of pixel (0, 0) misses: pixel (0, 0) averages 3 points
    owner = np.zeros((h * s, w * s), np.int64)
    owner[0, 0] = -1
    owner[:, 4:] = 1  # the last pixel column shows another mesh
    var = np.full((h * s, w * s, 3), 0.04)
    r = compare.Reference(ref, var, owner, {})
    baked = ref.copy()
    baked[0:2, 2, :3] = 1.2  # pixel (0, 1): +0.2 on its left column, -0.2 on its right
    baked[0:2, 3, :3] = 0.8
    b, rr, st = compare.footprint_stats(baked, r, s)
    assert st["footprint"] == 2 and st["pixels"] == 6
    assert b[0, 0, 3] == pytest.approx(0.75) and b[0, 1, 3] == 1.0
    assert st["relrmse"] == pytest.approx(0.0, abs=1e-7)  # +-0.2 cancel inside the pixel
    assert st["relrmse_subsamples"] == pytest.approx(np.sqrt(4 * 3 * 0.04 / (23 * 3)))
    v = 0.04 * (3 / 9 + 5 * 4 / 16)  # per channel: pixel (0, 0) 3 points, the others 4
    assert st["reference_noise"] == pytest.approx(np.sqrt(3 * v / (6 * 3)))
    # every pixel touches the background (0, 0) or mesh 1 within its 3 x 3 neighbourhood...
    assert st["edge_pixels"] == 6 and st["interior_pixels"] == 0
    edge = compare.edge_pixels(np.zeros((8, 8), np.int64), 2)
    assert not edge[1:3, 1:3].any() and edge[0].all()  # ...the image border counts as background
    scaled = ref.copy()
    scaled[..., :3] *= 0.9
    _, _, st9 = compare.footprint_stats(scaled, r, s)
    assert st9["relrmse"] == pytest.approx(0.1, rel=1e-6) and st9["bias"] == pytest.approx(-0.1)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--compare-footprint", "2"], "--compare-footprint is an option of --compare; add"),
        (["--compare", "--compare-footprint", "0"], "--compare-footprint 0: sub-pixel points"),
        (["--compare", "--compare-footprint", "9"], "--compare-footprint 9: sub-pixel points"),
        (
            ["--compare", "--compare-samples", "4"],
            "--compare-samples 4: with --compare-footprint 2 each of the 4 sub-pixel points "
            "needs at least 2 samples; give --compare-samples 8 or more",
        ),
    ],
)
def test_footprint_bad_options(baked, tmp_path, capsys, extra, message):
    layer, _ = baked
    capsys.readouterr()
    argv = ["preview", str(layer), "-o", str(tmp_path / "x.png"), *SIZE, *extra]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "x.png").exists()


def test_footprint_subprocess(baked, tmp_path):
    """As a user runs it: the JSON report carries the footprint fields; a bad footprint is one
    error line and exit code 2 (with --json: a JSON error)."""
    import os
    import subprocess
    import sys

    import usdahd

    layer, _ = baked
    env = dict(os.environ, PYTHONPATH=str(Path(usdahd.__file__).resolve().parents[1]))
    out = tmp_path / "s.png"
    base = [sys.executable, "-m", "usdahd", "preview", str(layer), "-o", str(out)]
    argv = [*base, "--size", "24", "18", "--compare", "--compare-samples", "8", "--json"]
    argv += ["--backend", "embree", "--compare-footprint", "2"]
    proc = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr
    c = json.loads(proc.stdout)["compare"]
    assert c["footprint"] == 2 and c["samples_per_point"] == 2 and c["relrmse"] > 0
    assert {"interior_relrmse", "edge_relrmse", "edge_error_share"} <= set(c)
    bad = subprocess.run(
        [*base, "--compare", "--compare-footprint", "0", "--json"],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert bad.returncode == 2
    assert "--compare-footprint 0" in bad.stdout + bad.stderr
