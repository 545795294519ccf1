"""kernels/pointnet.py against its NumPy reference (kernels/reference/pointnet.py), its gradients by float64
finite differences (research/checks/pointnet.py), the array-kind rule and bad input.

Max-pool and its backward are exact (a maximum and copies), so they are compared bit for bit. Grouping
is two IEEE operations per coordinate, (p_j - p_c) * (1/r), in the reference's order: bit for bit too.
Its backward sums in another order than np.add.at: compared to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import pointnet as kpn
from kernels.reference import pointnet as ref
from research.gradcheck import assert_gradcheck, run_checks

DTYPES = [np.float32, np.float64]


def _sets(seed, shape, dtype):
    return np.random.default_rng(seed).normal(size=shape).astype(dtype)


@pytest.mark.usefixtures("warp_device")
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", [(4, 9, 5), (1, 1, 3), (7, 33, 1)])
def test_max_pool_and_its_backward_equal_the_reference(dtype, shape):
    x = _sets(0, shape, dtype)
    x[0, -1] = x[0, 0]  # exact ties in the first set: the first row wins
    got = kpn.max_pool(x)
    y, arg = ref.max_pool(x)
    assert got.value.dtype == dtype and got.argmax.dtype == np.int32
    np.testing.assert_array_equal(got.value, y)
    np.testing.assert_array_equal(got.argmax, arg)
    if shape[1] > 1:
        assert np.all(got.argmax[0] < shape[1] - 1)  # the tie went to row 0, never to the copy
    g = _sets(1, (shape[0], shape[2]), dtype)
    np.testing.assert_array_equal(kpn.max_pool_backward(got, g, shape[1])["x"], ref.max_pool_grad(arg, g, shape[1]))


def _clouds(seed, b, n, dtype):
    return (np.random.default_rng(seed).normal(size=(b, n, 3)) * 0.5).astype(dtype)


@pytest.mark.usefixtures("warp_device")
@pytest.mark.parametrize("dtype", DTYPES)
def test_group_indices_and_local_coordinates_equal_the_reference(dtype):
    p = _clouds(0, 3, 60, dtype)
    idx = kpn.group_indices(p, 12, 0.4, 8)
    centers, neighbors = ref.group_indices(p, 12, 0.4, 8)
    np.testing.assert_array_equal(idx.centers, centers)
    np.testing.assert_array_equal(idx.neighbors, neighbors)
    assert np.all(idx.neighbors >= 0) and np.all(idx.count >= 1)  # a centre always finds itself
    assert np.any(idx.count < 8) and np.any(idx.count == 8)  # both padded and full balls occur
    u = kpn.group_local(p, idx.centers, idx.neighbors, 0.4)
    assert u.dtype == dtype and u.shape == (3, 12, 8, 3)
    np.testing.assert_array_equal(u, ref.group_local(p, centers, neighbors, 0.4))


@pytest.mark.usefixtures("warp_device")
@pytest.mark.parametrize("dtype", DTYPES)
def test_group_backward_equals_a_numpy_scatter(dtype):
    p = _clouds(1, 2, 20, dtype)
    idx = kpn.group_indices(p, 5, 0.6, 6)
    g = _sets(2, (2, 5, 6, 3), dtype)
    got = kpn.group_local_backward(p, idx.centers, idx.neighbors, 0.6, g)["points"]
    want = np.zeros((2, 20, 3))
    for b in range(2):
        np.add.at(want[b], idx.neighbors[b].reshape(-1), g[b].reshape(-1, 3) / 0.6)
        np.add.at(want[b], np.repeat(idx.centers[b], 6), -g[b].reshape(-1, 3) / 0.6)
    tol = 1e-5 if dtype == np.float32 else 1e-12  # another order of the same sums
    np.testing.assert_allclose(got, want, rtol=tol, atol=tol)


def test_split_launches_equal_one_thread(monkeypatch):
    """The forward kernels run split over CPU threads (each thread its own outputs): the thread count
    changes no bit."""
    from kernels import launch

    x = _sets(3, (40, 20, 64), np.float32)  # 2560 (set, channel) threads
    p = _clouds(4, 4, 200, np.float64)
    idx = kpn.group_indices(p, 32, 0.3, 32)  # 4096 grouping threads
    out = {}
    for threads in ("1", "3"):
        monkeypatch.setenv(launch.ENV_THREADS, threads)
        res = kpn.max_pool(x)
        out[threads] = (res.value, res.argmax, kpn.group_local(p, idx.centers, idx.neighbors, 0.3))
    for a, b in zip(out["1"], out["3"]):
        np.testing.assert_array_equal(a, b)


def test_gradient_checks_pass():
    assert_gradcheck(run_checks(["pointnet"]))


def test_wp_arrays_in_give_wp_arrays_out():
    x = wp.array(_sets(0, (2, 4, 3), np.float32), dtype=wp.float32)
    res = kpn.max_pool(x)
    assert isinstance(res.value, wp.array) and isinstance(res.argmax, wp.array)
    g = wp.array(_sets(1, (2, 3), np.float32), dtype=wp.float32)
    assert isinstance(kpn.max_pool_backward(res, g, 4)["x"], wp.array)
    p = wp.array(_clouds(0, 1, 10, np.float32), dtype=wp.float32)
    idx = kpn.group_indices(p, 3, 0.5, 4)
    assert isinstance(kpn.group_local(p, idx.centers, idx.neighbors, 0.5), wp.array)


@pytest.mark.parametrize("call, message", [
    (lambda: kpn.max_pool(np.zeros((2, 0, 3))), "x: expected a non-empty"),
    (lambda: kpn.max_pool(np.zeros((0, 4, 3))), "x: expected a non-empty"),
    (lambda: kpn.max_pool(np.zeros((4, 3))), "x: expected 3 dimensions"),
    (lambda: kpn.max_pool(np.full((1, 2, 2), np.nan)), "x: expected finite"),
    (lambda: kpn.max_pool(np.zeros((1, 2, 2), np.int32)), "x:"),
    (lambda: kpn.max_pool_backward(kpn.max_pool(np.arange(6.0).reshape(1, 3, 2)), np.ones((1, 2)), 2),
     "argmax: expected values < n_rows = 2"),
    (lambda: kpn.max_pool_backward(kpn.max_pool(np.ones((1, 3, 2))), np.ones((2, 2)), 3), "argmax:"),
    (lambda: kpn.max_pool_backward(kpn.max_pool(np.ones((1, 3, 2))), np.ones((1, 2)), 0), "n_rows:"),
    (lambda: kpn.group_local(np.zeros((1, 0, 3)), np.zeros((1, 1), int), np.zeros((1, 1, 1), int), 1.0),
     "points: expected B >= 1 non-empty"),
    (lambda: kpn.group_local(np.zeros((1, 4, 2)), np.zeros((1, 1), int), np.zeros((1, 1, 1), int), 1.0), "points:"),
    (lambda: kpn.group_local(np.full((1, 4, 3), np.nan), np.zeros((1, 1), int), np.zeros((1, 1, 1), int), 1.0),
     "points: expected finite"),
    (lambda: kpn.group_local(np.zeros((1, 4, 3)), np.array([[4]]), np.zeros((1, 1, 1), int), 1.0),
     "centers: expected point indices < N = 4"),
    (lambda: kpn.group_local(np.zeros((1, 4, 3)), np.zeros((1, 1), int), np.full((1, 1, 1), -1), 1.0),
     "neighbors: expected values >= 0"),
    (lambda: kpn.group_local(np.zeros((1, 4, 3)), np.zeros((1, 2), int), np.zeros((1, 1, 1), int), 1.0),
     "neighbors:"),
    (lambda: kpn.group_local(np.zeros((1, 4, 3)), np.zeros((1, 1), int), np.zeros((1, 1, 1), int), 0.0), "radius:"),
    (lambda: kpn.group_local_backward(np.zeros((1, 4, 3)), np.zeros((1, 1), int), np.zeros((1, 1, 2), int), 1.0,
                                      np.zeros((1, 1, 1, 3))), "grad:"),
    (lambda: kpn.group_indices(np.zeros((1, 4, 3)), 5, 1.0, 2), "n_centers: expected an integer in [1, 4]"),
    (lambda: kpn.group_indices(np.zeros((1, 4, 3)), 2, -1.0, 2), "radius:"),
    (lambda: kpn.group_indices(np.zeros((1, 4, 3)), 2, 1.0, 0), "max_neighbors:"),
    (lambda: kpn.group_indices(np.full((2, 4, 3), np.inf), 2, 1.0, 2), "points: expected finite"),
    (lambda: kpn.group_indices(np.zeros((0, 4, 3)), 2, 1.0, 2), "points: expected B >= 1"),
])
def test_bad_input_is_refused_naming_the_argument(call, message):
    with pytest.raises(ValueError, match="^" + message.replace("(", r"\(").replace("[", r"\[").replace(")", r"\)")
                       .replace("]", r"\]")):
        call()
