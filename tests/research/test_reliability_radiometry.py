"""research.radiometry: every bad input raises one ValueError line naming the argument."""

import numpy as np
import pytest

from research.radiometry import Stress, clean, stress, stress_pair
from tests.bad_input import assert_refused

IMG = np.full((8, 8, 3), 0.5)


@pytest.mark.parametrize("call, match", [
    (lambda: Stress(exposure_stops=-1.0), "exposure_stops"),
    (lambda: Stress(blur_sigma=float("nan")), "blur_sigma"),
    (lambda: Stress(vignetting=1.5), "vignetting"),
    (lambda: Stress(read_noise=True), "read_noise"),
    (lambda: Stress(bits=12), "bits"),
    (lambda: stress(IMG, 0), "rng"),
    (lambda: stress(IMG.astype(np.uint8), np.random.default_rng(0)), "image"),
    (lambda: stress(np.full((8, 8, 2), 0.5), np.random.default_rng(0)), "image"),
    (lambda: stress(np.zeros((0, 8)), np.random.default_rng(0)), "image"),
    (lambda: stress(np.full((8, 8), np.nan), np.random.default_rng(0)), "image"),
    (lambda: stress(np.full((8, 8), -0.1), np.random.default_rng(0)), "image"),
    (lambda: stress_pair(IMG, IMG[:4], 0), "left, right"),
    (lambda: stress_pair(IMG, IMG, -1), "seed"),
    (lambda: stress_pair(IMG, IMG, 1.5), "seed"),
    (lambda: stress_pair(IMG, np.full((8, 8, 3), np.inf), 0), "right"),
    (lambda: clean(IMG, bits=10), "bits"),
], ids=["negative-exposure", "nan-blur", "vignetting-above-1", "bool-noise", "12-bits", "int-rng", "uint8-image",
        "two-channels", "empty", "nan-pixel", "negative-radiance", "shape-mismatch", "negative-seed", "float-seed",
        "inf-right", "clean-10-bits"])
def test_bad_input(call, match):
    assert_refused(call, match)
