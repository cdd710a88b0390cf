"""``usdahd export gltf`` (issue 42): the file, the extension, the three.js importer in a real
browser against ``usdahd preview``, the Khronos validator, and the bad inputs.

The browser tests need Debian's ``chromium`` and node with the npm packages ``three``,
``puppeteer-core`` and ``gltf-validator`` (installed by ``.ci/run`` into
``$USDAHD_WEB_MODULES``, default ``~/.cache/usdahd-web``; :func:`web_modules` runs ``npm
install`` there itself when they are missing). They skip, saying why, only where node/npm or
chromium is not installed.
"""

from __future__ import annotations

import functools
import http.server
import json
import math
import os
import shutil
import struct
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
from conftest import copy_sample

from usdahd import cli

ROOT = Path(__file__).resolve().parents[1]
WEB = Path(__file__).resolve().parent / "web"
SIZE = (96, 72)
NPM_PACKAGES = ("three@0.187.0", "puppeteer-core@24", "gltf-validator@2")
CHROMIUM = os.environ.get("USDAHD_CHROMIUM", "/usr/bin/chromium")


# ---------------------------------------------------------------------------- environment


@functools.cache
def web_modules() -> Path | str:
    """node_modules with three, puppeteer-core and gltf-validator (installed on first use), or
    a string saying why not (the skip reason)."""
    if not shutil.which("node") or not shutil.which("npm"):
        return "node/npm not installed (apt-get install nodejs npm; .ci/run does)"
    base = Path(os.environ.get("USDAHD_WEB_MODULES", Path.home() / ".cache" / "usdahd-web"))
    mods = base / "node_modules"
    need = ("three", "puppeteer-core", "gltf-validator")
    if not all((mods / n / "package.json").exists() for n in need):
        base.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, "PUPPETEER_SKIP_DOWNLOAD": "1"}
        r = subprocess.run(
            ["npm", "install", "--prefix", str(base), "--no-audit", "--no-fund", *NPM_PACKAGES],
            capture_output=True, text=True, env=env, timeout=600,
        )  # fmt: skip
        if r.returncode != 0:
            pytest.fail(f"npm install failed: {r.stderr[-2000:]}")
    return mods


def _modules_or_skip() -> Path:
    m = web_modules()
    if isinstance(m, str):
        pytest.skip(m)
    return m


def _chromium_or_skip():
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} not installed (apt-get install chromium; .ci/run does)")


