"""kernels/sh.py against the NumPy reference (kernels/reference/sh.py): values, derivatives, orthonormality."""

from __future__ import annotations

import typing

import numpy as np
import pytest
import warp as wp

from kernels import _arrays as A
from kernels import sh
from kernels.reference import sh as ref


@wp.kernel(enable_backward=False)
def _eval_kernel(d: wp.array2d(dtype=typing.Any), basis: wp.array2d(dtype=typing.Any),
                 component: wp.array2d(dtype=typing.Any), grad: wp.array3d(dtype=typing.Any)):
    i = wp.tid()
    x = d[i, 0]
    y = d[i, 1]
    z = d[i, 2]
    b = sh.sh_basis(x, y, z)
    bx, by, bz = sh.sh_basis_grad(x, y, z)
    for k in range(16):
        basis[i, k] = b[k]
        component[i, k] = sh.sh_component(k, x, y, z)
        grad[i, k, 0] = bx[k]
        grad[i, k, 1] = by[k]
        grad[i, k, 2] = bz[k]


A.declare_float_overloads(_eval_kernel)


def _evaluate(d: np.ndarray):
    dt = A.WP_OF_NP[d.dtype]
    n = len(d)
    out = [wp.zeros((n, 16), dtype=dt), wp.zeros((n, 16), dtype=dt), wp.zeros((n, 16, 3), dtype=dt)]
    wp.launch(_eval_kernel, dim=n, inputs=[wp.array(d, dtype=dt), *out], device="cpu")
    return [o.numpy() for o in out]


@pytest.mark.parametrize("dtype, tol", [(np.float32, 1e-6), (np.float64, 1e-14)])
@pytest.mark.usefixtures("warp_device")
def test_basis_and_derivatives_match_reference(dtype, tol):
    rng = np.random.default_rng(0)
    d = rng.normal(size=(64, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(dtype)
    basis, component, grad = _evaluate(d)
    d64 = d.astype(np.float64)
    np.testing.assert_allclose(basis, ref.sh_basis(d64), rtol=tol, atol=tol)
    np.testing.assert_allclose(grad, ref.sh_basis_grad(d64), rtol=tol, atol=10 * tol)
    np.testing.assert_array_equal(component, basis)  # one formula, evaluated in the same order


def test_reference_derivative_matches_finite_differences():
    d = np.random.default_rng(1).normal(size=(20, 3))
    h = 1e-6
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        fd = (ref.sh_basis(d + e) - ref.sh_basis(d - e)) / (2 * h)
        np.testing.assert_allclose(ref.sh_basis_grad(d)[..., a], fd, atol=1e-8)


def test_basis_is_orthonormal():
    # Gauss-Legendre in cos(theta) x uniform phi integrates degree <= 6 products exactly.
    ct, wt = np.polynomial.legendre.leggauss(12)
    phi = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    C, P = np.meshgrid(ct, phi, indexing="ij")
    st = np.sqrt(1 - C**2)
    d = np.stack([st * np.cos(P), st * np.sin(P), C], axis=-1)
    w = (wt[:, None] * np.full_like(P, 2 * np.pi / len(phi)))[..., None]
    Y = ref.sh_basis(d)
    gram = np.einsum("ijk,ijl->kl", Y * w, Y)
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-12)


def test_lower_degrees_are_prefixes():
    d = np.random.default_rng(2).normal(size=(5, 3))
    full = ref.sh_basis(d)
    for deg in (0, 1, 2):
        np.testing.assert_array_equal(ref.sh_basis(d, deg), full[:, : sh.n_coeffs(deg)])
    np.testing.assert_array_equal(ref.sh_basis(d, None), 1.0)
