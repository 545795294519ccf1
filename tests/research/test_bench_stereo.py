"""research.bench.stereo: the stereo.default case times research.stereo.matching.DEFAULT_CONFIG's pipeline."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from experiments.performance import _target_status
from research.bench import stereo as bench
from research.stereo.matching import DEFAULT_CONFIG, match


def _rows(compare: bool) -> list[dict]:
    return list(bench.cases("cpu", tiny=True, compare=compare))


def test_tiny_rows_include_the_default_pipeline_case():
    rows = _rows(False)
    assert [r["bench"] for r in rows] == ["stereo.sgm", "stereo.default", "stereo.memory"]
    default = rows[1]
    assert (default["height"], default["width"], default["disparities"]) == bench.TINY_SIZES[0]
    assert default["config"] == DEFAULT_CONFIG.label and default["config"] != rows[0]["cost"]
    assert default["compact"] is False and default["paths"] == 8
    assert default["total_fast_s"] > 0  # FAST_DEFAULT_CONFIG's match, beside it
    for key in ("cost_s", "aggregate_s", "backend_s", "total_s"):
        assert default[key] > 0
    assert not any(k.startswith("ref") or k.startswith("speedup") for k in default)


def test_default_case_runs_what_match_runs_by_default():
    # The case's total is match(cfg=DEFAULT_CONFIG); match(cfg=None) must be that same pipeline.
    left, right = bench._pair(32, 64)
    a, b = match(left, right, 0, 16, DEFAULT_CONFIG), match(left, right, 0, 16)
    np.testing.assert_array_equal(a.disparity, b.disparity)
    np.testing.assert_array_equal(a.valid, b.valid)


def test_tiny_default_row_with_compare():
    rows = _rows(True)
    default = next(r for r in rows if r["bench"] == "stereo.default")
    if importlib.util.find_spec("cv2") is None:
        assert default["ref_missing"].startswith("cv2")
        return
    assert default["ref"].startswith("OpenCV") and "StereoSGBM" in default["ref"]
    assert default["speedup_total"] == pytest.approx(default["ref_total_s"] / default["total_s"])


@pytest.mark.parametrize("case", ["stereo.default", "stereo.sgm"])
@pytest.mark.parametrize("speedup,status", [(0.25, "met"), (0.1, "NOT met")])
def test_stereo_target_lines(case, speedup, status):
    row = {"bench": case, "height": 500, "width": 741, "disparities": 64, "speedup_total": speedup}
    (found,) = _target_status(row, full=True)
    assert found[3] == status
    if case == "stereo.default":
        assert "default SGM pipeline (DEFAULT_CONFIG)" in found[1]
    else:
        assert "census + SGM-8 (StereoConfig field defaults)" in found[1]
