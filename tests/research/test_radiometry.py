"""research.radiometry: the stress set's effects, each checked alone against its formula."""

import numpy as np
import pytest

from research.io import linear_to_srgb, srgb_to_linear
from research.radiometry import Camera, Stress, apply_camera, clean, draw_camera, stress, stress_pair

NO_NOISE = Stress(shot_noise=0.0, read_noise=0.0)


def _render(h=24, w=32, channels=4, seed=0):
    return np.random.default_rng(seed).uniform(0.0, 1.2, (h, w, channels)).astype(np.float32)


def test_none_equals_clean_and_clean_is_srgb_8bit():
    img = _render()
    out = stress(img, np.random.default_rng(3), Stress.none())
    ref = np.floor(np.clip(linear_to_srgb(np.clip(img[..., :3].astype(np.float64), 0, 1)), 0, 1) * 255 + 0.5)
    assert out.dtype == np.uint8 and out.shape == (24, 32, 3)
    np.testing.assert_array_equal(out, clean(img))
    np.testing.assert_array_equal(out, ref.astype(np.uint8))


def test_deterministic_from_the_seed_and_cameras_differ():
    img = _render()
    a1, b1 = stress_pair(img, img, seed=7)
    a2, b2 = stress_pair(img, img, seed=7)
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(b1, b2)
    assert not np.array_equal(a1, b1)  # two cameras
    assert not np.array_equal(a1, stress_pair(img, img, seed=8)[0])


def test_draw_camera_stays_in_the_ranges():
    p = Stress()
    rng = np.random.default_rng(0)
    cams = [draw_camera(rng, p) for _ in range(200)]
    for field, lo, hi in (("blur_sigma", 0, p.blur_sigma), ("vignetting", 0, p.vignetting),
                          ("exposure_stops", -p.exposure_stops, p.exposure_stops), ("offset", -p.offset, p.offset)):
        vals = np.array([getattr(c, field) for c in cams])
        assert vals.min() >= lo and vals.max() <= hi
        assert vals.max() - vals.min() > 0.8 * (hi - lo)  # the range is used


def test_exposure_and_offset_follow_the_formula():
    img = np.full((8, 8), 0.1)
    out = apply_camera(img, Camera(0.0, 0.0, 1.0, 0.02), np.random.default_rng(0), NO_NOISE)
    expect = np.floor(linear_to_srgb(0.1 * 2.0 + 0.02) * 255 + 0.5)
    assert out.dtype == np.uint8 and out.shape == (8, 8)
    assert np.all(out == expect)


def test_vignetting_darkens_the_corners_by_v():
    img = np.full((41, 61), 0.5)
    out = apply_camera(img, Camera(0.0, 0.4, 0.0, 0.0), np.random.default_rng(0), Stress.none(bits=16))
    lin = srgb_to_linear(out / 65535.0)
    assert lin[20, 30] == pytest.approx(0.5, abs=1e-4)  # the centre keeps its value
    for y, x in ((0, 0), (0, 60), (40, 0), (40, 60)):
        assert lin[y, x] == pytest.approx(0.5 * 0.6, abs=1e-4)
    assert lin[20, 0] > lin[0, 0]


def test_blur_keeps_the_mean_and_smooths():
    rng = np.random.default_rng(1)
    img = rng.uniform(0.2, 0.8, (32, 32))
    sharp = apply_camera(img, Camera(0.0, 0.0, 0.0, 0.0), rng, Stress.none(bits=16)) / 65535.0
    soft = apply_camera(img, Camera(0.8, 0.0, 0.0, 0.0), rng, Stress.none(bits=16)) / 65535.0
    lin_sharp, lin_soft = srgb_to_linear(sharp), srgb_to_linear(soft)
    assert lin_soft.mean() == pytest.approx(lin_sharp.mean(), abs=2e-3)
    assert np.abs(np.diff(lin_soft, axis=1)).mean() < 0.6 * np.abs(np.diff(lin_sharp, axis=1)).mean()


def test_noise_has_the_poisson_gaussian_deviation():
    img = np.full((200, 200), 0.3)
    p = Stress(shot_noise=0.05, read_noise=0.01, bits=16)
    out = apply_camera(img, Camera(0.0, 0.0, 0.0, 0.0), np.random.default_rng(2), p)
    lin = srgb_to_linear(out / 65535.0)
    assert lin.mean() == pytest.approx(0.3, abs=1e-3)
    assert lin.std() == pytest.approx(np.sqrt(0.05 ** 2 * 0.3 + 0.01 ** 2), rel=0.03)


def test_grey_and_16_bit_outputs():
    img = _render(channels=1)[..., 0]
    out = stress(img, np.random.default_rng(0), Stress(bits=16))
    assert out.dtype == np.uint16 and out.shape == img.shape
