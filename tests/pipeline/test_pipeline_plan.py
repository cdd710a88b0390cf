"""usdahd/pipeline/plan.py: the PrimJob every stage fills in has a real type per field."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np

from usdahd.bake.types import Texels
from usdahd.pipeline.plan import PrimJob
from usdahd.scene.types import ComputedNormals, MeshData
from usdahd.usd.schema import BakeResults


def test_prim_job_fields_resolve_to_concrete_types():
    hints = typing.get_type_hints(
        PrimJob,
        localns={
            "Texels": Texels,
            "ComputedNormals": ComputedNormals,
            "MeshData": MeshData,
            "BakeResults": BakeResults,
        },
    )
    assert set(hints) == {f.name for f in dataclasses.fields(PrimJob)}
    for name, hint in hints.items():  # no untyped slot (a dict's values may be Any)
        options = typing.get_args(hint) if typing.get_origin(hint) is not dict else ()
        assert not {object, typing.Any} & {hint, *options}, (name, hint)
    assert hints["texels"] == Texels | None
    assert hints["sh"] == hints["charts"] == hints["uv_primvar_values"] == np.ndarray | None
    for name in ("previous", "fallback", "results"):
        assert hints[name] == BakeResults | None


class _Texels:
    """What _uv_problem reads of a rasterisation: the covered count and its stats."""

    def __init__(self, covered: int, overlap: int):
        self.n, self.stats = covered, {"overlap_texels": overlap, "uv_outside_fraction": 0.0}

    def __len__(self) -> int:
        return self.n


def test_one_uv_overlap_limit_for_the_baker_and_the_validator():
    from usdahd.numerics.raster import UV_OVERLAP_LIMIT
    from usdahd.pipeline.plan import _uv_problem
    from usdahd.validate.options import Options

    at = round(UV_OVERLAP_LIMIT * 10000)
    assert _uv_problem(_Texels(10000, at)) is None
    assert _uv_problem(_Texels(10000, at + 1)) == "overlaps itself on 1% of its texels"
    assert Options().uv_overlap == UV_OVERLAP_LIMIT
