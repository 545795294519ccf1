"""research.flow.coarse_to_fine (coarse-to-fine correlation flow) and research.flow.texture (the real-photograph pairs)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from research.flow import coarse_to_fine as c2f
from research.flow import texture as tf


@pytest.fixture(scope="module")
def photo_pair():
    """A 96x128 crop of the photograph's evaluation half, warped by a smooth 4 px (median) flow."""
    src = tf.split("eval")[60:156, 192:320]
    flow = tf.smooth_flow(src.shape[:2], 4.0, seed=0)
    f1, f2, valid = tf.warped_pair(src, flow)
    return f1, f2, np.moveaxis(flow, 0, -1), valid


def _epe(flow, gt, valid):
    return float(np.linalg.norm(flow - gt, axis=-1)[valid].mean())


def test_photograph_beats_zero_flow_and_farneback(photo_pair):
    f1, f2, gt, valid = photo_pair
    flow = c2f.coarse_to_fine_flow(f1, f2)
    assert flow.shape == gt.shape and np.all(np.isfinite(flow))
    g1, g2 = (cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in (f1, f2))
    farneback = cv2.calcOpticalFlowFarneback(g1, g2, None, 0.5, 5, 15, 3, 5, 1.2, 0)
    ours, zero, fb = _epe(flow, gt, valid), _epe(np.zeros_like(gt), gt, valid), _epe(farneback, gt, valid)
    assert ours < 0.25 * zero, (ours, zero)
    assert ours < fb, (ours, fb)


def test_grey_float_and_uint8_inputs_agree(photo_pair):
    f1, f2, gt, valid = photo_pair
    g1, g2 = (cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in (f1, f2))
    a = c2f.coarse_to_fine_flow(g1, g2, c2f.C2FConfig(levels=3, warps=1))
    b = c2f.coarse_to_fine_flow(g1 / 255.0, g2 / 255.0, c2f.C2FConfig(levels=3, warps=1))
    np.testing.assert_allclose(a, b, atol=1e-4)
    assert _epe(a, gt, valid) < _epe(np.zeros_like(gt), gt, valid)


def test_dense_and_onthefly_lookups_give_the_same_flow(photo_pair):
    f1, f2 = (f[:48, :64] for f in photo_pair[:2])  # the dense level-0 volume: (48 x 64)^2 floats, 36 MiB
    info_dense, info_otf = {}, {}
    dense = c2f.coarse_to_fine_flow(f1, f2, c2f.C2FConfig(levels=2, warps=1, memory_budget_mib=64), info=info_dense)
    otf = c2f.coarse_to_fine_flow(f1, f2, c2f.C2FConfig(levels=2, warps=1, memory_budget_mib=1e-6), info=info_otf)
    assert set(info_dense["lookup"]) == {"dense"} and set(info_otf["lookup"]) == {"on the fly"}
    # The two lookups agree to float32 rounding (kernels.corr's tests); the matching's argmax can only
    # flip on exact ties, so the flows agree closely.
    assert np.abs(dense - otf).max() < 1e-3


def test_match_recovers_a_subpixel_peak():
    radius, h, w = 3, 4, 5
    side = 2 * radius + 1
    a, b = np.meshgrid(np.arange(side) - radius, np.arange(side) - radius, indexing="ij")
    true = (1.3, -0.8)  # x, y: a paraboloid's apex is recovered exactly by the per-axis parabola
    ncc = 1.0 - 0.05 * ((a - true[0]) ** 2 + (b - true[1]) ** 2)
    ncc = np.repeat(ncc.reshape(side * side, 1, 1), h, 1).repeat(w, 2)
    step, distinct = c2f.match(ncc, radius, np.ones_like(ncc, dtype=bool))
    np.testing.assert_allclose(step[0], true[0], atol=1e-9)
    np.testing.assert_allclose(step[1], true[1], atol=1e-9)
    assert np.all(distinct > 0)
    # Excluding every offset (all outside frame 2) gives no step and no confidence.
    step, distinct = c2f.match(ncc, radius, np.zeros_like(ncc, dtype=bool))
    assert not step.any() and not distinct.any()


def test_window_inside_matches_a_loop():
    rng = np.random.default_rng(0)
    flow = rng.uniform(-4, 4, (2, 6, 7))
    radius = 2
    got = c2f.window_inside(flow, radius)
    side = 2 * radius + 1
    for a in range(side):
        for b in range(side):
            for y in range(6):
                for x in range(7):
                    sx, sy = x + flow[0, y, x] + a - radius, y + flow[1, y, x] + b - radius
                    assert got[a * side + b, y, x] == (0 <= sx <= 6 and 0 <= sy <= 5)


def test_tv_l1_keeps_confident_values_and_fills_the_rest():
    m = np.zeros((2, 16, 16))
    m[0, :, 8:] = 3.0  # a step edge in u_x
    weight = np.full((16, 16), 10.0)
    weight[6:10, 6:10] = 0.0  # no data here: filled from the neighbours
    m[:, 6:10, 6:10] = 50.0  # (the data there is junk and must be ignored)
    u = c2f.tv_l1(m, weight, lam=4.0, iterations=300, u0=np.zeros_like(m))
    keep = weight > 0
    np.testing.assert_allclose(u[:, keep], m[:, keep], atol=1e-2)  # TV-L1 keeps a strongly weighted edge
    # Filled between the edge's two values (to the 300 primal-dual steps' convergence, 1e-3).
    assert np.all((u[0, 6:10, 6:10] >= -1e-3) & (u[0, 6:10, 6:10] <= 3.0 + 1e-3))
    assert np.abs(u[1, 6:10, 6:10]).max() < 1e-2


def test_grad_and_div_are_adjoint():
    rng = np.random.default_rng(1)
    u, px, py = rng.standard_normal((3, 2, 5, 6))
    gx, gy = c2f._grad(u)
    assert np.isclose((gx * px + gy * py).sum(), -(u * c2f._div(px, py)).sum())


def test_warped_pair_has_the_flow_it_claims():
    """On a linear ramp, cubic interpolation is exact: frame 1 at p equals frame 2 at p + flow."""
    h, w = 40, 50
    yy, xx = np.indices((h, w))
    src = (2 * xx + 3 * yy).astype(np.uint8)
    flow = tf.smooth_flow((h, w), 2.0, seed=3)
    f1, f2, valid = tf.warped_pair(src, flow)
    sx, sy = xx + flow[0], yy + flow[1]
    want = 2 * sx + 3 * sy
    # Away from the border (where the spline's boundary condition bends it), up to the uint8 rounding.
    inner = (sx >= 4) & (sx <= w - 5) & (sy >= 4) & (sy <= h - 5)
    assert inner.sum() > 500 and np.array_equal(valid, (sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1))
    assert np.abs(f1[inner].astype(float) - want[inner]).max() <= 0.5 + 1e-3
    assert np.array_equal(f2, src)
    assert np.median(np.hypot(*flow)) == pytest.approx(2.0)


def test_photograph_splits_do_not_overlap():
    img = tf.photograph()
    assert img.shape == (600, 512, 3) and img.dtype == np.uint8
    assert np.array_equal(np.concatenate([tf.split("eval", img), tf.split("tuning", img)]), img)
    assert not set(tf.TUNING_SEEDS) & set(tf.EVAL_SEEDS)
