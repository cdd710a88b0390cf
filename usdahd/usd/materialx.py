"""MaterialX surfaces: UsdShade graphs whose surface is a MaterialX node, and ``.mtlx`` files.

Production USD writes its looks as MaterialX: a Material's ``outputs:mtlx:surface`` (render
context ``mtlx``) connected to a Shader whose ``info:id`` is a MaterialX node definition
(``ND_standard_surface_surfaceshader``, ``ND_open_pbr_surface_surfaceshader``,
``ND_UsdPreviewSurface_surfaceshader``) fed by MaterialX pattern nodes (``ND_image_color3``,
``ND_tiledimage_float``, ``ND_texcoord_vector2``, ...), possibly inside NodeGraphs; or a
reference to a ``.mtlx`` document (``@look.mtlx@</MaterialX/Materials>``) that USD composes
through its usdMtlx file-format plugin.

The usd-core wheel has **no usdMtlx plugin**, so such a reference does not compose ("Cannot
determine file format") and the binding targets a prim that does not exist. The bake then
reads the document itself with the MaterialX library (PyPI ``materialx``; :func:`find_mtlx`
maps the binding target back to the document and the material's name the way usdMtlx maps
``<surfacematerial name="M">`` to ``/MaterialX/Materials/M``).

Both sources are read by one evaluator (:class:`Graph`) over two node adapters
(:class:`UsdNode`, :class:`MtlxNode`); input defaults come from the MaterialX standard
library's node definitions (shipped in the ``materialx`` wheel), not from a copy here. What a
Lambertian bake takes from each surface (docs/usd-semantics.md, Materials):

- ``standard_surface``: albedo ``base_color x base x (1 - metalness)``, emission
  ``emission_color x emission``, opacity the mean of ``opacity``;
- ``open_pbr_surface``: albedo ``base_color x base_weight x (1 - base_metalness)``, emission
  ``emission_color x emission_luminance`` (nits, the radiance unit of UsdLux), opacity
  ``geometry_opacity``;
- ``UsdPreviewSurface`` (MaterialX node): ``diffuseColor x (1 - metallic)`` (metallic workflow),
  ``emissiveColor``, ``opacity`` and ``opacityThreshold``.

Pattern nodes evaluated: image / tiledimage (file, colour space, default, address modes,
uvtiling / uvoffset), texcoord, geompropvalue, UsdPrimvarReader, UsdUVTexture, constant, dot,
convert, extract, and multiply / add / subtract / divide where the result stays
``scale x texel + bias`` (one operand constant) or is a product of two textures on the same
texcoord. Anything else is reported (material, node, value used, fix).
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass

import numpy as np
from pxr import Sdf, UsdShade

from usdahd.scene.types import Texture
from usdahd.usd.stage import fmt_values, one_line
from usdahd.usd.textures import outputs_on_grid

__all__ = [
    "SURFACES",
    "Graph",
    "MtlxNode",
    "MtlxSource",
    "Sig",
    "UsdNode",
    "composition_note",
    "find_mtlx",
    "load_document",
    "nodedef_default",
    "surface_terms",
    "fit_components",
    "mtlx_surface",
]

#: MaterialX surface node definitions the bake reads -> their kind.
SURFACES = {
    "ND_standard_surface_surfaceshader": "standard_surface",
    "ND_open_pbr_surface_surfaceshader": "open_pbr_surface",
    "ND_UsdPreviewSurface_surfaceshader": "UsdPreviewSurface",
}

_WRAP = {"periodic": "repeat", "clamp": "clamp", "mirror": "mirror", "constant": "black"}
_WIDTH = {"float": 1, "integer": 1, "vector2": 2, "color3": 3, "vector3": 3}
_WIDTH.update({"color4": 4, "vector4": 4})


def _mx():
    import MaterialX

    return MaterialX


_LIBRARY = []
_LIBRARY_LOCK = threading.Lock()


def library():
    """The MaterialX standard data libraries (node definitions and their defaults): one
    document for the process, built once. Single-flight under a lock: validation runs rules
    in parallel threads, and with ``lru_cache`` two first calls each built a document and the
    cache kept only one, so the other was freed while its node definitions were in use
    (MaterialX: "Requested root of orphaned element", seen as an InternalError of Staleness
    on the usd-wg Standard Shader Ball)."""
    with _LIBRARY_LOCK:
        if not _LIBRARY:
            mx = _mx()
            lib = mx.createDocument()
            mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
            _LIBRARY.append(lib)
        return _LIBRARY[0]


def _mx_value(v):
    """A MaterialX value as a float list (numbers, colours, vectors) or a str."""
    if v is None:
        return None
    if isinstance(v, str):
        return v
    if isinstance(v, bool | int | float):
        return [float(v)]
    try:
        return [float(x) for x in v]
    except TypeError:
        return str(v)


def nodedef_default(nodedef: str, name: str):
    """The default of input ``name`` of a MaterialX node definition (float list / str), or
    None (no such node definition or input)."""
    nd = library().getNodeDef(nodedef)
    inp = nd.getActiveInput(name) if nd else None
    return _mx_value(inp.getValue()) if inp is not None and inp.getValueString() else None


def _node_kind(nodedef: str) -> tuple[str, str]:
    """(node category, output type) of a node definition name (``ND_image_color3`` ->
    ('image', 'color3')); USD's own shader ids map to themselves."""
    nd = library().getNodeDef(nodedef)
    if nd is not None:
        return nd.getNodeString(), nd.getType()
    if nodedef.startswith("UsdPrimvarReader_"):
        t = nodedef.split("_", 1)[1]
        return "UsdPrimvarReader", {"float3": "vector3", "float4": "vector4"}.get(t, t)
    return nodedef, ""


