"""research.stereo.matching (named apart from tests/kernels/test_stereo.py, which pytest would confuse with it): KITTI fill,
disparity and depth metrics, patch features, and the pipeline end to end."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import warp as wp
import pytest

from research.stereo.matching import (StereoConfig, depth_abs_rel, disparity_metrics, fill_invalid, match, patch_features,
                             to_gray_u8)


def test_fill_invalid_takes_the_background_end_of_each_gap():
    disp = np.array([[9.0, 5.0, 7.0, 8.0, 3.0, 6.0],
                     [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]])
    valid = np.array([[False, True, False, False, True, False],
                      [False, False, False, False, False, False]])
    got = fill_invalid(disp, valid)
    # Row 0: the left border copies 5; the gap between 5 and 3 takes min = 3; the right border copies 3.
    np.testing.assert_array_equal(got[0], [5.0, 5.0, 3.0, 3.0, 3.0, 3.0])
    np.testing.assert_array_equal(got[1], 0.0)  # no valid pixel in the row


def test_disparity_metrics_by_hand():
    gt = np.array([[10.0, 10.0, 80.0, 80.0]])
    pred = np.array([[10.5, 12.5, 83.5, 85.0]])  # errors 0.5, 2.5, 3.5, 5.0
    m = disparity_metrics(pred, gt, np.ones_like(gt, dtype=bool))
    assert m["epe"] == pytest.approx((0.5 + 2.5 + 3.5 + 5.0) / 4)
    assert (m["bad1"], m["bad2"], m["bad3"]) == (0.75, 0.75, 0.5)
    # D1 needs > 3 px AND > 5 %: 3.5 px of 80 is 4.4 % (not an outlier), 5 px of 80 is 6.25 %.
    assert m["d1"] == 0.25 and m["pixels"] == 4
    with pytest.raises(ValueError, match="mask"):
        disparity_metrics(pred, gt, np.zeros_like(gt, dtype=bool))


def test_depth_abs_rel_skips_invalid_depth():
    disp = np.array([[2.0, 4.0, 0.0]])
    gt_depth = np.array([[10.0, 4.0, 7.0]])  # f b = 20: estimates 10 (exact) and 5 (25 % off); d = 0 is invalid
    m = depth_abs_rel(disp, gt_depth, np.ones((1, 3), dtype=bool), focal=100.0, baseline=0.2)
    assert m["abs_rel"] == pytest.approx(0.125) and m["depth_valid_fraction"] == pytest.approx(2 / 3)


def test_patch_features_are_zero_mean_and_normalised():
    img = np.random.default_rng(0).uniform(0.0, 1.0, (7, 9))
    f = patch_features(img, 1, floor=0.0)
    assert f.shape == (9, 7, 9)
    np.testing.assert_allclose(f.mean(axis=0), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(f, axis=0), 1.0, rtol=1e-5)
    np.testing.assert_allclose(f[:, 3, 4], (img[2:5, 3:6] - img[2:5, 3:6].mean()).ravel()
                               / np.linalg.norm(img[2:5, 3:6] - img[2:5, 3:6].mean()), rtol=1e-5)


def test_to_gray_u8():
    rgba = np.zeros((1, 3, 4))
    rgba[0, 1, :3] = 1.0
    rgba[0, 2, 1] = 1.0  # pure green: luminance 0.7152 -> sRGB 0.8625 -> 219.9 -> 220
    np.testing.assert_array_equal(to_gray_u8(rgba), [[0, 255, 220]])


@pytest.mark.parametrize("cfg", [StereoConfig("sad", "sgm8", p1=0.02, p2=0.2, radius=2),
                                 StereoConfig("census", "sgm4", p1=8.0, p2=64.0, census_radii=(2, 3)),
                                 StereoConfig("zncc", "none", radius=2),
                                 StereoConfig("bt", "sgm8", p1=0.02, p2=0.16, radius=1),
                                 StereoConfig("corr", "sgm8", p1=0.01, p2=0.1, radius=2),
                                 StereoConfig("sad", "sgm8", p1=0.02, p2=0.2, disparity="soft_argmin",
                                              temperature=0.02)])
def test_match_recovers_a_constant_disparity(cfg):
    # A smooth random texture shifted by 4 px: away from the left border every pipeline finds 4.
    rng = np.random.default_rng(1)
    base = rng.uniform(0.0, 1.0, (24, 52))
    base = (base + np.roll(base, 1, axis=1) + np.roll(base, 1, axis=0)) / 3.0
    left, right = base[:, 0:44], base[:, 4:48]  # left (x) = right (x - 4)
    r = match(left, right, 0, 12, cfg)
    assert set(r.timings) == {"cost_s", "aggregate_s", "disparity_s", "total_s"}
    inner = (slice(3, -3), slice(10, -3))
    np.testing.assert_allclose(r.disparity[inner], 4.0, atol=0.5)  # the sub-pixel fit stays within half a pixel
    assert r.valid[inner].mean() > 0.95


@pytest.mark.parametrize("dtype", ["uint8", "uint16", "float"])
def test_bt_takes_colour_in_any_unit(dtype):
    # One colour pair stored three ways gives one BT volume (up to the 8-bit rounding of the float copy).
    from research.stereo.matching import cost_volume

    rng = np.random.default_rng(2)
    base = rng.integers(0, 256, (12, 30, 3)).astype(np.uint8)
    left, right = base[:, 3:27], base[:, 0:24]
    conv = {"uint8": lambda x: x, "uint16": lambda x: x.astype(np.uint16) * 257, "float": lambda x: x / 255.0}[dtype]
    cfg = StereoConfig("bt", "sgm8", p1=0.02, p2=0.16, radius=1)
    got = cost_volume(conv(left), conv(right), 0, 6, cfg).numpy()
    want = cost_volume(left, right, 0, 6, cfg).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)
    assert got.shape == (12, 24, 6)


def test_compact_mode_gives_the_float32_result():
    # Census + SGM with integer penalties runs on uint8 costs and a uint16 aggregate: the numbers of the
    # float32 census volume through the same back end.
    import research.stereo.matching as rs
    from kernels import stereo

    rng = np.random.default_rng(3)
    left = rng.uniform(0.0, 1.0, (20, 48))
    right = np.roll(left, -3, axis=1)
    cfg = StereoConfig("census", "sgm8", p1=8.0, p2=64.0, census_radii=(2, 3), uniqueness=0.1)
    c32 = stereo.census_cost(left.astype(np.float32), right.astype(np.float32), 0, 16, 2, 3)
    want_d, want_v = stereo.sgm_disparity(c32, 0, 8.0, 64.0, 8, uniqueness=0.1, lr_max_diff=1.0)
    assert rs.uses_compact(cfg, 20, 48, 16) and not rs.uses_compact(cfg, 20, 48, 12)
    assert not rs.uses_compact(StereoConfig("census", "sgm8", p1=8.0, p2=7937.0), 20, 48, 16)
    assert not rs.uses_compact(StereoConfig("census", "sgm8", p1=8.5, p2=64.0), 20, 48, 16)
    assert rs.cost_volume(left, right, 0, 16, cfg).dtype == wp.uint8
    got = match(left, right, 0, 16, cfg)
    np.testing.assert_array_equal(got.disparity, want_d)
    np.testing.assert_array_equal(got.valid, want_v)
    assert rs.peak_volume_bytes(cfg, 20, 48, 16) == 20 * 48 * (16 + 3 * 32)


def test_adcensus_compact_mode_quantises_the_cost_and_the_penalties(monkeypatch):
    """Above the budget, adcensus + SGM runs on its uint8 cost (step 1 / 110 for the default's weights) with P1, P2
    rounded to that step; on a textured pair with a known shift the disparities barely move. FAST_DEFAULT_CONFIG
    (fast_compact) runs so at every size, with the vector rho."""
    import research.stereo.matching as rs

    DEFAULT_CONFIG, fast_cfg = rs.DEFAULT_CONFIG, rs.FAST_DEFAULT_CONFIG
    assert not DEFAULT_CONFIG.fast_compact and fast_cfg == replace(DEFAULT_CONFIG, fast_compact=True)
    assert rs.compact_penalties(DEFAULT_CONFIG) == (88, 704)
    rng = np.random.default_rng(4)
    left = rng.uniform(0.0, 1.0, (24, 64, 3)).astype(np.float32)
    right = np.roll(left, -5, axis=1)
    want = match(left, right, 0, 16)
    assert rs.cost_volume(left, right, 0, 16, DEFAULT_CONFIG).dtype == wp.float32
    monkeypatch.setattr(rs, "FLOAT_VOLUME_BUDGET", 0)
    assert rs.uses_compact(DEFAULT_CONFIG, 24, 64, 16) and not rs.uses_compact(DEFAULT_CONFIG, 24, 64, 12)
    assert not rs.uses_compact(StereoConfig("adcensus", "sgm8", p1=0.8, p2=100.0), 24, 64, 16)  # 8 (255 + P2 q)
    assert rs.cost_volume(left, right, 0, 16, DEFAULT_CONFIG).dtype == wp.uint8
    got = match(left, right, 0, 16)
    assert np.mean(np.abs(got.disparity - want.disparity)[:, 16:] <= 0.25) > 0.98
    assert np.mean(got.valid == want.valid) > 0.98
    # uint8 costs + the uint16 aggregate and a uint8 copy, both padded to whole 32-lane vectors
    assert rs.peak_volume_bytes(DEFAULT_CONFIG, 24, 64, 16) == 24 * 64 * (16 + 2 * 32 + 32)
    monkeypatch.undo()
    # Middlebury at half resolution: compact by the real budget (3.0 GB of float32 volumes > 1 GiB).
    assert rs.uses_compact(DEFAULT_CONFIG, 994, 1482, 256) and not rs.uses_compact(DEFAULT_CONFIG, 375, 450, 64)
    assert rs.peak_volume_bytes(DEFAULT_CONFIG, 994, 1482, 256) == 3 * 994 * 1482 * 256
    # fast_compact: compact at every size (D a multiple of 8), its cost by the vector rho.
    assert rs.uses_compact(fast_cfg, 375, 450, 64) and rs.uses_compact(fast_cfg, 24, 64, 16)
    assert not rs.uses_compact(fast_cfg, 24, 64, 12)
    assert rs.cost_volume(left, right, 0, 16, fast_cfg).dtype == wp.uint8
    assert rs.peak_volume_bytes(fast_cfg, 375, 450, 64) == 3 * 375 * 450 * 64
    fast = match(left, right, 0, 16, fast_cfg)
    assert np.mean(np.abs(fast.disparity - want.disparity)[:, 16:] <= 0.25) > 0.98
    assert np.mean(fast.valid == want.valid) > 0.98
    with pytest.raises(ValueError, match="fast_compact"):
        StereoConfig("adcensus", "sgm8", fast_compact=1)


def test_config_rejects_unknown_names():
    with pytest.raises(ValueError, match="cost"):
        StereoConfig(cost="ssd")
    with pytest.raises(ValueError, match="aggregation"):
        StereoConfig(aggregation="sgm16")


def test_border_invalidation_and_median_post_processing():
    """In the columns x < dmax - 1, pixels left of d_b + 1 (d_b: the row's first valid full-range disparity)
    become invalid; the median runs on the filled map and keeps the valid mask."""
    import research.stereo.matching as rs

    disp = np.array([[0.0, 1.0, 2.0, 3.0, 2.5, 2.5, 2.5, 2.5],
                     [0.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.5],
                     [0.0, 1.0, 2.0, 3.0, 3.0, 3.0, 3.0, 3.0]], np.float32)
    valid = np.ones_like(disp, bool)
    valid[2, 4:] = False  # no valid full-range pixel in row 2: nothing to go by, the row stays as it is
    cfg = StereoConfig("census", "sgm8", border_invalid=True)
    d, v = rs.post_process(disp, valid, 5, cfg)  # dmax 5: columns 0..3 lack some hypotheses
    np.testing.assert_array_equal(d, disp)
    assert v[0].tolist() == [False] * 4 + [True] * 4  # x < 2.5 + 1: the whole band, columns 0..3
    assert v[1].tolist() == [False, False] + [True] * 6  # x < 0.5 + 1
    assert v[2].tolist() == [True] * 4 + [False] * 4
    d2, v2 = rs.post_process(disp, valid, 5, StereoConfig("census", "sgm8", median=3))
    np.testing.assert_array_equal(v2, valid)
    from scipy.ndimage import median_filter

    np.testing.assert_array_equal(d2, median_filter(rs.fill_invalid(disp, valid), size=3, mode="nearest"))
