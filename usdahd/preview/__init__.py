"""Rendering behind ``usdahd preview`` (issue 14); the command is ``usdahd.commands.preview``.

- :mod:`~usdahd.preview.meshes`: the baked meshes of a layer, as vertex arrays;
- :mod:`~usdahd.preview.camera`: a UsdGeomCamera or the automatic framing;
- :mod:`~usdahd.preview.gpu`: wgpu rasterisation with the shipped WGSL decoders;
- :mod:`~usdahd.preview.raytrace`: the Embree fallback without a Vulkan adapter;
- :mod:`~usdahd.preview.cutout`: alpha cut-outs and opacity for the rasteriser;
- :mod:`~usdahd.preview.tonemap`: tone mapping and image statistics;
- :mod:`~usdahd.preview.compare`: ``--compare``, the path-traced reference and its statistics;
- :mod:`~usdahd.preview.atlas`: ``--atlas``, the contact sheet of the textures.
"""