@dataclass
class Port:
    """One input of a node: an authored value, or a connection (``src`` node, ``out``
    output name); ``colorspace`` of a filename value ("" when none applies)."""

    value: object = None
    src: object = None
    out: str = "out"
    colorspace: str = ""
    unresolved: bool = False  # an asset path USD's resolver does not resolve


class UsdNode:
    """A UsdShade Shader as a graph node; connections followed through NodeGraphs."""

    def __init__(self, shader, get):
        self.shader = shader
        self.get = get
        self.id = str(shader.GetShaderId() or "")
        self.path = str(shader.GetPath())

    def port(self, name):
        inp = self.shader.GetInput(name)
        if not inp:
            return None
        attrs = UsdShade.Utils.GetValueProducingAttributes(inp)
        if not attrs:
            return None
        attr = attrs[0]
        base, kind = UsdShade.Utils.GetBaseNameAndType(attr.GetName())
        if kind == UsdShade.AttributeType.Output:
            return Port(src=UsdNode(UsdShade.Shader(attr.GetPrim()), self.get), out=str(base))
        v = self.get(attr)
        cs = str(attr.GetColorSpace()) if attr.HasColorSpace() else ""
        if isinstance(v, Sdf.AssetPath):
            unresolved = bool(v.path) and not v.resolvedPath
            v = v.resolvedPath or v.path or None
            return Port(value=v, colorspace=cs, unresolved=unresolved)
        elif v is not None and not isinstance(v, str):
            v = [float(x) for x in np.ravel(np.asarray(v, np.float64))]
        return Port(value=v, colorspace=cs)


