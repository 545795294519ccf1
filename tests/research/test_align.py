"""research.poses.align: Umeyama's Sim(3) against known transforms and against evo, and the pose errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from research.poses.align import pose_errors, rotation_angle_deg, umeyama
from research.cameras import look_at


def _random_sim3(rng):
    return float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3) * 3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_umeyama_recovers_a_known_similarity(seed):
    rng = np.random.default_rng(seed)
    s, R, t = _random_sim3(rng)
    x = rng.normal(size=(20, 3))
    sim = umeyama(x, s * x @ R.T + t)
    assert abs(sim.scale - s) < 1e-12 * s and np.abs(sim.R - R).max() < 1e-12 and np.abs(sim.t - t).max() < 1e-11
    assert np.abs(sim.apply(x) - (s * x @ R.T + t)).max() < 1e-11
    rigid = umeyama(x, x @ R.T + t, with_scale=False)
    assert rigid.scale == 1.0 and np.abs(rigid.R - R).max() < 1e-12


def test_umeyama_is_least_squares_under_noise_and_matches_evo():
    evo_geometry = pytest.importorskip("evo.core.geometry")
    rng = np.random.default_rng(3)
    s, R, t = _random_sim3(rng)
    x = rng.normal(size=(50, 3))
    y = s * x @ R.T + t + rng.normal(scale=0.05, size=(50, 3))
    sim = umeyama(x, y)
    r_evo, t_evo, s_evo = evo_geometry.umeyama_alignment(x.T, y.T, with_scale=True)
    assert abs(sim.scale - s_evo) < 1e-12 and np.abs(sim.R - r_evo).max() < 1e-12
    assert np.abs(sim.t - t_evo).max() < 1e-12
    # a least-squares minimum: perturbing the solution never lowers the residual
    cost = lambda sc, Rm, tv: float(((y - sc * x @ Rm.T - tv) ** 2).sum())  # noqa: E731
    best = cost(sim.scale, sim.R, sim.t)
    for _ in range(20):
        dR = Rotation.from_rotvec(rng.normal(scale=1e-3, size=3)).as_matrix()
        assert cost(sim.scale * (1 + rng.normal(scale=1e-3)), dR @ sim.R, sim.t + rng.normal(scale=1e-3, size=3)) > best


def test_umeyama_turns_a_reflection_into_a_rotation():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(10, 3))
    sim = umeyama(x, x * np.array([1.0, 1.0, -1.0]))  # a mirror: the best proper rotation, not the mirror
    assert abs(np.linalg.det(sim.R) - 1.0) < 1e-12


def test_pose_errors_of_a_similarity_moved_rig_are_zero_and_a_known_perturbation_is_measured():
    rng = np.random.default_rng(5)
    gt = np.array([look_at(rng.normal(size=3) * 4 + [0, 0, 5], [0, 0, 0], [0, 0, 1]) for _ in range(12)])
    s, R, t = _random_sim3(rng)
    est = []
    for g in gt:  # the same rig in another frame: x_est = (R^T (x_gt - t)) / s
        M = np.eye(4)
        M[:3, :3] = R.T @ g[:3, :3]
        M[:3, 3] = R.T @ (g[:3, 3] - t) / s
        est.append(M)
    est = np.array(est)
    pe = pose_errors(est, gt)
    assert pe.rotation_deg.max() < 1e-9 and pe.translation.max() < 1e-10 and abs(pe.sim3.scale - s) < 1e-10
    for e, g in zip(est, gt):  # the aligned poses are the ground truth's
        assert np.abs(pe.sim3.apply_c2w(e) - g).max() < 1e-10
    assert np.abs(pe.sim3.matrix()[:3, :3] - s * R).max() < 1e-10
    tilted = est.copy()
    tilted[3, :3, :3] = tilted[3, :3, :3] @ Rotation.from_rotvec([0.0, 0.0, np.radians(2.0)]).as_matrix()
    pe = pose_errors(tilted, gt)
    assert abs(pe.rotation_deg[3] - 2.0) < 1e-9 and np.delete(pe.rotation_deg, 3).max() < 1e-9
    assert abs(rotation_angle_deg(Rotation.from_rotvec([0.3, 0.0, 0.0]).as_matrix()) - np.degrees(0.3)) < 1e-9


@pytest.mark.parametrize("x, y, match", [
    (np.zeros((2, 3)), np.zeros((2, 3)), "at least 3 point pairs"),
    (np.zeros((4, 2)), np.zeros((4, 2)), r"x: expected an \(n, 3\) array"),
    (np.ones((4, 3)), np.ones((5, 3)), "y: expected the shape of x"),
    (np.outer(np.arange(5.0), [1.0, 2.0, 3.0]), np.outer(np.arange(5.0), [1.0, 2.0, 3.0]), "collinear"),
    (np.full((4, 3), np.nan), np.zeros((4, 3)), "non-finite"),
], ids=["two-points", "2d-points", "shape-mismatch", "collinear", "nan"])
def test_umeyama_bad_inputs(x, y, match):
    with pytest.raises(ValueError, match=match):
        umeyama(x, y)
