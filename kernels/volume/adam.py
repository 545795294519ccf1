"""Adam (Kingma & Ba 2015) as an elementwise Warp kernel, for float32 and float64 parameters.

For gradient g at step t (1-based), with moments m, v (zero-initialised):

    m <- b1 m + (1 - b1) g,   v <- b2 v + (1 - b2) g^2,
    theta <- theta - lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)

One thread per element (disjoint writes: launch_split). warp.optim.Adam exists but supports
float32 only and runs single-threaded on the CPU.
"""

from __future__ import annotations

import math
import typing

import numpy as np
import warp as wp

from kernels.launch import launch_split
from kernels.volume import _util as U

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _adam_kernel(
    param: wp.array(dtype=typing.Any),
    grad: wp.array(dtype=typing.Any),
    m: wp.array(dtype=typing.Any),
    v: wp.array(dtype=typing.Any),
    lr: float,
    b1: float,
    b2: float,
    eps: float,
    bias1: float,
    bias2: float,
    offset: int,
):
    i = wp.tid() + offset
    g = grad[i]
    mi = param.dtype(b1) * m[i] + (param.dtype(1.0) - param.dtype(b1)) * g
    vi = param.dtype(b2) * v[i] + (param.dtype(1.0) - param.dtype(b2)) * g * g
    m[i] = mi
    v[i] = vi
    param[i] = param[i] - param.dtype(lr) * (mi / param.dtype(bias1)) / (wp.sqrt(vi / param.dtype(bias2)) + param.dtype(eps))


class Adam:
    """Adam over a dict of named wp.arrays (updated in place)."""

    def __init__(self, params: dict[str, wp.array], lr: float | dict[str, float] = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        self.params = params
        self.lr = {k: float(lr[k] if isinstance(lr, dict) else lr) for k in params}
        for k, v in self.lr.items():
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"lr: expected a finite value >= 0 for {k!r}, got {v}")
        if not all(0.0 <= b < 1.0 for b in betas):
            raise ValueError(f"betas: expected values in [0, 1), got {betas}")
        self.b1, self.b2 = float(betas[0]), float(betas[1])
        self.eps = float(eps)
        self.m = {k: wp.zeros_like(p) for k, p in params.items()}
        self.v = {k: wp.zeros_like(p) for k, p in params.items()}
        self.t = 0

    def step(self, grads: dict[str, wp.array]) -> None:
        missing = set(self.params) - set(grads)
        if missing:
            raise ValueError(f"grads: missing gradients for {sorted(missing)}")
        for k, p in self.params.items():
            U.check_shape(f"grads[{k!r}]", grads[k], tuple(p.shape))
        self.t += 1
        bias1 = 1.0 - self.b1**self.t
        bias2 = 1.0 - self.b2**self.t
        for k, p in self.params.items():
            flat = lambda a: a.reshape(-1)  # noqa: E731
            launch_split(_adam_kernel, p.size, [flat(p), flat(grads[k]), flat(self.m[k]), flat(self.v[k]),
                                                self.lr[k], self.b1, self.b2, self.eps, bias1, bias2],
                         device=p.device)
