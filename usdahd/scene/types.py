"""Scene description types: what :mod:`usdahd.usd` reads from a stage, without pxr.

- :class:`MeshData` : one triangulated world-space mesh (points, triangles, normals, lightmap
  UVs, per-triangle material indices).
- :class:`Texture` : a texture read into memory, with its UsdUVTexture scale/bias, channel
  selection and wrap modes, and its bilinear lookup.
- :class:`Material` : a Lambertian UsdPreviewSurface (constants and optional textures).
- :class:`ComputedNormals` : normals computed for a mesh that authors none
  (:mod:`usdahd.usd.normals`), to author into the output layer.
- :class:`Scene` : all of the above plus the lights (:mod:`usdahd.scene.lights` objects in
  UsdLux units, docs/lights.md), the warnings and failed prims of the read, the stage's
  metersPerUnit, upAxis and the bake time.

numpy only: the baker and the validator use these without a ``Usd.Stage``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "ComputedNormals",
    "InstanceRef",
    "MAX_RADIANCE",
    "Material",
    "MeshData",
    "Scene",
    "Texture",
]

#: Largest emitted radiance (or point-light intensity) accepted from a light or an emissive
#: material. The integrator accumulates radiance x sample weights and squares it for variance
#: estimates in float32 (max 3.4e38): 1e15^2 x 1e6 samples still fits. The sun's radiance is
#: ~1.6e9 W/(m^2 sr), so no physical light comes near.
MAX_RADIANCE = 1e15


@dataclass
class MeshData:
    """One UsdGeom.Mesh (or flattened instance) after triangulation, in world space.

    path : prim path string (instance proxies get their proxy path).
    points : (v, 3) float64 world positions.
    triangles : (t, 3) int32 vertex indices, counter-clockwise seen from the front side
        (``orientation = leftHanded`` and mirrored transforms already fixed).
    normals : (t, 3, 3) float32 per-corner unit world normals (authored or smooth-computed).
    uv : (t, 3, 2) float32 per-corner lightmap UVs, or None when the mesh has no such set.
    uv_name : name of the lightmap UV primvar read (or to author), e.g. "st".
    material : (t,) int32 index into the scene's material table.
    face : (t,) int32 index of the source polygon of each triangle.
    corner : (t, 3) int32 index of each triangle corner into the source mesh's
        faceVertexIndices (so per-corner data such as an unwrapped UV set can be authored back
        as a faceVarying primvar).
    bake : whether this mesh receives a lightmap (False: occluder only).
    double_sided : UsdGeomGprim ``doubleSided``: both sides are surfaces, so a ray reaching
        its back is not inside geometry (cards, leaves, single-wall props).
    cage : for a ``catmullClark`` / ``loop`` mesh, its control polygons
        (:class:`usdahd.scene.subdiv.Cage`); the mesh is traced on their refinement
        (:func:`usdahd.scene.subdiv.refine_scene`). None: traced as it is.
    instance : for an instance copy (scenegraph instance proxy or PointInstancer instance),
        where its bake record lives (:class:`InstanceRef`); None for an ordinary mesh.
    """

    path: str
    points: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    uv: np.ndarray | None
    uv_name: str
    material: np.ndarray
    face: np.ndarray
    corner: np.ndarray
    bake: bool = True
    warnings: list[str] = field(default_factory=list)
    double_sided: bool = False
    cage: object | None = None
    instance: InstanceRef | None = None


@dataclass(frozen=True)
class InstanceRef:
    """Where the bake record of one instance copy of a prototype mesh lives (docs/schema.md,
    "Instances"): outside the prototype, on the instance prim or the PointInstancer.

    carrier : path of the prim holding the record (the instanceable prim of a scenegraph
        instance, or the PointInstancer).
    index : the instance's index into the PointInstancer's ``positions`` (0 for scenegraph).
    prototype : the ``protoIndices`` value of a PointInstancer instance (0 for scenegraph).
    mesh : path of the mesh relative to the prototype root ("." when the root is the mesh).
    source : prim the copy's bake inputs and primvars are read from (the instance proxy, or
        the PointInstancer's prototype mesh).
    origin : the prototype mesh as a user finds it in the asset (``@layer@</Proto/mesh>``),
        named by messages about the prototype (e.g. no lightmap UV set).
    normals : where the normals the copy is traced with come from (``baked:normals``):
        "authored", or the rule that computed them for a prototype without normals (not
        authored: the prototype cannot be edited without de-instancing; a renderer computing
        its own normals by that rule shades the same).
    """

    carrier: str
    index: int
    prototype: int
    mesh: str
    source: str
    origin: str
    normals: str = "authored"


@dataclass
class Texture:
    """A texture read into memory. data : (h, w, c) float32, linear; row 0 = top (v = 1)."""

    path: str
    data: np.ndarray
    scale: np.ndarray  # (4,) UsdUVTexture inputs:scale
    bias: np.ndarray  # (4,) inputs:bias
    channels: tuple[int, ...]  # output channels selected (rgb -> (0,1,2), a -> (3,), ...)
    wrap: tuple[str, str] = ("repeat", "repeat")

    def outputs(self) -> np.ndarray:
        """The UsdUVTexture output of every texel (h, w, len(channels)) float32: missing
        channels padded as :meth:`sample` pads them, then ``scale * texel + bias``. Bilinear
        filtering commutes with this affine map, so sampling the result equals :meth:`sample`."""
        d = np.asarray(self.data, np.float32)
        h, w, c = d.shape
        if c < 4:
            pad = np.ones((h, w, 4 - c), np.float32)
            if c == 1:
                pad[..., :2] = d[..., :1]
            d = np.concatenate([d, pad], axis=2)
        v = d[..., :4] * self.scale[None, None, :] + self.bias[None, None, :]
        return np.ascontiguousarray(v[..., list(self.channels)], np.float32)

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear lookup. uv : (m, 2) -> (m, len(channels)) float32 (scale*tex+bias)."""
        h, w, c = self.data.shape
        x = uv[:, 0] * w - 0.5
        y = (1.0 - uv[:, 1]) * h - 0.5
        x0 = np.floor(x)
        y0 = np.floor(y)
        fx = (x - x0)[:, None]
        fy = (y - y0)[:, None]

        def wrapi(i, n, mode):
            i = i.astype(np.int64)
            if mode in ("clamp", "black"):
                return np.clip(i, 0, n - 1)
            if mode == "mirror":
                i = np.mod(i, 2 * n)
                return np.where(i >= n, 2 * n - 1 - i, i)
            return np.mod(i, n)

        xs = [wrapi(x0, w, self.wrap[0]), wrapi(x0 + 1, w, self.wrap[0])]
        ys = [wrapi(y0, h, self.wrap[1]), wrapi(y0 + 1, h, self.wrap[1])]
        d = self.data
        v = (
            d[ys[0], xs[0]] * (1 - fx) * (1 - fy)
            + d[ys[0], xs[1]] * fx * (1 - fy)
            + d[ys[1], xs[0]] * (1 - fx) * fy
            + d[ys[1], xs[1]] * fx * fy
        )
        if c < 4:  # missing channels: alpha = 1, grey replicated
            pad = np.ones((v.shape[0], 4 - c), v.dtype)
            if c == 1:
                pad[:, :2] = v[:, :1]
            v = np.concatenate([v, pad], axis=1)
        v = v * self.scale[None, :] + self.bias[None, :]
        return v[:, list(self.channels)].astype(np.float32)


