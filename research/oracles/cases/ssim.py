"""SSIM against its Dr.Jit oracle (research/oracles/ssim.py): an image pair (map, d/dx, d/dy).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: img, the side of the image pair (3 channels).
SIZES = {
    "full": dict(img=256),
    "quick": dict(img=128),
    "smoke": dict(img=24),
}


def case_ssim(dt, S, seed):
    from kernels import ssim as kssim
    from research.oracles.ssim import ssim_oracle

    rng = Rounded(seed)
    shape = (S["img"], S["img"], 3)
    y = rng.uniform(0, 1, shape)
    x = np.clip(y + rng.normal(0, 0.1, shape), 0, 1)
    g = rng.normal(size=shape)

    def drlab(t):
        st = kssim.ssim_map(x.astype(t), y.astype(t))
        return [st.map], list(kssim.ssim_map_backward(st, g.astype(t)))

    def oracle(t):
        m, (gx, gy) = ssim_oracle(x.astype(dt).astype(t), y.astype(dt).astype(t), g.astype(dt).astype(t))
        return [m], [gx, gy]

    return f"{shape[0]}x{shape[1]}x3", drlab, oracle


CASES = [
    Case("SSIM map", case_ssim),
]
