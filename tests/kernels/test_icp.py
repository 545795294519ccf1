"""kernels/icp against its NumPy reference (kernels/reference/icp.py); the pose Jacobians and the robust
cost's gradient by float64 finite differences (research/checks/icp.py); the array kinds, thread counts and
block sizes; bad input. (Its CUDA build is in tests/kernels/test_cuda_compile.py, with every module.)"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import icp
from kernels.reference import icp as ref
from research.checks import icp as cicp
from research.gradcheck import assert_gradcheck, check_vjp
from tests.bad_input import launches_before_refusal

# float32: the block sums accumulate a few hundred float32 terms (relative rounding ~ 256 u ~ 1e-5 worst
# case; about 5e-7 measured), compared with the float64 reference.
TOL = {np.float32: 2e-5, np.float64: 1e-12}


def _pairs(seed, n, plane, dtype=np.float64):
    d = cicp.correspondences(seed, n, plane, "none")
    cast = lambda x: None if x is None else x.astype(dtype)  # noqa: E731
    return cast(d["source"]), cast(d["target"]), cast(d["normals"])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("plane", [False, True], ids=["point", "plane"])
@pytest.mark.parametrize("robust", list(icp.ROBUST))
@pytest.mark.usefixtures("warp_device")
def test_forward_equals_the_reference(dtype, plane, robust):
    p, q, n = _pairs(0, 700, plane, dtype)
    scale = cicp.SCALE[robust]
    ne = icp.normal_equations(p, q, n, robust=robust, scale=scale, block=64)
    H, g, cost = ref.normal_equations(p, q, n, robust, scale)
    tol = TOL[dtype]
    np.testing.assert_allclose(ne.H, H, rtol=tol, atol=tol * np.abs(H).max())
    np.testing.assert_allclose(ne.g, g, rtol=tol, atol=tol * np.abs(g).max())
    assert ne.cost == pytest.approx(cost, rel=tol) and ne.count == 700
    res = icp.icp_residuals(p, q, n, robust=robust, scale=scale)
    r, J, e2 = ref.residuals(p, q, n)
    assert res.residuals.shape == (700, 1 if plane else 3) and res.residuals.dtype == dtype
    np.testing.assert_allclose(res.residuals, r, rtol=tol, atol=tol)
    np.testing.assert_allclose(res.jacobians, J, rtol=tol, atol=tol * 10)
    np.testing.assert_allclose(res.weights, ref.robust_weight(e2, robust, scale), rtol=tol * 10, atol=tol)
    np.testing.assert_allclose(res.rho, ref.robust_rho(e2, robust, scale), rtol=tol * 10, atol=tol)
    # H is J^T W J of the per-row Jacobians
    np.testing.assert_allclose(np.einsum("n,nra,nrb->ab", res.weights.astype(np.float64), J, J), H, rtol=tol * 10)


def test_robust_weights_are_the_derivative_of_rho():
    """w(e^2) = rho'(e) / e for every kernel (central differences of the reference rho in e)."""
    e = np.linspace(0.01, 2.0, 97)
    for robust, s in (("none", 1.0), ("huber", 0.37), ("gm", 0.2)):
        h = 1e-6
        d = (ref.robust_rho((e + h) ** 2, robust, s) - ref.robust_rho((e - h) ** 2, robust, s)) / (2 * h)
        keep = np.abs(e - s) > 1e-3 if robust == "huber" else np.ones_like(e, bool)
        np.testing.assert_allclose(ref.robust_weight(e ** 2, robust, s)[keep], (d / e)[keep], rtol=1e-7)
    # Geman-McClure down-weights a 1 m residual at s = 0.1 to under 1%, Huber to 10%
    assert ref.robust_weight(np.array([1.0]), "gm", 0.1)[0] < 0.01
    assert ref.robust_weight(np.array([1.0]), "huber", 0.1)[0] == pytest.approx(0.1)


@pytest.mark.usefixtures("warp_device")
def test_gradients_by_finite_differences():
    assert_gradcheck(cicp.jacobian_checks() + cicp.gradient_checks())


def test_gradcheck_catches_a_wrong_jacobian():
    data = cicp.correspondences(5, 20, False, "none")
    good = cicp.check_jacobian(5, 20, False)
    assert all(r.passed for r in good)

    def f(xi):
        return icp.icp_residuals(cicp._moved(data["source"], xi), data["target"]).residuals

    def bad(inputs, cot):  # the rotation block with the wrong sign: J = [I, +p^]
        J = icp.icp_residuals(data["source"], data["target"]).jacobians.copy()
        J[..., 3:] *= -1.0
        return {"xi": np.einsum("nr,nra->a", cot, J)}

    assert not all(r.passed for r in check_vjp(f, bad, {"xi": np.zeros(6)}))


def test_kinds_thread_counts_and_blocks(monkeypatch):
    p, q, n = _pairs(1, 3000, True)
    res = icp.icp_residuals(wp.array(p, dtype=wp.float64), wp.array(q, dtype=wp.float64),
                            wp.array(n, dtype=wp.float64), robust="gm", scale=0.05)
    assert isinstance(res.residuals, wp.array) and isinstance(res.jacobians, wp.array)
    ne = icp.normal_equations(p, q, n, robust="gm", scale=0.05, block=50)
    monkeypatch.setenv("DRLAB_THREADS", "1")
    one = icp.icp_residuals(p, q, n, robust="gm", scale=0.05)
    np.testing.assert_array_equal(res.jacobians.numpy(), one.jacobians)
    np.testing.assert_array_equal(res.weights.numpy(), one.weights)
    ne1 = icp.normal_equations(p, q, n, robust="gm", scale=0.05, block=50)
    np.testing.assert_array_equal(ne.H, ne1.H)  # fixed blocks: the same sums on any thread count
    big = icp.normal_equations(p, q, n, robust="gm", scale=0.05, block=3000)
    np.testing.assert_allclose(big.H, ne.H, rtol=1e-12)


P = np.zeros((4, 3))
N = np.tile([0.0, 0.0, 1.0], (4, 1))
NAN = np.array([[0.0, 0, 0], [np.nan, 0, 0]])
BAD = [
    ("empty source", lambda: icp.normal_equations(np.zeros((0, 3)), np.zeros((0, 3))), "source: expected a non-empty"),
    ("nan source", lambda: icp.normal_equations(NAN, np.zeros((2, 3))), "source: expected finite"),
    ("nan target", lambda: icp.icp_residuals(np.zeros((2, 3)), NAN), "target: expected finite"),
    ("target rows", lambda: icp.normal_equations(P, P[:3]), r"target: expected shape \(4, 3\)"),
    ("nan normals", lambda: icp.normal_equations(np.zeros((2, 3)), np.zeros((2, 3)), NAN), "normals: expected finite"),
    ("normals length", lambda: icp.normal_equations(P, P, N * 2), "normals: expected unit vectors"),
    ("normals rows", lambda: icp.icp_residuals(P, P, N[:2]), r"normals: expected shape \(4, 3\)"),
    ("robust", lambda: icp.normal_equations(P, P, robust="cauchy"), "robust: expected one of none, huber, gm"),
    ("scale", lambda: icp.normal_equations(P, P, robust="gm", scale=0.0), "scale: expected a positive"),
    ("block", lambda: icp.normal_equations(P, P, block=0), "block: expected an integer >= 1"),
    ("dtype", lambda: icp.normal_equations(P, P.astype(np.float32)), "target: expected dtype float64"),
]


@pytest.mark.parametrize("call, match", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input_raises_before_any_kernel(call, match, monkeypatch):
    assert not launches_before_refusal(call, match, monkeypatch)
