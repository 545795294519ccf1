"""Reliability of image inputs: research.images' one normalisation, stereo and optical flow.

Bad input: each case names the image or setting and the one-line ValueError (naming the argument)
it must raise before any kernel runs. Recovery: uint8 / uint16 / colour inputs give what the
documented normalisation says, float [0, 1] grey inputs are unchanged bit for bit, and a NaN flow
is drawn black instead of raising IndexError.
"""

from __future__ import annotations

import numpy as np
import pytest

from research.flow import raft as of
from research.stereo import matching as stereo
from research.images import LUMA_601, to_unit, to_unit_grey, unit_grey_pair, unit_pair

rng = np.random.default_rng(0)
GREY = rng.uniform(0, 1, (24, 32))
RGB = rng.uniform(0, 1, (24, 32, 3))
U8 = (GREY * 255).astype(np.uint8)
NAN = GREY.copy()
NAN[2, 3] = np.nan
CFG = stereo.StereoConfig(cost="sad", aggregation="none")

# (id, call, expected message (regex))
CASES = [
    ("float-0-255", lambda: to_unit_grey(GREY * 255, "left"),
     r"left: a float image must lie in \[0, 1\], got values in \[.*\] \(8-bit values\? divide by 255\)"),
    ("float-0-65535", lambda: to_unit_grey(GREY * 60000, "frame1"), r"frame1: .*\(16-bit values\? divide by 65535\)"),
    ("float-negative", lambda: to_unit_grey(GREY - 0.5, "image"), r"image: a float image must lie in \[0, 1\]"),
    ("float-nan", lambda: to_unit_grey(NAN, "right"), r"right: contains NaN or infinite values"),
    ("float-inf", lambda: to_unit(np.full((4, 4), np.inf), "rgb1"), r"rgb1: contains NaN or infinite values"),
    ("int32", lambda: to_unit_grey(GREY.astype(np.int32), "left"),
     r"left: expected uint8, uint16 or a float image in \[0, 1\], got dtype int32"),
    ("bool", lambda: to_unit_grey(GREY > 0.5, "left"), r"left: expected uint8, uint16 or a float image .* dtype bool"),
    ("four-channels", lambda: to_unit_grey(np.zeros((4, 4, 4)), "left"),
     r"left: expected a grey \(H, W\) or colour \(H, W, 3\) image, got shape \(4, 4, 4\)"),
    ("one-dimension", lambda: to_unit_grey(np.zeros(16), "left"), r"left: expected a grey \(H, W\) or colour"),
    ("empty", lambda: to_unit_grey(np.zeros((0, 5)), "left"), r"left: expected a non-empty image, got shape \(0, 5\)"),
    ("pair-sizes-differ", lambda: unit_grey_pair(GREY, GREY[:, :30]),
     r"left, right: expected images of one size, got \(24, 32\) and \(24, 30\)"),
    ("colour-pair-channels-differ", lambda: unit_pair(RGB, GREY),
     r"left, right: expected images of one size and channel count, got \(24, 32, 3\) and \(24, 32\)"),
    ("bt-left-0-255", lambda: stereo.match(RGB * 255, RGB, 0, 4, stereo.StereoConfig(cost="bt", aggregation="none")),
     r"left: a float image must lie in \[0, 1\]"),
    ("bt-colour-and-grey", lambda: stereo.match(RGB, GREY, 0, 4, stereo.StereoConfig(cost="bt", aggregation="none")),
     r"left, right: expected images of one size and channel count"),
    ("stereo-left-0-255", lambda: stereo.match(GREY * 255, GREY, 0, 4, CFG), r"left: a float image must lie in \[0, 1\]"),
    ("stereo-right-nan", lambda: stereo.match(GREY, NAN, 0, 4, CFG), r"right: contains NaN or infinite values"),
    ("stereo-sizes-differ", lambda: stereo.match(U8, U8[:20], 0, 4, CFG), r"left, right: expected images of one size"),
    ("stereo-dmax-below-dmin", lambda: stereo.match(GREY, GREY, 5, 2, CFG), r"dmax: expected dmax >= dmin = 5, got 2"),
    ("stereo-dmax-float", lambda: stereo.match(GREY, GREY, 0, 4.5, CFG), r"dmin, dmax: expected integers"),
    ("stereo-cost-unknown", lambda: stereo.StereoConfig(cost="ssd"), r"cost: expected one of"),
    ("stereo-p1-negative", lambda: stereo.StereoConfig(p1=-1.0), r"p1: expected a finite number >= 0, got -1.0"),
    ("stereo-p2-nan", lambda: stereo.StereoConfig(p2=float("nan")), r"p2: expected a finite number >= 0, got nan"),
    ("stereo-p2-below-p1", lambda: stereo.StereoConfig(p1=8.0, p2=4.0), r"p2: expected p2 >= p1 = 8.0, got 4.0"),
    ("stereo-temperature-0", lambda: stereo.StereoConfig(temperature=0.0), r"temperature: expected a finite number > 0"),
    ("stereo-radius-negative", lambda: stereo.StereoConfig(radius=-1), r"radius: expected an integer >= 0, got -1"),
    ("stereo-lr-max-diff-inf", lambda: stereo.StereoConfig(lr_max_diff=float("inf")), r"lr_max_diff: expected a finite"),
    ("stereo-median-even", lambda: stereo.StereoConfig(median=4), r"median: expected 0 \(off\) or an odd size >= 3, got 4"),
    ("stereo-median-1", lambda: stereo.StereoConfig(median=1), r"median: expected 0 \(off\) or an odd size >= 3, got 1"),
    ("stereo-border-not-bool", lambda: stereo.StereoConfig(border_invalid=1), r"border_invalid: expected True or False"),
    ("stereo-lambda-grad-0", lambda: stereo.StereoConfig(lambda_grad=0.0), r"lambda_grad: expected a finite number > 0"),
    ("stereo-bt-weight-negative", lambda: stereo.StereoConfig(bt_weight=-1.0), r"bt_weight: expected a finite number >= 0"),
    ("flow-config-levels-0", lambda: of.CorrFlowConfig(levels=0), r"levels: expected an integer >= 1, got 0"),
    ("flow-config-radius-0", lambda: of.CorrFlowConfig(radius=0), r"radius: expected an integer >= 1, got 0"),
    ("flow-config-iterations-float", lambda: of.CorrFlowConfig(iterations=2.5), r"iterations: expected an integer >= 1"),
    ("flow-config-temperature-nan", lambda: of.CorrFlowConfig(temperature=float("nan")),
     r"temperature: expected a finite number > 0, got nan"),
    ("flow-config-temperature-negative", lambda: of.CorrFlowConfig(temperature=-0.05), r"temperature: expected a finite"),
    ("flow-config-min-confidence-0", lambda: of.CorrFlowConfig(min_confidence=0.0), r"min_confidence: expected a finite"),
    ("flow-config-smooth-radius-negative", lambda: of.CorrFlowConfig(smooth_radius=-1), r"smooth_radius: expected an integer >= 0"),
    ("flow-config-aggregate-bool", lambda: of.CorrFlowConfig(aggregate=True), r"aggregate: expected an integer >= 0, got True"),
    ("corrflow-0-255", lambda: of.CorrFlow(RGB * 255, RGB), r"rgb1: a float image must lie in \[0, 1\]"),
    ("corrflow-shapes", lambda: of.CorrFlow(RGB, RGB[:20]), r"rgb2: expected the shape of rgb1 \(24, 32, 3\)"),
    ("corrflow-stride-0", lambda: of.CorrFlow(RGB, RGB, stride=0), r"stride: expected an integer >= 1, got 0"),
    ("lk-frame2-0-255", lambda: of.lucas_kanade(GREY, GREY * 255), r"frame2: a float image must lie in \[0, 1\]"),
    ("pyramidal-lk-frame1-nan", lambda: of.pyramidal_lucas_kanade(NAN, GREY), r"frame1: contains NaN or infinite values"),
    ("flow-to-color-shape", lambda: of.flow_to_color(np.zeros((4, 4, 3))), r"flow: expected shape \(H, W, 2\), got \(4, 4, 3\)"),
    ("flow-to-color-max-flow-0", lambda: of.flow_to_color(np.zeros((4, 4, 2)), max_flow=0.0),
     r"max_flow: expected a finite number > 0 or None, got 0.0"),
    ("flow-to-color-max-flow-nan", lambda: of.flow_to_color(np.zeros((4, 4, 2)), max_flow=float("nan")),
     r"max_flow: expected a finite number > 0 or None"),
    ("flow-to-color-valid-shape", lambda: of.flow_to_color(np.zeros((4, 4, 2)), valid=np.ones((3, 4), bool)),
     r"valid: expected shape \(4, 4\), got \(3, 4\)"),
]