class MtlxNode:
    """A node of a MaterialX document as a graph node (nodename, nodegraph/output and
    interfacename connections followed; filenames resolved against the document's folder
    and ``fileprefix``)."""

    def __init__(self, node, folder: str):
        self.node = node
        self.folder = folder
        nd = node.getNodeDef()
        self.id = nd.getName() if nd is not None else node.getCategory()
        self.path = f"{node.getNamePath()} ({node.getCategory()})"

    def port(self, name):
        inp = self.node.getInput(name)
        return None if inp is None else self._port(inp)

    def _port(self, inp):
        iface = inp.getInterfaceName() if hasattr(inp, "getInterfaceName") else ""
        if iface:
            graph = inp.getParent().getParent()
            outer = graph.getInput(iface) if graph is not None else None
            if outer is not None:
                return self._port(outer)
        doc = inp.getDocument()
        ngname = inp.getNodeGraphString()
        src = None
        out = inp.getOutputString() or "out"
        if ngname:
            graph = doc.getNodeGraph(ngname)
            o = graph.getOutput(inp.getOutputString()) if graph is not None else None
            if o is None and graph is not None and graph.getOutputs():
                o = graph.getOutputs()[0]
            if o is not None:
                src = o.getConnectedNode()
                out = o.getOutputString() or "out"
        elif inp.getNodeName():
            src = inp.getConnectedNode()
        if src is not None:
            return Port(src=MtlxNode(src, self.folder), out=out)
        if not inp.getValueString():
            return None
        if inp.getType() == "filename":
            v = inp.getResolvedValueString()
            if v and not os.path.isabs(v):
                v = os.path.normpath(os.path.join(self.folder, v))
            return Port(value=v or None, colorspace=inp.getActiveColorSpace())
        return Port(value=_mx_value(inp.getValue()))


@dataclass
class Sig:
    """A value in the graph: a constant (``const``, float32 (n,)) or a texture (``tex``, its
    selected channels are the value; ``tc`` the texcoord name it reads)."""

    const: np.ndarray | None = None
    tex: Texture | None = None
    tc: str = "st"

    @property
    def width(self) -> int:
        return len(self.tex.channels) if self.tex is not None else int(self.const.size)

    def describe(self) -> str:
        return fmt_values(self.const) if self.tex is None else f"the texture {self.tex.path}"


def fit_components(c: np.ndarray, n: int) -> np.ndarray:
    """A constant as n components (a scalar replicated; extra components dropped)."""
    c = np.asarray(c, np.float32).ravel()
    if c.size == n:
        return c
    if c.size == 1:
        return np.repeat(c, n)
    return np.resize(c, n) if c.size > n else np.r_[c, np.ones(n - c.size, np.float32)]


def _materialize(tex: Texture, n: int) -> Texture:
    """The texture's output values as their own texels (n channels, scale 1, bias 0)."""
    v = tex.outputs()
    if v.shape[2] != n:
        v = np.repeat(v[..., :1], n, axis=2) if v.shape[2] == 1 else v[..., :n]
    return Texture(
        tex.path,
        np.ascontiguousarray(v, np.float32),
        np.ones(4, np.float32),
        np.zeros(4, np.float32),
        tuple(range(n)),
        tex.wrap,
    )


def affine(s: Sig, k, c) -> Sig:
    """k x s + c, per component (k, c broadcast to the result's width)."""
    k = np.asarray(k, np.float32).ravel()
    c = np.asarray(c, np.float32).ravel()
    n = max(s.width, k.size, c.size)
    if s.tex is None:
        return Sig(
            const=fit_components(s.const, n) * fit_components(k, n) + fit_components(c, n), tc=s.tc
        )
    t = s.tex
    if len(t.channels) != n or len(set(t.channels)) != n:
        t = _materialize(t, n)
    else:
        t = Texture(t.path, t.data, t.scale.copy(), t.bias.copy(), tuple(t.channels), t.wrap)
    for i, q in enumerate(t.channels):
        t.scale[q] *= fit_components(k, n)[i]
        t.bias[q] = t.bias[q] * fit_components(k, n)[i] + fit_components(c, n)[i]
    return Sig(tex=t, tc=s.tc)


def multiply(a: Sig, b: Sig, warn) -> Sig:
    """a x b (component-wise, a scalar broadcast): exact for a constant factor (the
    texture's scale and bias); two textures on the same texcoord are multiplied on a common
    grid (:func:`texture_product`); on different texcoords the second is dropped (warned)."""
    if a.tex is None and b.tex is None:
        n = max(a.width, b.width)
        return Sig(const=fit_components(a.const, n) * fit_components(b.const, n))
    if a.tex is None:
        a, b = b, a
    if b.tex is None:
        return affine(a, b.const, 0.0)
    if a.tc != b.tc:
        warn(
            f"{a.tex.path} (texcoord '{a.tc}') is multiplied by {b.tex.path} (texcoord "
            f"'{b.tc}'): the bake cannot combine textures on different texcoords and uses "
            f"the first alone. Fix: read both through the same texcoord"
        )
        return a
    return Sig(tex=texture_product(a.tex, b.tex), tc=a.tc)