@dataclass
class Material:
    """Lambertian surface. Constants are used where the texture is None.

    albedo, emission : (3,) float32 linear; opacity : float; opacity_threshold : float
    (> 0: cut-out, opacity < threshold lets light through; 0 with opacity < 1: stochastic
    transmission); texcoord : primvar name the textures read.
    """

    name: str
    albedo: np.ndarray
    emission: np.ndarray
    opacity: float = 1.0
    opacity_threshold: float = 0.0
    albedo_tex: Texture | None = None
    emission_tex: Texture | None = None
    opacity_tex: Texture | None = None
    texcoord: str = "st"

    @property
    def emissive(self) -> bool:
        return bool(np.any(self.emission > 0) or self.emission_tex is not None)

    @property
    def transmissive(self) -> bool:
        return self.opacity_tex is not None or self.opacity < 1.0

    def key(self) -> str:
        parts = [
            self.name,
            repr(np.round(self.albedo, 7).tolist()),
            repr(np.round(self.emission, 7).tolist()),
            repr((self.opacity, self.opacity_threshold, self.texcoord)),
        ]
        for t in (self.albedo_tex, self.emission_tex, self.opacity_tex):
            if t is None:
                parts.append("")
                continue
            sb = repr((np.round(t.scale, 7).tolist(), np.round(t.bias, 7).tolist()))
            # the texels, not the resolved path: moving or packaging the project (usdz)
            # does not make a bake stale
            parts.append(f"{_digest(t.data.tobytes())}:{sb}:{t.channels}:{t.wrap}")
        return "|".join(parts)


