"""The bilateral-grid slice (kernels/appearance.py) against its Dr.Jit oracle (research/oracles/appearance.py):
the sliced image and the VJPs of the grid and the image, for a bilateral grid and for one affine transform.

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: appearance_img, the side of the square image (3 channels). gsplat's grid is 8 x 16 x 16.
SIZES = {
    "full": dict(appearance_img=256),
    "quick": dict(appearance_img=128),
    "smoke": dict(appearance_img=24),
}


def _case(grid_shape: tuple[int, int, int]):
    def build(dt, S, seed):
        from kernels import appearance as ka
        from research.oracles.appearance import bilateral_slice_oracle

        rng = Rounded(seed)
        n = S["appearance_img"]
        grid = ka.identity_grid(grid_shape, np.float64) + rng.normal(0.0, 0.2, (*grid_shape, ka.ENTRIES))
        rgb = rng.uniform(-0.05, 1.05, (n, n, 3))  # a few lumas outside [0, 1]: the clamp
        cot = rng.normal(size=(n, n, 3))

        def drlab(t):
            g, p = grid.astype(t), rgb.astype(t)
            d = ka.bilateral_slice_backward(g, p, cot.astype(t))
            return [ka.bilateral_slice(g, p)], [d["grid"], d["rgb"]]

        def oracle(t):
            c = lambda v: v.astype(dt).astype(t)  # noqa: E731
            out, d = bilateral_slice_oracle(c(grid), c(rgb), c(cot))
            return [out], [d["grid"], d["rgb"]]

        return f"{n}x{n}x3, grid {'x'.join(map(str, grid_shape))}", drlab, oracle

    return build


CASES = [
    Case("bilateral grid slice", _case((8, 16, 16))),
    Case("per-image affine (1x1x1 grid)", _case((1, 1, 1))),
]