def texture_product(a: Texture, b: Texture) -> Texture:
    """The product of two textures' outputs on a common grid (per axis the larger
    resolution; each evaluated at the texel centres by its own bilinear lookup: exact at
    those centres, see usdahd.usd.textures.albedo_times_metal). Wraps like ``a``."""

    h = max(a.data.shape[0], b.data.shape[0])
    w = max(a.data.shape[1], b.data.shape[1])
    n = max(len(a.channels), len(b.channels))

    def values(t):  # (h, w, k) outputs on the grid, in few whole-array passes
        if t.data.shape[:2] != (h, w):
            return outputs_on_grid(t, h, w)
        c = t.data.shape[2]
        ch = list(t.channels)
        if all(q < c for q in ch):
            out = t.data[..., ch] if ch != list(range(c)) else t.data.copy()
        else:  # channels the file lacks: USD's padding (grey replicated, alpha 1)
            out = np.empty((h, w, len(ch)), np.float32)
            for i, q in enumerate(ch):
                out[..., i] = (
                    t.data[..., q] if q < c else (t.data[..., 0] if c == 1 and q < 3 else 1)
                )
        k, d = t.scale[ch], t.bias[ch]
        if np.any(k != 1):
            out *= k
        if np.any(d != 0):
            out += d
        return out

    va, vb = values(a), values(b)
    if va.shape[2] < vb.shape[2]:
        va, vb = vb, va  # the wider one receives the product (a 1-channel one broadcasts)
    if va.shape[2] == 1 and n > 1:
        va = np.repeat(va, n, axis=2)
    np.multiply(va[..., :n], vb[..., :n] if vb.shape[2] > 1 else vb, out=va[..., :n])
    return Texture(
        a.path,
        np.ascontiguousarray(va[..., :n], np.float32),
        np.ones(4, np.float32),
        np.zeros(4, np.float32),
        tuple(range(n)),
        a.wrap,
    )


