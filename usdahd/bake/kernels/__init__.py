"""Every numba port of the baker, with its declared records and the numba cache policy.

- :mod:`~usdahd.bake.kernels.embree`: libembree4 bound directly (ctypes + numba intrinsics);
  loaded when the baker is imported, never by scene or USD reading.
- :mod:`~usdahd.bake.kernels.trace`: per-ray twins of the ``Tracer`` queries.
- :mod:`~usdahd.bake.kernels.integrate`: the fused integrator kernel, per texel
  (:func:`~usdahd.bake.kernels.integrate.native_pass`, ``native_result``, ``native_work``).
- :mod:`~usdahd.bake.kernels.paths`: the path wavefront behind a texel's hemisphere samples.
- :mod:`~usdahd.bake.kernels.shading`: light choice, MIS weights, shadow rays, light linking.

- :mod:`~usdahd.bake.kernels.cache`: cache locators stamping kernels with all their sources.
- :mod:`~usdahd.bake.kernels.layout`: every record the kernels read, declared once as field
  lists (``PAR_*`` light parameters from each light class's ``FIELDS``, ``PATH_*``, ``CFG_*``,
  the named-tuple arrays :class:`~usdahd.bake.kernels.layout.LightArrays`, ``NativeTables``,
  ``AccumArrays``, ``NativeWork``, ...).
- :mod:`~usdahd.bake.kernels.lights`: :func:`~usdahd.bake.kernels.lights.pack_lights` (a loop:
  each light packs its own fields) and the scalar light sampling / intersection / pdf routines
  (twins of :mod:`usdahd.scene.lights`).
"""