def validate(files) -> dict:
    """The Khronos glTF-Validator's report per file: {file: {errors, warnings, infos, ...}}."""
    mods = _modules_or_skip()
    r = subprocess.run(
        ["node", str(WEB / "validate.mjs"), *map(str, files)],
        capture_output=True, text=True, env={**os.environ, "USDAHD_WEB_MODULES": str(mods)},
        timeout=120,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass

    def end_headers(self):
        self.send_header("Cache-Control", "no-store")
        super().end_headers()


def browser_render(site: Path, jobs: dict) -> dict:
    """Render ``jobs`` ({name: job dict: gltf (relative to site), size, projection, irradiance})
    in headless Chromium with the importer; returns {name: (H, W, 4) float32, row 0 at the top}.
    ``site`` gets the page, the importer and a link to three."""
    mods = _modules_or_skip()
    _chromium_or_skip()
    shutil.copy(WEB / "page.html", site / "page.html")
    shutil.copy(ROOT / "usdahd" / "web" / "usdahd-lightmap.js", site / "usdahd-lightmap.js")
    if not (site / "three").exists():
        (site / "three").symlink_to(mods / "three")
    for name, job in jobs.items():
        (site / f"{name}.json").write_text(json.dumps(job))
    handler = functools.partial(_Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        base = f"http://127.0.0.1:{server.server_address[1]}"
        r = subprocess.run(
            ["node", str(WEB / "render.mjs"), base, str(site), *(f"{n}.json" for n in jobs)],
            capture_output=True, text=True, timeout=300,
            env={**os.environ, "USDAHD_WEB_MODULES": str(mods), "USDAHD_CHROMIUM": CHROMIUM},
        )  # fmt: skip
    finally:
        server.shutdown()
        server.server_close()
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads(r.stdout)
    out = {}
    for name, job in jobs.items():
        rep = report[f"{name}.json"]
        assert "error" not in rep, f"{rep['error']}\n" + "\n".join(rep["log"])
        w, h = job["size"]
        px = np.fromfile(site / f"{name}.f32", np.float32).reshape(h, w, 4)
        ids = np.fromfile(site / f"{name}.ids.f32", np.float32).reshape(h, w, 4)
        rep["ids"] = np.where(ids[::-1, :, 3] > 0, np.rint(1024 * ids[::-1, :, 0]), -1).astype(int)
        out[name] = (px[::-1].copy(), rep)
    return out


# ---------------------------------------------------------------------------- preview side


def gltf_root_matrix(up_axis: str, mpu: float) -> np.ndarray:
    """(4, 4) column-vector matrix of the exporter's root node: USD world -> glTF world."""
    c = np.eye(4)
    if up_axis == "Z":
        c[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]
    c[:3, :3] *= mpu
    return c


def preview_and_projection(layer: Path, size=SIZE, camera=None):
    """``usdahd preview``'s linear image (H, W, 4) of the layer (wgpu, else Embree), the
    three.js projection matrix (column-major list) of the same view in the glTF's world, the
    visible mesh per pixel (H, W) int (-1: none; drawn by the same renderer with a constant
    ``hemisphere`` texture of value id per mesh) and {prim path: id}."""
    from usdahd.preview import gpu
    from usdahd.preview.camera import view_projection
    from usdahd.preview.meshes import baked_meshes, draw_items, render_view
    from usdahd.usd.stage import meters_per_unit

    stage, meshes, up = baked_meshes(str(layer))
    w, h = size
    vp = view_projection(stage, meshes, up, camera, w / h)
    dev = gpu.device("auto")
    items = draw_items(meshes)
    img = render_view(stage, meshes, items, vp, size, dev[1] if dev else None)
    ids = {m.path: k + 1 for k, (m, *_) in enumerate(meshes)}
    flat = [
        (it[0], "hemisphere", "none", [np.full((1, 1, 3), k + 1, np.float32)], {})
        for k, it in enumerate(items)
    ]
    idimg = render_view(stage, meshes, flat, vp, size, dev[1] if dev else None)
    visible = np.where(idimg[..., 3] > 0, np.rint(idimg[..., 0]), -1).astype(int)
    zfix = np.eye(4)
    zfix[2] = [0, 0, 2, -1]  # WebGPU clip z in [0, 1] -> GL's [-1, 1]
    mpu = meters_per_unit(stage, str(layer))
    proj = zfix @ vp @ np.linalg.inv(gltf_root_matrix(up, mpu))
    return img, [float(x) for x in proj.flatten(order="F")], visible, ids


def rel_rmse(a: np.ndarray, b: np.ndarray, a_ids=None, b_ids=None) -> tuple[float, int]:
    """relRMSE of a against b over the pixels both cover (and, with ids, where both show the
    same mesh: a triangle edge between two meshes can fall on either side of a pixel centre in
    two rasterisers), and how many pixels that is."""
    both = (a[..., 3] > 0) & (b[..., 3] > 0)
    if a_ids is not None:
        both &= a_ids == b_ids
    d = a[..., :3][both] - b[..., :3][both]
    r = b[..., :3][both]
    return float(math.sqrt((d**2).sum() / (r**2).sum())), int(both.sum())


# ---------------------------------------------------------------------------- fixtures


def _bake(folder: Path, name: str, *extra) -> Path:
    stage = copy_sample(folder, name)
    argv = ["bake", str(stage), "--resolution", "16", "--samples", "16", "--bounces", "1"]
    assert cli.main([*argv, *extra, "--quiet"]) == 0
    return stage.with_name(stage.stem + ".lightmaps.usda")


@pytest.fixture(scope="module")
def cornell(tmp_path_factory):
    return _bake(tmp_path_factory.mktemp("gltf_cornell"), "cornell_box.usda")


def _export(layer: Path, out: Path, *extra) -> dict:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli.main(["export", "gltf", str(layer), "-o", str(out), "--json", "-q", *extra]) == 0
    return json.loads(buf.getvalue())


def read_glb(path: Path) -> tuple[dict, bytes]:
    data = Path(path).read_bytes()
    magic, version, total = struct.unpack_from("<III", data, 0)
    assert (magic, version, total) == (0x46546C67, 2, len(data))
    n, kind = struct.unpack_from("<II", data, 12)
    assert kind == 0x4E4F534A
    doc = json.loads(data[20 : 20 + n])
    m, kind2 = struct.unpack_from("<II", data, 20 + n)
    assert kind2 == 0x004E4942
    return doc, data[28 + n : 28 + n + m]