class Graph:
    """Evaluates MaterialX / UsdShade pattern nodes to :class:`Sig` values for one material
    read for one prim. ``mats`` : usdahd.usd.materials.MaterialReader (texture reading,
    primvar values of ``prim``, warnings); ``name`` : the material, for messages."""

    def __init__(self, mats, prim, name: str):
        self.mats = mats
        self.prim = prim
        self.name = name
        self.tcs: list[str] = []
        self.surface = None  # (surface node, input name) being evaluated

    def warn(self, msg, key=None):
        """A warning naming the prim the material is read for (the first one bound, when
        prims share it) and the material."""
        who = f"{self.prim.GetPath()}: " if self.prim is not None else ""
        self.mats.warn(f"{who}{self.name}: {msg}", key=key)

    def input(self, node, name: str, default=None) -> Sig:
        """The value of input ``name`` of ``node``: its connection evaluated, its authored
        value, else the node definition's default (else ``default``)."""
        port = node.port(name)
        if node.id in SURFACES or node.id == "UsdPreviewSurface":
            self.surface = (node, name)
        fb = nodedef_default(node.id, name)
        fb = default if fb is None else fb
        fb = [0.0] if fb is None or isinstance(fb, str) else fb
        if port is None or (port.src is None and port.value is None):
            return Sig(const=np.asarray(fb, np.float32))
        if port.src is None:
            v = port.value
            return Sig(const=np.asarray(fb if isinstance(v, str) else v, np.float32))
        got = self.node(port.src, port.out, fb, f"{node.path}.inputs:{name}")
        return got if got is not None else Sig(const=np.asarray(fb, np.float32))

    def value(self, node, name: str, default=None):
        """An uniform input's authored value or default (str or float list), unconnected."""
        port = node.port(name)
        if port is not None and port.src is None and port.value is not None:
            return port.value
        d = nodedef_default(node.id, name)
        return default if d is None else d

    def node(self, node, out: str, fallback, where: str) -> Sig | None:
        """The output ``out`` of ``node``, or None (unsupported: warned, ``fallback``)."""
        cat, typ = _node_kind(node.id)
        if cat in ("image", "tiledimage"):
            return self._image(node, cat, typ)
        if cat == "UsdUVTexture":
            return self.mats.graph_uvtexture(self, node, out)
        if cat in ("texcoord", "UsdPrimvarReader", "geompropvalue") and typ == "vector2":
            return None  # coordinates are read by the texture node, not as values
        if cat in ("UsdPrimvarReader", "geompropvalue"):
            var = self.value(node, "varname" if cat == "UsdPrimvarReader" else "geomprop", "")
            dflt = self.input(node, "fallback" if cat == "UsdPrimvarReader" else "default")
            v = self.mats.primvar_value(self.prim, str(var), None, self.name)
            if v is None:
                v = fit_components(dflt.const, _WIDTH.get(typ, dflt.width))
                who = self.prim.GetPath() if self.prim is not None else "a prim"
                self.mats.warn(
                    f"{who}: {node.path} reads primvars:{var}, which the prim does not have; "
                    f"{self.name} uses the reader's fallback {fmt_values(v)}. Fix: author "
                    f"primvars:{var} on the prim (or a fallback on the reader)",
                    key=f"pv-missing:{who}:{var}:{self.name}",
                )
            return Sig(const=np.asarray(v, np.float32))
        if cat in ("constant", "dot"):
            return self.input(node, "value" if cat == "constant" else "in")
        if cat == "convert":
            s = self.input(node, "in")
            n = _WIDTH.get(typ, s.width)
            if s.tex is None:
                return Sig(const=fit_components(s.const, n))
            return s if s.width == n else affine(s, np.ones(n), np.zeros(n))
        if cat == "extract":
            s = self.input(node, "in")
            i = int(np.ravel(self.value(node, "index", [0]))[0])
            if s.tex is None:
                return Sig(const=np.asarray(s.const, np.float32)[i : i + 1])
            t = s.tex
            t = Texture(t.path, t.data, t.scale, t.bias, (t.channels[i],), t.wrap)
            return Sig(tex=t, tc=s.tc)
        if cat in ("multiply", "add", "subtract", "divide"):
            a, b = self.input(node, "in1"), self.input(node, "in2")
            if cat == "multiply":
                return multiply(a, b, self.warn)
            if b.tex is None:
                if cat == "divide":
                    if np.any(b.const == 0):
                        return None
                    return affine(a, 1.0 / b.const, 0.0)
                return affine(a, 1.0, b.const if cat == "add" else -b.const)
            if a.tex is None and cat in ("add", "subtract"):
                k = 1.0 if cat == "add" else -1.0
                return affine(b, k, a.const)
        self.warn(
            f"{where} is connected to {node.path} ({node.id}), which the bake does not "
            f"evaluate; it uses {fmt_values(fallback)}. Fix: bake the pattern into a "
            "texture read by an image node",
            key=f"mtlx-node:{self.name}:{node.id}",
        )
        return None

    def _image(self, node, cat: str, typ: str) -> Sig | None:
        port = node.port("file")
        dflt = self.input(node, "default")
        n = _WIDTH.get(typ, 3)
        path = port.value if port is not None and port.src is None else None
        tc = self._texcoord(node, "texcoord")
        if cat == "tiledimage":
            tc = self._tiled(node, tc)
        if not path:
            return Sig(const=fit_components(dflt.const, n))
        wrap = tuple(
            _WRAP.get(str(self.value(node, a, "periodic")), "repeat")
            for a in ("uaddressmode", "vaddressmode")
        )
        if cat == "tiledimage":
            wrap = ("repeat", "repeat")
        if port.unresolved:
            tex, reason = None, f"it does not exist: the asset path @{path}@ does not resolve"
        else:
            tex, reason = self.mats.image_texture(path, port.colorspace, self.name)
        if tex is None:
            authored = node.port("default")
            if authored is not None and authored.src is None and authored.value is not None:
                v, what = (
                    fit_components(dflt.const, n),
                    f"the authored inputs:default of {node.path}",
                )
            else:
                v, what = self.substitute(fit_components(dflt.const, n))
            inp = self.surface[1] if self.surface is not None else ""
            self.mats.report_unreadable(self.prim, self.name, node.path, path, reason, v, what, inp)
            return Sig(const=fit_components(v, n))
        ch = tuple(range(n)) if n > 1 else (0,)
        t = Texture(tex.path, tex.data, np.ones(4, np.float32), np.zeros(4, np.float32), ch, wrap)
        self.tcs.append(tc)
        return Sig(tex=t, tc=tc)

    def substitute(self, node_default):
        """(value, what it is) used for a texture that cannot be read and authors no
        default of its own: for a base / diffuse colour the constant authored under the
        connection, else the prim's displayColor (what usdview shows), else the surface's
        default; for any other input the texture node's default."""
        if self.surface is None:
            return node_default, "the texture node's default"
        snode, sname = self.surface
        if sname not in ("base_color", "diffuseColor"):
            return node_default, "the texture node's default"
        if isinstance(snode, UsdNode):
            attr = snode.shader.GetInput(sname).GetAttr()
            v = self.mats.get(attr) if attr.HasAuthoredValue() else None
            if v is not None:
                return np.asarray(v, np.float32), f"the constant authored on {sname}"
        v = self.mats.primvar_value(self.prim, "displayColor", None, self.name)
        if v is not None:
            return np.asarray(v, np.float32), f"the displayColor of {self.prim.GetPath()}"
        d = nodedef_default(snode.id, sname) or [0.18, 0.18, 0.18]
        return np.asarray(d, np.float32), f"the default {sname} of {snode.id}"

    def _texcoord(self, node, name: str) -> str:
        """The primvar a texture node's coordinate input reads: a texcoord node (index 0 is
        ``st``, USD's primary UV set; index i > 0 ``st{i}``), a geompropvalue /
        UsdPrimvarReader_float2 (its primvar), unconnected: ``st``."""
        port = node.port(name)
        if port is None or port.src is None:
            return "st"
        src = port.src
        cat, _ = _node_kind(src.id)
        if cat == "texcoord":
            i = int(np.ravel(self.value(src, "index", [0]))[0])
            return "st" if i == 0 else f"st{i}"
        if cat in ("geompropvalue", "UsdPrimvarReader"):
            return str(self.value(src, "geomprop" if cat == "geompropvalue" else "varname", "st"))
        if cat == "UsdTransform2d" and isinstance(src, UsdNode):
            return self.mats._texcoord_name(src.shader, self.name)
        self.warn(
            f"{node.path}.{name} is connected to {src.path} ({src.id}); the bake reads "
            "primvar 'st'. Fix: connect a texcoord or geompropvalue node",
            key=f"mtlx-tc:{self.name}:{src.id}",
        )
        return "st"

    def _tiled(self, node, tc: str) -> str:
        """The derived texcoord of a tiledimage: ``texcoord x uvtiling - uvoffset``
        (registered as a transform, as UsdTransform2d's are)."""
        tiling = np.ravel(self.value(node, "uvtiling", [1.0, 1.0])).astype(np.float64)
        offset = np.ravel(self.value(node, "uvoffset", [0.0, 0.0])).astype(np.float64)
        rw = np.ravel(self.value(node, "realworldimagesize", [1.0, 1.0])).astype(np.float64)
        rt = np.ravel(self.value(node, "realworldtilesize", [1.0, 1.0])).astype(np.float64)
        s = rt / rw
        a = np.diag(tiling * s)
        b = -offset * s + 0.0  # no -0 in the derived name
        if np.allclose(a, np.eye(2)) and np.allclose(b, 0):
            return tc
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            return tc
        sx, sy, tx, ty = (f"{v:.9g}" for v in (a[0, 0], a[1, 1], b[0], b[1]))
        name = f"{tc}@scale({sx},{sy})rotate(0)translate({tx},{ty})"
        self.mats.tc_transforms[name] = (tc, a, b)
        return name


