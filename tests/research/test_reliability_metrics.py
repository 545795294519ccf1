"""Reliability of research.metrics: images outside [0, data_range], shapes, NaN, bad data_range.

Each case names the input and the one-line ValueError it must raise (PSNR of a 0-255 image
against a 0-1 one used to return -43.6 dB).
"""

from __future__ import annotations

import numpy as np
import pytest

from research.metrics import mse, psnr, ssim

rng = np.random.default_rng(0)
UNIT = rng.uniform(0, 1, (16, 16, 3))
GREY = rng.uniform(0, 1, (16, 16))
NAN = UNIT.copy()
NAN[3, 4, 1] = np.nan
INF = GREY.copy()
INF[0, 0] = np.inf

# (id, function, args, kwargs, expected message (regex))
CASES = [
    ("psnr-0-255-vs-0-1", psnr, (UNIT * 255, UNIT), {},
     r"pred: expected values in \[0, data_range=1\], got \[.*\] \(a 0-255 image\? divide it by 255"),
    ("psnr-target-0-255", psnr, (UNIT, UNIT * 255), {}, r"target: expected values in \[0, data_range=1\]"),
    ("psnr-negative-pred", psnr, (UNIT - 0.5, UNIT), {}, r"pred: expected values in \[0, data_range=1\]"),
    ("psnr-above-range-2", psnr, (UNIT * 2, UNIT), {"data_range": 1.5}, r"pred: expected values in \[0, data_range=1.5\]"),
    ("psnr-shapes-differ", psnr, (UNIT, GREY), {}, r"pred, target: shapes differ"),
    ("psnr-nan-pred", psnr, (NAN, UNIT), {}, r"pred, target: contain NaN or infinite values"),
    ("psnr-inf-target", psnr, (GREY, INF), {}, r"pred, target: contain NaN or infinite values"),
    ("psnr-data-range-0", psnr, (UNIT, UNIT), {"data_range": 0}, r"data_range: expected a finite number > 0, got 0"),
    ("psnr-data-range-negative", psnr, (UNIT, UNIT), {"data_range": -1.0}, r"data_range: expected a finite number > 0"),
    ("psnr-data-range-nan", psnr, (UNIT, UNIT), {"data_range": float("nan")}, r"data_range: expected a finite number > 0"),
    ("psnr-data-range-inf", psnr, (UNIT, UNIT), {"data_range": float("inf")}, r"data_range: expected a finite number > 0"),
    ("psnr-data-range-text", psnr, (UNIT, UNIT), {"data_range": "1"}, r"data_range: expected a finite number > 0"),
    ("psnr-1d", psnr, (UNIT[0, 0], UNIT[0, 0]), {}, r"pred: expected an image \(H, W\) or \(H, W, C\)"),
    ("psnr-mask-empty", psnr, (UNIT, UNIT), {"mask": np.zeros((16, 16), bool)}, r"mask: selects no pixel"),
    ("psnr-mask-shape", psnr, (UNIT, UNIT), {"mask": np.ones((8, 8), bool)}, r"mask: expected shape \(16, 16\)"),
    ("ssim-0-255-vs-0-1", ssim, (GREY * 255, GREY), {}, r"pred: expected values in \[0, data_range=1\]"),
    ("ssim-target-out-of-range", ssim, (GREY, GREY + 1.0), {}, r"target: expected values in \[0, data_range=1\]"),
    ("ssim-shapes-differ", ssim, (GREY, GREY[:, :12]), {}, r"pred, target: shapes differ"),
    ("ssim-nan", ssim, (NAN, UNIT), {}, r"contain NaN or infinite values"),
    ("ssim-too-small", ssim, (GREY[:8, :8], GREY[:8, :8]), {}, r"pred: SSIM needs images at least 11x11"),
    ("ssim-data-range-0", ssim, (GREY, GREY), {"data_range": 0.0}, r"data_range: expected a finite number > 0"),
    ("mse-nan", mse, (NAN, UNIT), {}, r"contain NaN or infinite values"),
]


@pytest.mark.parametrize("fn, args, kwargs, message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_metric_bad_input_is_one_line_value_error(fn, args, kwargs, message):
    with pytest.raises(ValueError, match=message) as info:
        fn(*args, **kwargs)
    assert "\n" not in str(info.value)


def test_values_in_range_are_scored_and_a_0_255_pair_with_its_data_range_agrees():
    a, b = np.round(UNIT * 255), np.round(np.clip(UNIT + 0.02, 0, 1) * 255)
    assert psnr(a, b, data_range=255) == pytest.approx(psnr(a / 255, b / 255), rel=1e-12)
    assert ssim(a, b, data_range=255) == pytest.approx(ssim(a / 255, b / 255), rel=1e-9)
    # sRGB encoding of 1.0 may land an ulp above 1: within the documented slack.
    assert np.isfinite(psnr(np.minimum(UNIT + 1e-12, 1 + 1e-12), UNIT))
