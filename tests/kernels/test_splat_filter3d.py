"""Mip-Splatting's 3D filter (kernels/splat/filter3d.py) against its NumPy reference, its gradient check,
and the filter sizes from the cameras (research/splats/mip.py)."""

from __future__ import annotations

import numpy as np
import pytest

from kernels.reference import splat_filter3d as ref
from kernels.splat.filter3d import filter_3d, filter_3d_backward
from research.cameras import Camera, look_at
from research.checks.mip_filter import check_filter
from research.gradcheck import assert_gradcheck
from research.splats import mip


def _splats(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    sigma = rng.uniform(0.0, 0.05, n)
    sigma[0] = 0.0  # no filter: the splat unchanged
    return rng.normal(-3.5, 1.0, (n, 3)), rng.uniform(-4, 4, n), sigma, rng.normal(size=(n, 4))


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-12), (np.float32, 2e-5)])
def test_forward_is_the_filtered_covariance(dtype, tol):
    ls, al, sg, q = _splats(64)
    out_s, out_l = filter_3d(ls.astype(dtype), al.astype(dtype), sg.astype(dtype))
    want_s, want_l = ref.filter_3d(ls, al, sg, q)
    assert out_s.dtype == dtype and out_l.dtype == dtype
    # float32: exp/log of values near e^-7 and the logit of q in (0.02, 0.98): a few ulps of each, relative
    np.testing.assert_allclose(out_s, want_s, rtol=tol, atol=0)
    np.testing.assert_allclose(out_l, want_l, rtol=tol, atol=tol)
    np.testing.assert_array_equal(out_s[0], ls[0].astype(dtype))  # sigma = 0: exactly the splat
    assert np.all(out_s >= ls.astype(dtype)) and np.all(out_l <= al.astype(dtype))  # wider, fainter


def test_reference_does_not_depend_on_the_rotation():
    ls, al, sg, q = _splats(16, seed=1)
    a = ref.filter_3d(ls, al, sg, q)
    b = ref.filter_3d(ls, al, sg, np.random.default_rng(5).normal(size=q.shape))
    np.testing.assert_allclose(a[0], b[0], rtol=1e-12)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-12)


def test_backward_passes_the_float64_gradient_check():
    assert_gradcheck(check_filter(seed=3))


def test_bad_inputs_are_named():
    ls, al, sg, _ = _splats(4)
    with pytest.raises(ValueError, match="log_scales"):
        filter_3d(ls[:, :2], al, sg)
    with pytest.raises(ValueError, match="opacity_logits"):
        filter_3d(ls, al[:3], sg)
    with pytest.raises(ValueError, match="sigma"):
        filter_3d(ls, al, -sg - 1)
    with pytest.raises(ValueError, match="grad_opacity_logits"):
        filter_3d_backward(ls, al, sg, ls, al[:2])


def _camera(eye, f: float = 50.0, size: int = 64) -> Camera:
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    return Camera(K, look_at(np.asarray(eye, float), np.zeros(3), up=(0.0, -1.0, 0.0)), size, size)


def test_filter_sigma_takes_the_closest_camera_that_sees_each_splat():
    near_cam, far_cam = _camera([0, 0, -2.0]), _camera([0, 0, -4.0], f=80.0)
    means = np.array([[0.0, 0.0, 0.0],     # seen by both: z / f = 2/50 and 4/80 -> 0.04
                      [0.0, 0.0, -3.0],    # behind near_cam, 1 in front of far_cam: 1/80
                      [0.0, 0.0, -10.0]])  # seen by neither: the largest of the others
    sigma = mip.filter_sigma(means, [near_cam, far_cam], s=0.2)
    np.testing.assert_allclose(sigma, np.sqrt(0.2) * np.array([0.04, 1 / 80, 0.04]), rtol=1e-6)
    with pytest.raises(ValueError, match="no splat centre"):
        mip.filter_sigma(means[2:], [near_cam, far_cam])
    with pytest.raises(ValueError, match="s: expected a positive"):
        mip.filter_sigma(means, [near_cam], s=0.0)


def test_train_config_refuses_a_negative_filter_or_dilation():
    from research.splats.train import TrainConfig

    with pytest.raises(ValueError, match="filter_3d"):
        TrainConfig(filter_3d=-0.2)
    with pytest.raises(ValueError, match="dilation"):
        TrainConfig(dilation=-1.0)


def test_training_with_the_filter_returns_the_filter_baked_in(monkeypatch):
    from research.splats import model as sm, train as st

    cams = [_camera([np.sin(a) * 3, 0.3, -np.cos(a) * 3], f=30.0, size=24) for a in (0.0, 0.4, 0.8)]
    rng = np.random.default_rng(0)
    init = sm.from_points(rng.uniform(-0.5, 0.5, (40, 3)), rng.uniform(0.2, 0.8, (40, 3)))
    init.log_scales[:] = np.log(0.004)  # far below the filter's sigma (about 0.045 here)
    images = np.full((3, 24, 24, 3), 0.5, np.float32)
    seen = []
    real = mip.filter_sigma
    monkeypatch.setattr(mip, "filter_sigma", lambda *a, **k: seen.append(real(*a, **k)) or seen[-1])
    cfg = st.TrainConfig(iterations=3, filter_3d=0.2, log_every=1)
    res = st.train(init, cams, images, 1.0, cfg, progress=False)
    assert seen and len(seen[-1]) == res.model.n
    # baked in: every axis of a filtered splat is at least the filter's sigma (s' = sqrt(s^2 + sigma^2))
    assert np.all(seen[-1] > 0)
    assert np.all(np.exp(res.model.log_scales) >= seen[-1][:, None] * (1 - 1e-6))
    plain = st.train(init, cams, images, 1.0, st.TrainConfig(iterations=3, log_every=1), progress=False)
    assert not np.all(np.exp(plain.model.log_scales) >= seen[-1][:, None])  # which training alone does not give