def _constant_if_flat(s: Sig) -> Sig:
    """A texture scaled by 0 (e.g. emission x an emission weight of 0) is its bias: a
    constant, so that a material is not taken for an emitter or textured for nothing."""
    if s.tex is None:
        return s
    q = list(s.tex.channels)
    if np.all(s.tex.scale[q] == 0):
        return Sig(const=np.asarray(s.tex.bias[q], np.float32))
    return s


def surface_terms(g: Graph, node) -> dict:
    """What the bake takes from a MaterialX surface node: {'albedo', 'emission', 'opacity',
    'opacity_threshold'} as :class:`Sig` / float, and 'ignored': [(input, value)] of
    non-default inputs that change the diffuse response and are not honoured."""
    kind = SURFACES[node.id]
    inp = g.input
    if kind == "standard_surface":
        base = multiply(inp(node, "base_color"), inp(node, "base"), g.warn)
        metal = inp(node, "metalness")
        emission = multiply(inp(node, "emission_color"), inp(node, "emission"), g.warn)
        op = inp(node, "opacity")
        thr = 0.0
        checked = ("transmission", "subsurface", "coat", "sheen", "thin_film_thickness")
    elif kind == "open_pbr_surface":
        base = multiply(inp(node, "base_color"), inp(node, "base_weight"), g.warn)
        metal = inp(node, "base_metalness")
        emission = multiply(inp(node, "emission_color"), inp(node, "emission_luminance"), g.warn)
        op = inp(node, "geometry_opacity")
        thr = 0.0
        checked = ("transmission_weight", "subsurface_weight", "coat_weight", "fuzz_weight")
    else:
        base = inp(node, "diffuseColor")
        spec = np.ravel(g.value(node, "useSpecularWorkflow", [0]))
        metal = Sig(const=np.zeros(1, np.float32)) if spec[0] else inp(node, "metallic")
        emission = inp(node, "emissiveColor")
        op = inp(node, "opacity")
        thr = float(np.ravel(g.value(node, "opacityThreshold", [0.0]))[0])
        checked = ("clearcoat", "occlusion", "displacement")
    if metal.tex is None and not np.all(np.isfinite(metal.const)):
        metal = Sig(const=np.zeros(1, np.float32))
    if metal.tex is not None or float(np.ravel(metal.const)[0]) != 0.0:
        if metal.tex is None:
            metal = Sig(const=np.clip(metal.const, 0.0, 1.0))
        albedo = multiply(base, affine(metal, -1.0, 1.0), g.warn)
    else:
        albedo = base
    albedo, emission, op = (_constant_if_flat(x) for x in (albedo, emission, op))
    if albedo.tex is None:
        albedo = Sig(const=fit_components(albedo.const, 3))
    if emission.tex is None:
        emission = Sig(const=fit_components(emission.const, 3))
    if op.tex is None:
        op = Sig(const=np.array([float(np.mean(op.const))], np.float32))
    elif op.width > 1:
        op = Sig(tex=Texture(**{**op.tex.__dict__, "channels": (op.tex.channels[0],)}), tc=op.tc)
    ignored = []
    for name in checked:
        s = inp(node, name)
        d = nodedef_default(node.id, name)
        if s.tex is not None:
            ignored.append((name, "a texture"))
        elif d is not None and not isinstance(d, str):
            if not np.allclose(fit_components(s.const, len(d)), d):
                ignored.append((name, fmt_values(s.const)))
    return {
        "albedo": albedo,
        "emission": emission,
        "opacity": op,
        "opacity_threshold": thr,
        "ignored": ignored,
    }


