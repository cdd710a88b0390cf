"""glTF export of instanced scenes (issue 42: "one scene with instances" in CI).

tests/instance_scene.py's stage (four scenegraph copies and a PointInstancer of one box
prototype, half under a roof) baked small: the scenegraph copies share one glTF mesh, the
PointInstancer copies are one EXT_mesh_gpu_instancing node whose per-instance attributes carry
each copy's lightmap rectangle; ``--instancing nodes`` writes one node per copy instead (still
one shared mesh). Both are valid glTF, every copy lands on its own world points and its own
atlas rectangle, and three.js (usdahd-lightmap.js in headless Chromium) renders them like
``usdahd preview`` of the same camera.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.export.test_export_gltf import (  # noqa: E402
    _export,
    accessor,
    browser_render,
    node_matrix,
    preview_and_projection,
    read_glb,
    rel_rmse,
    validate,
)
from tests.instance_scene import HIDDEN, POINTS, SCENEGRAPH, write_stage  # noqa: E402
from usdahd import cli

#: A camera looking at both columns of copies (open at x = 14, roofed at x = -6) from the side.
CAMERA = """    def Camera "Cam"
    {
        float2 clippingRange = (0.1, 200)
        float focalLength = 24
        float horizontalAperture = 36
        float verticalAperture = 27
        double3 xformOp:translate = (4, 3.5, 24)
        float3 xformOp:rotateXYZ = (-7, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
"""
CAM = "/World/Cam"
SIZE = (384, 288)
PI_KEYS = [f"/World/Pawns/instance_{i}/Box" for i in range(len(POINTS)) if i not in HIDDEN]
SG_KEYS = [f"{p}/Box" for p in SCENEGRAPH]


def write_camera_stage(folder: Path) -> Path:
    """tests/instance_scene.py's stage with :data:`CAMERA` at ``folder/inst.usda``."""
    stage = write_stage(Path(folder) / "inst.usda")
    text = stage.read_text()
    at = text.index('    def Xform "Lights"')
    stage.write_text(text[:at] + CAMERA + "\n" + text[at:])
    return stage


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gltf_instances")
    stage = write_camera_stage(folder)
    argv = ["bake", str(stage), "--resolution", "16", "--samples", "16", "--bounces", "1", "-q"]
    assert cli.main(argv) == 0
    return folder / "inst.lightmaps.usda"


def _world_points(layer: Path) -> dict:
    from usdahd.export.gltf import load_prims

    _, prims, _ = load_prims(str(layer))
    return {p.mesh.path: (np.asarray(p.mesh.points), p.results) for p in prims}


def _lands_on(got: np.ndarray, want: np.ndarray) -> bool:
    d = np.linalg.norm(got[:, None, :] - want[None, :, :], axis=-1)
    return d.min(axis=1).max() < 1e-5 and d.min(axis=0).max() < 1e-5


def _quat_matrix(q) -> np.ndarray:
    return node_matrix({"rotation": [float(x) for x in q]})


def test_point_instancer_copies_are_one_gpu_instanced_node_over_one_shared_mesh(baked, tmp_path):
    from usdahd.export.gltf import placement
    from usdahd.export.instancing import PAGE_ATTRIBUTE, SCALE_OFFSET_ATTRIBUTE

    rep = _export(baked, tmp_path / "gpu.glb")
    assert (rep["nodes"], rep["instanced_nodes"], rep["instances"]) == (10, 1, len(PI_KEYS))
    assert rep["meshes"] == 3  # ground, roof, one box for all eight copies
    doc, binary = read_glb(tmp_path / "gpu.glb")
    assert "EXT_mesh_gpu_instancing" in doc["extensionsUsed"]
    world = _world_points(baked)
    nodes = {n["name"]: n for n in doc["nodes"]}
    (inst,) = [n for n in doc["nodes"] if "EXT_mesh_gpu_instancing" in n.get("extensions", {})]
    ext = inst["extensions"]["USDAHD_lightmap_directional"]
    assert ext["prim"] == "/World/Pawns" and ext["instances"] == PI_KEYS
    box = inst["mesh"]
    assert all(nodes[k]["mesh"] == box for k in SG_KEYS)  # scenegraph copies: the same mesh
    attrs = inst["extensions"]["EXT_mesh_gpu_instancing"]["attributes"]
    for name in attrs.values():  # instance attributes: not vertex buffers
        assert "target" not in doc["bufferViews"][doc["accessors"][name]["bufferView"]]
    t, r, s = (accessor(doc, binary, attrs[k]) for k in ("TRANSLATION", "ROTATION", "SCALE"))
    so = accessor(doc, binary, attrs[SCALE_OFFSET_ATTRIBUTE])
    page = accessor(doc, binary, attrs[PAGE_ATTRIBUTE])
    (prim,) = doc["meshes"][box]["primitives"]
    pos = accessor(doc, binary, prim["attributes"]["POSITION"]).astype(np.float64)
    hom = np.c_[pos, np.ones(len(pos))].T
    rects = set()
    for i, key in enumerate(ext["instances"]):
        m = np.eye(4)
        m[:3, :3] = _quat_matrix(r[i])[:3, :3] * s[i]
        m[:3, 3] = t[i]
        got = (node_matrix(inst) @ m @ hom).T[:, :3]
        points, res = world[key]
        assert _lands_on(got, points), key  # node TRS x instance TRS x mesh = the copy
        scale, offset = placement(res)
        assert np.allclose(so[i], scale + offset, atol=0) and page[i] == ext["page"] == res.page
        rects.add(tuple(so[i]))
    assert len(rects) == len(PI_KEYS)  # each copy its own rectangle
    for key in SG_KEYS:
        got = (node_matrix(nodes[key]) @ hom).T[:, :3]
        assert _lands_on(got, world[key][0])


def test_docs_example_instanced_node_has_the_fields_the_exporter_writes(baked, tmp_path):
    """docs/gltf.md's example JSON: its EXT_mesh_gpu_instancing node names the same extension
    fields and instance attributes as a real export."""
    import re

    text = (Path(__file__).resolve().parents[2] / "docs" / "gltf.md").read_text("utf-8")
    (block,) = re.findall(r"```json\n(.*?)```", text, re.S)
    (ex,) = [n for n in json.loads(block)["nodes"] if "EXT_mesh_gpu_instancing" in n.get(
        "extensions", {})]  # fmt: skip
    _export(baked, tmp_path / "gpu.glb")
    doc, _ = read_glb(tmp_path / "gpu.glb")
    (got,) = [n for n in doc["nodes"] if "EXT_mesh_gpu_instancing" in n.get("extensions", {})]
    for name in ("EXT_mesh_gpu_instancing", "USDAHD_lightmap_directional"):
        assert set(ex["extensions"][name]) == set(got["extensions"][name])
    gpu = "EXT_mesh_gpu_instancing"
    assert set(ex["extensions"][gpu]["attributes"]) == set(got["extensions"][gpu]["attributes"])


def test_nodes_fallback_writes_a_node_per_copy_sharing_the_mesh(baked, tmp_path):
    rep = _export(baked, tmp_path / "nodes.glb", "--instancing", "nodes")
    assert (rep["nodes"], rep["instanced_nodes"], rep["meshes"]) == (10, 0, 3)
    doc, binary = read_glb(tmp_path / "nodes.glb")
    assert "EXT_mesh_gpu_instancing" not in doc["extensionsUsed"]
    world = _world_points(baked)
    nodes = {n["name"]: n for n in doc["nodes"]}
    (prim,) = doc["meshes"][nodes[PI_KEYS[0]]["mesh"]]["primitives"]
    pos = accessor(doc, binary, prim["attributes"]["POSITION"]).astype(np.float64)
    for key in PI_KEYS + SG_KEYS:
        assert nodes[key]["mesh"] == nodes[PI_KEYS[0]]["mesh"]
        got = (node_matrix(nodes[key]) @ np.c_[pos, np.ones(len(pos))].T).T[:, :3]
        assert _lands_on(got, world[key][0]), key


def test_unbaked_copies_are_plain_nodes_sharing_the_mesh(tmp_path):
    """Only the ground baked (``--prim``): the eight copies are occluders, exported as plain
    nodes (no lightmap) that share one box mesh, each on its copy's world points."""
    from usdahd.export.gltf import load_prims

    stage = write_camera_stage(tmp_path)
    argv = ["bake", str(stage), "--resolution", "16", "--samples", "16", "--prim", "/World/Ground"]
    assert cli.main([*argv, "-q"]) == 0
    layer = tmp_path / "inst.lightmaps.usda"
    rep = _export(layer, tmp_path / "u.glb")
    assert (rep["nodes"], rep["unbaked_nodes"], rep["meshes"]) == (1, 9, 3)
    assert rep["instanced_nodes"] == 0
    doc, binary = read_glb(tmp_path / "u.glb")
    nodes = {n["name"]: n for n in doc["nodes"]}
    _, prims, _ = load_prims(str(layer), unbaked=True)
    world = {p.mesh.path: np.asarray(p.mesh.points) for p in prims}
    (prim,) = doc["meshes"][nodes[PI_KEYS[0]]["mesh"]]["primitives"]
    pos = accessor(doc, binary, prim["attributes"]["POSITION"]).astype(np.float64)
    for key in PI_KEYS + SG_KEYS:
        node = nodes[key]
        assert node["mesh"] == nodes[PI_KEYS[0]]["mesh"] and "extensions" not in node
        got = (node_matrix(node) @ np.c_[pos, np.ones(len(pos))].T).T[:, :3]
        assert _lands_on(got, world[key]), key


def test_instancing_exports_are_valid(baked, tmp_path):
    """Khronos glTF-Validator: 0 errors, 0 warnings (this validator version reports
    EXT_mesh_gpu_instancing as an unsupported extension, an info; the test above checks the
    extension's rules itself); the extension objects match docs/gltf/*.schema.json."""
    a = _export(baked, tmp_path / "gpu.glb")
    b = _export(baked, tmp_path / "nodes.gltf", "--instancing", "nodes")
    reports = validate([tmp_path / "gpu.glb", tmp_path / "nodes.gltf"])
    for r in reports.values():
        assert (r["errors"], r["warnings"], r["schemaErrors"]) == (0, 0, []), r["messages"]
    assert a["meshes"] == b["meshes"] == 3  # one box mesh for the eight copies


@pytest.fixture(scope="module")
def paged(tmp_path_factory):
    """The stage baked with 32-texel atlas pages: a page per record, so the PointInstancer's
    copies are on four pages (four EXT_mesh_gpu_instancing nodes)."""
    stage = write_camera_stage(tmp_path_factory.mktemp("gltf_instances_paged"))
    argv = ["bake", str(stage), "--resolution", "16", "--samples", "16", "--bounces", "1"]
    assert cli.main([*argv, "--atlas-size", "32", "-q"]) == 0
    return stage.with_name("inst.lightmaps.usda")


@pytest.mark.parametrize("instancing", ["gpu", "nodes", "gpu-pages"])
def test_three_js_renders_instances_like_usdahd_preview(request, tmp_path, instancing):
    """Every copy with its own lightmap in three.js (InstancedMesh with per-instance
    scale/offset attributes, or a node per copy; ``gpu-pages``: the copies spread over four
    pages, one instanced node per page) within 2 % relRMSE of ``usdahd preview`` of the
    stage's camera over the pixels both show of the same copy, and per copy."""
    baked = request.getfixturevalue("paged" if instancing == "gpu-pages" else "baked")
    site = tmp_path / "site"
    site.mkdir()
    mode = instancing.split("-")[0]
    rep = _export(baked, site / "inst.glb", "--instancing", mode)
    if instancing == "gpu-pages":
        assert (rep["pages"], rep["instanced_nodes"], rep["instances"]) == (10, 4, 4)
    img, proj, visible, ids = preview_and_projection(baked, size=SIZE, camera=CAM)
    job = {"gltf": "inst.glb", "size": list(SIZE), "projection": proj, "irradiance": True,
           "ids": ids}  # fmt: skip
    (px, info), *_ = browser_render(site, {"inst": job}).values()
    assert info["patched"] == rep["nodes"] == len(ids)
    err, n = rel_rmse(px, img, info["ids"], visible, info["edges"])
    covered = int(((px[..., 3] > 0) & (img[..., 3] > 0)).sum())
    assert n >= 0.6 * covered and err < 0.02, (err, n, covered)
    seen = {}
    for key in PI_KEYS + SG_KEYS:
        k = ids[key]
        m = (visible == k) & (info["ids"] == k) & ~info["edges"]
        if m.sum() < 20:
            continue
        e, _ = rel_rmse(np.where(m[..., None], px, 0), np.where(m[..., None], img, 0))
        seen[key] = (round(e, 5), int(m.sum()))
        assert e < 0.02, (key, e)
    # both kinds of copy, open and roofed, are compared
    assert sum(k in seen for k in PI_KEYS) >= 3 and sum(k in seen for k in SG_KEYS) >= 3, seen
    print(json.dumps({"relRMSE": round(err, 5), "pixels": n, "copies": seen}))


def test_bad_instancing_option(baked, tmp_path, capsys):
    """An unknown ``--instancing`` is a usage error (exit 2) before anything is read or
    written, in-process, through the API and as a subprocess."""
    import subprocess

    from usdahd.errors import UsageError
    from usdahd.export.gltf import export

    argv = ["export", "gltf", str(baked), "-o", str(tmp_path / "x.glb"), "--instancing", "all"]
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2 and "invalid choice: 'all'" in capsys.readouterr().err
    with pytest.raises(UsageError, match="--instancing all: choose gpu or nodes"):
        export(str(baked), tmp_path / "x.glb", instancing="all")
    r = subprocess.run(
        [sys.executable, "-m", "usdahd", *argv], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 2 and "--instancing" in r.stderr
    assert not list(tmp_path.glob("*.glb"))


if __name__ == "__main__":  # python -m tests.export.test_gltf_instances FOLDER: the docs stage
    print(write_camera_stage(Path(sys.argv[1])))
