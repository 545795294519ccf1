"""kernels/splat/lens_projection.py against its Dr.Jit oracle (research/oracles/lens.py), per lens model:
means2d, conics, depths, colours and opacities and the VJPs of the splat parameters, the pose and the
intrinsics, in float64 to 1e-10 relative (the oracle's AD supplies the lens's second derivatives that
drlab's backward writes by hand)."""

from __future__ import annotations

import numpy as np
import pytest

from research.oracles.cases.lens import CASES, OUTPUTS, PARAMS
from tests.oracles.conftest import close64


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name.split(", ")[1].split(" ")[0])
def test_lens_projection_float64(case):
    _, drlab, oracle = case.build(np.float64, {"lens_splats": 60}, 0)
    (dv, dg), (ov, og) = drlab(np.float64), oracle(np.float64)
    for name, a, b in zip(OUTPUTS, dv, ov):
        close64(name, a, b)
    for name, a, b in zip((*PARAMS, "pose", "intrinsics"), dg, og):
        close64(f"d {name}", a, b)
