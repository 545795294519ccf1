"""Reliability of research.slam and experiments/splat_slam: a frame without depth in RGB-D mode, a sequence
shorter than the keyframe window, a pose that is not a rotation, and bad settings each raise one line
naming the argument before any render (the experiment exits 2 before rendering its dataset)."""

from __future__ import annotations

import numpy as np
import pytest

from research.slam import MapConfig, SlamConfig, TrackConfig, run_slam

N, H, W = 6, 8, 8
K = np.array([[8.0, 0.0, 4.0], [0.0, 8.0, 4.0], [0.0, 0.0, 1.0]])
RGBA = np.full((N, H, W, 4), 0.5, dtype=np.float32)
DEPTH = np.full((N, H, W), 2.0, dtype=np.float32)
POSE = np.eye(4)


def _with(arr, index, value):
    out = arr.copy()
    out[index] = value
    return out


SCALED = _with(POSE, (slice(0, 3), slice(0, 3)), 1.1 * np.eye(3))
REFLECT = _with(POSE, (2, 2), -1.0)

CASES = [
    ("depth-none", (RGBA, None, K, POSE), {}, r"depth: RGB-D mode needs a depth map for every frame, got None"),
    ("depth-list-frame-none", (RGBA, [DEPTH[0], DEPTH[1], None, DEPTH[3], DEPTH[4], DEPTH[5]], K, POSE), {},
     r"depth: frame 2 has no depth map"),
    ("depth-frame-all-zero", (RGBA, _with(DEPTH, 3, 0.0), K, POSE), {}, r"depth: frame 3 has no pixel with depth > 0"),
    ("depth-shape", (RGBA, DEPTH[:, :4], K, POSE), {}, r"depth: expected one \(H, W\) = \(8, 8\) map per frame"),
    ("depth-nan", (RGBA, _with(DEPTH, (1, 2, 2), np.nan), K, POSE), {}, r"rgba, depth: expected finite values"),
    ("rgba-not-frames", (RGBA[0], DEPTH, K, POSE), {}, r"rgba: expected float frames \(N, H, W, 3 or 4\)"),
    ("shorter-than-window", (RGBA, DEPTH, K, POSE), {"window": 7},
     r"rgba: the sequence has 6 frames, fewer than the keyframe window \(7\)"),
    ("pose-scaled", (RGBA, DEPTH, K, SCALED), {}, r"first_c2w: rotation part is not orthonormal"),
    ("pose-reflection", (RGBA, DEPTH, K, REFLECT), {}, r"first_c2w: rotation part has determinant -1"),
    ("pose-shape", (RGBA, DEPTH, K, POSE[:3]), {}, r"first_c2w: expected shape \(4, 4\)"),
    ("K-shape", (RGBA, DEPTH, K[:2], POSE), {}, r"K: expected a finite 3x3 intrinsics matrix"),
]


@pytest.mark.parametrize("args, window, match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_sequence_raises_one_line_before_work(args, window, match, monkeypatch):
    import research.slam.system as system

    def no_work(*a, **k):
        raise AssertionError("the map was started before the inputs were checked")

    monkeypatch.setattr(system, "init_map", no_work)
    cfg = SlamConfig(**window) if window else SlamConfig()
    with pytest.raises(ValueError, match=match) as e:
        run_slam(*args, cfg)
    assert "\n" not in str(e.value)


CONFIGS = [
    ("track-iters-0", lambda: TrackConfig(iters=0), r"iters: expected an integer >= 1"),
    ("track-lr-negative", lambda: TrackConfig(lr_rot=-0.1), r"lr_rot: expected a positive learning rate"),
    ("track-no-weight", lambda: TrackConfig(depth_weight=0.0, color_weight=0.0),
     r"depth_weight, color_weight: expected at least one positive weight"),
    ("track-silhouette-1", lambda: TrackConfig(min_silhouette=1.0), r"min_silhouette: expected a value in \[0, 1\)"),
    ("map-stride-0", lambda: MapConfig(stride=0), r"stride: expected an integer >= 1"),
    ("map-opacity-1", lambda: MapConfig(init_opacity=1.0), r"init_opacity: expected a value in \(0, 1\)"),
    ("map-lr-0", lambda: MapConfig(lr_means=0.0), r"lr_means: expected a positive value"),
    ("slam-window-0", lambda: SlamConfig(window=0), r"window: expected an integer >= 1"),
    ("slam-keyframe-every-0", lambda: SlamConfig(keyframe_every=0), r"keyframe_every: expected an integer >= 1"),
    ("slam-jump-negative", lambda: SlamConfig(max_jump_deg=-1.0), r"max_jump_deg: expected a positive value"),
]


@pytest.mark.parametrize("make, match", [c[1:] for c in CONFIGS], ids=[c[0] for c in CONFIGS])
def test_bad_settings_raise_one_line(make, match):
    with pytest.raises(ValueError, match=match) as e:
        make()
    assert "\n" not in str(e.value)


CLI = [
    ("frames-shorter-than-window", ["--frames", "4", "--window", "5"],
     "--frames: the sequence has 4 frames, fewer than the keyframe window (--window 5)"),
    ("frames-3", ["--frames", "3"], "--frames: expected an integer >= 4, got 3"),
    ("track-iters-0", ["--track-iters", "0"], "--track-iters: expected an integer >= 1, got 0"),
    ("window-0", ["--window", "0"], "--window: expected an integer >= 1, got 0"),
]


@pytest.mark.parametrize("argv, message", [c[1:] for c in CLI], ids=[c[0] for c in CLI])
def test_experiment_bad_options_exit_2_before_rendering(argv, message, tmp_path, capsys):
    from experiments.splat_slam import main

    data, out = tmp_path / "data", tmp_path / "out"
    rc = main(["--smoke", "--no-progress", "--data", str(data), "--out", str(out), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].endswith(message), err
    assert not data.exists() or not any(data.iterdir())  # no dataset rendered
    assert not out.exists()
