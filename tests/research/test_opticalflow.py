"""research.flow.raft: flow metrics, colour wheel, fixed features and the weight-free CorrFlow estimator."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from research.flow import raft as of


def test_flow_metrics_by_hand():
    gt = np.zeros((2, 3, 2))
    gt[..., 0] = 100.0  # |gt| = 100: 5% is 5 px, so an outlier needs EPE > 5
    flow = gt.copy()
    flow[0, 0] += [4.0, 0.0]  # EPE 4: > 3 but < 5% of 100 -> not an outlier
    flow[0, 1] += [0.0, 6.0]  # EPE 6 -> outlier
    flow[1, 2] += [3.0, 4.0]  # EPE 5 -> not (> 5 is required)
    mask = np.ones((2, 3), bool)
    m = of.flow_metrics(flow, gt, mask)
    assert m["epe"] == pytest.approx(15.0 / 6) and m["f1_all"] == pytest.approx(100.0 / 6) and m["pixels"] == 6
    mask[0, 1] = False
    assert of.flow_metrics(flow, gt, mask)["f1_all"] == 0.0
    with pytest.raises(ValueError, match="mask: expected at least one pixel"):
        of.flow_metrics(flow, gt, np.zeros((2, 3), bool))


def test_flow_to_color_wheel():
    flow = np.array([[[0.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0]]])
    col = of.flow_to_color(flow, max_flow=1.0)
    np.testing.assert_allclose(col[0, 0], [1, 1, 1])  # no motion is white
    # Middlebury's coding: rightwards is red (the wheel's end), leftwards cyan-blue (its middle).
    assert col[0, 2, 0] == 1.0 and col[0, 2, 1] == 0.0 and col[0, 2, 2] < 0.2
    np.testing.assert_allclose(col[0, 1], [0, 1 - 2 / 11, 1])
    assert col[0, 3, 2] == 1.0 and col[0, 3, 1] == 0.0 and col[0, 3, 0] < 0.5  # upwards: blue-violet
    assert np.all((col >= 0) & (col <= 1))


def test_fixed_features_are_normalised_blocks():
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (40, 48, 3))
    f = of.fixed_features(img, stride=4)
    assert f.shape == (3 * of.PATCH ** 2 * of.SCALES, 10, 12) and f.dtype == np.float32
    blocks = f.reshape(of.SCALES, -1, 10, 12).astype(np.float64)
    np.testing.assert_allclose(blocks.mean(axis=1), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.sqrt((blocks ** 2).sum(axis=1)), 1.0, rtol=1e-5)
    flat = of.fixed_features(np.full((40, 48, 3), 0.3), stride=4)
    assert np.abs(flat).max() < 1e-6  # no texture, no feature


def test_corrflow_recovers_translation_dense_and_onthefly_agree():
    rng = np.random.default_rng(1)
    img = ndimage.gaussian_filter(rng.uniform(0, 1, (96, 96, 3)), (2, 2, 0))
    img = (img - img.min()) / (img.max() - img.min())
    moved = ndimage.shift(img, (4.0, 10.0, 0), order=1, mode="nearest")  # +10 px in x, +4 px in y
    cfg = of.CorrFlowConfig(levels=3, radius=2)
    dense = of.CorrFlow(img, moved, stride=4, max_levels=3).estimate(cfg)
    otf = of.CorrFlow(img, moved, stride=4, max_levels=3, onthefly=True).estimate(cfg)
    inner = (slice(24, -24), slice(24, -24))
    np.testing.assert_allclose(np.median(dense[inner], axis=(0, 1)), [10.0, 4.0], atol=0.25)
    np.testing.assert_allclose(otf, dense, atol=1e-3)
    zero = np.zeros_like(dense)
    mask = np.zeros(dense.shape[:2], bool)
    mask[inner] = True
    gt = np.broadcast_to([10.0, 4.0], dense.shape)
    assert of.flow_metrics(dense, gt, mask)["epe"] < 0.1 * of.flow_metrics(zero, gt, mask)["epe"]


def test_corrflow_picks_the_lookup_by_the_memory_budget():
    img = np.random.default_rng(2).uniform(0, 1, (64, 64, 3))
    assert of.CorrFlow(img, img, stride=4, max_levels=2).onthefly is False  # 16x16 features: 0.3 MiB
    small = of.CorrFlow(img, img, stride=4, max_levels=2, memory_budget_mib=0.1)
    assert small.onthefly is True
    assert of.CorrFlow(img, img, stride=4, max_levels=2, onthefly=False, memory_budget_mib=0.1).onthefly is False
    with pytest.raises(ValueError, match="onthefly: expected True, False or None"):
        of.CorrFlow(img, img, onthefly=1)
    with pytest.raises(ValueError, match="memory_budget_mib: expected a finite number > 0"):
        of.CorrFlow(img, img, memory_budget_mib=0)


def test_upsample_flow_scales_displacements():
    flow = np.stack([np.full((4, 5), 1.5), np.full((4, 5), -0.5)])
    up = of.upsample_flow(flow, 4, 16, 20)
    assert up.shape == (16, 20, 2)
    np.testing.assert_allclose(up[..., 0], 6.0)
    np.testing.assert_allclose(up[..., 1], -2.0)
