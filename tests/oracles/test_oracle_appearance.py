"""kernels/appearance.py against its Dr.Jit oracle (research/oracles/appearance.py): the sliced image and the
VJPs of the grid and the image, in float64.

float32 is compared in the oracle_conformance table (reported, not asserted here): a worst-case rounding
bound of the trilinear weights and of the grid's scatter over every pixel lies orders of magnitude above
the errors seen, so it would test little.
"""

from __future__ import annotations

import numpy as np
import pytest

from kernels import appearance as ka
from research.oracles.appearance import bilateral_slice_oracle
from tests.oracles.conftest import close64


@pytest.mark.parametrize("seed, grid_shape, hw", [(0, (8, 5, 6), (23, 19)), (1, (1, 1, 1), (7, 9)),
                                                   (2, (4, 1, 3), (11, 8)), (3, (1, 3, 1), (6, 13))])
def test_float64_slice_and_vjp_match_the_oracle(seed, grid_shape, hw):
    rng = np.random.default_rng(seed)
    grid = ka.identity_grid(grid_shape, np.float64) + rng.normal(0.0, 0.2, (*grid_shape, ka.ENTRIES))
    rgb = rng.uniform(-0.1, 1.1, (*hw, 3))  # some lumas outside [0, 1]: the clamp's zero gradient
    cot = rng.normal(size=(*hw, 3))
    out = ka.bilateral_slice(grid, rgb)
    grads = ka.bilateral_slice_backward(grid, rgb, cot)
    want, want_grads = bilateral_slice_oracle(grid, rgb, cot)
    close64("out", out, want)
    close64("dL/dgrid", grads["grid"], want_grads["grid"])
    close64("dL/drgb", grads["rgb"], want_grads["rgb"])
