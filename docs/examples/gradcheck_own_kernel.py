"""Write a Warp kernel with a hand-written backward and check it against finite differences.

Run from the repository root:  python docs/examples/gradcheck_own_kernel.py

The kernel is a row-wise log-sum-exp, y_r = log sum_k exp(x_rk), computed in one pass with a
running maximum m and a running sum s of exp(x_rk - m):

    v > m:  s <- s exp(m - v) + 1,  m <- v;     otherwise  s <- s + exp(v - m);     y = m + log s.

That loop carries state from one pass to the next, the shape of loop whose gradient Warp's tape
gets wrong (docs/warp.md), so the backward is written by hand: dy_r/dx_rk = exp(x_rk - y_r), the
softmax of the row, and the vector-Jacobian product is grad_x[r, k] = grad_y[r] exp(x_rk - y_r).

The entry points follow the array contract of kernels/_arrays.py: NumPy or wp.array in, the same
kind out, float32 or float64, every argument checked before a launch. `check_vjp` then compares
the backward with central differences in float64 (relative tolerance 1e-6), and shows that a
backward with a deliberate mistake fails.
"""

from __future__ import annotations

import typing

import numpy as np
import warp as wp

from kernels._arrays import Inputs, declare_float_overloads
from research.gradcheck import check_vjp, format_table
from research.warp_runtime import init_warp


# ----------------------------------------------------------------------------- kernels


@wp.kernel
def _logsumexp_kernel(x: wp.array2d(dtype=typing.Any), y: wp.array(dtype=typing.Any), offset: int):
    r = wp.tid() + offset  # the last parameter `offset` lets launch_split run rows on several threads
    one = x.dtype(1.0)
    m = x[r, 0]
    s = one
    for k in range(1, x.shape[1]):
        v = x[r, k]
        if v > m:
            s = s * wp.exp(m - v) + one
            m = v
        else:
            s = s + wp.exp(v - m)
    y[r] = m + wp.log(s)


@wp.kernel
def _logsumexp_backward_kernel(x: wp.array2d(dtype=typing.Any), y: wp.array(dtype=typing.Any),
                               grad_y: wp.array(dtype=typing.Any), grad_x: wp.array2d(dtype=typing.Any),
                               offset: int):
    r = wp.tid() + offset  # one thread per row, writing only its own row: safe to split
    for k in range(x.shape[1]):
        grad_x[r, k] = grad_y[r] * wp.exp(x[r, k] - y[r])


declare_float_overloads(_logsumexp_kernel)  # float32 and float64, so the module compiles once
declare_float_overloads(_logsumexp_backward_kernel)


# ----------------------------------------------------------------------------- entry points


def logsumexp(x, device=None):
    """y (R,) = log sum_k exp(x[:, k]) for x (R, K), K >= 1; NumPy in -> NumPy out, wp in -> wp out."""
    a = Inputs(device, x)
    xw = a.floats("x", x, (None, None), nonempty=True)
    y = a.empty(x.shape[0])
    a.launch(_logsumexp_kernel, x.shape[0], [xw, y])
    return a.out(y)


def logsumexp_backward(x, grad_y, device=None) -> dict:
    """{"x": gradient (R, K)} of <grad_y, logsumexp(x)>, in the kind of `x`."""
    a = Inputs(device, x, grad_y)
    xw = a.floats("x", x, (None, None), nonempty=True)
    gw = a.floats("grad_y", grad_y, (x.shape[0],))
    y = a.floats("y", logsumexp(xw), (x.shape[0],))
    grad_x = a.empty(tuple(x.shape))
    a.launch(_logsumexp_backward_kernel, x.shape[0], [xw, y, gw, grad_x])
    return {"x": a.out(grad_x)}


# ----------------------------------------------------------------------------- the check


def main() -> None:
    init_warp()  # keep Warp's start-up banner off stdout
    rng = np.random.default_rng(0)
    x = 3.0 * rng.standard_normal((6, 9))

    reference = np.log(np.exp(x).sum(axis=1))
    err64 = np.abs(logsumexp(x) - reference).max()
    err32 = np.abs(logsumexp(x.astype(np.float32)) - reference).max()
    print(f"forward vs NumPy: max error {err64:.1e} in float64, {err32:.1e} in float32")

    results = check_vjp(
        lambda x: logsumexp(x),
        lambda inputs, cotangent: logsumexp_backward(inputs["x"], cotangent),
        {"x": x}, name="example.logsumexp")
    print(format_table(results), end="")

    def wrong_backward(inputs, cotangent):  # forgets to divide by the sum: exp(x) instead of softmax
        return {"x": cotangent[:, None] * np.exp(inputs["x"])}

    caught = check_vjp(lambda x: logsumexp(x), wrong_backward, {"x": x}, name="example.wrong")
    print(format_table(caught), end="")
    if not all(r.passed for r in results) or any(r.passed for r in caught):
        raise SystemExit("unexpected gradient-check outcome")
    print("hand-written backward passes; the wrong one is caught")

    try:
        logsumexp(np.zeros((0, 3)))
    except ValueError as exc:
        print(f"bad input is refused before any launch: {exc}")


if __name__ == "__main__":
    main()
