"""Linear Kalman filter and Rauch-Tung-Striebel smoother.

State-space model (Kalman 1960; notation of Bar-Shalom, Li & Kirubarajan,
"Estimation with Applications to Tracking and Navigation", 2001):

    x_k = F x_{k-1} + w_k,   w_k ~ N(0, Q)
    z_k = H x_k     + v_k,   v_k ~ N(0, R)
    x_0 ~ N(m_0, P_0)        (prior on the state at the first measurement)

Predict:   x^- = F x,   P^- = F P F^T + Q
Update:    y = z - H x^-                      innovation
           S = H P^- H^T + R                  innovation covariance
           K = P^- H^T S^{-1}                 gain
           x = x^- + K y
           P = (I - K H) P^- (I - K H)^T + K R K^T     (Joseph form)

The Joseph form equals (I - K H) P^- for the optimal gain, but it is a sum of
two symmetric positive semi-definite terms, valid for any gain, and
insensitive to first order to errors in K (Bucy & Joseph 1968), so rounding
does not drive P indefinite as it can (I - K H) P^-. Every covariance is also
symmetrised, (P + P^T) / 2, after each step.

`kalman_filter` also runs a batch of sequences that share the model and the
prior covariance: P and K do not depend on the measurements, so the batch
shares one covariance recursion.

Innovation log-likelihood, used to tune Q (and in tests):
    log p(z_k | z_{<k}) = -1/2 (y^T S^{-1} y + log det(2 pi S)).

RTS smoother (Rauch, Tung & Striebel 1965), backwards from the last filtered
estimate, x^s_{T-1} = x_{T-1}:
    G_k   = P_k F^T (P^-_{k+1})^{-1}
    x^s_k = x_k + G_k (x^s_{k+1} - x^-_{k+1})
    P^s_k = P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^T
It gives the exact Gaussian posterior p(x_k | z_0..z_{T-1}) of the
linear-Gaussian model.

Motion models (Bar-Shalom et al. 2001, sec. 6.2-6.3), per axis, time step dt:
* constant velocity (CV), state [p, v], continuous white-noise acceleration
  with spectral density q:  Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]];
* constant acceleration (CA), state [p, v, a], continuous white-noise jerk:
  Q = q [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]].
A d-dimensional model stacks the axes: the state is [p_1..p_d, v_1..v_d, (a_1..a_d)].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from research.tracking import checks
import scipy.linalg

_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class LinearGaussianModel:
    """Matrices of a time-invariant linear-Gaussian state-space model."""

    F: np.ndarray  # (n, n) transition
    H: np.ndarray  # (m, n) observation
    Q: np.ndarray  # (n, n) process noise covariance
    R: np.ndarray  # (m, m) measurement noise covariance

    def __post_init__(self) -> None:
        """Shapes, finite F and H, and Q, R symmetric positive semi-definite (research.tracking.checks)."""
        if np.ndim(self.F) != 2 or np.ndim(self.H) != 2:
            raise ValueError(f"F, H: expected matrices, got shapes {np.shape(self.F)}, {np.shape(self.H)}")
        n = self.F.shape[0]
        m = self.H.shape[0]
        if self.F.shape != (n, n) or self.Q.shape != (n, n):
            raise ValueError(f"F and Q must be ({n}, {n}); got {self.F.shape}, {self.Q.shape}")
        if self.H.shape != (m, n) or self.R.shape != (m, m):
            raise ValueError(f"H must be ({m}, {n}) and R ({m}, {m}); got {self.H.shape}, {self.R.shape}")
        for name in ("F", "H"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"{name}: contains NaN or infinite values")
        checks.covariance("Q", self.Q)
        checks.covariance("R", self.R)

    @property
    def state_dim(self) -> int:
        return self.F.shape[0]

    @property
    def meas_dim(self) -> int:
        return self.H.shape[0]


@dataclass(frozen=True)
class UpdateResult:
    x: np.ndarray  # posterior mean
    P: np.ndarray  # posterior covariance (Joseph form)
    innovation: np.ndarray  # y = z - H x^-
    S: np.ndarray  # innovation covariance
    loglik: float  # log N(y; 0, S)


@dataclass(frozen=True)
class FilterResult:
    """Per-step outputs of `kalman_filter`. Means are (T, n), or (B, T, n) for a
    batch; covariances are (T, n, n), shared by the batch. Index k holds step k;
    x_pred/P_pred at k = 0 are the prior."""

    x_pred: np.ndarray
    P_pred: np.ndarray
    x_filt: np.ndarray
    P_filt: np.ndarray
    loglik: np.ndarray  # (T,) or (B, T): log p(z_k | z_<k); 0 where z_k is missing


def _symmetrise(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x^- = F x, P^- = F P F^T + Q."""
    return F @ x, _symmetrise(F @ P @ F.T + Q)


