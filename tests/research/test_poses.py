"""research.poses.se3: SE(3) exp/log, TUM files, ATE and RPE checked against the evo package."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from research.poses import se3 as P

evo_traj = pytest.importorskip("evo.core.trajectory")
from evo.core import metrics as evo_metrics  # noqa: E402
from evo.tools import file_interface as evo_files  # noqa: E402


def _trajectory(n: int, seed: int) -> np.ndarray:
    """A smooth random camera path (c2w)."""
    rng = np.random.default_rng(seed)
    xi = np.cumsum(rng.normal(scale=[0.2, 0.2, 0.2, 0.1, 0.1, 0.1], size=(n, 6)), axis=0)
    return np.array([P.se3_exp(x) for x in xi])


def _noisy(ref: np.ndarray, seed: int, scale: float = 1.0) -> np.ndarray:
    """ref moved by a rigid transform and a scale, plus per-pose noise (so alignment matters)."""
    rng = np.random.default_rng(seed)
    G = P.se3_exp(rng.normal(size=6))
    out = np.array([G @ P.perturb_c2w(T, rng.normal(scale=0.02, size=6)) for T in ref])
    out[:, :3, 3] *= scale
    return out


def _evo(c2w: np.ndarray) -> "evo_traj.PoseTrajectory3D":
    return evo_traj.PoseTrajectory3D(poses_se3=list(c2w), timestamps=np.arange(len(c2w), dtype=float))


@pytest.mark.parametrize("seed", range(5))
def test_exp_log_round_trip(seed):
    rng = np.random.default_rng(seed)
    xi = rng.normal(size=6)
    xi[3:] *= (math.pi - 0.01) * rng.uniform() / np.linalg.norm(xi[3:])
    T = P.se3_exp(xi)
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(P.se3_log(T), xi, atol=1e-9)
    np.testing.assert_allclose(P.se3_exp(P.se3_log(T)), T, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-4, 1.0, math.pi - 1e-4, math.pi])
def test_so3_log_small_and_near_pi(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = P.so3_exp(angle * axis)
    phi = P.so3_log(R)
    np.testing.assert_allclose(P.so3_exp(phi), R, atol=1e-12)
    assert abs(np.linalg.norm(phi) - angle) < 1e-9


def test_exp_matches_matrix_exponential():
    from scipy.linalg import expm
    xi = np.array([0.3, -0.2, 0.5, 0.4, -0.7, 0.2])
    M = np.zeros((4, 4))
    M[:3, :3] = P.hat(xi[3:])
    M[:3, 3] = xi[:3]
    np.testing.assert_allclose(P.se3_exp(xi), expm(M), atol=1e-13)


def test_left_perturbation_convention():
    """perturb_c2w(c2w, xi) is the inverse of exp(xi^) c2w^-1 (left perturbation of world-to-camera)."""
    c2w = _trajectory(3, 0)[2]
    xi = np.array([0.1, 0.2, -0.3, 0.05, -0.02, 0.04])
    np.testing.assert_allclose(P.perturb_c2w(c2w, xi), np.linalg.inv(P.perturb_w2c(np.linalg.inv(c2w), xi)),
                               atol=1e-12)


def test_random_perturbations_have_exact_size():
    xi = P.random_perturbations(10, 5.0, 0.2, seed=3)
    np.testing.assert_allclose(np.degrees(np.linalg.norm(xi[:, 3:], axis=1)), 5.0)
    np.testing.assert_allclose(np.linalg.norm(xi[:, :3], axis=1), 0.2)
    np.testing.assert_array_equal(xi, P.random_perturbations(10, 5.0, 0.2, seed=3))


def test_quaternion_round_trip_against_evo():
    from evo.core import transformations as tr
    for T in _trajectory(20, 1):
        q = P.matrix_to_quat(T[:3, :3])
        np.testing.assert_allclose(P.quat_to_matrix(q), T[:3, :3], atol=1e-12)
        wxyz = tr.quaternion_from_matrix(T)
        wxyz = wxyz if wxyz[0] >= 0 else -wxyz
        np.testing.assert_allclose(q, [wxyz[1], wxyz[2], wxyz[3], wxyz[0]], atol=1e-12)


def test_tum_round_trip_through_evo(tmp_path):
    ref = _trajectory(15, 2)
    stamps = 1000.0 + 0.033 * np.arange(15)
    path = tmp_path / "ours.txt"
    P.write_tum(path, stamps, ref)
    t = evo_files.read_tum_trajectory_file(str(path))           # evo reads our file
    np.testing.assert_allclose(t.timestamps, stamps, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.array(t.poses_se3), ref, atol=1e-12)
    evo_path = tmp_path / "evo.txt"
    evo_files.write_tum_trajectory_file(str(evo_path), _evo(ref))  # we read evo's file
    s, c2w = P.read_tum(evo_path)
    np.testing.assert_allclose(s, np.arange(15), atol=0)
    np.testing.assert_allclose(c2w, ref, atol=1e-12)
    s2, c2w2 = P.read_tum(path)
    np.testing.assert_array_equal(s2, stamps)
    np.testing.assert_allclose(c2w2, ref, atol=1e-14)


def test_tum_file_that_evo_reads_is_read_the_same(tmp_path):
    """evo's reader keeps a file's order (timestamps that go back or repeat), normalises quaternions of
    any norm and skips a byte-order mark: drlab reads such a file to the same stamps and poses."""
    rng = np.random.default_rng(11)
    lines = []
    for k, t in enumerate([3.0, 1.0, 2.0, 2.0, 0.5]):
        q = rng.normal(size=4) * rng.uniform(0.2, 3.0)  # norms far from 1
        lines.append(" ".join(repr(float(v)) for v in [t, *rng.normal(size=3), *q]))
    path = tmp_path / "unsorted.txt"
    path.write_bytes(("\ufeff# timestamp tx ty tz qx qy qz qw\n" + "\n".join(lines) + "\n").encode("utf-8"))
    t = evo_files.read_tum_trajectory_file(str(path))
    stamps, c2w = P.read_tum(path)
    np.testing.assert_array_equal(stamps, t.timestamps)
    np.testing.assert_allclose(c2w, np.array(t.poses_se3), rtol=0, atol=1e-12)


@pytest.mark.parametrize("align,scale", [("none", 1.0), ("se3", 1.0), ("sim3", 1.0), ("sim3", 0.37)])
def test_ate_matches_evo(align, scale):
    ref = _trajectory(40, 3)
    est = _noisy(ref, 4, scale)
    ours = P.ate(est, ref, align)
    e_ref, e_est = _evo(ref), _evo(est)
    if align != "none":
        e_est.align(e_ref, correct_scale=align == "sim3")
    m = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    m.process_data((e_ref, e_est))
    assert ours.rmse == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(ours.errors, m.error, rtol=1e-9, atol=1e-12)
    assert ours.median == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.median), rel=1e-9)
    assert ours.max == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.max), rel=1e-9)


@pytest.mark.parametrize("delta", [1, 3, 10])
@pytest.mark.parametrize("relation", ["translation", "rotation"])
def test_rpe_matches_evo(delta, relation):
    ref = _trajectory(40, 5)
    est = _noisy(ref, 6)
    ours = P.rpe(est, ref, delta=delta)
    rel = evo_metrics.PoseRelation.translation_part if relation == "translation" \
        else evo_metrics.PoseRelation.rotation_angle_deg
    m = evo_metrics.RPE(rel, delta=delta, delta_unit=evo_metrics.Unit.frames, all_pairs=True)
    m.process_data((_evo(ref), _evo(est)))
    stats = ours.translation if relation == "translation" else ours.rotation_deg
    np.testing.assert_allclose(stats.errors, m.error, rtol=1e-9, atol=1e-12)
    assert stats.rmse == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9)


def test_rpe_sim3_matches_evo_after_scale_alignment():
    ref = _trajectory(30, 7)
    est = _noisy(ref, 8, scale=2.5)
    ours = P.rpe(est, ref, delta=2, align="sim3")
    e_ref, e_est = _evo(ref), _evo(est)
    e_est.align(e_ref, correct_scale=True)
    m = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, delta=2, delta_unit=evo_metrics.Unit.frames,
                        all_pairs=True)
    m.process_data((e_ref, copy.deepcopy(e_est)))
    np.testing.assert_allclose(ours.translation.errors, m.error, rtol=1e-9, atol=1e-12)


def test_ate_zero_for_rigidly_moved_copy():
    ref = _trajectory(12, 9)
    G = P.se3_exp([1.0, -2.0, 0.5, 0.3, 0.2, -0.1])
    assert P.ate(G @ ref, ref, "se3").rmse < 1e-12
    assert P.ate(G @ ref, ref, "none").rmse > 0.1


def test_tum_file_as_the_benchmark_ships_it(tmp_path):
    """A TUM RGB-D groundtruth.txt: its three '#' header lines, 4-decimal values (quaternion norm off 1 by
    ~1e-4), a blank line, and the separators the benchmark's read_file_list accepts (tabs, commas, CRLF)."""
    path = tmp_path / "groundtruth.txt"
    path.write_bytes(b"# ground truth trajectory\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n"
                     b"# timestamp tx ty tz qx qy qz qw\n"
                     b"1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\n\n"
                     b"1305031098.6758\t1.3543\t0.6306\t1.6360\t0.6129\t0.5966\t-0.3316\t-0.3980\r\n"
                     b"1305031098.6858,1.3524,0.6306,1.6342,0.6129,0.5967,-0.3316,-0.3979\n")
    stamps, c2w = P.read_tum(path)
    np.testing.assert_array_equal(stamps, [1305031098.6659, 1305031098.6758, 1305031098.6858])
    np.testing.assert_array_equal(c2w[:, :3, 3], [[1.3563, 0.6305, 1.6380], [1.3543, 0.6306, 1.6360],
                                                  [1.3524, 0.6306, 1.6342]])
    q = np.array([0.6132, 0.5962, -0.3311, -0.3986])
    np.testing.assert_allclose(c2w[0, :3, :3], P.quat_to_matrix(q / np.linalg.norm(q)), atol=1e-15)
