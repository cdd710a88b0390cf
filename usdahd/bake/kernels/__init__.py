"""Every numba port of the baker, with named offsets and the numba cache policy.

- :mod:`~usdahd.bake.kernels.embree`: libembree4 bound directly (ctypes + numba intrinsics);
  loaded when the baker is imported, never by scene or USD reading.
- :mod:`~usdahd.bake.kernels.trace`: per-ray twins of the ``Tracer`` queries.
- :mod:`~usdahd.bake.kernels.integrate`: the fused integrator kernel.

- :mod:`~usdahd.bake.kernels.cache`: cache locators stamping kernels with all their sources.
- :mod:`~usdahd.bake.kernels.layout`: named slots of every flat array the kernels read
  (``PAR_*`` light parameters, :class:`~usdahd.bake.kernels.layout.NativeTables`, ``CFG_*``).
- :mod:`~usdahd.bake.kernels.lights`: :func:`~usdahd.bake.kernels.lights.pack_lights` and the
  scalar light sampling / intersection / pdf routines (twins of :mod:`usdahd.scene.lights`).
"""
