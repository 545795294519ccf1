"""kernels/points against its NumPy reference (kernels/reference/points.py) and SciPy's cKDTree; the chamfer
gradient by float64 finite differences; bad input.

On the CPU the indices are compared for exact equality (the definitions are exact: keys (d2, index),
and the kernels evaluate d2 in the reference's order), including clouds on a lattice full of ties.
cKDTree is an independent oracle: the distances it returns agree to rounding, and its indices equal ours
wherever the neighbours are not tied within that rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from scipy.spatial import cKDTree

from kernels import points as kp
from kernels.points import grid as kgrid
from kernels.reference import points as ref
from research.checks import points as cpoints
from research.gradcheck import assert_gradcheck
from tests.bad_input import launches_before_refusal

DTYPES = [np.float32, np.float64]


def _cloud(seed, n, dtype, scale=1.0, shift=0.0):
    return (np.random.default_rng(seed).normal(size=(n, 3)) * scale + shift).astype(dtype)


def _lattice(side):
    g = np.arange(side, dtype=np.float64)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


# --------------------------------------------------------------------------- k nearest neighbours


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("k", [1, 7, 32])
def test_knn_equals_the_reference_exactly(dtype, k):
    p = _cloud(0, 1500, dtype)
    q = _cloud(1, 200, dtype, scale=2.5)  # some queries far outside the cloud
    for queries in (q, None):
        got = kp.knn(p, k, queries)
        idx, sq = ref.knn(p, k, queries)
        assert got.idx.dtype == np.int32 and got.sq_dist.dtype == dtype
        np.testing.assert_array_equal(got.idx, idx)
        np.testing.assert_array_equal(got.sq_dist, sq)


def test_knn_ties_on_a_lattice_go_to_the_smaller_index():
    p = _lattice(6)  # 216 points, every distance shared by many
    q = np.array([[2.0, 2.0, 2.0], [2.5, 2.5, 2.5], [-3.0, 0.0, 9.0], [0.0, 0.0, 0.0]])
    for dtype in DTYPES:
        for k in (1, 6, 27, 216):
            got = kp.knn(p.astype(dtype), k, q.astype(dtype))
            idx, sq = ref.knn(p.astype(dtype), k, q.astype(dtype))
            np.testing.assert_array_equal(got.idx, idx)
            np.testing.assert_array_equal(got.sq_dist, sq)
    # the 8 corners around (2.5, 2.5, 2.5) are tied: the 8 smallest indices of them, ascending
    got = kp.knn(p, 8, q[1:2])
    assert list(got.idx[0]) == sorted(got.idx[0])


@pytest.mark.parametrize("cell_size", [0.04, 0.3, 5.0, 100.0])  # 0.04: ~1 point per 600 cells
def test_knn_does_not_depend_on_the_cell_size(cell_size):
    p, q = _cloud(2, 800, np.float64), _cloud(3, 100, np.float64, scale=3.0)
    got = kp.knn(p, 5, q, cell_size=cell_size)
    idx, sq = ref.knn(p, 5, q)
    np.testing.assert_array_equal(got.idx, idx)
    np.testing.assert_array_equal(got.sq_dist, sq)


def _agree_with_ckdtree(p, q, k, idx, sq, rtol):
    dist, cidx = cKDTree(p.astype(np.float64)).query(q.astype(np.float64), k)
    dist, cidx = dist.reshape(len(q), k), cidx.reshape(len(q), k)
    np.testing.assert_allclose(np.sqrt(sq.astype(np.float64)), dist, rtol=rtol, atol=rtol)
    # indices where the neighbour is not tied with the next or previous one within rounding
    d2 = dist**2
    gap = np.full(d2.shape, np.inf)
    gap[:, 1:] = np.minimum(gap[:, 1:], np.diff(d2, axis=1))
    gap[:, :-1] = np.minimum(gap[:, :-1], np.diff(d2, axis=1))
    clear = gap > 10 * rtol * (1 + d2)
    assert clear.mean() > 0.9
    np.testing.assert_array_equal(idx[clear], cidx[clear])


@pytest.mark.parametrize("dtype, rtol", [(np.float32, 1e-5), (np.float64, 1e-12)])
def test_knn_matches_ckdtree(dtype, rtol):
    p, q = _cloud(4, 3000, dtype), _cloud(5, 300, dtype, scale=1.5)
    got = kp.knn(p, 12, q)
    _agree_with_ckdtree(p, q, 12, got.idx, got.sq_dist, rtol)


def test_knn_corner_cases():
    one = np.array([[1.0, 2.0, 3.0]])
    got = kp.knn(one, 1, np.array([[0.0, 0.0, 0.0], [1e6, 0.0, 0.0]]))
    np.testing.assert_array_equal(got.idx, [[0], [0]])
    np.testing.assert_array_equal(got.sq_dist, [[14.0], [(1e6 - 1) ** 2 + 13.0]])
    same = np.zeros((9, 3))  # coincident points: all tied at 0, by index
    np.testing.assert_array_equal(kp.knn(same, 4).idx, np.tile(np.arange(4), (9, 1)))
    flat = _cloud(6, 500, np.float64) * np.array([1.0, 1.0, 0.0])  # a planar cloud
    np.testing.assert_array_equal(kp.knn(flat, 6).idx, ref.knn(flat, 6)[0])


@pytest.mark.usefixtures("warp_device")
def test_knn_on_every_device():
    p, q = _cloud(7, 1000, np.float64), _cloud(8, 100, np.float64)
    got = kp.knn(p, 8, q)
    idx, sq = ref.knn(p, 8, q)
    np.testing.assert_allclose(got.sq_dist, sq, rtol=1e-13)
    np.testing.assert_array_equal(got.idx, idx)


def test_knn_array_kinds_and_thread_counts(monkeypatch):
    p = _cloud(9, 5000, np.float32)
    res = kp.knn(wp.array(p, dtype=wp.float32), 4)
    assert isinstance(res.idx, wp.array) and isinstance(res.sq_dist, wp.array)
    monkeypatch.setenv("DRLAB_THREADS", "1")
    one = kp.knn(p, 4)
    np.testing.assert_array_equal(res.idx.numpy(), one.idx)
    np.testing.assert_array_equal(res.sq_dist.numpy(), one.sq_dist)


# --------------------------------------------------------------------------- ball query


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("radius, kmax", [(0.2, 8), (0.5, 32), (3.0, 5)])
def test_ball_query_equals_the_reference_and_ckdtree(dtype, radius, kmax):
    p, q = _cloud(10, 2000, dtype), _cloud(11, 300, dtype, scale=1.5)
    got = kp.ball_query(p, q, radius, kmax)
    idx, count = ref.ball_query(p, q, radius, kmax)
    np.testing.assert_array_equal(got.idx, idx)
    np.testing.assert_array_equal(got.count, count)
    balls = cKDTree(p.astype(np.float64)).query_ball_point(q.astype(np.float64), radius)
    for i, b in enumerate(balls):
        first = sorted(b)[:kmax]  # cKDTree's ball is |d| <= r; random clouds put no point on the sphere
        assert got.count[i] == len(first)
        if first:
            np.testing.assert_array_equal(got.idx[i], first + [first[0]] * (kmax - len(first)))
        else:
            assert (got.idx[i] == -1).all()


def test_ball_query_padding_and_the_strict_radius():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.5, 0, 0], [9.0, 0, 0]])
    got = kp.ball_query(p, np.array([[0.0, 0, 0], [20.0, 0, 0]]), 1.0, 4)
    np.testing.assert_array_equal(got.idx, [[0, 2, 0, 0], [-1, -1, -1, -1]])  # |p_1| = r is outside
    np.testing.assert_array_equal(got.count, [2, 0])
    lat = _lattice(5)
    got = kp.ball_query(lat, lat, 1.01, 30)
    idx, count = ref.ball_query(lat, lat, 1.01, 30)
    np.testing.assert_array_equal(got.idx, idx)
    np.testing.assert_array_equal(got.count, count)


# --------------------------------------------------------------------------- farthest-point sampling


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("n, s, start", [(5000, 300, 0), (700, 700, 13), (10000, 64, 9999)])
def test_fps_equals_the_reference(dtype, n, s, start):
    p = _cloud(12, n, dtype)
    got = kp.farthest_point_sampling(p, s, start=start)
    want = ref.farthest_point_sampling(p, s, start=start)
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, want)


def test_fps_each_sample_is_the_farthest_by_ckdtree():
    p = _cloud(13, 3000, np.float64)
    s = kp.farthest_point_sampling(p, 50)
    assert s[0] == 0 and len(set(s.tolist())) == 50
    for t in (1, 5, 20, 49):
        dist, _ = cKDTree(p[s[:t]]).query(p)
        assert dist[s[t]] == pytest.approx(dist.max(), rel=1e-12)
        assert s[t] == np.flatnonzero(dist >= dist.max() * (1 - 1e-12))[0]


def test_fps_ties_and_repeats():
    lat = _lattice(3)
    np.testing.assert_array_equal(kp.farthest_point_sampling(lat, 27), ref.farthest_point_sampling(lat, 27))
    two = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0]])  # 2 distinct points, 3 samples: 0 is repeated
    np.testing.assert_array_equal(kp.farthest_point_sampling(two, 3), [0, 1, 0])


# --------------------------------------------------------------------------- normals


def _surface(seed, n, dtype):
    u = np.random.default_rng(seed).uniform(-1, 1, (n, 2))
    return np.c_[u, 0.2 * np.sin(2 * u[:, 0]) * np.cos(u[:, 1])].astype(dtype)


@pytest.mark.parametrize("dtype, tol", [(np.float32, 2e-4), (np.float64, 1e-9)])
def test_normals_equal_the_reference_and_a_ckdtree_pca(dtype, tol):
    p = _surface(14, 3000, dtype)
    got = kp.estimate_normals(p, 10, viewpoint=(0.0, 0.0, 4.0))
    want, valid = ref.normals(p, 10, (0.0, 0.0, 4.0))
    assert got.valid.all() and valid.all() and got.normals.dtype == dtype
    np.testing.assert_allclose(got.normals, want, atol=tol)
    _, nb = cKDTree(p.astype(np.float64)).query(p.astype(np.float64), 10)
    d = p.astype(np.float64)[nb]
    d -= d.mean(axis=1, keepdims=True)
    n = np.linalg.eigh(np.einsum("nki,nkj->nij", d, d))[1][:, :, 0]
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", got.normals.astype(np.float64), n)), 1.0, atol=tol)


def test_normals_point_toward_the_viewpoint():
    p = _surface(15, 1000, np.float64) * np.array([1.0, 1.0, 0.0])  # the plane z = 0
    up = kp.estimate_normals(p, 8, viewpoint=(0.0, 0.0, 3.0)).normals
    down = kp.estimate_normals(p, 8, viewpoint=(0.3, 0.0, -2.0)).normals
    np.testing.assert_allclose(up, np.tile([0.0, 0.0, 1.0], (1000, 1)), atol=1e-12)
    np.testing.assert_allclose(down, -up, atol=1e-12)
    sphere = _cloud(16, 2000, np.float64)
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    out = kp.estimate_normals(sphere, 12, viewpoint=(0.0, 0.0, 0.0)).normals  # toward the centre: inward
    assert np.all(np.einsum("ni,ni->n", out, -sphere) > 0.99)


def test_degenerate_neighbourhoods_give_nan_and_invalid():
    line = np.c_[np.linspace(0, 1, 20), 2 * np.linspace(0, 1, 20), np.zeros(20)]
    res = kp.estimate_normals(line, 5)
    assert not res.valid.any() and np.isnan(res.normals).all()
    pair = np.array([[0.0, 0, 0]] * 4 + [[1.0, 1, 1]] * 4)  # two distinct points
    res = kp.estimate_normals(pair, 4)
    assert not res.valid.any() and np.isnan(res.normals).all()
    mixed = np.r_[_surface(17, 200, np.float64), np.array([[5.0, 5, 5]] * 6)]  # a far clump of duplicates
    res = kp.estimate_normals(mixed, 6)
    assert res.valid[:200].all() and not res.valid[200:].any()
    assert np.isnan(res.normals[200:]).all() and np.isfinite(res.normals[:200]).all()


# --------------------------------------------------------------------------- chamfer distance


@pytest.mark.parametrize("dtype, rtol", [(np.float32, 1e-5), (np.float64, 1e-13)])
def test_chamfer_equals_the_reference_and_ckdtree(dtype, rtol):
    x, y = _cloud(18, 2000, dtype), _cloud(19, 1500, dtype, scale=0.7, shift=0.4)
    res = kp.chamfer_distance(x, y)
    assert res.value == pytest.approx(ref.chamfer(x, y), rel=rtol)
    dxy, _ = cKDTree(y.astype(np.float64)).query(x.astype(np.float64))
    dyx, _ = cKDTree(x.astype(np.float64)).query(y.astype(np.float64))
    assert res.value == pytest.approx(np.mean(dxy**2) + np.mean(dyx**2), rel=rtol)
    np.testing.assert_array_equal(res.near_y, ref.knn(y, 1, x)[0][:, 0])
    np.testing.assert_array_equal(res.near_x, ref.knn(x, 1, y)[0][:, 0])
    g = kp.chamfer_backward(x, y, res, 0.5)
    gx, gy = ref.chamfer_grad(x, y)
    scale = max(np.abs(gx).max(), np.abs(gy).max())
    np.testing.assert_allclose(g["x"], 0.5 * gx, atol=10 * rtol * scale)
    np.testing.assert_allclose(g["y"], 0.5 * gy, atol=10 * rtol * scale)


@pytest.mark.usefixtures("warp_device")
def test_chamfer_gradients_by_finite_differences():
    assert_gradcheck(cpoints.chamfer_checks())


def test_chamfer_gradcheck_catches_a_wrong_gradient():
    from research.gradcheck import check_vjp

    x, y = cpoints.screened_clouds(3, 10, 8, 0.0)
    f, vjp = cpoints.chamfer_fn()
    bad = lambda inputs, cot: {k: v * 1.01 for k, v in vjp(inputs, cot).items()}  # noqa: E731
    assert not all(r.passed for r in check_vjp(f, bad, {"x": x, "y": y}))


def test_chamfer_kinds_and_thread_counts(monkeypatch):
    x, y = _cloud(20, 3000, np.float64), _cloud(21, 2500, np.float64)
    res = kp.chamfer_distance(wp.array(x, dtype=wp.float64), wp.array(y, dtype=wp.float64))
    assert isinstance(res.near_y, wp.array)
    g = kp.chamfer_backward(wp.array(x, dtype=wp.float64), wp.array(y, dtype=wp.float64), res)
    assert isinstance(g["x"], wp.array)
    monkeypatch.setenv("DRLAB_THREADS", "1")
    one = kp.chamfer_backward(x, y, kp.chamfer_distance(x, y))
    np.testing.assert_array_equal(g["x"].numpy(), one["x"])
    np.testing.assert_array_equal(g["y"].numpy(), one["y"])


# --------------------------------------------------------------------------- bad input

P = np.zeros((5, 3))
NAN = np.array([[0.0, 0, 0], [np.nan, 0, 0]])
BAD = [
    ("knn empty", lambda: kp.knn(np.zeros((0, 3)), 1), "points: expected a non-empty cloud"),
    ("knn nan", lambda: kp.knn(NAN, 1), "points: expected finite coordinates"),
    ("knn nan queries", lambda: kp.knn(P, 1, NAN), "queries: expected finite coordinates"),
    ("knn empty queries", lambda: kp.knn(P, 1, np.zeros((0, 3))), "queries: expected a non-empty cloud"),
    ("knn k > N", lambda: kp.knn(P, 6), r"k: expected an integer in \[1, 5\]"),
    ("knn k = 0", lambda: kp.knn(P, 0), "k: expected an integer >= 1"),
    ("knn shape", lambda: kp.knn(np.zeros((5, 2)), 1), r"points: expected shape \(N, 3\)"),
    ("knn dtype", lambda: kp.knn(np.zeros((5, 3), np.int32), 1), "points: expected dtype float32 or float64"),
    ("knn mixed", lambda: kp.knn(P, 1, np.zeros((2, 3), np.float32)), "queries: expected dtype float64"),
    ("knn cell", lambda: kp.knn(P, 1, cell_size=0.0), "cell_size: expected a positive"),
    ("knn tiny cell", lambda: kp.knn(np.array([[0.0, 0, 0], [1e9, 0, 0]]), 1, cell_size=1e-3), "cell_size: expected"),
    ("ball r = 0", lambda: kp.ball_query(P, P, 0.0, 4), "radius: expected a positive"),
    ("ball r < 0", lambda: kp.ball_query(P, P, -1.0, 4), "radius: expected a positive"),
    ("ball r nan", lambda: kp.ball_query(P, P, float("nan"), 4), "radius: expected a positive"),
    ("ball K = 0", lambda: kp.ball_query(P, P, 1.0, 0), "max_neighbors: expected an integer >= 1"),
    ("ball empty", lambda: kp.ball_query(np.zeros((0, 3)), P, 1.0, 2), "points: expected a non-empty cloud"),
    ("ball nan", lambda: kp.ball_query(P, NAN, 1.0, 2), "queries: expected finite coordinates"),
    ("fps S > N", lambda: kp.farthest_point_sampling(P, 6), r"n_samples: expected an integer in \[1, 5\]"),
    ("fps S = 0", lambda: kp.farthest_point_sampling(P, 0), "n_samples: expected an integer >= 1"),
    ("fps start", lambda: kp.farthest_point_sampling(P, 2, start=5), r"start: expected an integer in \[0, 4\]"),
    ("fps nan", lambda: kp.farthest_point_sampling(NAN, 1), "points: expected finite coordinates"),
    ("fps empty", lambda: kp.farthest_point_sampling(np.zeros((0, 3)), 1), "points: expected a non-empty cloud"),
    ("normals k < 3", lambda: kp.estimate_normals(P, 2), "k: expected an integer >= 3"),
    ("normals k > N", lambda: kp.estimate_normals(P, 6), r"k: expected an integer in \[3, 5\]"),
    ("normals viewpoint", lambda: kp.estimate_normals(P, 3, viewpoint=(0, 1)), "viewpoint: expected 3 finite"),
    ("normals viewpoint nan", lambda: kp.estimate_normals(P, 3, viewpoint=(0, 1, np.nan)), "viewpoint: expected"),
    ("normals ratio", lambda: kp.estimate_normals(P, 3, degenerate_ratio=-1), "degenerate_ratio: expected"),
    ("normals nan", lambda: kp.estimate_normals(NAN, 2), "points: expected finite coordinates"),
    ("chamfer empty", lambda: kp.chamfer_distance(P, np.zeros((0, 3))), "y: expected a non-empty cloud"),
    ("chamfer nan", lambda: kp.chamfer_distance(NAN, P), "x: expected finite coordinates"),
    ("chamfer grad", lambda: kp.chamfer_backward(P, P, kp.chamfer_distance(P, P), float("inf")), "grad: expected"),
    ("chamfer result", lambda: kp.chamfer_backward(P, P[:4], kp.chamfer_distance(P, P)), "result.near_x: expected"),
]


@pytest.mark.parametrize("call, match", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input_raises_before_any_kernel(call, match, monkeypatch):
    launched = launches_before_refusal(call, match, monkeypatch)
    if "result" not in match and "grad" not in match:  # those two build their result first
        assert not launched


def test_grid_margin_is_small():
    g = kgrid.build_grid(_cloud(22, 100, np.float32), 0.1)
    assert 0 < g.margin < 1e-3 and g.n == 100