# -- .mtlx documents -------------------------------------------------------------------------


@dataclass
class MtlxSource:
    """Where a binding target that USD could not compose lives in a ``.mtlx`` file:
    ``file`` (absolute), ``material`` (its surfacematerial's name), ``layer`` (the layer that
    references it), ``reason`` (why usdahd cannot read it either: "" when it can)."""

    file: str
    material: str
    layer: str
    reason: str = ""


def find_mtlx(stage, target) -> MtlxSource | None:
    """The ``.mtlx`` reference or payload (on ``target`` or an ancestor) that should have
    provided the prim ``target``, or None. usdMtlx maps a document's materials to
    ``/MaterialX/Materials/<name>``, so the material is the last element of the arc's prim
    path extended by the target's path below the referencing prim (``@a.mtlx@</MaterialX/
    Materials>`` on ``/W/Looks``, target ``/W/Looks/M``: ``M``; ``@a.mtlx@</MaterialX/
    Materials/M>`` on the target itself: ``M``)."""
    target = Sdf.Path(str(target))
    anc = target
    while anc != Sdf.Path.absoluteRootPath and not anc.isEmpty:
        prim = stage.GetPrimAtPath(anc)
        if prim:
            for spec in prim.GetPrimStack():
                arcs = list(spec.referenceList.GetAddedOrExplicitItems())
                arcs += list(spec.payloadList.GetAddedOrExplicitItems())
                for arc in arcs:
                    ap = str(arc.assetPath)
                    if not ap.lower().endswith(".mtlx"):
                        continue
                    f = spec.layer.ComputeAbsolutePath(ap)
                    name = target.name
                    if not arc.primPath.isEmpty:  # the prim the arc targets in the document
                        rel = target.MakeRelativePath(anc)
                        full = (
                            arc.primPath if rel == Sdf.Path(".") else arc.primPath.AppendPath(rel)
                        )
                        name = full.name
                    src = MtlxSource(f, name, spec.layer.identifier)
                    src.reason = _mtlx_problem(f, name)
                    return src
            break  # the nearest existing ancestor decides
        anc = anc.GetParentPath()
    return None


