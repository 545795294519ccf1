"""Adam (Kingma & Ba, ICLR 2015) as one elementwise Warp kernel: the optimiser of every fit.

Per parameter group p with gradient g, zero-initialised moments m, v and a step count t of
its own (1-based after the first step):

    m <- b1 m + (1 - b1) g,    v <- b2 v + (1 - b2) g^2,
    p <- p - lr (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps).

This is PyTorch's Adam (which NeRF codebases and 3DGS use): PyTorch writes the denominator
sqrt(v) / sqrt(1 - b2^t) + eps, the same number up to rounding. One thread per run of BLOCK
consecutive elements, and every thread writes only its own elements, so the launch splits across CPU threads
(kernels.launch). The hyper-parameters reach the kernel as float64 (a Python float passed to a
Warp `float` parameter would be rounded to float32, which costs float64 groups about 1e-7 of
relative accuracy) and are rounded once to the group's dtype. Groups are float32 or float64
arrays, NumPy (updated in place through a zero-copy view, CPU only) or wp.arrays on any device. Rows can be kept (`select`) or added
with zero moments (`append`) as 3DGS densification does; its optimiser keeps each group's step
count across such edits, and so does this one. warp.optim.Adam exists but takes float32 only
and keeps one step count for all groups.
"""

from __future__ import annotations

import typing
from typing import Any, Mapping

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.launch import DEFAULT_MIN_CHUNK, launch_split

wp.set_module_options({"enable_backward": False})


# Elements per CPU kernel thread (1 on CUDA): a thread updates a run of BLOCK consecutive elements, so the per-thread
# cost of a Warp CPU launch (the kernel function called once per thread, every argument reloaded and
# the hyper-parameters converted again) is paid once per run. Each element's arithmetic is unchanged.
BLOCK = 16


@wp.kernel
def _adam_kernel(param: wp.array(dtype=typing.Any), grad: wp.array(dtype=typing.Any),
                 m: wp.array(dtype=typing.Any), v: wp.array(dtype=typing.Any),
                 lr: wp.float64, b1: wp.float64, b2: wp.float64, eps: wp.float64,
                 bias1: wp.float64, bias2: wp.float64, block: int, offset: int):
    run = wp.tid() + offset
    one = param.dtype(1.0)
    b1_t = param.dtype(b1)
    b2_t = param.dtype(b2)
    lr_t = param.dtype(lr)
    bias1_t = param.dtype(bias1)
    bias2_t = param.dtype(bias2)
    eps_t = param.dtype(eps)
    for i in range(run * block, wp.min(param.shape[0], (run + 1) * block)):
        g = grad[i]
        mi = b1_t * m[i] + (one - b1_t) * g
        vi = b2_t * v[i] + (one - b2_t) * g * g
        m[i] = mi
        v[i] = vi
        param[i] = param[i] - lr_t * (mi / bias1_t) / (wp.sqrt(vi / bias2_t) + eps_t)


def _flat_view(name: str, x: Any) -> wp.array:
    """A flat wp.array sharing memory with the float array `x` (NumPy arrays must be contiguous)."""
    if isinstance(x, wp.array):
        A.float_dtype(name, x)
        if not x.is_contiguous:
            raise ValueError(f"{name}: expected a contiguous wp.array")
        return x.reshape(-1)
    if not isinstance(x, np.ndarray):
        raise ValueError(f"{name}: expected a NumPy array or a wp.array, got {type(x).__name__}")
    dtype = A.float_dtype(name, x)
    if not x.flags.c_contiguous:
        raise ValueError(f"{name}: expected a C-contiguous NumPy array (updated in place)")
    return wp.array(x.reshape(-1), dtype=dtype, device="cpu", copy=False)


