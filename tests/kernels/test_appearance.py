"""The bilateral-grid slice (kernels/appearance.py) against its NumPy reference, its gradient checks, and
the per-image appearance models in splat training (research/splats/appearance.py)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import appearance as ka
from kernels.reference import appearance as ref
from research.gradcheck import assert_gradcheck, run_checks
from research.splats import appearance as ap


def _inputs(shape, size=(11, 13), seed=0, lo=-0.1, hi=1.1):
    rng = np.random.default_rng(seed)
    grid = ka.identity_grid(shape, np.float64) + rng.normal(0.0, 0.2, (*shape, 12))
    return grid, rng.uniform(lo, hi, (*size, 3))  # some luminances outside [0, 1]: the border clamp


@pytest.mark.usefixtures("warp_device")
@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-13), (np.float32, 2e-6)])
@pytest.mark.parametrize("shape", [(8, 16, 16), (3, 4, 5), (1, 1, 1), (5, 1, 2)])
def test_slice_matches_the_reference(dtype, tol, shape):
    grid, rgb = _inputs(shape)
    out = ka.bilateral_slice(grid.astype(dtype), rgb.astype(dtype))
    assert out.dtype == dtype and out.shape == rgb.shape
    # float32: a sum of 8 weighted corners of entries near 1 times colours near 1: a few ulps
    np.testing.assert_allclose(out, ref.bilateral_slice(grid, rgb), rtol=0, atol=tol)


def test_identity_and_affine_grids():
    _, rgb = _inputs((1, 1, 1))
    np.testing.assert_allclose(ka.bilateral_slice(ka.identity_grid((8, 16, 16), np.float64), rgb), rgb, atol=1e-15)
    m = np.array([[1.2, 0.1, 0.0, 0.05], [0.0, 0.9, 0.0, -0.02], [0.1, 0.0, 1.5, 0.0]])
    out = ka.bilateral_slice(m.reshape(1, 1, 1, 12), rgb)
    np.testing.assert_allclose(out, rgb @ m[:, :3].T + m[:, 3], atol=1e-14)
    # a grid that holds the same transform at every node is that transform, wherever the pixel is
    np.testing.assert_allclose(ka.bilateral_slice(np.broadcast_to(m.reshape(12), (3, 4, 5, 12)).copy(), rgb), out,
                               atol=1e-14)


def test_wp_arrays_in_give_wp_arrays_out():
    grid, rgb = _inputs((3, 4, 5))
    g, r = wp.array(grid, dtype=wp.float64), wp.array(rgb, dtype=wp.float64)
    out = ka.bilateral_slice(g, r)
    assert isinstance(out, wp.array)
    np.testing.assert_array_equal(out.numpy(), ka.bilateral_slice(grid, rgb))
    d = ka.bilateral_slice_backward(g, r, out)
    assert isinstance(d["grid"], wp.array) and d["grid"].shape == grid.shape
    np.testing.assert_array_equal(d["rgb"].numpy(), ka.bilateral_slice_backward(grid, rgb, out.numpy())["rgb"])


def test_split_forward_equals_one_launch(monkeypatch):
    grid, rgb = _inputs((8, 16, 16), size=(64, 80))
    split = ka.bilateral_slice(grid, rgb)
    monkeypatch.setenv("DRLAB_THREADS", "1")
    np.testing.assert_array_equal(ka.bilateral_slice(grid, rgb), split)


def test_backwards_pass_the_float64_gradient_checks():
    assert_gradcheck(run_checks(["appearance"]))


def test_bad_inputs_are_named():
    grid, rgb = _inputs((3, 4, 5))
    with pytest.raises(ValueError, match="grid: expected"):
        ka.bilateral_slice(grid[..., :9], rgb)
    with pytest.raises(ValueError, match="grid: expected 4 dimensions"):
        ka.bilateral_slice(grid[0], rgb)
    with pytest.raises(ValueError, match="rgb: expected an"):
        ka.bilateral_slice(grid, rgb[..., :2])
    with pytest.raises(ValueError, match="rgb: expected dtype float64"):
        ka.bilateral_slice(grid, rgb.astype(np.float32))
    with pytest.raises(ValueError, match="grad_out"):
        ka.bilateral_slice_backward(grid, rgb, rgb[:3])
    bad = rgb.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="rgb"):
        ka.bilateral_slice(grid, bad)
    with pytest.raises(ValueError, match="shape"):
        ka.identity_grid((0, 4, 4))


def test_total_variation_is_gsplats():
    rng = np.random.default_rng(0)
    g = rng.normal(size=(2, 3, 4, 5, 12))
    value, _ = ap.total_variation(g)
    # gsplat's total_variation_loss on its (N, 12, L, H, W) layout, written out
    t = np.moveaxis(g, -1, 1)
    want = sum(((np.diff(t, axis=a)) ** 2).sum() / np.diff(t, axis=a)[0].size for a in (2, 3, 4)) / 2
    assert value == pytest.approx(want, rel=1e-12)
    assert ap.total_variation(np.broadcast_to(g[:, :1, :1, :1], g.shape))[0] == 0.0
    assert ap.total_variation(g[:, :1, :1, :1])[0] == 0.0  # the affine model: no neighbours, no TV
    with pytest.raises(ValueError, match="grids"):
        ap.total_variation(g[0])


def test_learning_rate_schedule_is_gsplats_scaled():
    assert ap.lr_at(0, 3000) == pytest.approx(2e-5)
    assert ap.lr_at(100, 3000) == pytest.approx(2e-3 * 0.01 ** (100 / 3000))  # warm-up over 1/30
    assert ap.lr_at(3000, 3000) == pytest.approx(2e-5)


def test_affine_fit_recovers_a_colour_transform():
    rng = np.random.default_rng(1)
    render = rng.uniform(0.0, 0.7, (16, 16, 3)).astype(np.float32)
    m = np.array([[1.3, 0.1, 0.0, 0.02], [0.0, 0.8, 0.1, 0.0], [0.05, 0.0, 1.1, -0.01]])
    target = (render @ m[:, :3].T + m[:, 3]).astype(np.float32)
    np.testing.assert_allclose(ap.affine_fit(render, target), m, atol=1e-5)
    assert ap.corrected_psnr(render, target) > 60


def test_config_refuses_bad_values():
    from research.splats.train import TrainConfig

    for kwargs, name in [({"kind": "grid"}, "kind"), ({"grid": (8, 16)}, "grid"), ({"tv_weight": -1.0}, "tv_weight"),
                         ({"lr": 0.0}, "lr")]:
        with pytest.raises(ValueError, match=f"appearance.{name}"):
            TrainConfig(appearance=ap.AppearanceConfig(**kwargs))


def test_training_fits_each_views_exposure():
    from research.cameras import Camera, look_at
    from research.splats import model as sm, train as st

    def cam(a):
        K = np.array([[30.0, 0, 12], [0, 30.0, 12], [0, 0, 1.0]])
        return Camera(K, look_at(np.array([np.sin(a) * 3, 0.3, -np.cos(a) * 3]), np.zeros(3), up=(0.0, -1.0, 0.0)),
                      24, 24)

    cams = [cam(a) for a in (0.0, 0.4, 0.8)]
    rng = np.random.default_rng(0)
    init = sm.from_points(rng.uniform(-0.5, 0.5, (40, 3)), rng.uniform(0.2, 0.8, (40, 3)))
    images = np.full((3, 24, 24, 3), 0.4, np.float32)
    images[2] *= 2.0  # one view a stop brighter
    plain = st.train(init, cams, images, 1.0, st.TrainConfig(iterations=40, log_every=40), progress=False)
    assert plain.appearance is None
    res = st.train(init, cams, images, 1.0, st.TrainConfig(iterations=40, log_every=40,
                                                           appearance=ap.AppearanceConfig("affine")), progress=False)
    gains = res.appearance.grids[:, 0, 0, 0, [0, 5, 10]].mean(axis=1)
    assert gains[2] > gains[0] and gains[2] > gains[1]  # the bright view's transform brightens