@pytest.mark.parametrize("call, message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_image_bad_input_is_one_line_value_error(call, message):
    with pytest.raises(ValueError, match=message) as info:
        call()
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------- the normalisation


@pytest.mark.parametrize("image, expected", [
    (U8, U8 / 255.0),
    ((GREY * 65535).astype(np.uint16), (GREY * 65535).astype(np.uint16) / 65535.0),
    (RGB, RGB @ np.array(LUMA_601)),
    ((RGB * 255).astype(np.uint8), ((RGB * 255).astype(np.uint8) / 255.0) @ np.array(LUMA_601)),
    (GREY, GREY),
], ids=["uint8", "uint16", "float-colour", "uint8-colour", "float-grey"])
def test_the_documented_normalisation(image, expected):
    got = to_unit_grey(image)
    assert got.dtype == np.float32 and got.shape == image.shape[:2] and got.flags.c_contiguous
    np.testing.assert_array_equal(got, np.clip(expected, 0, 1).astype(np.float32))
    assert 0.0 <= got.min() and got.max() <= 1.0


def test_float32_grey_comes_back_bit_identical_and_float64_keeps_its_precision_on_request():
    g32 = GREY.astype(np.float32)
    assert np.array_equal(to_unit_grey(g32), g32)
    assert to_unit_grey(GREY, dtype=None).dtype == np.float64 and np.array_equal(to_unit_grey(GREY, dtype=None), GREY)


def test_stereo_gives_the_same_disparity_for_uint8_and_its_float_division():
    """Recovery from the silent-units fault: uint8 input is scaled, not matched in 0-255 units."""
    base = rng.uniform(0, 1, (24, 40))
    left, right = base[:, 4:36], base[:, 2:34]
    l8, r8 = (np.round(x * 255).astype(np.uint8) for x in (left, right))
    cfg = stereo.StereoConfig(cost="sad", aggregation="sgm4")
    a = stereo.match(l8, r8, 0, 6, cfg)
    b = stereo.match(l8 / 255.0, r8 / 255.0, 0, 6, cfg)
    np.testing.assert_array_equal(a.disparity, b.disparity)
    np.testing.assert_array_equal(a.valid, b.valid)
    c = stereo.match(np.stack([l8] * 3, -1), np.stack([r8] * 3, -1), 0, 6, cfg)  # grey as colour: same image
    np.testing.assert_allclose(c.disparity, a.disparity, atol=1e-4)


# --------------------------------------------------------------------------- NaN flow is drawn, not a crash


def test_nan_flow_is_drawn_black_and_the_scale_comes_from_valid_pixels():
    flow = np.zeros((4, 5, 2))
    flow[..., 0] = 1.0
    flow[0, 0] = np.nan
    flow[1, 1, 1] = np.inf
    flow[2, 2] = [100.0, 0.0]  # masked out below: must not set the scale
    valid = np.ones((4, 5), bool)
    valid[2, 2] = False
    col = of.flow_to_color(flow, valid=valid)
    assert np.all(np.isfinite(col)) and col.shape == (4, 5, 3)
    for ij in ((0, 0), (1, 1), (2, 2)):
        np.testing.assert_array_equal(col[ij], 0.0)
    np.testing.assert_allclose(col[3, 3], of.flow_to_color(np.array([[[1.0, 0.0]]]))[0, 0])
    assert np.all(of.flow_to_color(np.full((3, 3, 2), np.nan)) == 0.0)