class Adam:
    """Adam over named parameter groups, updated in place; see the module docstring.

    `params` maps names to arrays; `lr` is one rate or one per name (`self.lr` may be changed
    between steps, for schedules). `step(grads)` updates `self.params`; pass `params=` to step
    arrays that replaced them (a model whose arrays were reallocated).
    """

    def __init__(self, params: Mapping[str, Any], lr: float | Mapping[str, float] = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        if not params:
            raise ValueError("params: expected at least one parameter group")
        self.params = dict(params)
        if isinstance(lr, Mapping):
            unknown = set(lr) ^ set(self.params)
            if unknown:
                raise ValueError(f"lr: expected one rate per parameter {sorted(self.params)}, "
                                 f"mismatch {sorted(unknown)}")
        self.lr = {k: A.check_float(f"lr[{k!r}]", lr[k] if isinstance(lr, Mapping) else lr, nonnegative=True)
                   for k in self.params}
        if len(betas) != 2 or not all(0.0 <= float(b) < 1.0 for b in betas):
            raise ValueError(f"betas: expected two values in [0, 1), got {tuple(betas)}")
        self.b1, self.b2 = float(betas[0]), float(betas[1])
        self.eps = A.check_float("eps", eps, nonnegative=True)
        self.m = {k: self._zeros_like(k, p) for k, p in self.params.items()}
        self.v = {k: self._zeros_like(k, p) for k, p in self.params.items()}
        self.t = {k: 0 for k in self.params}

    @staticmethod
    def _zeros_like(name: str, p: Any) -> Any:
        _flat_view(f"params[{name!r}]", p)
        return wp.zeros_like(p) if isinstance(p, wp.array) else np.zeros_like(p)

    def step(self, grads: Mapping[str, Any], params: Mapping[str, Any] | None = None) -> None:
        """One Adam step of every group from `grads` (arrays of each parameter's shape and kind)."""
        if params is not None:
            if set(params) != set(self.params):
                raise ValueError(f"params: expected the groups {sorted(self.params)}, got {sorted(params)}")
            self.params = dict(params)
        missing = set(self.params) - set(grads)
        if missing:
            raise ValueError(f"grads: missing gradients for {sorted(missing)}")
        views = {}
        for k, p in self.params.items():  # every check before the first update
            A.check_shape(f"grads[{k!r}]", grads[k], tuple(p.shape))
            A.check_shape(f"params[{k!r}]", p, tuple(self.m[k].shape))
            pv = _flat_view(f"params[{k!r}]", p)
            gv = _flat_view(f"grads[{k!r}]", grads[k])
            if gv.dtype != pv.dtype or gv.device != pv.device:
                raise ValueError(f"grads[{k!r}]: expected dtype {A.type_name(pv.dtype)} on {pv.device} like the "
                                 f"parameter, got {A.type_name(gv.dtype)} on {gv.device}")
            views[k] = (pv, gv, _flat_view("m", self.m[k]), _flat_view("v", self.v[k]))
        for k, (pv, gv, mv, vv) in views.items():
            self.t[k] += 1
            bias1 = 1.0 - self.b1 ** self.t[k]
            bias2 = 1.0 - self.b2 ** self.t[k]
            if pv.size:
                hyper = (self.lr[k], self.b1, self.b2, self.eps, bias1, bias2)
                block = 1 if pv.device.is_cuda else BLOCK  # a GPU thread per element (coalesced accesses)
                launch_split(_adam_kernel, -(-pv.size // block), [pv, gv, mv, vv, *map(wp.float64, hyper), block],
                             device=pv.device, min_chunk=max(1, DEFAULT_MIN_CHUNK // block))

    def select(self, index: Any) -> None:
        """Keep the moments of rows `index` (a boolean mask or indices over the first axis)."""
        for k in self.m:
            self.m[k] = self._rows(self.m[k], index)
            self.v[k] = self._rows(self.v[k], index)

    def append(self, n: int) -> None:
        """Zero moments for `n` new rows at the end of every group."""
        n = A.check_int("n", n, minimum=0)
        for k in self.m:
            self.m[k] = self._grow(self.m[k], n)
            self.v[k] = self._grow(self.v[k], n)

    def reset(self, name: str) -> None:
        """Zero the moments of group `name` (its step count goes on, as in 3DGS's opacity reset)."""
        if name not in self.m:
            raise ValueError(f"name: expected one of {sorted(self.m)}, got {name!r}")
        for state in (self.m[name], self.v[name]):
            state.zero_() if isinstance(state, wp.array) else state.fill(0.0)

    def reset_rows(self, index: Any) -> None:
        """Zero the moments of rows `index` (indices or a boolean mask over the first axis) in every group
        (MCMC relocation: moved splats start afresh); the step counts go on."""
        for k in self.m:
            for state in (self.m[k], self.v[k]):
                if isinstance(state, np.ndarray):
                    state[index] = 0.0
                else:
                    h = state.numpy()
                    h[index] = 0.0
                    wp.copy(state, wp.array(h, dtype=state.dtype, device=state.device))

    @staticmethod
    def _rows(x: Any, index: Any) -> Any:
        if isinstance(x, np.ndarray):
            return np.ascontiguousarray(x[index])
        return wp.array(x.numpy()[index], dtype=x.dtype, device=x.device)

    @staticmethod
    def _grow(x: Any, n: int) -> Any:
        h = x if isinstance(x, np.ndarray) else x.numpy()
        grown = np.concatenate([h, np.zeros((n,) + h.shape[1:], dtype=h.dtype)])
        return grown if isinstance(x, np.ndarray) else wp.array(grown, dtype=x.dtype, device=x.device)


A.declare_float_overloads(_adam_kernel)