_DOCUMENTS: dict = {}
_DOCUMENTS_LOCK = threading.Lock()


def load_document(path: str):
    """(MaterialX document with the standard libraries imported, error text): a document
    is read once per path and kept for the process (single-flight, like :func:`library`: a
    document freed by a cache while elements taken from it are in use orphans them)."""
    with _DOCUMENTS_LOCK:
        if path not in _DOCUMENTS:
            _DOCUMENTS[path] = _read_document(path)
        return _DOCUMENTS[path]


def _read_document(path: str):
    mx = _mx()
    if not os.path.isfile(path):
        return None, f"{path} does not exist"
    doc = mx.createDocument()
    try:
        mx.readFromXmlFile(doc, path)
    except Exception as exc:  # MaterialX raises its own ExceptionParseError etc.
        return None, f"MaterialX cannot parse {path}: {one_line(exc, 200)}"
    doc.importLibrary(library())
    return doc, ""


def _mtlx_problem(path: str, material: str) -> str:
    doc, err = load_document(path)
    if doc is None:
        return err
    node = doc.getChild(material)
    if node is None or node.getCategory() != "surfacematerial":
        names = [m.getName() for m in doc.getMaterialNodes()]
        return f"it has no surfacematerial named {material!r} (it has {names[:6]})"
    return ""


def mtlx_surface(src: MtlxSource):
    """The surface shader node (MtlxNode) of the material ``src`` names, or (None, reason)."""
    doc, err = load_document(src.file)
    if doc is None:
        return None, err
    mat = doc.getChild(src.material)
    inp = mat.getInput("surfaceshader") if mat is not None else None
    if inp is None:
        return None, f"material {src.material!r} has no surfaceshader input"
    port = MtlxNode(mat, os.path.dirname(src.file))._port(inp)
    if port is None or port.src is None:
        return None, f"material {src.material!r} has no connected surface shader"
    return port.src, ""


def composition_note(error_text: str) -> str | None:
    """For a USD composition error about a ``.mtlx`` asset, the message the user needs (the
    file, why USD cannot compose it, that the bake reads it anyway), else None. For callers
    that report composition errors (usdahd.usd.stage)."""
    import re

    m = re.search(r"@([^@]+?\.mtlx)(?::SDF_FORMAT_ARGS[^@]*)?@", error_text, re.IGNORECASE)
    if not m:
        return None
    path = m.group(1)
    if "Cannot determine file format" in error_text:
        why = "the usd-core wheel has no usdMtlx file-format plugin"
    else:
        why = one_line(error_text, 160)
    return (
        f"MaterialX file {path} could not be composed ({why}); the bake reads the materials "
        "bound from it with the MaterialX library (docs/usd-semantics.md, Materials)"
    )
