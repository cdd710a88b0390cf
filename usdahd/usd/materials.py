"""Materials: UsdShade binding, UsdPreviewSurface, MaterialX, UsdUVTexture, UsdTransform2d,
displayColor, colour spaces.

MaterialX surfaces (the ``mtlx`` render context, preferred when authored) and ``.mtlx``
files that USD cannot compose are read through :mod:`usdahd.usd.materialx`; a material
that reads primvars of the bound prim (displayColor through a UsdPrimvarReader_float3) is
one table entry per distinct value (:meth:`MaterialReader._indexed`); a texture that cannot
be read is replaced by a named value (:meth:`MaterialReader.report_unreadable`).

:class:`MaterialReader` builds the material table of a stage (:class:`usdahd.scene.types.Material`,
one per bound material, or one per displayColor for unbound prims): the ``full`` binding
purpose, else all-purpose (prims and GeomSubsets: :meth:`MaterialReader.face_materials` gives
the per-face material indices); UsdPreviewSurface ``diffuseColor`` (times ``1 - metallic``,
a constant or a texture: :func:`albedo_times_metal`), ``emissiveColor``, ``opacity`` /
``opacityThreshold``, each a constant or a UsdUVTexture (:class:`usdahd.scene.types.Texture`:
scale, bias, channel, wrap; bilinear lookup in ``Texture.sample``) reading a primvar,
optionally through a UsdTransform2d (then a derived texcoord name whose values
:mod:`usdahd.usd.geometry` computes per corner).

Texture files are read through USD's asset resolver (:mod:`usdahd.usd.assets`: usdz
packages) and OpenImageIO (:mod:`usdahd.images`, the only OpenImageIO user) by
:func:`read_image`, which applies the colour space rule (:func:`source_color_space`:
``sourceColorSpace``, the file's ``colorSpace`` metadata, else Hydra's 8-bit rule) to the
working space :data:`LINEAR_SPACE`. docs/usd-semantics.md (Materials, Colour spaces) lists what
is honoured and what is warned.
"""

from __future__ import annotations

import math

import numpy as np
from pxr import UsdGeom, UsdShade

from usdahd.errors import StageError
from usdahd.scene.types import MAX_RADIANCE, Material, Texture
from usdahd.usd import materialx
from usdahd.usd.stage import fmt_values
from usdahd.usd.textures import (  # re-exported: the texture half of this module
    LINEAR_SPACE,
    MAX_MATERIAL_TEXTURE,
    albedo_times_metal,
    box_downsample,
    read_image,
    sanitize_image,
    source_color_space,
    texture_channels,
    to_rgb,
)

__all__ = [
    "DEFAULT_ALBEDO",
    "LINEAR_SPACE",
    "MaterialReader",
    "SubsetError",
    "albedo_times_metal",
    "read_image",
    "sanitize_image",
    "source_color_space",
    "tex_path",
    "texture_channels",
    "to_rgb",
]

#: UsdPreviewSurface diffuseColor fallback.
DEFAULT_ALBEDO = (0.18, 0.18, 0.18)


class SubsetError(Exception):
    """A GeomSubset of a mesh is invalid (internal; becomes a mesh failure)."""