def update(
    x: np.ndarray, P: np.ndarray, z: np.ndarray, H: np.ndarray, R: np.ndarray, with_loglik: bool = True
) -> UpdateResult:
    """Measurement update with the Joseph-form covariance (see module docstring).

    with_loglik=False skips the log-likelihood (then NaN), which trackers do not need.
    """
    y = z - H @ x
    PHt = P @ H.T
    S = _symmetrise(H @ PHt + R)
    # One solve gives both K^T = S^{-1} H P and S^{-1} y (S is small; no explicit inverse).
    sol = np.linalg.solve(S, np.concatenate([PHt.T, y[:, None]], axis=1))
    K = sol[:, :-1].T
    x_new = x + K @ y
    A = np.eye(P.shape[0]) - K @ H
    P_new = _symmetrise(A @ P @ A.T + K @ R @ K.T)
    loglik = float("nan")
    if with_loglik:
        sign, logdet = np.linalg.slogdet(S)
        if sign <= 0:
            raise np.linalg.LinAlgError("innovation covariance is not positive definite")
        loglik = -0.5 * (float(y @ sol[:, -1]) + logdet + len(y) * _LOG_2PI)
    return UpdateResult(x_new, P_new, y, S, loglik)


def kalman_filter(
    zs: np.ndarray, model: LinearGaussianModel, x0: np.ndarray, P0: np.ndarray
) -> FilterResult:
    """Run the filter over measurements zs (T, m), or over a batch (B, T, m).

    (x0, P0) is the prior of the state at step 0: x0 is (n,) or (B, n); P0 is
    (n, n). Step 0 is an update only (no prediction before the first
    measurement); each later step predicts, then updates. A step whose
    measurement contains NaN only predicts; in a batch, such a step must be
    missing in every sequence.

    A batch shares one covariance recursion: P and the gains do not depend on
    the measurements, only on the model and P0, so B sequences cost little
    more than one.
    """
    zs = np.asarray(zs, dtype=float)
    single = zs.ndim == 2
    zb = zs[None] if single else zs
    if zb.ndim != 3 or zb.shape[2] != model.meas_dim:
        raise ValueError(f"zs must be (T, {model.meas_dim}) or (B, T, {model.meas_dim}); got {zs.shape}")
    B, T = zb.shape[:2]
    n = model.state_dim
    P = checks.covariance("P0", P0, n)
    x0 = np.asarray(x0, dtype=float)
    if x0.shape not in ((n,), (B, n)) or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0: expected finite values of shape ({n},) or ({B}, {n}), got shape {x0.shape}")
    x = np.broadcast_to(x0, (B, n)).copy()
    present = np.isfinite(zb).all(axis=2)  # (B, T)
    if not np.all(present == present[:1]):
        raise ValueError("in a batch, a missing measurement (NaN) must be missing in every sequence")
    x_pred = np.empty((B, T, n))
    x_filt = np.empty((B, T, n))
    P_pred = np.empty((T, n, n))
    P_filt = np.empty((T, n, n))
    loglik = np.zeros((B, T))
    F, H, Q, R = model.F, model.H, model.Q, model.R
    eye = np.eye(n)
    for k in range(T):
        if k > 0:
            x = x @ F.T
            P = _symmetrise(F @ P @ F.T + Q)
        x_pred[:, k], P_pred[k] = x, P
        if present[0, k]:
            y = zb[:, k] - x @ H.T  # (B, m)
            PHt = P @ H.T
            S = _symmetrise(H @ PHt + R)
            K = np.linalg.solve(S, PHt.T).T
            x = x + y @ K.T
            A = eye - K @ H
            P = _symmetrise(A @ P @ A.T + K @ R @ K.T)
            sign, logdet = np.linalg.slogdet(S)
            if sign <= 0:
                raise np.linalg.LinAlgError("innovation covariance is not positive definite")
            maha = np.einsum("bi,bi->b", y, np.linalg.solve(S, y.T).T)
            loglik[:, k] = -0.5 * (maha + logdet + len(R) * _LOG_2PI)
        x_filt[:, k], P_filt[k] = x, P
    if single:
        x_pred, x_filt, loglik = x_pred[0], x_filt[0], loglik[0]
    return FilterResult(x_pred, P_pred, x_filt, P_filt, loglik)


