"""The one check that a matrix is a rotation (or a rigid transform), shared by every reader and camera.

Host code only (NumPy), no kernels. Every place that takes a rotation or a rigid transform from
outside -- the camera classes (`research.cameras.Camera`, `kernels.splat.SplatCamera`, the ray
generator of `kernels.volume.rays`), the dataset readers (NeRF-synthetic, COLMAP, trajectories) and
the pose optimisers that re-orthonormalise after each step -- goes through `checked_rotation` or
`checked_rigid`, so one tolerance and one repair hold everywhere.

**What is accepted.** A 3x3 matrix R is taken as a rotation when it is finite, its orthonormality
error

    err = max_ij |(R^T R - I)_ij|

is at most `tol` (default `ROTATION_TOL` = 1e-5), and det R > 0. A matrix with err > tol is refused
(ValueError naming the argument, with err and the tolerance), and so is one with det R <= 0 (a
reflection; with err <= tol the determinant is within 2e-5 of +-1, so its sign is the whole test).

**Why 1e-5: how the formats store matrices.** Let R be an exact rotation and R~ = R + E its stored
copy. To first order R~^T R~ - I = R^T E + E^T R, and by Cauchy-Schwarz over R's unit columns

    |(R^T E)_ij| = |sum_k r_ki e_kj| <= (sum_k |r_ki| |r_kj|) max_k |e_kj / r_kj| <= u   (relative error u)
                                    <= (sum_k |r_ki|) max_k |e_kj| <= sqrt(3) a           (absolute error a)

so err <= 2u + u^2, or err <= 2 sqrt(3) a + 3 a^2, from the storage alone:

* float32 (NeRF-synthetic's `transform_matrix`: Blender's float32 matrices written as JSON):
  u = 2^-24 = 6.0e-8, err <= 1.2e-7 (1.0e-7 is the largest over 20 000 random rotations);
* text with p significant digits (or p decimals): every entry lies in [-1, 1], so a <= 0.5 10^-p
  and err <= sqrt(3) 10^-p: 1.7e-6 for p = 6 (`%g`, `%.6f`; 1.5e-6 measured), 1.7e-7 for p = 7
  (KITTI's `%e`), 1.7e-8 for p = 8.

The writer's own arithmetic comes on top: a matrix computed in float32 before it was stored carries
the rounding of each float32 3x3 product, up to about 2 gamma_3 = 6u = 3.6e-7 per product by the same
argument (chains of 2 to 6 random float32 rotations measure 2.5e-7 to 6.1e-7). The official lego
`transforms_train.json` reaches err = 1.25e-6 (frame 88), about 21u: a few float32 products, then
exact float32 storage. The worst honest case among these formats is therefore 6-digit text written
by a float32 pipeline, about 1.7e-6 + 1.3e-6 = 3e-6. The tolerance 1e-5 leaves a margin of 3 over it
(8 over the lego file), while what a mistake produces lies above it: a scale of 1 + 1e-5 or more, a
shear, a scale or intrinsics folded into the matrix, float16 storage (err ~ 1e-3). Text with 5 digits
or fewer can reach 1.7e-5 and needs an explicit `tol`, as does any source known to be coarser.

**The repair: the orthogonal polar factor.** An accepted R is replaced by the rotation nearest to it
in the Frobenius norm: the orthogonal factor Q of the polar decomposition R = Q H (H symmetric
positive definite), which is U V^T for the SVD R = U S V^T (Fan & Hoffman 1955; Higham, "Computing the
polar decomposition", 1986). It treats the three columns alike (Gram-Schmidt would keep the first
column and push all the error into the others), and it moves R only by |R - Q|_2 = max_i |s_i - 1|
<= |R^T R - I|_2 / (1 + s_min), about 1.5 err at most (|R^T R - I|_2 <= 3 err), i.e. within the
precision the file stored it with. det R > 0 makes det Q = +1, so no sign fix is needed.
Q is computed by Newton's polar iteration X <- (X + X^-T) / 2 from X = R, which keeps the polar
factor (X = Q H maps to Q (H + H^-1) / 2) and converges quadratically to it (|H - I| ~ e becomes
~ e^2 / 2): it stops after the step that moves no entry by more than 1e-12, two or three steps for
err <= 1e-5, since the next would move it by ~1e-24. Here it is more accurate than LAPACK's U V^T: over
20 000 float32-rounded rotations err(Q) <= 4.4e-16 and Q^T R is symmetric to 4.1e-16, where U V^T
gives 2.9e-15 and 1.1e-14. A matrix already orthonormal to 16 float64 ulps (err <= 3.6e-15: anything
computed in float64, such as `look_at`, scipy's quaternion-to-matrix, an se(3) exponential) is
returned unchanged (a float64 copy), so exact inputs stay bit for bit. `tol` may be at most 0.1 (the
singular values are then within [0.83, 1.14], so R is far from singular).

`checked_rigid` does the same for a 4x4 (or 3x4) matrix [[R, t], [0, 0, 0, 1]]: the rotation part is
checked and repaired as above, the last row must be (0, 0, 0, 1) to `tol` and is then set exactly, t is
kept; it returns a 4x4 float64 matrix.
"""