class MaterialReader:
    """The material table of one stage read at ``ctx.time`` (see the module docstring).

    ctx : usdahd.usd.reader.ReadContext. ``materials`` : [Material], indexed by
    ``MeshData.material``; ``tc_transforms`` : derived texcoord name -> (primvar, A (2, 2),
    b (2,)) float64, the UsdTransform2d ``out = A @ in + b`` of that name.
    """

    def __init__(self, ctx):
        self.ctx = ctx
        self.warn = ctx.warn
        self.get = ctx.get
        self.materials: list[Material] = []
        self._mat_index: dict[str, int] = {}
        self._textures: dict = {}
        self.tc_transforms: dict = {}  # derived texcoord name -> (primvar, A (2,2), b (2,))
        self.unhonoured: dict[str, list[str]] = {}  # UsdPreviewSurface input -> materials
        self._deps: dict[str, list[str]] = {}  # material -> primvars it reads from the prim
        self._used: list[str] | None = None  # primvars read while reading one material
        self._prim = None  # the gprim a material is being read for
        self._mtlx: dict = {}  # binding target -> materialx.MtlxSource or None

    def face_materials(self, prim, n_faces, path):
        """(n_faces,) int32 material index of each face of a gprim: its bound material, and
        the GeomSubsets' bindings over it. Raises SubsetError for out-of-range indices."""
        api = UsdShade.MaterialBindingAPI(prim)
        # A baker renders final quality: the "full" binding, else the all-purpose one.
        base = self.material_index(*api.ComputeBoundMaterial(UsdShade.Tokens.full), prim=prim)
        fm = np.full(n_faces, base, np.int32)
        for subset in api.GetMaterialBindSubsets():
            ind = self.get(subset.GetIndicesAttr())
            if ind is None or len(ind) == 0:
                continue
            ind = np.asarray(ind, np.int64)
            if ind.min() < 0 or ind.max() >= n_faces:
                raise SubsetError(
                    f"{path}: GeomSubset {subset.GetPath()} indices out of range [0, {n_faces}); "
                    "fix the subset"
                )
            sub = UsdShade.MaterialBindingAPI(subset.GetPrim())
            fm[ind] = self.material_index(
                *sub.ComputeBoundMaterial(UsdShade.Tokens.full), prim=prim
            )
        return fm

    def material_index(self, mat, rel=None, prim=None):
        """Index of a UsdShade.Material in ``materials`` for the gprim ``prim`` (read the
        first time it is bound; again per distinct value of the primvars it reads, e.g.
        displayColor through a UsdPrimvarReader_float3). No material: a binding to a
        material of a ``.mtlx`` file USD could not compose (``rel``, the binding) is read
        from the file (:mod:`usdahd.usd.materialx`); else one material per distinct
        displayColor (mean), else DEFAULT_ALBEDO."""
        if prim is None:  # material_index(mat, prim): the former signature
            rel, prim = None, rel
        if not mat:
            src = self._mtlx_binding(rel)
            if src is not None:
                key = f"<{src[1].file}>{src[1].material}"  # instances share it
                return self._indexed(key, prim, lambda: self._read_mtlx_file(*src, prim))
            color = DEFAULT_ALBEDO
            v = self.primvar_value(prim, "displayColor", None, str(prim.GetPath()))
            if v is not None:
                color = tuple(float(x) for x in v)
            key = f"<displayColor {np.round(color, 6).tolist()}>"
            if key not in self._mat_index:
                self._mat_index[key] = len(self.materials)
                self.materials.append(
                    Material(key, np.array(color, np.float32), np.zeros(3, np.float32))
                )
            return self._mat_index[key]
        key = str(mat.GetPath())
        return self._indexed(key, prim, lambda: self._read_material(mat))

    def _indexed(self, base: str, prim, read) -> int:
        """The index of material ``base`` as read for ``prim``: one entry per distinct
        value of the primvars the material reads from the prim (none: one entry)."""
        deps = self._deps.get(base)
        if deps is not None:
            key = base + (repr([self._dep_value(prim, d) for d in deps]) if deps else "")
            if key in self._mat_index:
                return self._mat_index[key]
        self._used, self._prim = [], prim
        try:
            m = read()
        finally:
            used, self._used, self._prim = self._used, [], None
        deps = sorted(set(used))
        self._deps[base] = deps
        key = base + (repr([self._dep_value(prim, d) for d in deps]) if deps else "")
        if key not in self._mat_index:
            self._mat_index[key] = len(self.materials)
            self.materials.append(m)
        return self._mat_index[key]

    def _dep_value(self, prim, name):
        v = self._primvar_mean(prim, name)
        return None if v is None else np.round(v, 7).tolist()

    def _primvar_mean(self, prim, name):
        """(mean value (n,) float64, number of distinct values) of a primvar, or None."""
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name) if prim is not None else None
        if not pv or not pv.HasValue():
            return None
        v = pv.ComputeFlattened(self.ctx.time)
        if v is None or len(v) == 0:
            return None
        a = np.asarray(v, np.float64)
        a = a.reshape(len(v), -1)
        return a.mean(axis=0)

    def primvar_value(self, prim, name: str, fallback, mat_name: str):
        """The value of primvar ``name`` of ``prim`` as a material reads it (a primvar
        reader, displayColor of an unbound mesh): its mean when it varies over the mesh
        (warned: a Lambertian material is one colour per material in the bake), else
        ``fallback``. Records the dependency (see :meth:`_indexed`)."""
        if self._used is not None:
            self._used.append(name)
        v = self._primvar_mean(prim, name)
        if v is None:
            return fallback
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        flat = np.asarray(pv.ComputeFlattened(self.ctx.time), np.float64).reshape(-1, v.size)
        if len(flat) > 1 and np.ptp(flat, axis=0).max() > 1e-6:
            self.warn(
                f"{prim.GetPath()}: primvars:{name} varies over the mesh ({len(flat)} values, "
                f"{pv.GetInterpolation()}); {mat_name} uses its mean {fmt_values(v)} for the "
                "whole prim. Fix: bake the colours into a texture, or split the mesh by colour",
                key=f"pv-varies:{prim.GetPath()}:{name}",
            )
        return v

    def _mtlx_binding(self, rel):
        """(target path, MtlxSource) when the binding ``rel`` targets a prim that a ``.mtlx``
        reference should have provided, else None."""
        if not rel:
            return None
        stage = self.ctx.stage
        for t in rel.GetTargets():
            tp = stage.GetPrimAtPath(t)
            if tp and tp.IsA(UsdShade.Material):
                continue
            src = self._mtlx_binding_of(t)
            if src is not None:
                return str(t), src
        return None

    def _mtlx_binding_of(self, path):
        key = str(path)
        if key not in self._mtlx:
            self._mtlx[key] = materialx.find_mtlx(self.ctx.stage, path)
        return self._mtlx[key]

    def _read_mtlx_file(self, target: str, src, prim) -> Material:
        """The material ``target`` read from its ``.mtlx`` document (see materialx)."""
        out = Material(target, np.array(DEFAULT_ALBEDO, np.float32), np.zeros(3, np.float32))
        node, err = (None, src.reason) if src.reason else materialx.mtlx_surface(src)
        if node is None:
            self.warn(
                f"{prim.GetPath()}: material:binding targets {target}, which comes from "
                f"{src.file}: MaterialX file could not be composed (USD: usd-core has no "
                f"usdMtlx plugin; usdahd: {err}); the default material (grey 0.18, no "
                "emission) is used. Fix: the MaterialX file or the reference to it "
                f"in {src.layer}",
                key=f"mtlx-bad:{target}",
            )
            return out
        self.warn(
            f"{src.file}: MaterialX file could not be composed by USD (the usd-core wheel has "
            "no usdMtlx file-format plugin); usdahd reads the materials bound from it "
            f"(e.g. {target}) with the MaterialX library",
            key=f"mtlx-read:{src.file}",
        )
        return self._read_surface_node(node, target)

    def _read_surface_node(self, node, name: str) -> Material:
        """A Material from a MaterialX surface node (UsdNode or MtlxNode)."""
        g = materialx.Graph(self, self._prim, name)
        terms = materialx.surface_terms(g, node)
        out = Material(name, np.array(DEFAULT_ALBEDO, np.float32), np.zeros(3, np.float32))
        tcs = []
        for field, sig in (("albedo", terms["albedo"]), ("emission", terms["emission"])):
            if sig.tex is not None:
                setattr(out, f"{field}_tex", sig.tex)
                tcs.append(sig.tc)
            else:
                setattr(out, field, np.asarray(sig.const, np.float32)[:3].copy())
        op = terms["opacity"]
        if op.tex is not None:
            out.opacity_tex = op.tex
            tcs.append(op.tc)
        else:
            out.opacity = float(np.ravel(op.const)[0])
        out.opacity_threshold = terms["opacity_threshold"]
        kind = materialx.SURFACES[node.id]
        for what, v in terms["ignored"]:
            self.unhonoured.setdefault(f"{kind} {what} = {v}", []).append(name)
        self._check_material(out)
        if tcs:
            out.texcoord = tcs[0]
            if len(set(tcs)) > 1:
                self.warn(
                    f"{name}: textures read different texcoords {sorted(set(tcs))}; using "
                    f"'{tcs[0]}' for all. Fix: read all through one texcoord"
                )
        return out

    def _read_material(self, mat):
        name = str(mat.GetPath())
        out = Material(name, np.array(DEFAULT_ALBEDO, np.float32), np.zeros(3, np.float32))
        # A renderer with MaterialX (Storm, Karma, RenderMan, Omniverse) renders the "mtlx"
        # render context when the material has one, else the universal one.
        shader = mat.ComputeSurfaceSource("mtlx")[0]
        sid = str(shader.GetShaderId() or "") if shader else None
        if sid and sid not in materialx.SURFACES and sid != "UsdPreviewSurface":
            universal = mat.ComputeSurfaceSource()[0]
            if universal and universal.GetShaderId() == "UsdPreviewSurface":
                shader, sid = universal, "UsdPreviewSurface"
        if not shader:
            src = self._mtlx_binding_of(mat.GetPath())
            if src is not None:  # a Material prim whose .mtlx reference did not compose
                return self._read_mtlx_file(name, src, self._prim)
            self.warn(
                f"{name}: no surface shader (outputs:surface or outputs:mtlx:surface); the "
                f"bake uses albedo {fmt_values(DEFAULT_ALBEDO)}. Fix: connect a surface"
            )
            return out
        if sid in materialx.SURFACES and sid != "ND_UsdPreviewSurface_surfaceshader":
            return self._read_surface_node(materialx.UsdNode(shader, self.get), name)
        if sid not in ("UsdPreviewSurface", "ND_UsdPreviewSurface_surfaceshader"):
            self.warn(
                f"{name}: surface shader {shader.GetPath()} is {sid}, which the bake does not "
                f"read (it reads UsdPreviewSurface, {', '.join(materialx.SURFACES)}); albedo "
                f"{fmt_values(DEFAULT_ALBEDO)}. Fix: add a UsdPreviewSurface in the universal "
                "render context",
                key=f"shader:{name}",
            )
            return out
        tc_names = []
        out.albedo, out.albedo_tex = self.surface_input(
            shader, "diffuseColor", DEFAULT_ALBEDO, name, tc_names
        )
        metal = self._metallic_texture(shader, out, tc_names)
        out.emission, out.emission_tex = self.surface_input(
            shader, "emissiveColor", (0, 0, 0), name, tc_names
        )
        op, out.opacity_tex = self.surface_input(shader, "opacity", 1.0, name, tc_names)
        out.opacity = float(np.ravel(op)[0])
        out.opacity_threshold = float(self._uniform(shader, "opacityThreshold", 0.0))
        self._check_material(out)
        self._metallic(shader, out, *metal)
        self._unhonoured_inputs(shader, name)
        if tc_names:
            out.texcoord = tc_names[0]
            if len(set(tc_names)) > 1:
                self.warn(
                    f"{name}: textures read different primvars or UsdTransform2d "
                    f"{sorted(set(tc_names))}; using '{tc_names[0]}' for all"
                )
        return out

    def _metallic_texture(self, shader, out: Material, tc_names) -> tuple:
        """(texture or None, fallback metallic or None): the UsdUVTexture ``inputs:metallic``
        is connected to, if the bake can apply it: metallic workflow, a readable texture, and
        the same texcoord (primvar and UsdTransform2d) as the diffuseColor texture when there
        is one (appended to ``tc_names`` when diffuseColor is a constant). A connection the
        bake cannot apply is warned (naming the material and the fix); an unreadable texture
        gives its ``fallback`` (a constant metallic, applied by :meth:`_metallic`); not
        connected: (None, None)."""
        if int(self._uniform(shader, "useSpecularWorkflow", 0)) == 1:
            return None, None
        inp = shader.GetInput("metallic")
        if not inp or not inp.HasConnectedSource():
            return None, None
        name = out.name
        tcs: list[str] = []
        m, tex = self.surface_input(shader, "metallic", 0.0, name, tcs)
        fallback = float(np.ravel(m)[0])
        if tex is None:
            return None, fallback
        src = inp.GetConnectedSources()[0][0]
        where = f"{src.source.GetPath()}.outputs:{src.sourceName}"
        if len(tex.channels) != 1:
            self.warn(
                f"{name}: inputs:metallic (a float) is connected to {where}, "
                f"{len(tex.channels)} channels; the bake reads its first channel (r). Fix: "
                "connect outputs:r, g, b or a"
            )
            tex.channels = (tex.channels[0],)
        q = tex.channels[0]
        c = tex.data.shape[2]
        if q >= c and not (c == 1 and q < 3):
            self.warn(
                f"{name}: inputs:metallic reads channel '{'rgba'[q]}' of {tex.path}, which has "
                f"{c} channels: the missing channel reads 1 before scale and bias (fully "
                "metallic: no diffuse albedo). Fix: connect an output the file has"
            )
        tc = tcs[0]
        if out.albedo_tex is not None:
            dtc = tc_names[-1]
            if tc != dtc:
                self.warn(
                    f"{name}: the metallic texture {tex.path} reads texcoord '{tc}' but the "
                    f"diffuseColor texture reads '{dtc}': the bake cannot combine them and "
                    "does not reduce the diffuse albedo by metallic. Fix: read both textures "
                    "through the same primvar and UsdTransform2d, or author a constant metallic",
                    key=f"metallic-texcoord:{name}",
                )
                return None, 0.0
        else:
            tc_names.append(tc)
        return tex, None

    def _metallic(
        self, shader, out: Material, metal_tex: Texture | None = None, fallback=None
    ) -> None:
        """UsdPreviewSurface metallic workflow: a metal has no diffuse lobe, so the diffuse
        albedo is diffuseColor x (1 - metallic). The specular workflow
        (useSpecularWorkflow = 1) ignores metallic.

        A constant metallic scales the diffuseColor constant, or the diffuseColor texture's
        scale and bias (exact: bilinear filtering commutes with the affine map). A metallic
        texture (``metal_tex``, :meth:`_metallic_texture`) becomes part of the albedo
        texture (:func:`albedo_times_metal`); an unreadable one gives its ``fallback``."""
        if int(self._uniform(shader, "useSpecularWorkflow", 0)) == 1:
            return
        inp = shader.GetInput("metallic")
        if not inp:
            return
        if metal_tex is not None:
            out.albedo_tex = albedo_times_metal(out, metal_tex, self.warn)
            return
        if inp.HasConnectedSource():
            m = 0.0 if fallback is None else fallback  # unreadable texture, uncombinable: 0
        else:
            m = self.get(inp.GetAttr(), 0.0)
            m = float(np.ravel(np.asarray(m, np.float64))[0]) if m is not None else 0.0
        if not math.isfinite(m):
            raise StageError(f"{out.name}: UsdPreviewSurface inputs:metallic is {m}: fix it")
        if not 0.0 <= m <= 1.0:
            self.warn(f"{out.name}: metallic {m:g} outside [0, 1]; clamped")
            m = min(max(m, 0.0), 1.0)
        if m == 0.0:
            return
        k = np.float32(1.0 - m)
        out.albedo = (out.albedo * k).astype(np.float32)
        if out.albedo_tex is not None:
            tex = out.albedo_tex
            tex.scale = tex.scale.copy()
            tex.bias = tex.bias.copy()
            tex.scale[:3] *= k
            tex.bias[:3] *= k

    def _uniform(self, shader, name: str, default: float) -> float:
        """An unconnected shader input's value, through NodeGraph / Material interface
        inputs (usdMtlx writes those), else ``default``."""
        port = materialx.UsdNode(shader, self.get).port(name)
        if port is None or port.src is not None or port.value is None:
            return default
        if isinstance(port.value, str):
            return default
        return float(np.ravel(np.asarray(port.value, np.float64))[0])

    def _unhonoured_inputs(self, shader, name) -> None:
        """Record the UsdPreviewSurface inputs that change the diffuse response and that the
        baker ignores (a Lambertian bake of the base layer); see material_warnings."""
        neutral = {
            "normal": (0.0, 0.0, 1.0),
            "displacement": 0.0,
            "occlusion": 1.0,
            "clearcoat": 0.0,
        }
        node = materialx.UsdNode(shader, self.get)
        for inp_name, value in neutral.items():
            port = node.port(inp_name)  # through NodeGraph / Material interface inputs
            if port is None:
                continue
            if port.src is not None:
                what = f"UsdPreviewSurface {inp_name} (connected)"
                self.unhonoured.setdefault(what, []).append(name)
                continue
            v = port.value
            if v is not None and not np.allclose(np.asarray(v, np.float64), value):
                what = f"UsdPreviewSurface {inp_name} = {fmt_values(v)}"
                self.unhonoured.setdefault(what, []).append(name)

    def material_warnings(self) -> None:
        """One warning per stage and unhonoured UsdPreviewSurface input, naming materials."""
        for what, mats in sorted(self.unhonoured.items()):
            mats = sorted(set(mats))
            more = f" and {len(mats) - 3} more" if len(mats) > 3 else ""
            fix = " (the bake shades the flat diffuse base layer)"
            self.warn(
                f"{what} is not honoured by the bake in {len(mats)} "
                f"materials ({', '.join(mats[:3])}{more}){fix}",
                key=f"unhonoured:{what}",
            )

    def _check_material(self, out: Material) -> None:
        """NaN/Inf or negative emission is a broken light source (StageError); non-physical
        albedo and opacity are clamped to [0, 1] with a warning."""
        name = out.name
        values = {
            "emissiveColor": out.emission,
            "diffuseColor": out.albedo,
            "opacity": np.array([out.opacity]),
            "opacityThreshold": np.array([out.opacity_threshold]),
        }
        for key, v in values.items():
            v = np.asarray(v, np.float64)
            if not np.all(np.isfinite(v)):
                kind = "NaN" if np.isnan(v).any() else "Inf"
                raise StageError(
                    f"{name}: UsdPreviewSurface inputs:{key} is {kind} ({fmt_values(v)}); it would "
                    "spoil every prim that sees this material: fix the material"
                )
        em = np.asarray(out.emission, np.float64)
        if np.any(em < 0) or em.max(initial=0.0) > MAX_RADIANCE:
            raise StageError(
                f"{name}: UsdPreviewSurface inputs:emissiveColor {fmt_values(em)} must be in "
                f"[0, {MAX_RADIANCE:.0e}]: fix the material"
            )
        alb = np.asarray(out.albedo, np.float64)
        if np.any(alb < 0) or np.any(alb > 1):
            clamped = np.clip(alb, 0.0, 1.0)
            self.warn(
                f"{name}: inputs:diffuseColor {fmt_values(alb)} is non-physical (outside [0, 1]: "
                f"energy would grow with every bounce); clamped to {fmt_values(clamped)}"
            )
            out.albedo = clamped.astype(np.float32)
        for key in ("opacity", "opacity_threshold"):
            v = float(getattr(out, key))
            if not 0.0 <= v <= 1.0:
                self.warn(f"{name}: {key} {v:g} outside [0, 1]; clamped")
                setattr(out, key, min(max(v, 0.0), 1.0))

    def surface_input(self, shader, inp_name, fallback, mat_name, tc_names):
        """(constant, Texture or None) of a UsdPreviewSurface input: its value, a
        UsdUVTexture, or any other node (a primvar reader, MaterialX nodes: evaluated by
        usdahd.usd.materialx.Graph), followed through NodeGraph outputs."""
        fb = np.array(fallback, np.float32)
        usd_node = materialx.UsdNode(shader, self.get)
        port = usd_node.port(inp_name)
        if port is None:
            return fb, None
        if port.src is None:
            v = port.value
            return (fb if v is None or isinstance(v, str) else np.array(v, np.float32)), None
        src = port.src
        out_name = port.out
        if src.id not in ("UsdUVTexture", "ND_UsdUVTexture", "ND_UsdUVTexture_23"):
            g = materialx.Graph(self, self._prim, mat_name)
            g.surface = (usd_node, inp_name)
            sig = g.node(src, out_name, fb, f"{shader.GetPath()}.inputs:{inp_name}")
            if sig is None:
                return fb, None
            if sig.tex is None:
                return materialx.fit_components(sig.const, fb.size), None
            tc_names.append(sig.tc)
            return fb, sig.tex
        tex_shader = src.shader
        tex, reason = self._texture(tex_shader, out_name, mat_name)
        if tex is None:
            fbi = tex_shader.GetInput("fallback")
            authored = bool(fbi) and fbi.GetAttr().HasAuthoredValue()
            f4 = self.get(fbi.GetAttr(), (0, 0, 0, 1)) if fbi else (0, 0, 0, 1)
            f4 = np.array(f4, np.float32)
            ch = texture_channels(out_name)
            value = f4[list(ch)] if len(ch) == fb.size else fb
            what = f"inputs:fallback of {tex_shader.GetPath()}"
            if not authored:
                what = f"the default inputs:fallback of UsdUVTexture {fmt_values(f4)}"
            if reason is None:  # no file authored: the fallback, as USD renders it
                return value, None
            if inp_name == "diffuseColor" and not authored:
                g = materialx.Graph(self, self._prim, mat_name)
                g.surface = (usd_node, inp_name)
                value, what = g.substitute(fb)
                value = materialx.fit_components(value, fb.size)
            self.report_unreadable(
                self._prim,
                mat_name,
                f"{tex_shader.GetPath()}",
                tex_path(tex_shader),
                reason,
                value,
                what,
                inp_name,
            )
            return value, None
        tc_names.append(self._texcoord_name(tex_shader, mat_name))
        return fb, tex

    def graph_uvtexture(self, g, node, out):
        """A UsdUVTexture reached from a MaterialX graph (usdahd.usd.materialx.Graph)."""
        if not isinstance(node, materialx.UsdNode):
            return None
        tex, reason = self._texture(node.shader, out, g.name)
        if tex is None:
            return None
        tc = self._texcoord_name(node.shader, g.name)
        g.tcs.append(tc)
        return materialx.Sig(tex=tex, tc=tc)

    def image_texture(self, path, colorspace, owner):
        """(Texture of a MaterialX image node's file (rgb(a) channels, scale 1, bias 0), or
        None, the reason it cannot be read). ``colorspace`` : the file input's colour
        space (MaterialX ``colorspace`` / USD ``colorSpace``; "" applies Hydra's rule)."""
        if "<UDIM>" in path:
            return None, "UDIM textures are not supported"
        data, reason = self._read_image(path, "auto", owner, colorspace)
        if data is None:
            return None, reason
        one = np.ones(4, np.float32)
        return Texture(path, data, one, np.zeros(4, np.float32), (0, 1, 2)), ""

    def report_unreadable(self, prim, mat_name, node, file, reason, value, what, inp=""):
        """The warning for a texture that cannot be read: prim, file, value used, fix."""
        who = f"{prim.GetPath()}: " if prim is not None else ""
        for_ = f"{mat_name}" + (f" inputs:{inp}" if inp else "")
        self.warn(
            f"{who}cannot read texture {file} ({node}: {reason}); {for_} uses "
            f"{fmt_values(value)} ({what}) instead. Fix: make the file readable (a path "
            "that resolves, a format OpenImageIO decodes) or author the colour you want",
            key=f"unreadable:{file}:{mat_name}:{inp}",
        )

    def _texcoord_name(self, tex_shader, mat_name) -> str:
        """The texcoord a UsdUVTexture reads: the primvar of its UsdPrimvarReader_float2,
        optionally through a UsdTransform2d (then a derived name ``<primvar>@<transform>``
        whose values usdahd.usd.geometry computes: out = rotate(scale * in) + translation)."""
        st = tex_shader.GetInput("st")
        if not st or not st.HasConnectedSource():
            return "st"
        node = UsdShade.Shader(st.GetConnectedSources()[0][0].source.GetPrim())
        nid = node.GetIdAttr().Get() if node.GetIdAttr() else None
        xf = None
        if nid == "UsdTransform2d":

            def val(n, d):
                i = node.GetInput(n)
                v = self.get(i.GetAttr()) if i else None
                return np.array(d if v is None else v, np.float64).reshape(-1)

            scale, rot, trans = (
                val("scale", (1, 1)),
                val("rotation", 0.0),
                val("translation", (0, 0)),
            )
            if not (np.all(np.isfinite(scale)) and np.all(np.isfinite(rot))):
                raise StageError(f"{node.GetPath()}: UsdTransform2d inputs are NaN/Inf: fix it")
            xf = (float(scale[0]), float(scale[1]), float(rot[0]), float(trans[0]), float(trans[1]))
            inp = node.GetInput("in")
            if not inp or not inp.HasConnectedSource():
                self.warn(
                    f"{mat_name}: {node.GetPath()} (UsdTransform2d) has no connected 'in'; "
                    "the texture reads primvar 'st'"
                )
                reader = None
            else:
                reader = UsdShade.Shader(inp.GetConnectedSources()[0][0].source.GetPrim())
        else:
            reader = node
        var = "st"
        if reader:
            vn = reader.GetInput("varname")
            if vn:
                var = str(self.get(vn.GetAttr(), "st"))
        if xf is None or xf == (1.0, 1.0, 0.0, 0.0, 0.0):
            return var
        sx, sy, r, tx, ty = (f"{v:.9g}" for v in xf)
        name = f"{var}@scale({sx},{sy})rotate({r})translate({tx},{ty})"
        c, s_ = math.cos(math.radians(xf[2])), math.sin(math.radians(xf[2]))
        a = np.array([[c, -s_], [s_, c]]) @ np.diag([xf[0], xf[1]])
        self.tc_transforms[name] = (var, a, np.array([xf[3], xf[4]]))
        return name

    def _texture(self, tex_shader, out_name, mat_name):
        """(Texture, "") of a UsdUVTexture, or (None, why it cannot be read; None when no
        file is authored)."""
        fin = tex_shader.GetInput("file")
        asset = self.get(fin.GetAttr()) if fin else None
        if asset is None or not (asset.path or asset.resolvedPath):
            return None, None
        path = asset.resolvedPath or asset.path
        if "<UDIM>" in (asset.path or ""):
            return None, "UDIM textures are not supported"
        if not asset.resolvedPath:
            return None, f"it does not exist: the asset path @{asset.path}@ does not resolve"
        cs = tex_shader.GetInput("sourceColorSpace")
        cs = str(self.get(cs.GetAttr(), "auto")) if cs else "auto"
        fattr = fin.GetAttr()
        file_cs = str(fattr.GetColorSpace()) if fattr.HasColorSpace() else ""
        data, reason = self._read_image(path, cs, mat_name, file_cs)
        if data is None:
            return None, reason

        def vec4(n, d):
            i = tex_shader.GetInput(n)
            v = self.get(i.GetAttr()) if i else None
            return np.array(d if v is None else v, np.float32)

        wrap = []
        for w in ("wrapS", "wrapT"):
            i = tex_shader.GetInput(w)
            v = str(self.get(i.GetAttr(), "useMetadata")) if i else "useMetadata"
            wrap.append("repeat" if v == "useMetadata" else v)
        return Texture(
            path,
            data,
            vec4("scale", (1, 1, 1, 1)),
            vec4("bias", (0, 0, 0, 0)),
            texture_channels(out_name),
            (wrap[0], wrap[1]),
        ), ""

    def _read_image(self, path, colorspace, owner, file_colorspace=""):
        """(linear texels or None, why not): read once per path and colour space. Why a
        file cannot be read is returned for the caller's message (which names the value
        used instead); other warnings (colour space) are warned here."""
        key = (path, colorspace, file_colorspace)
        if key in self._textures:
            return self._textures[key]
        problems: list[str] = []

        def warn(m):
            if "fallback used" in m:
                m = m.replace("; fallback used", "")
                for head in (f"cannot read texture {path}", f"cannot decode texture {path}"):
                    m = m.replace(head, "cannot decode it" if "decode" in head else "")
                m = m.strip()
                m = m[1:].strip() if m.startswith(":") else m
                m = m[1:-1] if m.startswith("(") and m.endswith(")") else m
                problems.append(m or "unreadable")
            else:
                self.warn(f"{owner}: {m}")

        data = read_image(path, colorspace, warn, file_colorspace=file_colorspace)
        if data is not None:
            data = sanitize_image(data, f"{owner}: {path}", self.warn)
            # material textures are seen only through bounce rays: MAX_MATERIAL_TEXTURE
            data = box_downsample(data, MAX_MATERIAL_TEXTURE)
        reason = problems[0] if problems else ("cannot be decoded" if data is None else "")
        self._textures[key] = (data, reason)
        return data, reason


def tex_path(tex_shader) -> str:
    """The authored file of a UsdUVTexture, for messages."""
    fin = tex_shader.GetInput("file")
    a = fin.Get() if fin else None
    return (a.resolvedPath or a.path) if a is not None else ""
