"""Every numba port of the baker, with named offsets and the numba cache policy.

- :mod:`~usdahd.bake.kernels.cache`: cache locators stamping kernels with all their sources.
- :mod:`~usdahd.bake.kernels.layout`: named slots of every flat array the kernels read
  (``PAR_*`` light parameters, :class:`~usdahd.bake.kernels.layout.NativeTables`, ``CFG_*``).
- :mod:`~usdahd.bake.kernels.lights`: :func:`~usdahd.bake.kernels.lights.pack_lights` and the
  scalar light sampling / intersection / pdf routines (twins of :mod:`usdahd.scene.lights`).
"""
