"""kernels/rotation.py: the one rotation check. Rotations stored as the formats store them (float32,
6-digit text, a float32 pipeline's drift of 1.25e-6) pass and come back orthonormal to 1e-15; a
reflection, a scale, a shear beyond the tolerance, NaN and wrong shapes are refused by name."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kernels.rotation import ROTATION_TOL, checked_rigid, checked_rotation, orthonormality_error

ROTATIONS = Rotation.random(50, random_state=7).as_matrix()


def _text(R: np.ndarray, fmt: str) -> np.ndarray:
    return np.array([[float(fmt % x) for x in row] for row in R])


def _drift(R: np.ndarray, eps: float) -> np.ndarray:
    """R (I + eps S), S symmetric with unit entries: max |R^T R - I| = 2 eps to first order (a float32
    pipeline's rounding, as in the official lego file's 1.25e-6)."""
    S = np.array([[0.0, 1.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 1.0, 0.0]])
    return R @ (np.eye(3) + eps * S)


def _assert_rotation(Q: np.ndarray, near: np.ndarray, atol: float) -> None:
    assert Q.dtype == np.float64 and Q.shape == (3, 3)
    assert orthonormality_error(Q) < 1e-15
    assert abs(np.linalg.det(Q) - 1.0) < 1e-15
    assert np.abs(Q - near).max() < atol


@pytest.mark.parametrize("source, bound", [("float32", 1.2e-7), ("%.6g", 1.8e-6), ("%.6e", 1.8e-7), ("%.8g", 1.8e-8),
                                           ("drift", 1.4e-6)])
def test_stored_rotations_pass_and_come_back_orthonormal(source, bound):
    worst = 0.0
    for R in ROTATIONS:
        if source == "float32":
            stored = R.astype(np.float32)
        elif source == "drift":
            stored = _drift(R, 6.25e-7).astype(np.float32)
        else:
            stored = _text(R, source)
        err = orthonormality_error(stored)
        worst = max(worst, err)
        assert err <= bound  # the storage bound of the module docstring
        Q = checked_rotation("R", stored)
        _assert_rotation(Q, R, 2.0 * bound + 1e-7)
        H = Q.T @ stored  # the polar decomposition stored = Q H: H symmetric positive definite
        assert np.abs(H - H.T).max() < 1e-15 and np.all(np.linalg.eigvalsh(0.5 * (H + H.T)) > 0)
    assert worst < ROTATION_TOL / 3  # the margin the docstring claims
    if source == "drift":
        assert worst > 1e-6  # what the old 1e-6 checks refused


def test_the_polar_factor_is_the_nearest_rotation():
    rng = np.random.default_rng(3)
    for R in ROTATIONS[:10]:
        stored = _drift(R, 4e-6)
        Q = checked_rotation("R", stored)
        for _ in range(20):  # any other rotation near Q is farther from `stored` in the Frobenius norm
            other = Rotation.from_rotvec(rng.normal(scale=1e-6, size=3)).as_matrix() @ Q
            assert np.linalg.norm(other - stored) >= np.linalg.norm(Q - stored)


def test_an_exact_rotation_is_returned_unchanged():
    R = ROTATIONS[0]
    Q = checked_rotation("R", R)
    assert np.array_equal(Q, R) and Q is not R
    assert np.array_equal(checked_rotation("R", np.eye(3)), np.eye(3))


@pytest.mark.parametrize("case, make, message", [
    ("reflection", lambda R: R @ np.diag([1.0, 1.0, -1.0]),
     r"^R: matrix has determinant -1, expected \+1 \(a reflection, not a rotation\)"),
    ("scaled", lambda R: 1.001 * R, r"^R: matrix is not orthonormal \(max \|R\^T R - I\| = 0\.002, tolerance 1e-05\)"),
    ("shear-beyond-tolerance", lambda R: R @ np.array([[1.0, 1.5e-5, 0], [0, 1, 0], [0, 0, 1]]),
     r"^R: matrix is not orthonormal \(max \|R\^T R - I\| = 1\.5e-05"),
    ("drift-2e-5-as-5-digit-text", lambda R: _text(_drift(R, 1e-5), "%.5g"), r"^R: matrix is not orthonormal"),
    ("nan", lambda R: np.where(np.eye(3) > 0, np.nan, R), r"^R: contains non-finite values"),
    ("inf", lambda R: np.full((3, 3), np.inf), r"^R: contains non-finite values"),
    ("wrong-shape", lambda R: R[:2], r"^R: expected a 3x3 rotation matrix, got shape \(2, 3\)"),
    ("four-by-four", lambda R: np.eye(4), r"^R: expected a 3x3 rotation matrix, got shape \(4, 4\)"),
    ("not-numbers", lambda R: [["a", "b", "c"]] * 3, r"^R: expected a 3x3 rotation matrix"),
])
def test_refused_by_name(case, make, message):
    with pytest.raises(ValueError, match=message):
        checked_rotation("R", make(ROTATIONS[1]))


def test_tolerance_argument():
    coarse = _text(_drift(ROTATIONS[2], 1e-5), "%.5g")  # about 2e-5: refused by default, passes when told
    _assert_rotation(checked_rotation("R", coarse, tol=1e-4), ROTATIONS[2], 1e-4)
    with pytest.raises(ValueError, match=r"^R: matrix is not orthonormal .*tolerance 1e-06"):
        checked_rotation("R", _drift(ROTATIONS[2], 1e-6), tol=1e-6)
    for bad in (-1.0, np.nan, 0.2):
        with pytest.raises(ValueError, match=r"^tol: expected a value in \[0, 0\.1\]"):
            checked_rotation("R", ROTATIONS[2], tol=bad)


@pytest.mark.parametrize("rows", [4, 3])
def test_rigid_transforms(rows):
    R, t = ROTATIONS[3], np.array([0.5, -2.0, 3.25])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    stored = T.astype(np.float32)[:rows]
    out = checked_rigid("c2w", stored)
    assert out.shape == (4, 4) and out.dtype == np.float64
    _assert_rotation(out[:3, :3], R, 2.5e-7)
    assert np.array_equal(out[:3, 3], stored[:3, 3].astype(np.float64))  # the translation is kept as stored
    assert np.array_equal(out[3], [0.0, 0.0, 0.0, 1.0])
    exact = checked_rigid("c2w", T)
    assert np.array_equal(exact, T)


@pytest.mark.parametrize("case, make, message", [
    ("last-row", lambda T: T + np.diag([0, 0, 0, 1e-3]),
     r"^c2w: last row must be \[0, 0, 0, 1\], got \[0\.0, 0\.0, 0\.0, 1\.001\]"),
    ("reflection", lambda T: T @ np.diag([1.0, -1.0, 1.0, 1.0]), r"^c2w: rotation part has determinant -1, expected \+1"),
    ("scaled", lambda T: T @ np.diag([2.0, 2.0, 2.0, 1.0]),
     r"^c2w: rotation part is not orthonormal \(max \|R\^T R - I\| = 3"),
    ("nan", lambda T: np.where(np.eye(4) > 0, np.nan, T), r"^c2w: contains non-finite values"),
    ("shape", lambda T: T[:2],
     r"^c2w: expected a 4x4 \(or 3x4\) rigid transform \[\[R, t\], \[0, 0, 0, 1\]\], got shape \(2, 4\)"),
])
def test_rigid_refused_by_name(case, make, message):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = ROTATIONS[4], (1.0, 2.0, 3.0)
    with pytest.raises(ValueError, match=message):
        checked_rigid("c2w", make(T))


def _w2c(R: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, (0.1, -0.2, 3.0)
    return T


def test_the_kernel_cameras_use_the_one_check():
    """SplatCamera and the volume ray camera accept a float32 pipeline's 1.25e-6 (the old copies refused
    it at 1e-6), keep the repaired matrix, and refuse 2e-5 and a reflection by their argument's name."""
    from kernels.splat import SplatCamera
    from kernels.volume.rays import check_camera

    K = np.array([[20.0, 0.0, 8.0], [0.0, 20.0, 8.0], [0.0, 0.0, 1.0]])
    stored = _w2c(_drift(ROTATIONS[5], 6.25e-7).astype(np.float32))
    assert orthonormality_error(stored[:3, :3]) > 1e-6
    expected = checked_rigid("w2c", stored)
    assert np.array_equal(SplatCamera(stored, K, 16, 16).viewmat, expected)
    assert np.array_equal(check_camera(stored, [20.0, 20.0, 8.0, 8.0])[0], expected)
    for bad, message in ((_w2c(_drift(ROTATIONS[5], 1e-5)), "is not orthonormal"),
                         (_w2c(ROTATIONS[5] @ np.diag([1.0, 1.0, -1.0])), "has determinant -1")):
        with pytest.raises(ValueError, match=r"^viewmat: expected a rigid world-to-camera transform .*; "
                                             r"rotation part " + message):
            SplatCamera(bad, K, 16, 16)
        with pytest.raises(ValueError, match=r"^w2c: rotation part " + message):
            check_camera(bad, [20.0, 20.0, 8.0, 8.0])