@dataclass
class ComputedNormals:
    """Normals the scene reader computed for a mesh that authors none (usdahd.usd.normals).

    rule : usdahd.usd.normals.RULE_CREASE or RULE_SMOOTH; values : (c, 3) float32 unit
    object-space normals, one per faceVertexIndices entry (faceVarying); attr : the attribute
    to author them in (``normals``, or ``primvars:normals`` when the mesh has that primvar).
    """

    rule: str
    values: np.ndarray
    attr: str = "normals"


@dataclass
class Scene:
    """Everything a bake reads from a stage (:func:`usdahd.usd.reader.load_scene`).

    meshes : triangulated world-space meshes; ``bake`` is True for visible default/render
        purpose UsdGeom.Mesh prims (narrowed by ``prims``); instances and implicit gprims are
        occluders.
    materials : the material table ``MeshData.material`` indexes.
    lights : :mod:`usdahd.scene.lights` objects in UsdLux units (docs/lights.md).
    warnings : one string per unsupported feature met; never silent.
    meters_per_unit, up_axis : stage metadata (up_axis "Y" or "Z").
    texcoords : per mesh, ``{varname: (t, 3, 2) float32}`` texture coordinates the materials
        of that mesh read (the lightmap set is ``MeshData.uv``).
    source : the stage's file (root layer identifier).
    failed : prim path -> one-line message for meshes that cannot be used; they are not in
        ``meshes`` (they neither bake nor occlude).
    """

    meshes: list[MeshData]
    materials: list[Material]
    lights: list
    warnings: list[str]
    meters_per_unit: float
    up_axis: str
    texcoords: list[dict[str, np.ndarray]] = field(default_factory=list)
    source: str = ""
    failed: dict[str, str] = field(default_factory=dict)
    #: prim path -> ComputedNormals, for meshes without usable authored normals.
    computed_normals: dict[str, ComputedNormals] = field(default_factory=dict)
    #: the time every attribute was read at (None: Usd.TimeCode.Default()), and whether it was
    #: chosen automatically (resolve_time) rather than given.
    time: float | None = None
    time_auto: bool = True

    @property
    def time_setting(self):
        """The bake time as recorded in ``baked:settings``: a number or ``"default"``."""
        return "default" if self.time is None else self.time

    @property
    def baked_meshes(self) -> list[MeshData]:
        return [m for m in self.meshes if m.bake]

    @property
    def triangle_count(self) -> int:
        return int(sum(len(m.triangles) for m in self.meshes))

    def hash_parts(self) -> dict[str, str]:
        """Content hashes for staleness checks.

        Keys: each baked mesh's prim path (geometry + normals + lightmap UVs + materials
        indices), ``"occluders"`` (all non-baked geometry), ``"lights"``, ``"materials"``.
        """
        out = {}
        occ = hashlib.sha256()
        for m in self.meshes:
            h = hashlib.sha256()
            for a in (m.points, m.triangles, m.normals, m.material, m.uv):
                h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
            if m.bake:
                out[m.path] = h.hexdigest()
            else:
                occ.update(m.path.encode() + h.digest())
        out["occluders"] = occ.hexdigest()
        lh = hashlib.sha256()
        for light in self.lights:
            lh.update(type(light).__name__.encode())
            for k, v in sorted(vars(light).items()):
                if k.startswith("_"):
                    continue
                lh.update(k.encode())
                a = None if v is None or isinstance(v, str) else np.asarray(v)
                if a is None or a.dtype == object:
                    lh.update(repr(v).encode())
                else:
                    lh.update(np.ascontiguousarray(a).tobytes())
        out["lights"] = lh.hexdigest()
        out["materials"] = _digest("\n".join(m.key() for m in self.materials).encode())
        return out


def _digest(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()
