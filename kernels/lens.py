"""Lens camera models: camera-frame point -> normalised image point, its Jacobian, its inverse.

Four models, in the OpenCV camera frame (x right, y down, z forward). A camera-frame point
p = (x, y, z) maps to a normalised image point m = (m_x, m_y), and the intrinsics give the pixel
(u, v) = (fx m_x + cx, fy m_y + cy) (pixel (i, j) has its centre at (i + 1/2, j + 1/2)).

* "pinhole": m = w = (x / z, y / z).
* "opencv" (radial-tangential, OpenCV's `projectPoints` with (k1, k2, p1, p2, k3); COLMAP's
  SIMPLE_RADIAL, RADIAL and OPENCV are the cases with some coefficients 0): with w = (a, b),
  s = a^2 + b^2 and R(s) = 1 + k1 s + k2 s^2 + k3 s^3,

      m_x = a R + 2 p1 a b + p2 (s + 2 a^2),     m_y = b R + p1 (s + 2 b^2) + 2 p2 a b.

* "fisheye" (equidistant, OpenCV's `cv2.fisheye` and COLMAP's OPENCV_FISHEYE with (k1, k2, k3,
  k4)): theta = atan(r), r = |w|, theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8),
  m = (theta_d / r) w, written m = G(s) w with G(s) = theta_d / r (G(0) = 1).
* "orthographic": m = (x, y); the depth z only culls. Its rays are parallel: origin (m_x, m_y, 0),
  direction (0, 0, 1) in the camera frame.

Jacobian. For the central models, J_m = dm/dp = J_D(w) J_w with J_w = [[1/z, 0, -x/z^2], [0, 1/z,
-y/z^2]] and J_D = dm/dw:
  opencv  J_D = [[R + 2 a^2 R' + 2 p1 b + 6 p2 a,  2 a b R' + 2 p1 a + 2 p2 b],
                 [2 a b R' + 2 p1 a + 2 p2 b,      R + 2 b^2 R' + 6 p1 b + 2 p2 a]]   (R' = dR/ds)
  fisheye J_D = G I + 2 G'(s) w w^T.
The splat projection's backward needs the second derivatives of m (the covariance goes through
J_m(p)); `lens_project_vjp` contracts them with a cotangent of J_m, writing the Hessian of D
term by term (opencv) or as 2 G' (w_l delta_ik + delta_il w_k + w_i delta_kl) + 4 G'' w_i w_k w_l
(fisheye). G, G' and G'' are evaluated in float64 whatever the dtype: their closed forms cancel
near the axis (relative error about eps / r^5 for G''), so below s = 1e-4 the series
G = 1 + c1 s + c2 s^2 + c3 s^3 + c4 s^4 is used (c1 = k1 - 1/3, c2 = 1/5 - k1 + k2,
c3 = -1/7 + 14/15 k1 - 5/3 k2 + k3, c4 = 1/9 - 818/945 k1 + 19/9 k2 - 7/3 k3 + k4; the dropped
terms are below 1e-16 there).

Valid domain. A lens polynomial folds back beyond its first turning point, where points on two
radii map to one image point. Both lens models are limited to s < s_lim, computed on the host
(`Lens.s_limit`): opencv, the first positive root of d(r R(r^2))/dr = 1 + 3 k1 s + 5 k2 s^2 +
7 k3 s^3 (tangential terms ignored for the bound); fisheye, tan^2 of the first root in (0, pi/2)
of d theta_d / d theta = 1 + 3 k1 t^2 + ... + 9 k4 t^8 (no root: s_lim = infinity, so theta < pi/2,
the model's own limit, as r = tan theta). Points with z <= 0 (central models) or s >= s_lim are
flagged invalid; the splat projection culls them and the ray generator marks their pixels.

Inverse (pixel -> unit ray e, `lens_unproject`), in float64 whatever the dtype:
  opencv   Newton on D(w) = m from w = m: w <- w - J_D(w)^-1 (D(w) - m), until max |D(w) - m| <=
           1e-12 (1 + |m|), then one step more (quadratic convergence: the solution to rounding, so
           the ray is a smooth function of the pixel for finite differences), at most
           NEWTON_ITERS = 30 steps; e = (w, 1) / |(w, 1)|.
  fisheye  Newton on theta_d(theta) = |m| from theta = min(|m|, theta_lim), stopping when |step| <=
           1e-14 (1 + theta), at most 30 steps; e = (sin theta m / |m|, cos theta).
A pixel is invalid when Newton does not meet its criterion or when the solution leaves s < s_lim
(opencv) or theta < theta_lim = atan(sqrt(s_lim)) (fisheye: so theta > pi/2 is never returned);
the pinhole's and the orthographic inverse are exact and always valid. The inverse's derivative (`lens_unproject_vjp`) needs no
iteration: for a central model m(e) is constant along rays, so de/dm is the 3x2 block of
[J_m(e); e^T]^-1 (J_m de/dm = I, e . de/dm = 0 since |e| = 1).

The Warp functions take the lens as a model id (MODEL_IDS) and a parameter array `lens`
(Lens.params: the five coefficients, then s_lim), both dtypes. This module also holds `Lens`,
the host-side description that cameras carry, and `project_points` (points to pixels, one
thread per point), the entry point research.cameras projects with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})

MODEL_IDS = {"pinhole": 0, "opencv": 1, "fisheye": 2, "orthographic": 3}
COEFFS = {"pinhole": (), "opencv": ("k1", "k2", "p1", "p2", "k3"), "fisheye": ("k1", "k2", "k3", "k4"),
          "orthographic": ()}
N_PARAMS = 6  # five coefficient slots, then s_lim
NEWTON_ITERS = 30
S_LIMIT_CAP = 1e30  # s_lim stored when the model has no turning point (finite in float32)
FISHEYE_SERIES_S = 1e-4
# G(s) = 1 + sum_n c_n s^n with c_n = SERIES[n-1] . (1, k1, ..., k_{n-1}) + k_n (module docstring);
# tests/kernels/test_lens.py derives them exactly from the series of atan.
SERIES = ((-1.0 / 3.0,), (1.0 / 5.0, -1.0), (-1.0 / 7.0, 14.0 / 15.0, -5.0 / 3.0),
          (1.0 / 9.0, -818.0 / 945.0, 19.0 / 9.0, -7.0 / 3.0))
_S10 = wp.constant(SERIES[0][0])
_S20, _S21 = (wp.constant(c) for c in SERIES[1])
_S30, _S31, _S32 = (wp.constant(c) for c in SERIES[2])
_S40, _S41, _S42, _S43 = (wp.constant(c) for c in SERIES[3])


def _first_positive_root(coeffs_low_first: list[float], upper: float) -> float:
    """The smallest real root in (0, upper) of the polynomial sum c_k x^k, else `upper`."""
    c = np.trim_zeros(np.asarray(coeffs_low_first, dtype=np.float64), "b")
    if len(c) <= 1:
        return upper
    roots = np.roots(c[::-1])
    real = roots[np.abs(roots.imag) <= 1e-9 * np.maximum(1.0, np.abs(roots))].real
    real = real[(real > 0) & (real < upper)]
    return float(real.min()) if len(real) else upper


@dataclass(frozen=True)
class Lens:
    """A lens model and its coefficients (module docstring): "pinhole" (), "opencv" (k1, k2, p1, p2,
    k3), "fisheye" (k1, k2, k3, k4) or "orthographic" (). Shorter coefficient tuples are padded with 0."""

    model: str = "pinhole"
    coeffs: tuple = ()

    def __post_init__(self) -> None:
        if self.model not in MODEL_IDS:
            raise ValueError(f"lens: expected a model in {sorted(MODEL_IDS)}, got {self.model!r}")
        names = COEFFS[self.model]
        c = np.asarray(self.coeffs, dtype=np.float64).reshape(-1)
        if len(c) > len(names):
            raise ValueError(f"lens: model {self.model!r} takes at most {len(names)} coefficients {names}, "
                             f"got {len(c)}")
        if not np.all(np.isfinite(c)):
            raise ValueError(f"lens: coefficients must be finite, got {c.tolist()}")
        c = np.concatenate([c, np.zeros(len(names) - len(c))])
        object.__setattr__(self, "coeffs", tuple(float(x) for x in c))

    @property
    def model_id(self) -> int:
        return MODEL_IDS[self.model]

    @property
    def central(self) -> bool:
        return self.model != "orthographic"

    def s_limit(self) -> float:
        """s_lim of the module docstring (S_LIMIT_CAP where the model has no turning point)."""
        if self.model == "opencv":
            k1, k2, _, _, k3 = self.coeffs
            return _first_positive_root([1.0, 3 * k1, 5 * k2, 7 * k3], S_LIMIT_CAP)
        if self.model == "fisheye":
            k1, k2, k3, k4 = self.coeffs
            t2 = _first_positive_root([1.0, 3 * k1, 5 * k2, 7 * k3, 9 * k4], (math.pi / 2) ** 2)
            return S_LIMIT_CAP if t2 >= (math.pi / 2) ** 2 else min(math.tan(math.sqrt(t2)) ** 2, S_LIMIT_CAP)
        return S_LIMIT_CAP

    def params(self) -> np.ndarray:
        """(N_PARAMS,) float64: the coefficients in their slots, then s_lim (the kernels' `lens` array)."""
        out = np.zeros(N_PARAMS)
        out[:len(self.coeffs)] = self.coeffs
        out[N_PARAMS - 1] = self.s_limit()
        return out

    def to_dict(self) -> dict:
        return {"model": self.model, "coeffs": list(self.coeffs)}


def check_lens(name: str, lens: Any) -> Lens | None:
    """`lens` as a Lens, or None for no lens or a plain pinhole; ValueError naming `name` otherwise."""
    if lens is None:
        return None
    if isinstance(lens, dict):
        lens = Lens(lens.get("model", ""), tuple(lens.get("coeffs", ())))
    if not isinstance(lens, Lens):
        raise ValueError(f"{name}: expected a kernels.lens.Lens, got {type(lens).__name__}")
    return None if lens.model == "pinhole" else lens


# =========================================================================== radial functions


@wp.func
def opencv_radial(s: Any, k1: Any, k2: Any, k3: Any):
    """(R, R', R'') of R(s) = 1 + k1 s + k2 s^2 + k3 s^3."""
    one = type(s)(1.0)
    two = type(s)(2.0)
    three = type(s)(3.0)
    return (one + s * (k1 + s * (k2 + s * k3)), k1 + s * (two * k2 + three * k3 * s),
            two * k2 + type(s)(6.0) * k3 * s)


@wp.func
def fisheye_radial(s: Any, c1_: Any, c2_: Any, c3_: Any, c4_: Any):
    """(G, G', G'') of G(s) = theta_d / r (module docstring) for (k1, k2, k3, k4), computed in float64."""
    s64 = wp.float64(s)
    k1 = wp.float64(c1_)
    k2 = wp.float64(c2_)
    k3 = wp.float64(c3_)
    k4 = wp.float64(c4_)
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    G = one
    G1 = wp.float64(0.0)
    G2 = wp.float64(0.0)
    if s64 < wp.float64(FISHEYE_SERIES_S):
        c1 = wp.float64(_S10) + k1
        c2 = wp.float64(_S20) + wp.float64(_S21) * k1 + k2
        c3 = wp.float64(_S30) + wp.float64(_S31) * k1 + wp.float64(_S32) * k2 + k3
        c4 = wp.float64(_S40) + wp.float64(_S41) * k1 + wp.float64(_S42) * k2 + wp.float64(_S43) * k3 + k4
        G = one + s64 * (c1 + s64 * (c2 + s64 * (c3 + s64 * c4)))
        G1 = c1 + s64 * (two * c2 + s64 * (wp.float64(3.0) * c3 + s64 * wp.float64(4.0) * c4))
        G2 = two * c2 + s64 * (wp.float64(6.0) * c3 + s64 * wp.float64(12.0) * c4)
    else:
        r = wp.sqrt(s64)
        th = wp.atan(r)
        t2 = th * th
        T = th * (one + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        T1 = one + t2 * (wp.float64(3.0) * k1 + t2 * (wp.float64(5.0) * k2 + t2 * (wp.float64(7.0) * k3
                                                                                     + t2 * wp.float64(9.0) * k4)))
        T2 = th * (wp.float64(6.0) * k1 + t2 * (wp.float64(20.0) * k2 + t2 * (wp.float64(42.0) * k3
                                                                              + t2 * wp.float64(72.0) * k4)))
        tr = one / (one + s64)
        trr = -two * r * tr * tr
        g = T / r
        g1 = T1 * tr / r - T / s64
        g2 = (T2 * tr * tr + T1 * trr) / r - two * T1 * tr / s64 + two * T / (s64 * r)
        G = g
        G1 = g1 / (two * r)
        G2 = (g2 - g1 / r) / (wp.float64(4.0) * s64)
    return type(s)(G), type(s)(G1), type(s)(G2)


@wp.func
def opencv_distortion(a: Any, b: Any, k1: Any, k2: Any, p1: Any, p2: Any, k3: Any):
    """(m_x, m_y, J_D) of the radial-tangential model at w = (a, b) (module docstring)."""
    two = type(a)(2.0)
    s = a * a + b * b
    R, R1, R2 = opencv_radial(s, k1, k2, k3)
    mx = a * R + two * p1 * a * b + p2 * (s + two * a * a)
    my = b * R + p1 * (s + two * b * b) + two * p2 * a * b
    off = two * a * b * R1 + two * p1 * a + two * p2 * b
    J = wp.matrix(R + two * a * a * R1 + two * p1 * b + type(a)(6.0) * p2 * a, off,
                  off, R + two * b * b * R1 + type(a)(6.0) * p1 * b + two * p2 * a, shape=(2, 2), dtype=type(a))
    return mx, my, J


@wp.func
def distortion(model: int, a: Any, b: Any, lens: wp.array(dtype=Any)):
    """(m_x, m_y, J_D) of the normalised point w = (a, b) (module docstring; pinhole: identity)."""
    zero = type(a)(0.0)
    one = type(a)(1.0)
    two = type(a)(2.0)
    if model == 1:
        return opencv_distortion(a, b, lens[0], lens[1], lens[2], lens[3], lens[4])
    if model == 2:
        G, G1, G2 = fisheye_radial(a * a + b * b, lens[0], lens[1], lens[2], lens[3])
        J = wp.matrix(G + two * G1 * a * a, two * G1 * a * b, two * G1 * a * b, G + two * G1 * b * b, shape=(2, 2),
                      dtype=type(a))
        return G * a, G * b, J
    return a, b, wp.matrix(one, zero, zero, one, shape=(2, 2), dtype=type(a))


@wp.func
def distortion_hvp(model: int, a: Any, b: Any, lens: wp.array(dtype=Any), Gm: Any):
    """sum_ik Gm_ik d(J_D)_ik / dw_l for l = 0, 1: a cotangent Gm (2x2) of J_D pulled back to w."""
    zero = type(a)(0.0)
    two = type(a)(2.0)
    s = a * a + b * b
    if model == 1:
        p1 = lens[2]
        p2 = lens[3]
        R, R1, R2 = opencv_radial(s, lens[0], lens[1], lens[4])
        six = type(a)(6.0)
        four = type(a)(4.0)
        # H_i[k][l] = d^2 m_i / dw_k dw_l
        xaa = six * a * R1 + four * a * a * a * R2 + six * p2
        xab = two * b * R1 + four * a * a * b * R2 + two * p1
        xbb = two * a * R1 + four * a * b * b * R2 + two * p2
        yaa = two * b * R1 + four * a * a * b * R2 + two * p1
        yab = two * a * R1 + four * a * b * b * R2 + two * p2
        ybb = six * b * R1 + four * b * b * b * R2 + six * p1
        ga = Gm[0, 0] * xaa + Gm[0, 1] * xab + Gm[1, 0] * yaa + Gm[1, 1] * yab
        gb = Gm[0, 0] * xab + Gm[0, 1] * xbb + Gm[1, 0] * yab + Gm[1, 1] * ybb
        return wp.vector(ga, gb, length=2, dtype=type(a))
    if model == 2:
        G, G1, G2 = fisheye_radial(s, lens[0], lens[1], lens[2], lens[3])
        w = wp.vector(a, b, length=2, dtype=type(a))
        tr = Gm[0, 0] + Gm[1, 1]
        quad = wp.dot(w, Gm * w)
        return two * G1 * (tr * w + Gm * w + wp.transpose(Gm) * w) + type(a)(4.0) * G2 * quad * w
    return wp.vector(zero, zero, length=2, dtype=type(a))


# =========================================================================== projection


@wp.func
def lens_valid(model: int, p: Any, lens: wp.array(dtype=Any)):
    """Whether the camera-frame point p lies in the model's valid domain (module docstring)."""
    if model == 3:
        return True
    if p[2] <= type(p[2])(0.0):
        return False
    a = p[0] / p[2]
    b = p[1] / p[2]
    return a * a + b * b < lens[N_PARAMS - 1]


@wp.func
def lens_project(model: int, p: Any, lens: wp.array(dtype=Any)):
    """(m_x, m_y, J_m = dm/dp (2x3), valid) of the camera-frame point p (module docstring)."""
    zero = type(p[0])(0.0)
    one = type(p[0])(1.0)
    valid = lens_valid(model, p, lens)
    if model == 3:
        return p[0], p[1], wp.matrix(one, zero, zero, zero, one, zero, shape=(2, 3), dtype=type(p[0])), valid
    z = p[2]
    if not valid:
        z = one  # any finite value: the caller discards an invalid point
    iz = one / z
    a = p[0] * iz
    b = p[1] * iz
    mx, my, JD = distortion(model, a, b, lens)
    Jw = wp.matrix(iz, zero, -a * iz, zero, iz, -b * iz, shape=(2, 3), dtype=type(p[0]))
    return mx, my, JD * Jw, valid


@wp.func
def lens_project_vjp(model: int, p: Any, lens: wp.array(dtype=Any), g_mx: Any, g_my: Any, g_J: Any):
    """dL/dp for the cotangents (g_mx, g_my) of m and g_J (2x3) of J_m = dm/dp (module docstring)."""
    zero = type(p[0])(0.0)
    one = type(p[0])(1.0)
    two = type(p[0])(2.0)
    if model == 3:
        return wp.vector(g_mx, g_my, zero, length=3, dtype=type(p[0]))
    z = p[2]
    iz = one / z
    a = p[0] * iz
    b = p[1] * iz
    mx, my, JD = distortion(model, a, b, lens)
    Jw = wp.matrix(iz, zero, -a * iz, zero, iz, -b * iz, shape=(2, 3), dtype=type(p[0]))
    # J_m = J_D(w(p)) J_w(p): the J_D factor's share through w, then J_w's own.
    g_w = wp.transpose(JD) * wp.vector(g_mx, g_my, length=2, dtype=type(p[0]))
    g_w = g_w + distortion_hvp(model, a, b, lens, g_J * wp.transpose(Jw))
    gJw = wp.transpose(JD) * g_J
    iz2 = iz * iz
    gx = g_w[0] * iz - gJw[0, 2] * iz2
    gy = g_w[1] * iz - gJw[1, 2] * iz2
    gz = (-(g_w[0] * a + g_w[1] * b) * iz - (gJw[0, 0] + gJw[1, 1]) * iz2
          + two * (gJw[0, 2] * a + gJw[1, 2] * b) * iz2)
    return wp.vector(gx, gy, gz, length=3, dtype=type(p[0]))


# =========================================================================== inverse


@wp.func
def _opencv_undistort(mx: wp.float64, my: wp.float64, lens: wp.array(dtype=Any)):
    """(a, b, converged): Newton on D(w) = m in float64 (module docstring)."""
    k1 = wp.float64(lens[0])
    k2 = wp.float64(lens[1])
    p1 = wp.float64(lens[2])
    p2 = wp.float64(lens[3])
    k3 = wp.float64(lens[4])
    a = mx
    b = my
    tol = wp.float64(1e-12) * (wp.float64(1.0) + wp.sqrt(mx * mx + my * my))
    ok = int(0)
    for it in range(NEWTON_ITERS + 1):
        dx, dy, JD = opencv_distortion(a, b, k1, k2, p1, p2, k3)
        rx = dx - mx
        ry = dy - my
        det = JD[0, 0] * JD[1, 1] - JD[0, 1] * JD[1, 0]
        if det == wp.float64(0.0) or wp.isnan(det) or wp.isinf(det):
            break
        if wp.max(wp.abs(rx), wp.abs(ry)) <= tol:
            ok = 1
        if it == NEWTON_ITERS:
            break
        a = a - (JD[1, 1] * rx - JD[0, 1] * ry) / det
        b = b - (-JD[1, 0] * rx + JD[0, 0] * ry) / det
        if ok != 0:
            break  # the criterion met: this was one last step (quadratic convergence: to rounding)
    return a, b, ok != 0


@wp.func
def _fisheye_theta(rd: wp.float64, lens: wp.array(dtype=Any), th_lim: wp.float64):
    """(theta, converged): Newton on theta_d(theta) = rd in float64 (module docstring)."""
    k1 = wp.float64(lens[0])
    k2 = wp.float64(lens[1])
    k3 = wp.float64(lens[2])
    k4 = wp.float64(lens[3])
    one = wp.float64(1.0)
    th = wp.min(rd, th_lim)
    ok = int(0)
    for it in range(NEWTON_ITERS):
        t2 = th * th
        T = th * (one + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        T1 = one + t2 * (wp.float64(3.0) * k1 + t2 * (wp.float64(5.0) * k2 + t2 * (wp.float64(7.0) * k3
                                                                                     + t2 * wp.float64(9.0) * k4)))
        if T1 <= wp.float64(0.0):
            break
        step = (T - rd) / T1
        th = th - step
        if wp.abs(step) <= wp.float64(1e-14) * (one + wp.abs(th)):
            ok = 1
            break
    return th, ok != 0


@wp.func
def lens_unproject(model: int, mx: Any, my: Any, lens: wp.array(dtype=Any)):
    """(origin q (3,), unit direction e (3,), valid) in the camera frame of the normalised image
    point m (module docstring); central models have q = 0."""
    zero = type(mx)(0.0)
    one = type(mx)(1.0)
    q = wp.vector(zero, zero, zero, length=3, dtype=type(mx))
    axis = wp.vector(zero, zero, one, length=3, dtype=type(mx))
    if model == 3:
        return wp.vector(mx, my, zero, length=3, dtype=type(mx)), axis, True
    a = wp.float64(mx)
    b = wp.float64(my)
    s_lim = wp.float64(lens[N_PARAMS - 1])
    ok = True
    if model == 1:
        a, b, ok = _opencv_undistort(a, b, lens)
        ok = ok and a * a + b * b < s_lim
    if model == 2:
        rd = wp.sqrt(a * a + b * b)
        th_lim = wp.atan(wp.sqrt(s_lim))
        th, ok = _fisheye_theta(rd, lens, th_lim)
        ok = ok and th >= wp.float64(0.0) and th < th_lim
        if ok:
            st = wp.sin(th)
            if rd > wp.float64(0.0):
                e = wp.vector(type(mx)(st * a / rd), type(mx)(st * b / rd), type(mx)(wp.cos(th)), length=3,
                              dtype=type(mx))
                return q, e, True
            return q, axis, True
        return q, axis, False
    if not ok:
        return q, axis, False
    n = wp.sqrt(a * a + b * b + wp.float64(1.0))
    e = wp.vector(type(mx)(a / n), type(mx)(b / n), type(mx)(wp.float64(1.0) / n), length=3, dtype=type(mx))
    return q, e, True


@wp.func
def lens_unproject_vjp(model: int, e: Any, lens: wp.array(dtype=Any), g_q: Any, g_e: Any):
    """(dL/dm_x, dL/dm_y) for the cotangents of the ray's origin q and unit direction e at a valid
    pixel (module docstring: de/dm is the 3x2 block of [J_m(e); e^T]^-1)."""
    if model == 3:
        return g_q[0], g_q[1]
    mx, my, Jm, valid = lens_project(model, e, lens)
    A = wp.matrix(Jm[0, 0], Jm[0, 1], Jm[0, 2], Jm[1, 0], Jm[1, 1], Jm[1, 2], e[0], e[1], e[2], shape=(3, 3),
                  dtype=type(e[0]))
    Ai = wp.inverse(A)
    gm = wp.transpose(Ai) * g_e
    return gm[0], gm[1]


# =========================================================================== entry point


@wp.kernel
def _project_points_kernel(points: wp.array2d(dtype=Any), intr: wp.array(dtype=Any), model: int,
                           lens: wp.array(dtype=Any), out: wp.array2d(dtype=Any), valid: wp.array(dtype=wp.uint8),
                           offset: int):
    i = wp.tid() + offset
    p = wp.vector(points[i, 0], points[i, 1], points[i, 2], length=3, dtype=points.dtype)
    mx, my, Jm, ok = lens_project(model, p, lens)
    out[i, 0] = intr[0] * mx + intr[2]
    out[i, 1] = intr[1] * my + intr[3]
    valid[i] = wp.uint8(0)
    if ok:
        valid[i] = wp.uint8(1)


def project_points(lens: Any, intrinsics: Any, points: Any, device: Any = None) -> tuple[Any, Any]:
    """(pixels (N, 2), valid (N,)) of camera-frame points (N, 3) through `lens` (None: the pinhole) and
    intrinsics (fx, fy, cx, cy), in the kind and dtype of `points` (kernels/_arrays.py); invalid
    points (module docstring) get valid = False and pixel values to be ignored."""
    checked = check_lens("lens", lens) or Lens("opencv")  # the pinhole: opencv with zero coefficients
    K = np.asarray(intrinsics, dtype=np.float64).reshape(-1)
    if K.shape != (4,) or not np.all(np.isfinite(K)) or K[0] <= 0 or K[1] <= 0:
        raise ValueError(f"intrinsics: expected finite (fx, fy, cx, cy) with fx, fy > 0, got {K.tolist()}")
    a = A.Inputs(device, points)
    pts = a.floats("points", points, (None, 3))
    n = pts.shape[0]
    out = a.empty((n, 2))
    valid = wp.empty(n, dtype=wp.uint8, device=a.device)
    arr = lambda x: wp.array(np.asarray(x, dtype=a.np_dtype), dtype=a.scalar, device=a.device)  # noqa: E731
    a.launch(_project_points_kernel, n, [pts, arr(K), checked.model_id, arr(checked.params()), out, valid])
    return a.out(out), a.out_mask(valid)


A.declare_float_overloads(_project_points_kernel)
