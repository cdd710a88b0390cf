"""Numerics: I/O-free array code that imports only numpy, numba and the standard library.

- :mod:`usdahd.numerics.sh` — real SH basis through band 2, constants, quadrature rules.
- :mod:`usdahd.numerics.hemi` — hemisphere algebra: SH multiplies, hemisphere lights,
  self-bounce.
- :mod:`usdahd.numerics.sampling` — the direction samplers and pdfs the integrators call.
- :mod:`usdahd.numerics.encoding` — texture quantizers (hemi-octahedral directions, UNORM8/SNORM8,
  float16 scale).
- :mod:`usdahd.numerics.raster` — the one UV rasteriser, fan triangulation and UV -> pixel
  mapping, shared by the baker and the validator (``docs/texels.md``).

Nothing here touches files, pxr or OpenImageIO (tests/test_layers.py enforces it), so
``import usdahd.numerics`` works wherever numpy does. Submodules are imported on use.
"""
