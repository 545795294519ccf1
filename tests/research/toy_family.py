"""A toy kernel family, "toy", written the way docs/kernels.md ("Adding a kernel family") says.

    y_i = a_i * x_i^2                       (elementwise, x and a of one shape (N,))

For a cotangent g shaped like y, the VJP of <g, y> is

    dL/dx_i = 2 a_i x_i g_i,        dL/da_i = x_i^2 g_i.

Every part a real family has lives here in one module, so that tests/research/test_toy_family.py can
register it with research.registry (as the module "toy_family", which pytest puts on sys.path) for
the length of a test and check that `drlab gradcheck`, the oracle comparison and `drlab bench` find
it. A real family splits these parts over kernels/<family>, kernels/reference/<family>.py,
research/checks/<family>.py, research/oracles/<family>.py and research/oracles/cases/<family>.py,
research/bench/<family>.py. Importing this module registers its gradient check (like any `checks`
module), so only the test's registration fixture imports it.
"""

from __future__ import annotations

import typing
from typing import Iterator

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs, declare_float_overloads, host_view
from kernels.launch import default_threads
from research.bench import time_medians
from research.gradcheck import GradcheckResult, check_vjp, register_check
from research.oracles import backend
from research.oracles.cases import Case, Rounded

wp.set_module_options({"enable_backward": False})  # the backward is written by hand


# --------------------------------------------------------------------------- 1. the NumPy reference

def square_reference(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The plain float64 NumPy forward the tests compare against (kernels/reference/<family>.py)."""
    return np.asarray(a, np.float64) * np.asarray(x, np.float64) ** 2


# --------------------------------------------------------------------------- 2. plain Warp kernels

@wp.kernel
def _square_kernel(x: wp.array(dtype=typing.Any), a: wp.array(dtype=typing.Any), y: wp.array(dtype=typing.Any),
                   offset: int):
    i = wp.tid() + offset
    y[i] = a[i] * x[i] * x[i]


@wp.kernel
def _square_backward_kernel(x: wp.array(dtype=typing.Any), a: wp.array(dtype=typing.Any),
                            g: wp.array(dtype=typing.Any), gx: wp.array(dtype=typing.Any),
                            ga: wp.array(dtype=typing.Any), offset: int):
    i = wp.tid() + offset  # each thread writes its own slots only: safe to split over threads
    gx[i] = x.dtype(2.0) * a[i] * x[i] * g[i]
    ga[i] = x[i] * x[i] * g[i]


declare_float_overloads(_square_kernel)
declare_float_overloads(_square_backward_kernel)


# --------------------------------------------------------------------------- 3. entry points (+ fast path)

def _square_cpu(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The CPU fast path: the kernel's two products in the same order, so bit for bit the kernel."""
    return a * x * x


def square(x, a, device=None):
    """y (N,) = a * x^2 for x, a (N,); NumPy in -> NumPy out, wp.array in -> wp.array out."""
    ins = Inputs(device, x, a)
    xw = ins.floats("x", x, (None,), nonempty=True)
    aw = ins.floats("a", a, (xw.shape[0],))
    if fast_paths.on(ins.device):  # one switch for every fast path (kernels.fast_paths)
        y = _square_cpu(host_view(xw), host_view(aw))
        return y if ins.as_numpy else wp.array(y, device=ins.device)
    y = ins.empty(xw.shape[0])
    ins.launch(_square_kernel, xw.shape[0], [xw, aw, y])
    return ins.out(y)


def square_backward(x, a, grad, device=None) -> dict:
    """{"x": dL/dx, "a": dL/da} of L = <grad, square(x, a)>, in the kind of `x`."""
    ins = Inputs(device, x, a, grad)
    xw = ins.floats("x", x, (None,), nonempty=True)
    aw = ins.floats("a", a, (xw.shape[0],))
    gw = ins.floats("grad", grad, (xw.shape[0],))
    gx, ga = ins.empty(xw.shape[0]), ins.empty(xw.shape[0])
    ins.launch(_square_backward_kernel, xw.shape[0], [xw, aw, gw, gx, ga])
    return {"x": ins.out(gx), "a": ins.out(ga)}


# --------------------------------------------------------------------------- 4. the gradient check

def _inputs(seed: int, n: int = 17) -> dict:
    rng = np.random.default_rng(seed)
    return {"x": rng.uniform(-2.0, 2.0, n), "a": rng.uniform(0.5, 1.5, n)}


@register_check("toy.square")
def square_checks() -> list[GradcheckResult]:
    """Float64 central differences of <g, a x^2> for every input, over three seeds."""
    results: list[GradcheckResult] = []
    for seed in range(3):
        results += check_vjp(lambda x, a: square(x, a),
                             lambda inputs, g: square_backward(inputs["x"], inputs["a"], g),  # looked up per call
                             _inputs(seed), name="toy.square", seed=seed)
    return results


# --------------------------------------------------------------------------- 5. the Dr.Jit oracle and its case

def square_oracle(x: np.ndarray, a: np.ndarray, grad: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """(y, (dL/dx, dL/da)) written again in Dr.Jit, the VJP by Dr.Jit's AD (research/oracles)."""
    be = backend(x.dtype)
    xl, al = be.leaf(x), be.leaf(a)
    y = al * xl * xl
    be.dr.backward(be.dot([y], [grad]))
    return be.numpy(y, x.shape), (be.grad(xl, x.shape), be.grad(al, a.shape))


SIZES = {"full": dict(toy_n=65536), "quick": dict(toy_n=8192), "smoke": dict(toy_n=200)}


def case_square(dt, S, seed):
    rng = Rounded(seed)
    n = S["toy_n"]
    x, a, g = rng.uniform(-2, 2, n), rng.uniform(0.5, 1.5, n), rng.normal(size=n)

    def drlab(t):
        b = square_backward(x.astype(t), a.astype(t), g.astype(t))
        return [square(x.astype(t), a.astype(t))], [b["x"], b["a"]]

    def oracle(t):
        y, (gx, ga) = square_oracle(*(v.astype(dt).astype(t) for v in (x, a, g)))
        return [y], [gx, ga]

    return f"{n} elements", drlab, oracle


CASES = [Case("toy square", case_square)]


# --------------------------------------------------------------------------- 6. the bench

def cases(device: str = "cpu", quick: bool = False, tiny: bool = False) -> Iterator[dict]:
    """The case `toy.square`: forward, and forward + backward, float32."""
    n = 1_000 if tiny else 100_000 if quick else 1_000_000
    rng = np.random.default_rng(0)
    x, a, g = (wp.array(rng.uniform(-2, 2, n).astype(np.float32), device=device) for _ in range(3))
    sync = lambda: wp.synchronize_device(device)  # noqa: E731
    t = time_medians({"fwd": lambda: square(x, a), "fwd_bwd": lambda: (square(x, a), square_backward(x, a, g))},
                     sync=sync)
    yield {"bench": "toy.square", "device": str(wp.get_device(device)),
           "threads": 1 if wp.get_device(device).is_cuda else default_threads(), "n": n,
           "fwd_s": t["fwd"], "fwd_bwd_s": t["fwd_bwd"]}
