"""The pxr-free description of a scene to bake, like pbrt's parsed scene.

:mod:`usdahd.usd` reads a stage into these types (:func:`usdahd.usd.reader.load_scene`); the
baker (``usdahd.bake``) and the validator read them and never a ``Usd.Stage``. Everything here
imports numpy (and ``usdahd.numerics``) only.

- :mod:`usdahd.scene.types`: meshes (:class:`~usdahd.scene.types.MeshData`), materials and
  textures, computed normals, and the :class:`~usdahd.scene.types.Scene` that holds them.
- :mod:`usdahd.scene.lights`: the light sources in UsdLux units with their numpy sampling
  (the numba twins are in ``usdahd.bake.kernels.lights``).
"""
