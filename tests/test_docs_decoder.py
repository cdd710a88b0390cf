"""The decoder written from docs/schema.md alone (tests/docs_decoder.py) against the package.

Every model and ratio is baked synthetically (tests/data/validate/make_assets.py: usdahd's fit,
encode and image writer, no path tracing), then read back two ways: by the docs-only decoder
(pxr + OpenImageIO + the page's tables and formulas) and by usdahd's own validator.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd

import usdahd.usd  # noqa: F401
from usdahd import models
from usdahd import validate as V
from usdahd.numerics import sh as shm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "data" / "validate"))
import make_assets as MA  # noqa: E402

from tests import docs_decoder as DD  # noqa: E402

VARIANTS = [(m, r) for m in models.names() for r in models.get(m).RATIOS]


def test_the_decoder_does_not_import_usdahd():
    text = (ROOT / "tests" / "docs_decoder.py").read_text()
    assert "import usdahd" not in text and "from usdahd" not in text
    assert len(VARIANTS) == 14  # 9 models; IrradZ x 2 ratios, sh_l1 x 3 variants


@pytest.fixture(scope="module")
def bakes(tmp_path_factory):
    top = tmp_path_factory.mktemp("docs_decoder")
    return {v: MA.bake(top / f"{v[0]}_{v[1]}", model=v[0], ratio=v[1], seed=4) for v in VARIANTS}


@pytest.mark.parametrize("variant", VARIANTS, ids=[f"{m}-{r}" for m, r in VARIANTS])
def test_docs_decoder_matches_the_package(bakes, variant):
    model, ratio = variant
    stage = Usd.Stage.Open(str(bakes[variant]))
    prim = stage.GetPrimAtPath(MA.PRIM)
    doc = DD.read_prim(prim)
    assert (doc["model"], doc["ratio"]) == variant
    cov = doc["covered"]
    texels = {role: a[cov] for role, a in doc["stored"].items()}
    q = DD.quantities(doc["layout"], texels, doc["factors"])
    dirs = shm.fibonacci_sphere(32, hemisphere=True)
    n = np.broadcast_to(dirs, (int(cov.sum()),) + dirs.shape)
    got = DD.irradiance(model, ratio, {k: v[:, None] for k, v in q.items()}, n)

    bake = V.load_bake(prim)  # usdahd: same files, its own reader and decoder
    pkg = bake.mod.evaluate(bake.params, n).astype(np.float64)
    order = np.lexsort((bake.xy[:, 0], bake.xy[:, 1]))  # row-major like np.nonzero
    scale = np.abs(got).max()
    # Same codes decoded twice: float32 (package) vs float64 (docs); C_d = .../d_z amplifies.
    np.testing.assert_allclose(pkg[order], got, atol=2e-5 * scale, err_msg=str(variant))

    # Within the documented quantization of the unquantized fit (validate's derived bound).
    iz = [f for f in V.check_iz(prim) if f.rule == "IzCheck"]
    assert [f.code for f in iz] == ["IzOk"], iz[0].message
    assert iz[0].data["worst_error_over_tolerance"] <= 1.0

    # validate's IzCheck figures, reproduced from the page where it defines the fit.
    figs = DD.iz_figures(doc)
    if figs is not None:
        assert figs["max_relative"] == pytest.approx(iz[0].data["max_relative"], rel=1e-3, abs=1e-7)
        assert figs["mean_relative"] == pytest.approx(
            iz[0].data["mean_relative"], rel=1e-3, abs=1e-8
        )
