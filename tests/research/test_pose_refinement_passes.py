"""experiments.pose_refinement.fit_splats: the refined rows' fits run REFINED_LENGTH x the iterations (schedule
scaled) in REFINE_PASSES fits, each from a fresh model back-projected at the previous pass's poses; the gt and noisy
rows run one fit of the base length at their starting poses."""

from __future__ import annotations

import numpy as np
import pytest

from experiments import pose_refinement as pr
from research.poses import refine_splats as prs
from research.cameras import Camera, look_at
from research.splats import model as sm


def _views(n=4, size=16):
    K = np.array([[20.0, 0, size / 2], [0, 20.0, size / 2], [0, 0, 1]])
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        cams.append(Camera(K, look_at([3 * np.cos(a), 3 * np.sin(a), 1.0], [0, 0, 0]), size, size))
    rng = np.random.default_rng(0)
    rgba = np.concatenate([rng.uniform(0.2, 0.8, (n, size, size, 3)), np.ones((n, size, size, 1))], axis=3)
    depth = rng.uniform(2.5, 3.5, (n, size, size))
    return cams, rgba.astype(np.float32), depth.astype(np.float32)


def test_defaults():
    assert (pr.REFINED_LENGTH, pr.REFINE_PASSES) == (1, 1)
    assert pr.splat_setup(quick=False, smoke=False)["iterations"] == 6000  # every full-mode row (docstring)
    assert pr.splat_setup(quick=True, smoke=False)["iterations"] == 3000


@pytest.mark.parametrize("passes", [1, 2])
@pytest.mark.parametrize("run", ["gt", "noisy", "refined", "refined_rgbd"])
def test_refined_runs_restart_from_the_previous_passes_poses(run, passes, monkeypatch):
    monkeypatch.setattr(pr, "REFINE_PASSES", passes)
    monkeypatch.setattr(pr, "REFINED_LENGTH", 2)  # the knob the seed 1/2 study used (module docstring)
    cams, rgba, depth = _views()
    calls = []

    def fake_joint(model, w2c, K, images, extent, cfg, *, progress, desc, depths):
        calls.append({"model": model, "w2c": np.array(w2c), "extent": extent, "depths": depths, "cfg": cfg})
        # a deterministic pose change per pass: every camera moved by 0.1 along its own x axis
        out = np.array(w2c)
        out[:, 0, 3] += 0.1
        return model, out, prs.SplatJointLog([1.0, 0.5], [0.1], 2.0, 0)

    monkeypatch.setattr(prs, "train_joint_splats", fake_joint)
    c2w = np.array([c.c2w for c in cams])
    sizes = {"iterations": 10, "init_points": 50}
    dw = 0.5 if run == "refined_rgbd" else 0.0
    model, c2w_final, _, log = pr.fit_splats(run, cams, c2w, rgba, depth, sizes, 3, False, dw)
    refined = run.startswith("refined")
    passes = passes if refined else 1
    assert len(calls) == passes
    assert log["train_s"] == 2.0 * passes and len(log["losses"]) == 2 * passes
    start = c2w
    for call in calls:
        length = 10 * pr.REFINED_LENGTH if refined else 10
        assert call["cfg"].iterations == length and call["cfg"].pose_start == length // 10
        assert call["cfg"].refine_poses == refined
        # the pass's starting poses, and its fresh model back-projected at them
        np.testing.assert_allclose(call["w2c"], np.linalg.inv(start), atol=1e-12)
        start_cams = [Camera(c.K, T, c.width, c.height) for c, T in zip(cams, start)]
        expect = sm.from_points(*sm.points_from_depth(start_cams, rgba, depth, 50, 3))
        np.testing.assert_array_equal(call["model"].means, expect.means)
        assert call["extent"] == sm.scene_extent(start_cams)
        assert (call["depths"] is not None) == (dw > 0)
        start = np.array([np.linalg.inv(T) for T in call["w2c"]])
        start[:, :3, 3] -= 0.1 * start[:, :3, 0]  # the fake's step as camera-to-world: the centre moves by -0.1 x_cam
    np.testing.assert_allclose(c2w_final, start, atol=1e-12)
