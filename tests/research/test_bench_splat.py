"""The splat bench family's rows and the performance experiment's size-filtered targets."""

import importlib.util

import pytest

from experiments.performance import _target_status
from research.bench import splat as bench_splat


def test_splat_bench_tiny_rows_have_every_phase_and_the_reference_or_its_absence():
    rows = list(bench_splat.cases(tiny=True, compare=True))
    assert len(rows) == 1
    row = rows[0]
    for phase in ("fwd", "project", "bin", "raster", "rasterize", "fwd_bwd", "fwd_bwd_camera"):
        assert row[f"{phase}_s"] > 0, phase
    if importlib.util.find_spec("torch") is None:
        assert row["ref_missing"].startswith("torch")
        assert "speedup_rasterize" not in row
    else:  # the dense reference draws the same image, up to splats whose alpha rounds across 1/255
        assert row["speedup_rasterize"] > 0 and row["ref_max_abs_diff"] < 0.05


def test_splat_bench_forward_only_case_is_full_size_only():
    assert all(b for *_, b in bench_splat.QUICK_CASES + bench_splat.TINY_CASES)
    assert (1_000_000, 1080, 1920, False) in bench_splat.CASES


@pytest.mark.parametrize("row, want", [
    ({"bench": "splat.render", "gaussians": 1_000_000, "height": 1080, "width": 1920, "fwd_s": 0.8},
     [("forward <= 1 s at 1M Gaussians, 1920x1080", "met")]),
    ({"bench": "splat.render", "gaussians": 1_000_000, "height": 1080, "width": 1920, "fwd_s": 1.5},
     [("forward <= 1 s at 1M Gaussians, 1920x1080", "NOT met")]),
    ({"bench": "splat.render", "gaussians": 100_000, "height": 512, "width": 512, "fwd_s": 0.5}, []),
    ({"bench": "splat.render", "gaussians": 2000, "height": 128, "width": 128, "fwd_s": 0.01,
      "speedup_rasterize": 120.0}, [("rasteriser >= 100x the dense reference at 2000 Gaussians, 128x128", "met")]),
    ({"bench": "stereo.sgm", "height": 375, "width": 1242, "disparities": 128, "speedup_total": 0.1}, []),
    ({"bench": "stereo.sgm", "height": 500, "width": 741, "disparities": 64, "speedup_total": 0.1},
     [("census + SGM-8 (StereoConfig field defaults) <= 5x SGBM at 741x500x64", "NOT met")]),
    ({"bench": "corr.lookup_onthefly", "ratio_to_dense_fwd": 2.0, "memory_ratio": 5.0},
     [("on-the-fly within 3x of the dense lookup (float32 features, shown beside it)", "met"),
      ("on-the-fly holds >= 10x less memory (float32 features, shown beside it)", "NOT met")]),
], ids=["splat_1M_met", "splat_1M_not_met", "splat_100k_no_target", "splat_dense_ratio", "stereo_kitti_no_target",
        "stereo_middlebury_not_met", "corr_onthefly"])
def test_targets_apply_to_the_sizes_they_name(row, want):
    assert [(text, status) for _, text, _, status in _target_status(row, full=True)] == want
    assert all(status.startswith("n/a") for *_, status in _target_status(row, full=False))
