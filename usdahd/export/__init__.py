"""Exporters of a baked stage for engines without USD import (issue 42).

- :mod:`usdahd.export.gltf` : ``usdahd export gltf`` — glTF 2.0 (``.glb`` or ``.gltf`` + side
  files) with the ``USDAHD_lightmap_directional`` vendor extension (docs/gltf.md);
- :mod:`usdahd.export.hdr` : the RGBM / RGBE PNG encodings of the float16 lightmap textures;
- :mod:`usdahd.export.png` : a minimal deterministic PNG writer.
"""
