"""kernels.volume.sampling and occupancy: ray-box hits, strata, jitter, empty-space skipping, EMA updates."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from kernels import _arrays as A
from kernels._arrays import value_checks
from kernels.reference import volume as ref_volume
from kernels.volume import OccupancyGrid, ray_aabb, sample_rays
from kernels.volume.sampling import dense_samples

BOX = np.array([[-1.0, -0.5, -0.8], [1.2, 0.7, 0.9]])


def random_rays(seed, n=40):
    """Rays from outside, from inside, axis-parallel ones (inside and outside a slab) and misses."""
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3, 3, (n, 3))
    o[: n // 4] = rng.uniform(BOX[0] * 0.9, BOX[1] * 0.9, (n // 4, 3))  # start inside the box
    d = rng.uniform(BOX[0], BOX[1], (n, 3)) - o
    d[n // 4: n // 4 + 4, 1] = 0.0  # axis-parallel in y
    d[-3:] = -d[-3:]  # mostly pointing away: misses
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.usefixtures("warp_device")
def test_ray_aabb_matches_reference(dtype, seed):
    o, d = random_rays(seed)
    for near, far in ((0.0, 1e10), (0.5, 3.0)):
        t0, t1, hit = ray_aabb(o.astype(dtype), d.astype(dtype), BOX, near, far)
        r0, r1, rh = ref_volume.ray_aabb(o.astype(dtype).astype(np.float64), d.astype(dtype).astype(np.float64),
                                        BOX, near, far)
        np.testing.assert_array_equal(hit, rh)
        tol = 1e-5 if dtype == np.float32 else 1e-12
        np.testing.assert_allclose(t0, r0, atol=tol)
        np.testing.assert_allclose(t1, r1, atol=tol)
        assert t0.dtype == dtype and hit.dtype == np.int32
        assert 0 < rh.sum() < len(rh)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_stratified_samples_without_jitter_are_midpoints(dtype):
    o, d = random_rays(0)
    o, d = o.astype(dtype), d.astype(dtype)
    S = 7
    zs = np.linspace(0.5, 1.0, len(o)).astype(dtype)
    s = sample_rays(o, d, BOX, n_samples=S, z_scale=zs)
    t0, t1, hit = ref_volume.ray_aabb(o.astype(np.float64), d.astype(np.float64), BOX, 0.0, 1e10)
    np.testing.assert_array_equal(np.diff(s.ray_offsets), hit * S)
    hits = np.flatnonzero(hit)
    t_ref, h = ref_volume.midpoint_strata(t0[hits], t1[hits], S)
    tol = 2e-5 if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(s.t, t_ref.ravel(), atol=tol)
    np.testing.assert_allclose(s.delta, np.repeat(h, S), atol=tol)
    np.testing.assert_allclose(s.z, (t_ref * zs[hits, None]).ravel(), atol=tol)
    np.testing.assert_array_equal(s.ray_index, np.repeat(hits, S))
    pts_ref = o[hits, None, :] + t_ref[..., None] * d[hits, None, :]
    np.testing.assert_allclose(s.points, pts_ref.reshape(-1, 3), atol=10 * tol)
    np.testing.assert_allclose(s.dirs, np.repeat(d[hits], S, axis=0))
    # wp.arrays in: the same samples as wp.arrays.
    w = sample_rays(wp.array(o), wp.array(d), BOX, n_samples=S, z_scale=wp.array(zs))
    for k in vars(s):
        assert isinstance(getattr(w, k), wp.array)
        np.testing.assert_array_equal(getattr(w, k).numpy(), getattr(s, k))


def test_jitter_is_seeded_and_stays_in_strata():
    o, d = random_rays(1)
    a = sample_rays(o, d, BOX, step=0.13, jitter=True, seed=5)
    b = sample_rays(o, d, BOX, step=0.13, jitter=True, seed=5)
    c = sample_rays(o, d, BOX, step=0.13, jitter=True, seed=6)
    mid = sample_rays(o, d, BOX, step=0.13, jitter=False)
    np.testing.assert_array_equal(a.t, b.t)
    assert not np.array_equal(a.t, c.t)
    # Same strata; each jittered sample lies in its stratum [mid - delta/2, mid + delta/2).
    np.testing.assert_array_equal(a.ray_offsets, mid.ray_offsets)
    u = (a.t - (mid.t - 0.5 * mid.delta)) / mid.delta
    assert np.all(u >= -1e-9) and np.all(u < 1.0 + 1e-9)
    assert u.std() > 0.2  # spread over the stratum, not stuck at one point


def test_fixed_step_strata_cover_the_segment():
    o, d = random_rays(2)
    step = 0.11
    s = sample_rays(o, d, BOX, step=step)
    t0, t1, hit = ref_volume.ray_aabb(o, d, BOX, 0.0, 1e10)
    off = s.ray_offsets
    delta = s.delta
    for r in np.flatnonzero(hit):
        n = off[r + 1] - off[r]
        assert n == max(math.ceil((t1[r] - t0[r]) / step - 1e-6), 1)
        assert delta[off[r]:off[r + 1]].sum() == pytest.approx(t1[r] - t0[r], abs=1e-12)
        assert np.all(delta[off[r]:off[r + 1] - 1] == pytest.approx(step))


def test_occupancy_skips_empty_cells():
    o, d = random_rays(3, 60)
    res = (5, 4, 3)
    grid = OccupancyGrid(BOX, res, decay=0.5, threshold=0.5)
    rng = np.random.default_rng(0)
    sigma = (rng.uniform(size=grid.n_cells) > 0.6).astype(np.float64) * 2.0
    grid.update(sigma)
    occ = grid.occupied.numpy()
    assert 0 < occ.sum() < occ.size
    full = sample_rays(o, d, BOX, step=0.05)
    skipped = sample_rays(o, d, BOX, step=0.05, occupancy=grid)
    keep = ref_volume.occupied(full.points, occ, BOX, res).astype(bool)  # midpoints (no jitter)
    np.testing.assert_allclose(skipped.t, full.t[keep])
    np.testing.assert_array_equal(skipped.ray_index, full.ray_index[keep])
    np.testing.assert_array_equal(np.diff(skipped.ray_offsets), np.bincount(full.ray_index[keep], minlength=len(o)))


def test_occupancy_update_is_ema_max_then_threshold():
    grid = OccupancyGrid(BOX, (3, 2, 2), decay=0.9, threshold=0.3)
    assert grid.occupied_fraction() == 1.0  # everything is occupied before the first update
    rng = np.random.default_rng(1)
    rho = np.zeros(grid.n_cells)
    for it in range(4):
        sigma = rng.uniform(0.0, 1.0, grid.n_cells) * (it < 2)
        grid.update(sigma.astype(np.float32))
        rho = np.maximum(0.9 * rho, sigma)
        np.testing.assert_allclose(grid.density.numpy(), rho, rtol=1e-6)
        np.testing.assert_array_equal(grid.occupied.numpy(), rho > min(rho.mean(), 0.3))


def test_cell_points_fall_in_their_cells():
    res = (4, 3, 2)
    grid = OccupancyGrid(BOX, res)
    pts = grid.cell_points(seed=3, dtype=wp.float64).numpy()
    cell = (BOX[1] - BOX[0]) / np.array(res)
    idx = np.floor((pts - BOX[0]) / cell).astype(int)
    flat = idx[:, 0] + res[0] * (idx[:, 1] + res[1] * idx[:, 2])
    np.testing.assert_array_equal(flat, np.arange(grid.n_cells))
    assert not np.array_equal(pts, grid.cell_points(seed=4, dtype=wp.float64).numpy())


def test_dense_samples_layout():
    o = np.zeros((2, 3))
    d = np.array([[0, 0, 1.0], [0, 1.0, 0]])
    t = np.array([[1.0, 2.0, 3.0], [0.5, 1.5, 2.5]])
    s = dense_samples(o, d, t, np.full((2, 3), 0.1), z_scale=np.array([1.0, 0.5]))
    np.testing.assert_array_equal(s.ray_offsets.numpy(), [0, 3, 6])
    np.testing.assert_allclose(s.points.numpy()[4], [0, 1.5, 0])
    np.testing.assert_allclose(s.z.numpy(), [1, 2, 3, 0.25, 0.75, 1.25])


@pytest.mark.parametrize("kwargs, match", [
    (dict(near=2.0, far=1.0, n_samples=4), "near < far"),
    (dict(near=1.0, far=1.0, n_samples=4), "near < far"),
    (dict(near=-1.0, n_samples=4), "near: expected near >= 0"),
    (dict(n_samples=4, step=0.1), "exactly one"),
    (dict(), "exactly one"),
    (dict(step=0.0), "step: expected a positive"),
    (dict(n_samples=0), "n_samples: expected an integer >= 1"),
    (dict(n_samples=4, near=float("nan")), "near: expected a finite number"),
    (dict(n_samples=4, z_scale=np.ones(8, np.float32)), "z_scale: expected dtype float64"),
    (dict(n_samples=4, z_scale=np.ones(3)), "z_scale: expected shape"),
])
def test_sample_rays_bad_input(kwargs, match):
    o, d = random_rays(0, 8)
    with pytest.raises(ValueError, match=match):
        sample_rays(o, d, BOX, **kwargs)


def test_ray_bad_input():
    o, d = random_rays(0, 8)
    with pytest.raises(ValueError, match="dirs: expected shape"):
        ray_aabb(o, d[:5], BOX)
    with pytest.raises(ValueError, match="dirs: expected non-zero directions"):
        ray_aabb(o, np.zeros_like(d), BOX)
    with pytest.raises(ValueError, match="origins: expected finite values"):
        ray_aabb(np.full_like(o, np.nan), d, BOX)
    with value_checks(False):  # the value checks are skipped, the shape checks stay
        ray_aabb(o, np.zeros_like(d), BOX)
        with pytest.raises(ValueError, match="dirs: expected shape"):
            ray_aabb(o, d[:5], BOX)
    with pytest.raises(ValueError, match="bbox: expected finite corners with min < max"):
        ray_aabb(o, d, BOX[::-1])
    with pytest.raises(ValueError, match="dirs: expected dtype float64 like the other inputs"):
        ray_aabb(o, d.astype(np.float32), BOX)
    with pytest.raises(ValueError, match="resolution"):
        OccupancyGrid(BOX, (4, 4))
    with pytest.raises(ValueError, match="decay"):
        OccupancyGrid(BOX, (4, 4, 4), decay=1.0)
    with pytest.raises(ValueError, match="sigma: expected values >= 0"):
        OccupancyGrid(BOX, (2, 2, 2)).update(-np.ones(8))


def test_device_value_checks_count_like_the_host_checks():
    """The counting kernels that check offsets and directions on CUDA, run here as one CPU launch."""
    from kernels.volume import _checks

    def count(kernel, x, *extra):
        return A.device_count(kernel, x.shape[0], [x, *extra], x.device)

    offsets = lambda *v: wp.array(np.array(v, np.int32))  # noqa: E731
    assert count(_checks._count_bad_offsets, offsets(0, 2, 2, 6), 6) == 0
    assert count(_checks._count_bad_offsets, offsets(0, 4, 2, 6), 6) == 1  # decreasing
    assert count(_checks._count_bad_offsets, offsets(1, 2, 2, 6), 6) == 1  # does not start at 0
    assert count(_checks._count_bad_offsets, offsets(0, 2, 2, 6), 7) == 1  # does not end at N
    for dtype in (wp.float32, wp.float64):
        dirs = wp.array(np.array([[0, 0, 1.0], [0, 0, 0], [1e-30, 0, 0], [0, 0, 0]]), dtype=dtype)
        assert count(_checks._count_zero_rows, dirs) == 2


@pytest.mark.parametrize("s", [17, 16, 4], ids=["S17", "S16_quads", "S4_quads"])
@pytest.mark.parametrize("layout", ["contiguous", "strided"])
@pytest.mark.parametrize("np_t", [np.float32, np.float64], ids=["float32", "float64"])
def test_dense_samples_match_numpy_broadcasting_bit_for_bit(np_t, layout, s):
    # The packing kernel rounds as NumPy does: x = o + (t d), z = t z_scale (four samples at a
    # time when S % 4 == 0). On the CPU it reads the inputs in place; strided and Fortran-ordered
    # inputs are made contiguous first.
    rng = np.random.default_rng(7)
    r = 300
    o = rng.normal(size=(r, 3)).astype(np_t)
    d = rng.normal(size=(r, 3)).astype(np_t)
    t = np.sort(rng.uniform(0.5, 6.0, (r, s)), axis=1).astype(np_t)
    delta = rng.uniform(0.0, 0.3, (r, s)).astype(np_t)
    zs = rng.uniform(0.5, 1.0, r).astype(np_t)
    if layout == "strided":
        o = np.asfortranarray(o)
        d = np.repeat(d, 2, axis=1)[:, ::2]
        t = np.repeat(t, 2, axis=0)[::2]
        zs = np.repeat(zs, 3)[::3]
    inputs = [x.copy() for x in (o, d, t, delta, zs)]
    got = dense_samples(o, d, t, delta, z_scale=zs)
    for x, x0 in zip((o, d, t, delta, zs), inputs):  # read, never written
        np.testing.assert_array_equal(x, x0)
    # bit-equal on any CPU: x = o + t d is one IEEE product then one IEEE sum in the kernel (no contraction across
    # Warp's statements) and in NumPy's two ufuncs, each correctly rounded; the rest are copies and integers
    np.testing.assert_array_equal(got.points.numpy(), (o[:, None, :] + t[:, :, None] * d[:, None, :]).reshape(-1, 3))
    np.testing.assert_array_equal(got.dirs.numpy(), np.repeat(d, s, axis=0))
    np.testing.assert_array_equal(got.t.numpy(), t.reshape(-1))
    np.testing.assert_array_equal(got.delta.numpy(), delta.reshape(-1))
    np.testing.assert_array_equal(got.z.numpy(), (t * zs[:, None]).reshape(-1))
    np.testing.assert_array_equal(got.ray_index.numpy(), np.repeat(np.arange(r), s))
    np.testing.assert_array_equal(got.ray_offsets.numpy(), np.arange(r + 1) * s)