from __future__ import annotations

from typing import Any

import numpy as np

ROTATION_TOL = 1e-5  # max |R^T R - I| accepted (module docstring: float32 JSON and 6-8 digit text)
_EXACT = 16.0 * float(np.finfo(np.float64).eps)  # already orthonormal to float64 rounding: left as is
_MAX_TOL = 0.1  # singular values within [0.83, 1.14]: R is far from singular and the iteration converges fast
_NEWTON_STEPS = 30


def _as_float64(name: str, value: Any, shapes: tuple[tuple[int, int], ...], what: str) -> np.ndarray:
    try:
        M = np.array(value.numpy() if hasattr(value, "numpy") else value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected {what}, got {type(value).__name__} ({exc})") from None
    if M.shape not in shapes:
        raise ValueError(f"{name}: expected {what}, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name}: contains non-finite values")
    return M


def _tolerance(tol: float | None) -> float:
    tol = ROTATION_TOL if tol is None else float(tol)
    if not (np.isfinite(tol) and 0.0 <= tol <= _MAX_TOL):
        raise ValueError(f"tol: expected a value in [0, {_MAX_TOL}], got {tol}")
    return tol


def orthonormality_error(R: np.ndarray) -> float:
    """max_ij |(R^T R - I)_ij| of a 3x3 matrix."""
    R = np.asarray(R, dtype=np.float64)
    return float(np.abs(R.T @ R - np.eye(3)).max())


def _rotation(name: str, R: np.ndarray, tol: float, what: str) -> np.ndarray:
    err = orthonormality_error(R)
    if err > tol:
        raise ValueError(f"{name}: {what} is not orthonormal (max |R^T R - I| = {err:.3g}, tolerance {tol:.3g}); "
                         f"expected a rotation")
    det = float(np.linalg.det(R))
    if det <= 0.0:
        raise ValueError(f"{name}: {what} has determinant {det:.6g}, expected +1 (a reflection, not a rotation)")
    if err <= _EXACT:
        return R.copy()
    return _polar_factor(R)


def _polar_factor(R: np.ndarray) -> np.ndarray:
    """The orthogonal polar factor of R (module docstring): Newton's iteration X <- (X + X^-T) / 2 from
    X = R, until a step moves no entry by more than 1e-12 (the next would move it by ~1e-24)."""
    X = R
    for _ in range(_NEWTON_STEPS):
        nxt = 0.5 * (X + np.linalg.inv(X).T)
        done = float(np.abs(nxt - X).max()) <= 1e-12
        X = nxt
        if done:
            return X
    raise AssertionError("the polar iteration did not converge")  # unreachable for err <= tol <= 0.1


def checked_rotation(name: str, R: Any, tol: float | None = None) -> np.ndarray:
    """R (3, 3) as the nearest rotation (float64), after checking that it is one to `tol` (default
    ROTATION_TOL); ValueError naming `name` for a wrong shape, a non-finite entry, max |R^T R - I| above
    `tol` or det R <= 0 (module docstring: the tolerance and the polar-factor repair)."""
    M = _as_float64(name, R, ((3, 3),), "a 3x3 rotation matrix")
    return _rotation(name, M, _tolerance(tol), "matrix")


def checked_rigid(name: str, T: Any, tol: float | None = None) -> np.ndarray:
    """T (4, 4) or (3, 4) = [[R, t], [0, 0, 0, 1]] as a 4x4 float64 rigid transform with R replaced by its
    nearest rotation and the last row exact; ValueError naming `name` for a wrong shape, a non-finite
    entry, a last row not (0, 0, 0, 1) to `tol`, or a rotation part that `checked_rotation` refuses."""
    M = _as_float64(name, T, ((4, 4), (3, 4)), "a 4x4 (or 3x4) rigid transform [[R, t], [0, 0, 0, 1]]")
    tol = _tolerance(tol)
    if M.shape == (4, 4) and np.abs(M[3] - (0.0, 0.0, 0.0, 1.0)).max() > tol:
        raise ValueError(f"{name}: last row must be [0, 0, 0, 1], got {M[3].tolist()}")
    out = np.eye(4)
    out[:3, :3] = _rotation(name, M[:3, :3], tol, "rotation part")
    out[:3, 3] = M[:3, 3]
    return out