def rts_smoother(result: FilterResult, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel smoothed means ((T, n) or (B, T, n)) and covariances (T, n, n)."""
    single = result.x_filt.ndim == 2
    xf = result.x_filt[None] if single else result.x_filt
    xp = result.x_pred[None] if single else result.x_pred
    T = xf.shape[1]
    xs = xf.copy()
    Ps = result.P_filt.copy()
    for k in range(T - 2, -1, -1):
        P_next = result.P_pred[k + 1]
        # G = P_k F^T P_next^{-1}, via a solve with the symmetric positive-definite P_next.
        G = scipy.linalg.solve(P_next, F @ result.P_filt[k], assume_a="pos").T
        xs[:, k] = xf[:, k] + (xs[:, k + 1] - xp[:, k + 1]) @ G.T
        Ps[k] = _symmetrise(result.P_filt[k] + G @ (Ps[k + 1] - P_next) @ G.T)
    return (xs[0] if single else xs), Ps


def _kinematic_blocks(order: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis transition and unit-density process noise for a kinematic model.

    order 1: constant velocity, state [p, v]; order 2: constant acceleration, [p, v, a].
    """
    if order == 1:
        F1 = np.array([[1.0, dt], [0.0, 1.0]])
        Q1 = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    elif order == 2:
        F1 = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
        Q1 = np.array(
            [
                [dt**5 / 20, dt**4 / 8, dt**3 / 6],
                [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                [dt**3 / 6, dt**2 / 2, dt],
            ]
        )
    else:
        raise ValueError(f"order must be 1 (CV) or 2 (CA); got {order}")
    return F1, Q1


def kinematic_model(order: int, ndim: int, q: float, r: float, dt: float = 1.0) -> LinearGaussianModel:
    """CV (order 1) or CA (order 2) model in `ndim` axes, positions observed with variance r.

    q >= 0 and r >= 0 finite (a variance; q = 0 is a noiseless motion), dt > 0 finite, ndim >= 1.
    """
    checks.integer("ndim", ndim, 1)
    checks.number("q", q, 0.0)
    checks.number("r", r, 0.0)
    checks.number("dt", dt, 0.0, low_open=True)
    F1, Q1 = _kinematic_blocks(order, dt)
    eye = np.eye(ndim)
    F = np.kron(F1, eye)
    Q = q * np.kron(Q1, eye)
    H = np.kron(np.eye(1, order + 1), eye)
    return LinearGaussianModel(F=F, H=H, Q=Q, R=r * np.eye(ndim))


def constant_velocity(ndim: int = 2, q: float = 1.0, r: float = 1.0, dt: float = 1.0) -> LinearGaussianModel:
    """Constant-velocity model, continuous white-noise acceleration of density q."""
    return kinematic_model(1, ndim, q, r, dt)


def constant_acceleration(ndim: int = 2, q: float = 1.0, r: float = 1.0, dt: float = 1.0) -> LinearGaussianModel:
    """Constant-acceleration model, continuous white-noise jerk of density q."""
    return kinematic_model(2, ndim, q, r, dt)


def diffuse_prior(model: LinearGaussianModel, z0: np.ndarray, var: float = 1e6) -> tuple[np.ndarray, np.ndarray]:
    """A vague prior: mean H^T z0 (positions at the first measurement), covariance var * I.

    With a large var the first update puts the position at z0 with covariance
    about R, and the derivatives are learnt from the following measurements
    instead of being assumed zero.
    """
    checks.number("var", var, 0.0, low_open=True)
    x0 = model.H.T @ np.asarray(z0, dtype=float)
    return x0, var * np.eye(model.state_dim)
