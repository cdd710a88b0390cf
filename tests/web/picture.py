"""The docs/gltf.md picture: ``usdahd preview`` | three.js with usdahd-lightmap.js in headless
Chromium | three.js shading the materials (albedo x lightmap, MeshStandardMaterial) | the
preview's error heat map of panel 2 against panel 1 (20 % = red).

    python tests/web/picture.py STAGE.lightmaps.usda OUT.png [W H [CAMERA]]

Prints the relRMSE of panel 2 against panel 1 over the pixels both show the same mesh.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


from tests.export import test_export_gltf as T  # noqa: E402


def main(argv):
    from usdahd import images
    from usdahd.export.gltf import export
    from usdahd.preview import compare
    from usdahd.preview.tonemap import tonemap, tonemap_with

    layer, out = Path(argv[0]), Path(argv[1])
    size = tuple(int(x) for x in argv[2:4]) if len(argv) >= 4 else (320, 240)
    with tempfile.TemporaryDirectory() as tmp:
        site = Path(tmp)
        export(str(layer), site / "scene.glb")
        camera = argv[4] if len(argv) >= 5 else None  # a UsdGeomCamera, as preview --camera
        img, proj, visible, ids = T.preview_and_projection(layer, size, camera=camera)
        job = {"gltf": "scene.glb", "size": list(size), "projection": proj, "ids": ids}
        r = T.browser_render(site, {"irr": {**job, "irradiance": True}, "lit": job})
    three, rep = r["irr"]
    lit, _ = r["lit"]
    err, n = T.rel_rmse(three, img, rep["ids"], visible, rep["edges"])
    ldr, scale = tonemap(img)
    lit_ldr, _ = tonemap(lit)
    panels = compare.side_by_side(
        ldr, tonemap_with(three, scale), lit_ldr, compare.heat_map(three, img)
    )
    images.write(out, panels, color_space="srgb_rec709_scene")
    print(f"{out}: {size[0]}x{size[1]} panels; three.js vs preview relRMSE {err:.3%} over {n} px")


if __name__ == "__main__":
    main(sys.argv[1:])
