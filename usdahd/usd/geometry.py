"""Mesh and gprim geometry: points, topology, primvars, normals, tessellation.

:class:`GeometryReader` turns one UsdGeom.Mesh (or an implicit gprim: Cube, Sphere, Capsule,
Cylinder, Cone, Plane, tessellated as an occluder) at a world transform into a
:class:`usdahd.scene.types.MeshData`: fan triangulation in faceVertex (corner) index space
(:class:`Topology`), counter-clockwise front faces (``orientation`` and mirrored transforms
fixed), world-space float64 points, per-corner unit normals (authored, else the crease-angle /
smooth rule of :mod:`usdahd.usd.normals`, remembered as
:class:`usdahd.scene.types.ComputedNormals` to author), the lightmap UV primvar and the
texture coordinates the mesh's materials read (UsdTransform2d applied), per (t, 3, 2) float32.

A mesh that cannot be used (NaN/Inf points, inconsistent topology, a bad lightmap UV primvar,
zero area, a non-invertible transform, coordinates beyond float32 precision) raises
:class:`MeshFailure` inside the reader and ends up in ``failed`` (a prim that would bake) or
as a warning (an occluder); it never stops the rest of the stage. The traversal that calls
the reader is :mod:`usdahd.usd.reader`; materials come from :mod:`usdahd.usd.materials`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pxr import Usd, UsdGeom

from usdahd.numerics.offsets import FLT_EPS, OFFSET_ULPS
from usdahd.numerics.triangles import triangle_areas
from usdahd.scene.subdiv import cage_from_topology
from usdahd.scene.types import ComputedNormals, MeshData
from usdahd.usd import normals as N
from usdahd.usd.materials import SubsetError

__all__ = ["GeometryReader", "MeshFailure", "Topology", "tessellate", "SINGULAR_DET_REL"]

#: A mesh is unusable when its bounding-box diagonal spans fewer than this many float32 ulps
#: of its largest world coordinate: the tracer stores float32 positions, so its vertices
#: would snap to a grid coarser than 1/32 of its size (normals, texel positions and ray
#: offsets wrong by > 3%). A 1 cm part passes up to ~5 km from the origin.
MIN_SIZE_ULPS = 32.0
#: A baked mesh whose diagonal is below this many times the largest ray offset of the scene
#: gets a warning: rays leaving a triangle start ``OFFSET_ULPS`` float32 ulps of its largest
#: coordinate off it (up to ``OFFSET_ULPS * eps * max |coordinate|``: 1.2 mm on a
#: 160 m ground quad), so rays from the surfaces around such a mesh can start beyond it and its
#: contact shadows and self-occlusion are unreliable.
SMALL_MESH_OFFSETS = 10.0
#: A triangle is degenerate (dropped, with a warning) when twice its area is below this
#: fraction of its mesh's squared bounding-box diagonal: three collinear float32 points give
#: |cross| ~ 6e-8 x diag^2 from rounding, real slivers are far above 1e-10.
DEGENERATE_AREA_REL = 1e-10
#: Transform 3x3 blocks with |det| below this fraction of the product of their row lengths
#: are treated as non-invertible (zero scale or rank < 3).
SINGULAR_DET_REL = 1e-12
#: Value types accepted for a lightmap UV primvar (2 components per value).
UV_TYPES = ("texCoord2f[]", "texCoord2d[]", "texCoord2h[]", "float2[]", "double2[]", "half2[]")


class MeshFailure(Exception):
    """A mesh cannot be used; the message names the prim and what to do (raised and caught
    inside the reader: the mesh goes to ``failed`` or becomes a warning)."""


class GeometryReader:
    """Meshes of one stage read at ``ctx.time`` (see the module docstring).

    ctx : usdahd.usd.reader.ReadContext (time, transforms, warnings); mats :
    usdahd.usd.materials.MaterialReader (the material table meshes index); uv_name : the
    lightmap UV primvar. After the traversal: ``meshes`` (MeshData), per mesh ``texcoords``
    ({varname: (t, 3, 2) float32}), ``instanced`` (bool), ``link_paths`` (the prim path light
    collections are queried by); ``failed`` (prim path -> message), ``computed_normals``
    (prim path -> ComputedNormals).
    """

    def __init__(self, ctx, mats, uv_name):
        self.ctx = ctx
        self.mats = mats
        self.uv_name = uv_name
        self.warn = ctx.warn
        self.get = ctx.get
        self.meshes: list[MeshData] = []
        self.texcoords: list[dict] = []
        self.instanced: list[bool] = []
        self.implicit: dict[int, bool] = {}
        self.failed: dict[str, str] = {}
        self.computed_normals: dict[str, ComputedNormals] = {}
        self.unauthored_scheme: list[str] = []
        self.computed_instanced = 0
        self.link_paths: list[str] = []  # per mesh: the prim path collections are queried by
        self.instancer: str | None = None  # the PointInstancer being expanded
        #: InstanceRef of the instance copy being read (set by the traversal), else None
        self.instance_ref = None

    def fail(self, path: str, msg: str, bakeable: bool, key: str | None = None) -> None:
        """A mesh is unusable: a failed prim if it would be baked, else a warning (once per
        ``key``: one warning for all instances of a prototype)."""
        if bakeable:
            self.failed[path] = msg
        else:
            self.warn(f"{msg} (occluder dropped; same for its other instances)", key=key)

    def size_warnings(self) -> None:
        """One warning naming the baked meshes too small for the tracer's ray offsets
        (SMALL_MESH_OFFSETS times the largest)."""
        if not self.meshes:
            return
        big = max(float(np.abs(m.points).max(initial=0.0)) for m in self.meshes)
        offset = OFFSET_ULPS * FLT_EPS * big  # the largest ray offset of the scene
        small = []
        for m in self.meshes:
            d = float(np.linalg.norm(m.points.max(axis=0) - m.points.min(axis=0)))
            if m.bake and d < SMALL_MESH_OFFSETS * offset:
                small.append(f"{m.path} ({d:.3g} units)")
        if small:
            more = f" and {len(small) - 5} more" if len(small) > 5 else ""
            self.warn(
                f"{len(small)} baked meshes are very small, under {SMALL_MESH_OFFSETS:g}x the "
                f"scene's largest ray offset {offset:.3g}: {', '.join(small[:5])}{more}; rays "
                "from the surfaces around them start up to that far off, so their lighting is "
                "approximate (the offset grows with the largest coordinate: a huge ground plane "
                "or a stray far-away prim)"
            )

    def normals_warnings(self) -> None:
        """One warning per stage naming the meshes whose normals were computed, and one for
        those that leave subdivisionScheme unauthored (see docs/schema.md, Normals)."""

        def names(paths):
            more = f" and {len(paths) - 3} more" if len(paths) > 3 else ""
            return ", ".join(paths[:3]) + more

        comp = sorted(self.computed_normals)
        if comp or self.computed_instanced:
            rules = sorted({self.computed_normals[p].rule for p in comp}) or [N.RULE_CREASE]
            copies = (
                f" and {self.computed_instanced} instanced copies"
                if self.computed_instanced
                else ""
            )
            self.warn(
                f"{len(comp)} meshes{copies} author no normals ({names(comp)}): normals "
                f"computed by the {' / '.join(rules)} rule (crease angle "
                f"{N.CREASE_ANGLE_DEG:g} degrees, angle-weighted; smooth for catmullClark/loop) "
                "and authored into the output layer for baked meshes; author normals to choose "
                "the shading yourself (docs/schema.md#normals)",
                key="normals:computed",
            )
        if self.unauthored_scheme:
            p = sorted(set(self.unauthored_scheme))
            self.warn(
                f"{len(p)} meshes leave subdivisionScheme unauthored ({names(p)}): USD's "
                "fallback is catmullClark (a subdividing renderer smooths them and ignores "
                "their authored normals), but usdahd bakes the polygons as they are, with their "
                "normals or, without normals, crease-angle normals (as RTX renders unsubdivided "
                'meshes without normals faceted); author subdivisionScheme = "none" (or '
                '"catmullClark" to bake the refined smooth surface) to say which you mean',
                key="normals:scheme",
            )

    def guarded(self, fn, prim, xform, path, instanced):
        """Run a mesh/gprim extractor; per-mesh problems become failures, not exceptions."""
        try:
            fn(prim, xform, path, instanced)
        except MeshFailure as exc:
            bakeable = prim.IsA(UsdGeom.Mesh) and not instanced
            src = prim.GetPrimInPrototype() if prim.IsInstanceProxy() else prim
            self.fail(path, str(exc), bakeable, key=f"fail:{src.GetPath()}")

    # --------------------------------------------------------------------- meshes
    def mesh(self, prim, xform, path, instanced, bake=True):
        """Read a UsdGeom.Mesh at world transform ``xform`` (4, 4) (row vectors, Gf layout)
        into ``meshes`` (or skip it with a warning). Raises MeshFailure."""
        mesh = UsdGeom.Mesh(prim)
        pts = self.get(mesh.GetPointsAttr())
        counts = self.get(mesh.GetFaceVertexCountsAttr())
        idx = self.get(mesh.GetFaceVertexIndicesAttr())
        n_pts = 0 if pts is None else len(pts)
        n_faces = 0 if counts is None else len(counts)
        if n_pts == 0 and n_faces == 0:
            self.warn(f"{path}: empty mesh (no points, no faces): skipped")
            return
        if n_faces == 0 or idx is None or len(idx) == 0:
            self.warn(f"{path}: mesh has {n_pts} points but no faces: skipped")
            return
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        counts = np.asarray(counts, dtype=np.int64)
        idx = np.asarray(idx, dtype=np.int64)
        bad = ~np.all(np.isfinite(pts), axis=1)
        if bad.any():
            first = int(np.argmax(bad))
            kind = "NaN" if np.isnan(pts[bad]).any() else "Inf"
            raise MeshFailure(
                f"{path}: points contain {kind} ({int(bad.sum())} of {len(pts)}, first at "
                f"index {first}: {tuple(pts[first].tolist())}); fix or re-export the geometry"
            )
        if np.any(counts < 0):
            raise MeshFailure(
                f"{path}: faceVertexCounts has negative entries; fix or re-export the geometry"
            )
        if counts.sum() != len(idx):
            raise MeshFailure(
                f"{path}: faceVertexCounts sum to {int(counts.sum())} but faceVertexIndices has "
                f"{len(idx)} entries; fix or re-export the geometry"
            )
        if idx.min() < 0 or idx.max() >= len(pts):
            raise MeshFailure(
                f"{path}: faceVertexIndices out of range [0, {len(pts)}) "
                f"(min {int(idx.min())}, max {int(idx.max())}); fix or re-export the geometry"
            )
        if np.any(counts < 3):
            self.warn(f"{path}: {int((counts < 3).sum())} faces with fewer than 3 vertices ignored")
            if not np.any(counts >= 3):
                self.warn(f"{path}: no face with 3 or more vertices: skipped")
                return
        left = self.get(mesh.GetOrientationAttr()) == UsdGeom.Tokens.leftHanded
        sda = mesh.GetSubdivisionSchemeAttr()
        sd = str(self.get(sda)) if sda.HasAuthoredValue() else None
        if sd not in (None, UsdGeom.Tokens.none, *N.SMOOTH_SCHEMES):
            self.warn(
                f"{path}: subdivisionScheme {sd}: the control cage is baked as is", key="subdiv"
            )
        if sd in N.SMOOTH_SCHEMES:
            self._subdiv_tags(mesh, path, sd)
        try:
            face_mat = self.mats.face_materials(prim, len(counts), path)
        except SubsetError as exc:
            raise MeshFailure(str(exc)) from None
        ctx = Topology(counts, idx)
        if sd is None:
            self.unauthored_scheme.append(path)
        self._emit(prim, xform, path, pts, ctx, left, face_mat, instanced, bake, scheme=sd)

    def _emit(
        self,
        prim,
        xform,
        path,
        pts,
        topo,
        left,
        face_mat,
        instanced,
        bake,
        implicit=False,
        scheme=None,
    ):
        m3 = xform[:3, :3]
        check_transform(xform, path)
        flip = left ^ (np.linalg.det(m3) < 0)
        corners = topo.corners.copy()
        if flip:
            corners = corners[:, [0, 2, 1]]
        wp = pts @ m3 + xform[3, :3]
        if not np.all(np.isfinite(wp)):
            raise MeshFailure(
                f"{path}: world-space points overflow to Inf (transform scale too large); "
                "fix the transform"
            )
        check_precision(wp, path)
        corners, keep = drop_degenerate(wp, topo, corners, path, self.warn)
        if len(corners) == 0:
            raise MeshFailure(
                f"{path}: zero surface area (every triangle is degenerate: points coincide or "
                "lie on one line); fix or delete the mesh"
            )
        face = topo.face[keep]
        tri = topo.idx[corners].astype(np.int32)
        normals = None
        if not implicit:
            normals = self._authored_normals(prim, topo, corners, m3, path)
        computed = None
        if normals is None:
            rule = N.rule_for_scheme(scheme)
            fv = N.compute_normals(pts, topo.counts, topo.idx, rule, left_handed=left)
            normals = N.to_world(fv[corners], m3)
            if not implicit and not instanced:
                computed = ComputedNormals(rule, fv, self._normals_attr(prim))
            elif not implicit:
                self.computed_instanced += 1  # copies of a prototype: counted, not authored
                if self.instance_ref is not None:
                    self.instance_ref = replace(self.instance_ref, normals=rule)
        uv = None
        texcoords = {}
        if not implicit:
            uv = self._primvar2(prim, self.uv_name, topo, corners, path)
            used = np.flatnonzero(np.bincount(face_mat)) if face_mat.min() >= 0 else face_mat
            for mi in np.unique(used):  # bincount first: O(faces), not a sort or hash of all
                name = self.mats.materials[mi].texcoord
                if (
                    any(
                        t is not None
                        for t in (
                            self.mats.materials[mi].albedo_tex,
                            self.mats.materials[mi].emission_tex,
                            self.mats.materials[mi].opacity_tex,
                        )
                    )
                    and name not in texcoords
                ):
                    base, a, b = self.mats.tc_transforms.get(name, (name, None, None))
                    tc = (
                        uv
                        if base == self.uv_name
                        else self._primvar2(prim, base, topo, corners, path)
                    )
                    if tc is not None and a is not None:  # UsdTransform2d (affine: exact)
                        tc = (tc.astype(np.float64) @ a.T + b).astype(np.float32)
                    if tc is None:
                        self.warn(
                            f"{path}: material texture reads primvar '{base}' which the "
                            "mesh lacks; texture sampled at (0, 0)"
                        )
                    else:
                        texcoords[name] = tc
        md = MeshData(
            path=path,
            points=wp,
            triangles=tri,
            normals=normals.astype(np.float32),
            uv=uv,
            uv_name=self.uv_name,
            material=face_mat[face].astype(np.int32),
            face=face.astype(np.int32),
            corner=corners.astype(np.int32),
            bake=bake and not instanced and not implicit,
            double_sided=bool(UsdGeom.Gprim(prim).GetDoubleSidedAttr().Get()),
            instance=self.instance_ref if instanced and not implicit else None,
        )
        if scheme in N.SMOOTH_SCHEMES and not implicit:  # traced on its refinement
            md.cage = cage_from_topology(scheme, topo.counts, topo.idx, bool(flip))
        self.meshes.append(md)
        self.link_paths.append(self.instancer or str(prim.GetPath()))
        if computed is not None:
            self.computed_normals[path] = computed
        self.texcoords.append(texcoords)
        self.instanced.append(bool(instanced) and not implicit)
        self.implicit[id(md)] = implicit

    def _subdiv_tags(self, mesh, path, scheme) -> None:
        """Warn once per prim about subdivision tags the refinement does not apply (creases,
        corners, holes); see docs/usd-semantics.md, "Subdivision surfaces"."""
        tags = []
        sharp = self.get(mesh.GetCreaseSharpnessesAttr())
        if sharp is not None and len(sharp) and max(sharp) > 0:
            tags.append(f"{len(sharp)} creases")
        corner = self.get(mesh.GetCornerSharpnessesAttr())
        if corner is not None and len(corner) and max(corner) > 0:
            tags.append(f"{len(corner)} corners")
        holes = self.get(mesh.GetHoleIndicesAttr())
        if holes is not None and len(holes):
            tags.append(f"{len(holes)} holes")
        if tags:
            self.warn(
                f"{path}: subdivisionScheme {scheme} with {', '.join(tags)}: usdahd refines the "
                "surface smooth everywhere (creases, corners and holes are not applied), so "
                "sharp features bake rounded; split the sharp parts into a mesh with "
                'subdivisionScheme = "none" if that matters',
                key=f"subdiv-tags:{path}",
            )

    def _primvar_corner_values(self, pv, topo, path, width, strict=False):
        """Expand a primvar to per faceVertex (corner) values (len(idx), width) or None.

        strict (the lightmap UV set): a wrong type, interpolation, length or index raises
        MeshFailure; otherwise (normals, material texcoords) those warn and return None,
        except a too-short array, which always fails the mesh.
        """
        name = pv.GetName()

        def bad(msg):
            if strict:
                raise MeshFailure(f"{path}: {msg}")
            self.warn(f"{path}: {msg} (ignored)")
            return None

        tname = str(pv.GetTypeName())
        if strict and tname not in UV_TYPES:
            return bad(
                f"lightmap UV primvar {name} is {tname}, expected texCoord2f[] (or float2[]); "
                "re-author it as texCoord2f[] or pick another UV set with --uv"
            )
        if strict and pv.GetInterpolation() in (UsdGeom.Tokens.uniform, UsdGeom.Tokens.constant):
            return bad(
                f"lightmap UV primvar {name} has {pv.GetInterpolation()} interpolation (one UV "
                "per face or per mesh); a lightmap needs faceVarying or vertex UVs: re-author "
                "it or pick another UV set with --uv"
            )
        t = self.ctx.time
        if pv.GetAttr().Get(t) is None and pv.GetAttr().GetNumTimeSamples():
            t = Usd.TimeCode(pv.GetAttr().GetTimeSamples()[0])
        raw = pv.GetAttr().Get(t)
        if raw is None or len(raw) == 0:
            return None
        if pv.IsIndexed():
            ind = pv.GetIndices(t)
            ind = np.asarray(ind if ind is not None else [], np.int64)
            if len(ind) and (ind.min() < 0 or ind.max() >= len(raw)):
                return bad(
                    f"primvar {name} indices out of range [0, {len(raw)}) (min {int(ind.min())},"
                    f" max {int(ind.max())}); fix {name}:indices"
                )
        vals = pv.ComputeFlattened(t)
        if vals is None or len(vals) == 0:
            return None
        try:
            v = np.asarray(vals, dtype=np.float64).reshape(len(vals), -1)
        except (TypeError, ValueError):
            return bad(f"primvar {name} of type {tname} is not numeric")
        if v.shape[1] != width:
            return bad(f"primvar {name} ({tname}) has {v.shape[1]} components, expected {width}")
        interp = pv.GetInterpolation()
        need, sel = topo.selection(interp, fallback=UsdGeom.Tokens.constant)
        if len(v) < need:
            raise MeshFailure(
                f"{path}: primvar {name} ({interp}) has {len(v)} values, needs {need}; "
                "fix or re-export it"
            )
        return v[sel]

    def _primvar2(self, prim, name, topo, corners, path):
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        if not pv or not pv.HasValue():
            return None
        strict = name == self.uv_name
        v = self._primvar_corner_values(pv, topo, path, 2, strict=strict)
        if v is None:
            return None
        v = v[corners]
        bad = ~np.isfinite(v)
        if bad.any():
            kind = "NaN" if np.isnan(v[bad]).any() else "Inf"
            msg = f"{path}: primvar {pv.GetName()} contains {kind} ({int(bad.sum())} values)"
            if strict:
                raise MeshFailure(f"{msg}; fix the UVs or pick another UV set with --uv")
            self.warn(f"{msg}: texture sampled at 0 there")
            v = np.where(bad, 0.0, v)
        return v.astype(np.float32)

    def _authored_normals(self, prim, topo, corners, m3, path):
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
        if pv and pv.HasValue():
            v = self._primvar_corner_values(pv, topo, path, 3)
        else:
            attr = UsdGeom.Mesh(prim).GetNormalsAttr()
            vals = self.get(attr)
            if vals is None or len(vals) == 0:
                return None
            interp = UsdGeom.Mesh(prim).GetNormalsInterpolation()
            v = np.asarray(vals, dtype=np.float64).reshape(-1, 3)
            need, sel = topo.selection(interp, fallback=UsdGeom.Tokens.vertex)
            if len(v) < need:
                self.warn(
                    f"{path}: {len(v)} normals for {interp} interpolation (needs {need}); "
                    "normals recomputed"
                )
                return None
            v = v[sel]
        if v is None:
            return None
        v = v[corners]
        ln = np.linalg.norm(v, axis=-1)
        if not np.all(np.isfinite(v)) or np.any(ln < 1e-12):
            self.warn(f"{path}: degenerate or NaN authored normals; normals recomputed")
            return None
        return N.to_world(v, m3)

    @staticmethod
    def _normals_attr(prim) -> str:
        """The attribute a renderer reads normals from: ``primvars:normals`` when the mesh has
        one (it wins over ``normals``), else ``normals``; the bake authors computed ones there."""
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("normals")
        return "primvars:normals" if pv and pv.HasAuthoredValue() else "normals"

    # --------------------------------------------------------------------- implicit gprims
    def implicit_gprim(self, prim, xform, path, instanced):
        """Tessellate an implicit gprim (:func:`tessellate`) into ``meshes`` as an occluder."""
        pts, tris = tessellate(prim, self.get)
        if pts is None:
            self.warn(
                f"{path}: {prim.GetTypeName()} gprims are not supported (ignored)",
                key=f"gprim:{prim.GetTypeName()}",
            )
            return
        counts = np.full(len(tris), 3, np.int64)
        topo = Topology(counts, tris.reshape(-1).astype(np.int64))
        face_mat = self.mats.face_materials(prim, len(tris), path)
        self._emit(prim, xform, path, pts, topo, False, face_mat, instanced, False, implicit=True)


class Topology:
    """Fan triangulation of a polygon mesh in faceVertex (corner) index space.

    counts : (f,) int64 faceVertexCounts; idx : (c,) int64 faceVertexIndices. After init:
    ``face`` (t,) source polygon of each fan triangle, ``corners`` (t, 3) indices into idx
    (polygon k's triangles are (s, s+j+1, s+j+2), s its first corner).
    """

    def __init__(self, counts, idx):
        self.counts = counts
        self.idx = idx
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        ntri = np.maximum(counts - 2, 0)
        face = np.repeat(np.arange(len(counts)), ntri)
        first = np.concatenate([[0], np.cumsum(ntri)[:-1]])
        k = np.arange(len(face)) - first[face]
        s = start[face]
        self.face = face
        self.corners = np.stack([s, s + k + 1, s + k + 2], axis=1)

    def selection(self, interp: str, fallback: str = "constant"):
        """How a primvar of interpolation ``interp`` maps to corners: (need, sel), the number
        of values it must have and (c,) int64 the value index of each corner (faceVarying:
        the corner itself; vertex/varying: its point; uniform: its face; constant: 0).
        An unknown token is read as ``fallback`` (primvars: constant; ``normals``: vertex)."""
        kinds = ("faceVarying", "vertex", "varying", "uniform", "constant")
        interp = interp if interp in kinds else fallback
        n_corner = len(self.idx)
        if interp == "faceVarying":
            return n_corner, np.arange(n_corner)
        if interp in ("vertex", "varying"):
            return int(self.idx.max()) + 1, self.idx
        if interp == "uniform":
            return len(self.counts), np.repeat(np.arange(len(self.counts)), self.counts)
        return 1, np.zeros(n_corner, np.int64)


def check_transform(xform, path) -> None:
    """Raise MeshFailure for a NaN/Inf or non-invertible local-to-world transform."""
    if not np.all(np.isfinite(xform)):
        raise MeshFailure(
            f"{path}: world transform contains NaN/Inf; fix the xformOps of the prim or its "
            "ancestors"
        )
    m3 = xform[:3, :3]
    rows = np.linalg.norm(m3, axis=1)
    det = abs(float(np.linalg.det(m3)))
    if rows.min() == 0.0 or det <= SINGULAR_DET_REL * float(np.prod(rows)):
        what = "a zero scale" if rows.min() == 0.0 else "rank < 3"
        raise MeshFailure(
            f"{path}: world transform is not invertible ({what}, determinant {det:.3g}), so "
            "the mesh is flattened and its normals are undefined; fix the xformOps of the prim "
            "or its ancestors"
        )


def check_precision(wp, path) -> None:
    """Raise MeshFailure when float32 cannot resolve the mesh at its position."""
    far = float(np.abs(wp).max())
    size = float(np.linalg.norm(wp.max(axis=0) - wp.min(axis=0)))
    ulp = float(np.spacing(np.float32(far)))
    if size < MIN_SIZE_ULPS * ulp and far > 0:
        raise MeshFailure(
            f"{path}: {size:.3g} units across at coordinate {far:.3g}: beyond float32 "
            f"ray-tracing precision (ulp {ulp:.3g} there); move it nearer the origin "
            "(re-centre the stage)"
        )


def drop_degenerate(wp, topo, corners, path, warn):
    """Drop zero-area triangles (DEGENERATE_AREA_REL); returns (corners, keep mask)."""
    tri = topo.idx[corners]
    area2 = 2.0 * triangle_areas(wp[tri])
    diag = float(np.linalg.norm(wp.max(axis=0) - wp.min(axis=0)))
    keep = area2 > DEGENERATE_AREA_REL * diag * diag
    n_bad = int((~keep).sum())
    if n_bad and keep.any():
        dropped = topo.face[~keep]  # non-decreasing (fan triangles in face order): O(n) count
        faces = 1 + int(np.count_nonzero(np.diff(dropped)))
        warn(
            f"{path}: {n_bad} degenerate (zero-area) triangles in {faces} faces dropped "
            "(repeated or collinear points)"
        )
    return corners[keep], keep


# ----------------------------------------------------------------------------- tessellation


def tessellate(prim, get):
    """Local-space (points (v,3), triangles (t,3)) of an implicit gprim, CCW outward."""
    g = get
    if prim.IsA(UsdGeom.Cube):
        s = 0.5 * float(g(UsdGeom.Cube(prim).GetSizeAttr(), 2.0))
        p = np.array([[x, y, z] for x in (-s, s) for y in (-s, s) for z in (-s, s)], float)
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        t = [(q[0], q[1], q[2]) for q in quads] + [(q[0], q[2], q[3]) for q in quads]
        return p, np.array(t, np.int64)
    if prim.IsA(UsdGeom.Sphere):
        r = float(g(UsdGeom.Sphere(prim).GetRadiusAttr(), 1.0))
        return _revolve(
            np.linspace(0, np.pi, 13), lambda th: (r * np.sin(th), -r * np.cos(th)), "Z"
        )
    if prim.IsA(UsdGeom.Capsule):
        c = UsdGeom.Capsule(prim)
        r = float(g(c.GetRadiusAttr(), 0.5))
        h = float(g(c.GetHeightAttr(), 1.0))
        ax = str(g(c.GetAxisAttr(), "Z"))
        th = np.linspace(0, np.pi, 13)
        rr = np.concatenate([r * np.sin(th[:7]), r * np.sin(th[6:])])
        zz = np.concatenate([-0.5 * h - r * np.cos(th[:7]), 0.5 * h - r * np.cos(th[6:])])
        return _revolve_profile(rr, zz, ax)
    if prim.IsA(UsdGeom.Cylinder) or prim.IsA(UsdGeom.Cone):
        is_cyl = prim.IsA(UsdGeom.Cylinder)
        sch = UsdGeom.Cylinder(prim) if is_cyl else UsdGeom.Cone(prim)
        r = float(g(sch.GetRadiusAttr(), 1.0))
        h = float(g(sch.GetHeightAttr(), 2.0))
        ax = str(g(sch.GetAxisAttr(), "Z"))
        rtop = r if is_cyl else 0.0
        return _revolve_profile(
            np.array([0, r, rtop, 0]), np.array([-h / 2, -h / 2, h / 2, h / 2]), ax
        )
    if prim.IsA(UsdGeom.Plane):
        pl = UsdGeom.Plane(prim)
        w = 0.5 * float(g(pl.GetWidthAttr(), 2.0))
        ln = 0.5 * float(g(pl.GetLengthAttr(), 2.0))
        ax = str(g(pl.GetAxisAttr(), "Z"))
        p = np.array([[-w, -ln, 0], [w, -ln, 0], [w, ln, 0], [-w, ln, 0]], float)
        p = _axis(p, ax)
        return p, np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return None, None


def _axis(p, ax):
    if ax == "X":
        return p[:, [2, 0, 1]]
    if ax == "Y":
        return p[:, [1, 2, 0]]
    return p


def _revolve(th, fn, ax):
    r, z = fn(th)
    return _revolve_profile(np.asarray(r), np.asarray(z), ax)


def _revolve_profile(r, z, ax, n_phi=24):
    """Surface of revolution of the profile (r_i, z_i) (bottom to top) about z."""
    phi = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    p = np.stack(
        [
            r[:, None] * np.cos(phi)[None, :],
            r[:, None] * np.sin(phi)[None, :],
            np.broadcast_to(z[:, None], (len(r), n_phi)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    tris = []
    for i in range(len(r) - 1):
        for j in range(n_phi):
            a = i * n_phi + j
            b = i * n_phi + (j + 1) % n_phi
            c = (i + 1) * n_phi + j
            d = (i + 1) * n_phi + (j + 1) % n_phi
            tris += [(a, b, d), (a, d, c)]
    t = np.array(tris, np.int64)
    good = 2.0 * triangle_areas(p[t]) > 1e-12
    return _axis(p, ax), t[good]
