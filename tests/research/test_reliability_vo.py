"""Bad input to the feature odometry (research/vo): one ValueError naming the argument, before any work;
tracking that cannot start or is lost ends in TrackingError, never in a silent trajectory."""

from __future__ import annotations

import numpy as np
import pytest

from research.vo import ba as vba
from research.vo.loop import LoopConfig
from research.vo.odometry import TrackingError, VOConfig, run_vo

N, H, W = 6, 32, 32
RGBA = np.zeros((N, H, W, 4), np.float32)
DEPTH = np.full((N, H, W), 2.0)
K = np.array([[40.0, 0, 16], [0, 40.0, 16], [0, 0, 1]])
POSE = np.eye(4)

REFLECTION = np.diag([1.0, 1.0, -1.0, 1.0])
SHEARED = np.eye(4)
SHEARED[0, 1] = 0.2
NO_DEPTH_FRAME = DEPTH.copy()
NO_DEPTH_FRAME[3] = 0.0
NEG_DEPTH = DEPTH.copy()
NEG_DEPTH[1, 4, 4] = -1.0

SEQ_CASES = [
    ("depth_none", dict(depth=None), r"^depth: RGB-D"),
    ("frame_without_depth", dict(depth=NO_DEPTH_FRAME), r"^depth\[3\]: frame 3 has no depth"),
    ("negative_depth", dict(depth=NEG_DEPTH), r"^depth\[1\]"),
    ("depth_shape", dict(depth=DEPTH[:, :16]), r"^depth: expected one"),
    ("rgba_not_4d", dict(rgba=RGBA[0]), r"^rgba: expected frames"),
    ("shorter_than_window", dict(rgba=RGBA[:3], depth=DEPTH[:3]), r"^rgba: the sequence has 3 frames"),
    ("pose_reflection", dict(c2w0=REFLECTION), r"^c2w0: rotation part has determinant"),
    ("pose_not_orthonormal", dict(c2w0=SHEARED), r"^c2w0: rotation part is not orthonormal"),
    ("K_negative_focal", dict(K=np.diag([-40.0, 40.0, 1.0])), r"^K: expected"),
]


@pytest.mark.parametrize("override, message", [(c[1], c[2]) for c in SEQ_CASES], ids=[c[0] for c in SEQ_CASES])
def test_run_vo_bad_sequence(override, message):
    args = dict(rgba=RGBA, depth=DEPTH, K=K, c2w0=POSE)
    args.update(override)
    with pytest.raises(ValueError, match=message):
        run_vo(args["rgba"], args["depth"], args["K"], args["c2w0"], VOConfig(window=4))


CFG_CASES = [
    ("window_1", dict(window=1), r"^window"),
    ("min_inliers_0", dict(min_inliers=0), r"^min_inliers"),
    ("ratio_above_1", dict(ratio=1.5), r"^ratio"),
    ("pnp_px_zero", dict(pnp_px=0.0), r"^pnp_px"),
    ("search_px_negative", dict(search_px=-1.0), r"^search_px"),
    ("ba_loss_unknown", dict(ba_loss="l1"), r"^ba_loss"),
]


@pytest.mark.parametrize("override, message", [(c[1], c[2]) for c in CFG_CASES], ids=[c[0] for c in CFG_CASES])
def test_vo_config_bad_values(override, message):
    with pytest.raises(ValueError, match=message):
        VOConfig(**override).validate()


def test_loop_config_bad_values():
    with pytest.raises(ValueError, match=r"^min_gap"):
        LoopConfig(min_gap=0).validate()


def test_featureless_frames_stop_with_tracking_error():
    """Too few matches to initialise (blank frames: no keypoints) is a clear error, not a trajectory."""
    with pytest.raises(TrackingError, match=r"frame 1: initialisation failed \(0 matches"):
        run_vo(RGBA, DEPTH, K, POSE, VOConfig(window=4))


BA_P = np.tile(np.eye(4), (2, 1, 1))
BA_P[:, 2, 3] = 3.0
BA_CASES = [
    ("loss_unknown", dict(loss="l2"), r"^loss"),
    ("f_scale_zero", dict(f_scale=0.0), r"^f_scale"),
    ("fixed_empty", dict(fixed=()), r"^fixed"),
    ("fixed_out_of_range", dict(fixed=(5,)), r"^fixed"),
]


@pytest.mark.parametrize("override, message", [(c[1], c[2]) for c in BA_CASES], ids=[c[0] for c in BA_CASES])
def test_bundle_adjust_bad_options(override, message):
    with pytest.raises(ValueError, match=message):
        vba.bundle_adjust(BA_P, np.zeros((2, 3)), np.zeros((2, 2)), [0, 1], [0, 1], (40.0, 40.0, 16.0, 16.0),
                          **override)


@pytest.mark.parametrize("argv, message", [
    (["--ba-depth-weight", "-1"], "--ba-depth-weight: expected a value >= 0"),
    (["--window", "1"], "--window: expected an integer >= 2"),
    (["--features", "0"], "--features: expected an integer >= 1"),
], ids=["ba_depth_weight_negative", "window_1", "features_0"])
def test_feature_vo_bad_options_exit_2_before_any_work(argv, message, tmp_path, capsys):
    from experiments import feature_vo

    rc = feature_vo.main([*argv, "--out", str(tmp_path / "out"), "--data", str(tmp_path / "data"), "--no-progress"])
    assert rc == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and not (tmp_path / "data").exists()
