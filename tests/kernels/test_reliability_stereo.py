"""kernels.stereo's newer entry points (Birchfield-Tomasi cost, compact mode): each bad input raises one
ValueError naming the argument, before any kernel runs."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import stereo


@pytest.mark.parametrize("left, right, match", [
    (np.zeros((4, 6, 3)), np.zeros((4, 6)), "right"),
    (np.zeros((4, 6, 3, 1)), np.zeros((4, 6, 3, 1)), "left"),
    (np.zeros(6), np.zeros(6), "left"),
    (np.full((4, 6), np.nan), np.zeros((4, 6)), "left"),
], ids=["colour-and-grey", "four-dimensions", "one-dimension", "nan-left"])
def test_bt_bad_images(left, right, match):
    with pytest.raises(ValueError, match=match) as e:
        stereo.bt_cost(left, right, 0, 3, 1)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("p1, p2, match", [(8.5, 64, "p1: a uint8 volume needs integer penalties"),
                                           (8, 64.5, "p2: a uint8 volume needs integer penalties"),
                                           (8, 9000, "p2: a uint8 volume needs P2 <= 7936")],
                         ids=["fractional-p1", "fractional-p2", "uint16-overflow"])
def test_compact_sgm_bad_penalties(p1, p2, match):
    c8 = np.full((4, 9, 8), 62, dtype=np.uint8)
    with pytest.raises(ValueError, match=match) as e:
        stereo.sgm(c8, p1, p2, 8)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("call, match", [
    (lambda: stereo.sgm(np.zeros((4, 9, 8), np.int8), 8, 64), "cost: expected dtype float32 or float64, got int8"),
    (lambda: stereo.sgm(np.zeros((4, 9, 12), np.uint8), 8, 64, method="axes"),
     "cost: a uint8 volume needs a multiple of 8"),
    (lambda: stereo.sgm(np.zeros((4, 9), np.uint8), 8, 64), "cost: expected a non-empty"),
    (lambda: stereo.wta(np.zeros((4, 9, 8), np.uint8), 0), "cost: expected dtype float32 or float64, got uint8"),
    (lambda: stereo.wta_left_right(np.zeros((4, 9, 8), np.uint32), 0), "cost: expected dtype float32"),
    (lambda: stereo.soft_argmin(np.zeros((4, 9, 8), np.uint16), 0), "cost: expected dtype float32"),
    (lambda: stereo.wta_left_right(np.zeros((4, 9, 8)), 0, uniqueness=1.0), "uniqueness"),
], ids=["int8-volume", "uint8-d12", "uint8-2d", "wta-of-uint8", "winners-of-uint32", "soft-argmin-of-uint16",
        "uniqueness-1"])
def test_integer_volumes_other_than_compact_ones_are_refused(call, match):
    with pytest.raises(ValueError, match=match) as e:
        call()
    assert "\n" not in str(e.value)


_G = np.zeros((4, 6))
_C = np.zeros((4, 6, 3))


@pytest.mark.parametrize("call, match", [
    (lambda: stereo.adcensus_cost(_C, _C, 0, 3), "grey: expected the \\(left, right\\) grey images"),
    (lambda: stereo.adcensus_cost(_C, _C, 0, 3, grey=_G), "grey: expected a \\(left, right\\) pair"),
    (lambda: stereo.adcensus_cost(_C, _C, 0, 3, grey=(np.zeros((4, 5)), np.zeros((4, 5)))), "grey\\[0\\]: expected shape"),
    (lambda: stereo.adcensus_cost(_C, _C, 0, 3, grey=(_G, _G.astype(np.float32))), "grey\\[1\\]: expected dtype float64 like"),
    (lambda: stereo.adcensus_cost(_G, _C, 0, 3), "right"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 9), "dmax"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, lambda_census=0.0), "lambda_census"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, grad_cap=-1.0), "grad_cap"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, bt_weight=float("nan")), "bt_weight"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, census_radii=(4, 4)), "radius_y, radius_x"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, radius=-1), "radius"),
    (lambda: stereo.adcensus_cost(_G.astype(np.float32), _G.astype(np.float32), 0, 3, levels=111, bt_weight=0.3),
     "levels: expected at most 110"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, levels=100), "levels: compact mode .* float32"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, levels=-1), "levels"),
    (lambda: stereo.adcensus_cost(_G, _G, 0, 3, census_eps=-0.1), "census_eps"),
    (lambda: stereo.sobel_x_clipped(np.zeros(6), 0.25), "image: expected a grey"),
    (lambda: stereo.sobel_x_clipped(_G, 0.0), "cap"),
], ids=["colour-without-grey", "grey-not-a-pair", "grey-wrong-shape", "grey-wrong-dtype", "grey-and-colour",
        "range-wider-than-image", "lambda-census-0", "grad-cap-negative", "bt-weight-nan", "census-81-bits",
        "radius-negative", "levels-overflow-uint8", "levels-with-float64", "levels-negative", "census-eps-negative",
        "sobel-1d", "sobel-cap-0"])
def test_adcensus_bad_input(call, match):
    with pytest.raises(ValueError, match=match) as e:
        call()
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("call, match", [
    (lambda: stereo.sgm(np.zeros((4, 9, 8), np.float32), 8, 64, method="rows"), "method: expected 'auto'"),
    (lambda: stereo.sgm_disparity(np.zeros((4, 9, 8), np.uint8), 0, 8, 64, lr_max_diff=-1.0), "lr_max_diff"),
    (lambda: stereo.sgm_disparity(np.zeros((4, 9, 8), np.uint8), 0, 8, 64, uniqueness=1.0), "uniqueness"),
    (lambda: stereo.sgm_disparity(np.zeros((4, 9, 8), np.uint8), 0, 8.5, 64), "p1: a uint8 volume needs integer"),
    (lambda: stereo.sgm_disparity(np.zeros((4, 9, 8), np.uint8), 0, 8, 64, paths=6), "paths: expected 4 or 8"),
    (lambda: stereo.sgm_disparity(np.zeros((4, 9, 8), np.uint8), 3, 8, 64), "dmin, dmax: the range"),
    (lambda: stereo.sgm_disparity(np.zeros((4, 9, 8), np.uint16), 0, 8, 64), "cost: expected dtype float32"),
    (lambda: stereo.sgm_disparity(np.zeros((4, 9), np.uint8), 0, 8, 64), "cost: expected a non-empty"),
], ids=["sgm-method-rows", "lr-max-diff-negative", "uniqueness-1", "fractional-p1", "paths-6", "dmin-past-width",
        "uint16-cost", "uint8-2d"])
def test_sgm_disparity_bad_arguments(call, match):
    with pytest.raises(ValueError, match=match) as e:
        call()
    assert "\n" not in str(e.value)
