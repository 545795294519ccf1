"""experiments.pose_refinement's sizes: the splats' full mode renders the quick dataset's cameras at 128 px and scales
the coarse phase's blur with the width; quick and smoke keep their 2-px blur (their fits unchanged)."""

from __future__ import annotations

from dataclasses import asdict

from experiments import pose_refinement as pr
from experiments.fit_nerf import dataset_config


def test_full_mode_renders_the_quick_cameras_at_128_px():
    quick, full = asdict(pr.splat_dataset(True, False)), asdict(pr.splat_dataset(False, False))
    assert quick == asdict(dataset_config(True, 0, False))
    assert (full["res"], full["spp"]) == (128, 64)
    # same scene, view count, seed and split fractions: the same cameras and train/test split
    assert {k: v for k, v in full.items() if k not in ("res", "spp")} == \
        {k: v for k, v in quick.items() if k not in ("res", "spp")}
    assert asdict(pr.splat_dataset(False, True)) == asdict(dataset_config(True, 0, True))


def test_blur_scales_with_the_width_above_64_px():
    assert pr.blur_start(32) == pr.blur_start(64) == pr.BLUR_START_PX == 2.0
    assert pr.blur_start(128) == 4.0
    assert pr.splat_config("refined", 3000, 1, width=128).blur_start == 4.0
    # the quick size's schedule is SplatJointConfig's default blur
    from research.poses.refine_splats import SplatJointConfig
    assert pr.splat_config("refined", 3000, 1, width=64).blur_start == SplatJointConfig().blur_start
