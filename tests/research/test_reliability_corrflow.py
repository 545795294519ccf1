"""research.flow.coarse_to_fine / research.flow.texture bad inputs: one ValueError line naming the argument."""

from __future__ import annotations

import numpy as np
import pytest

from research.flow import coarse_to_fine as c2f
from research.flow import texture as tf

IMG = np.random.default_rng(0).uniform(0, 1, (24, 24, 3))

CASES = [
    ("levels-0", lambda: c2f.C2FConfig(levels=0), r"levels: expected an integer >= 1, got 0"),
    ("radius-0", lambda: c2f.C2FConfig(radius=0), r"radius: expected an integer >= 1, got 0"),
    ("warps-float", lambda: c2f.C2FConfig(warps=1.5), r"warps: expected an integer >= 1"),
    ("patch-even", lambda: c2f.C2FConfig(patch=4), r"patch: expected an odd side >= 3, got 4"),
    ("patch-1", lambda: c2f.C2FConfig(patch=1), r"patch: expected an integer >= 3"),
    ("tv-weight-nan", lambda: c2f.C2FConfig(tv_weight=float("nan")), r"tv_weight: expected a finite number > 0"),
    ("tv-iterations-negative", lambda: c2f.C2FConfig(tv_iterations=-1), r"tv_iterations: expected an integer >= 0"),
    ("texture-floor-0", lambda: c2f.C2FConfig(texture_floor=0.0), r"texture_floor: expected a finite number > 0"),
    ("budget-bool", lambda: c2f.C2FConfig(memory_budget_mib=True), r"memory_budget_mib: expected a finite number"),
    ("frames-shapes", lambda: c2f.coarse_to_fine_flow(IMG, IMG[:20]), r"frame2: expected the shape of frame1"),
    ("frame1-0-255", lambda: c2f.coarse_to_fine_flow(IMG * 255, IMG), r"frame1: a float image must lie in \[0, 1\]"),
    ("frame2-4-channels", lambda: c2f.coarse_to_fine_flow(IMG, np.zeros((24, 24, 4))),
     r"frame2: expected a grey \(H, W\) or colour \(H, W, 3\) image"),
    ("frame-too-small", lambda: c2f.coarse_to_fine_flow(IMG[:8], IMG[:8]),
     r"frame1: expected at least 10x10 pixels for radius 4, got 8x24"),
    ("split-name", lambda: tf.split("test", np.zeros((4, 4, 3))), r"split: expected 'tuning' or 'eval', got 'test'"),
]


@pytest.mark.parametrize("make, message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_raises_one_line(make, message):
    with pytest.raises(ValueError, match=message) as info:
        make()
    assert "\n" not in str(info.value)
