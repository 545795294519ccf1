"""kernels.lens and kernels.reference.lens: the NumPy reference against OpenCV and COLMAP, the Warp
functions (through the ray generator and the splat projection) against the reference, the valid
domain, bad input, and the registered float64 gradient checks."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pycolmap
import pytest
import warp as wp

import kernels.splat as ks
from kernels.lens import Lens, fisheye_radial
from kernels.reference import lens as ref
from kernels.reference import splat as splat_ref
from kernels.volume.lens_rays import lens_rays
from kernels.volume.rays import camera_rays, camera_rays_backward
from research.checks.lens import LENSES, lens_scene
from research.gradcheck import assert_gradcheck, run_checks

K = np.array([[300.0, 0.0, 160.0], [0.0, 310.0, 120.0], [0.0, 0.0, 1.0]])
OPENCV = (-0.2, 0.05, 0.001, -0.002, 0.01)
FISHEYE = (0.05, -0.01, 0.002, -0.0005)


def _points(seed: int, n: int = 60, spread: float = 0.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-spread, spread, (n, 2)), np.ones(n)] * rng.uniform(1.0, 3.0, (n, 1))


def _unit(p: np.ndarray) -> np.ndarray:
    return p / np.linalg.norm(p, axis=1, keepdims=True)


# --------------------------------------------------------------------------- reference vs OpenCV / COLMAP


def test_reference_matches_opencv():
    p = _points(0)
    uv, ok = ref.pixels(Lens("opencv", OPENCV), K, p)
    cv_uv, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), K, np.array(OPENCV))
    assert ok.all()
    np.testing.assert_allclose(uv, cv_uv[:, 0], rtol=0, atol=1e-9)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    und = cv2.undistortPoints(uv[:, None], K, np.array(OPENCV), criteria=crit)[:, 0]
    _, e, valid = ref.unproject(Lens("opencv", OPENCV), ref.normalised(K, uv))
    assert valid.all()
    np.testing.assert_allclose(e[:, :2] / e[:, 2:], und, atol=1e-12)
    np.testing.assert_allclose(e, _unit(p), atol=1e-13)


def test_reference_matches_opencv_fisheye():
    p = _points(1, spread=1.2)
    lens = Lens("fisheye", FISHEYE)
    uv, ok = ref.pixels(lens, K, p)
    cv_uv, _ = cv2.fisheye.projectPoints(p[:, None], np.zeros(3), np.zeros(3), K, np.array(FISHEYE))
    assert ok.all()
    np.testing.assert_allclose(uv, cv_uv[:, 0], rtol=0, atol=1e-9)
    und = cv2.fisheye.undistortPoints(uv[:, None], K, np.array(FISHEYE), criteria=(3, 100, 1e-15))[:, 0]
    _, e, valid = ref.unproject(lens, ref.normalised(K, uv))
    assert valid.all()
    np.testing.assert_allclose(e[:, :2] / e[:, 2:], und, atol=1e-11)
    np.testing.assert_allclose(e, _unit(p), atol=1e-13)


@pytest.mark.parametrize("model,params,lens", [
    ("SIMPLE_RADIAL", [300.0, 160.0, 120.0, -0.15], Lens("opencv", (-0.15,))),
    ("RADIAL", [300.0, 160.0, 120.0, -0.15, 0.04], Lens("opencv", (-0.15, 0.04))),
    ("OPENCV", [300.0, 310.0, 160.0, 120.0, -0.2, 0.05, 0.001, -0.002], Lens("opencv", OPENCV[:4])),
    ("OPENCV_FISHEYE", [300.0, 310.0, 160.0, 120.0, *FISHEYE], Lens("fisheye", FISHEYE)),
    ("SIMPLE_RADIAL_FISHEYE", [300.0, 160.0, 120.0, FISHEYE[0]], Lens("fisheye", FISHEYE[:1])),
    ("RADIAL_FISHEYE", [300.0, 160.0, 120.0, *FISHEYE[:2]], Lens("fisheye", FISHEYE[:2])),
    ("SIMPLE_FISHEYE", [300.0, 160.0, 120.0], Lens("fisheye")),
    ("FISHEYE", [300.0, 310.0, 160.0, 120.0], Lens("fisheye")),
])
def test_reference_matches_colmap(model, params, lens):
    cam = pycolmap.Camera(model=model, width=320, height=240, params=params)
    two_focal = model in ("OPENCV", "OPENCV_FISHEYE", "FISHEYE")
    f = params[:2] if two_focal else [params[0], params[0]]
    c = params[2:4] if two_focal else params[1:3]
    Kc = np.array([[f[0], 0.0, c[0]], [0.0, f[1], c[1]], [0.0, 0.0, 1.0]])
    p = _points(2, spread=0.6)
    uv, ok = ref.pixels(lens, Kc, p)
    assert ok.all()
    np.testing.assert_allclose(uv, cam.img_from_cam(p), rtol=0, atol=1e-9)
    _, e, valid = ref.unproject(lens, ref.normalised(Kc, uv))
    assert valid.all()
    np.testing.assert_allclose(e[:, :2] / e[:, 2:], cam.cam_from_img(uv), atol=1e-9)  # COLMAP's own solver


def test_jacobian_is_the_derivative():
    p = _points(3)
    for lens in (Lens("opencv", OPENCV), Lens("fisheye", FISHEYE), Lens("orthographic")):
        J = ref.jacobian(lens, p)
        h = 1e-6
        fd = np.stack([(ref.project(lens, p + h * e)[0] - ref.project(lens, p - h * e)[0]) / (2 * h)
                       for e in np.eye(3)], axis=2)
        np.testing.assert_allclose(J, fd, atol=1e-8)


def test_valid_domain():
    # OpenCV k1 = -0.3: r (1 + k1 r^2) turns at s = 1 / (3 * 0.3).
    lens = Lens("opencv", (-0.3,))
    assert lens.s_limit() == pytest.approx(1.0 / 0.9, rel=1e-12)
    p = np.array([[1.0, 0.0, 1.0], [1.1, 0.0, 1.0], [0.0, 0.0, -1.0]])
    _, ok = ref.project(lens, p)
    assert ok.tolist() == [True, False, False]
    # A point past the largest distorted radius r_max (1 - 0.3 s) at s_lim has no inverse.
    s = lens.s_limit()
    r_max = math.sqrt(s) * (1 - 0.3 * s)
    _, _, valid = ref.unproject(lens, np.array([[0.9 * r_max, 0.0], [1.1 * r_max, 0.0]]))
    assert valid.tolist() == [True, False]
    # Fisheye: theta is limited to pi/2 (no turning point) or to the first turning point of theta_d.
    assert Lens("fisheye", FISHEYE).s_limit() == pytest.approx(1e30)
    fold = Lens("fisheye", (-0.3,))  # d theta_d / d theta = 1 - 0.9 theta^2 = 0 at theta = 1.054
    assert fold.s_limit() == pytest.approx(math.tan(math.sqrt(1 / 0.9)) ** 2, rel=1e-9)
    _, _, valid = ref.unproject(Lens("fisheye"), np.array([[1.5, 0.0], [1.6, 0.0]]))  # theta_d = theta
    assert valid.tolist() == [True, False]  # pi/2 = 1.5708


def test_lens_checks_bad_input():
    with pytest.raises(ValueError, match="lens: expected a model"):
        Lens("kannala")
    with pytest.raises(ValueError, match="at most 4 coefficients"):
        Lens("fisheye", (0.1, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="finite"):
        Lens("opencv", (math.nan,))
    with pytest.raises(ValueError, match="lens: expected a kernels.lens.Lens"):
        ks.SplatCamera(np.eye(4), K, 32, 32, lens="opencv")
    with pytest.raises(ValueError, match="lens: expected a kernels.lens.Lens"):
        camera_rays(np.eye(4), [300.0, 300.0, 16.0, 16.0], np.zeros((2, 2)), lens=(0.1,))
    assert ks.SplatCamera(np.eye(4), K, 32, 32, lens=Lens("pinhole")).lens is None


# --------------------------------------------------------------------------- Warp functions


@wp.kernel
def _radial_kernel(s: wp.array(dtype=wp.float64), lens: wp.array(dtype=wp.float64), out: wp.array2d(dtype=wp.float64)):
    i = wp.tid()
    G, G1, G2 = fisheye_radial(s[i], lens[0], lens[1], lens[2], lens[3])
    out[i, 0] = G
    out[i, 1] = G1
    out[i, 2] = G2


def test_fisheye_radial_series_and_closed_form():
    # G(s) = theta_d / r; its derivatives by the complex step (G') and central differences of it (G'').
    k = np.array([0.08, -0.02, 0.005, -0.001])
    s = np.array([1e-8, 3e-5, 0.99e-4, 1.01e-4, 3e-3, 0.2, 1.5])
    out = wp.zeros((len(s), 3), dtype=wp.float64)
    wp.launch(_radial_kernel, len(s), [wp.array(s, dtype=wp.float64), wp.array(k, dtype=wp.float64), out])
    out = out.numpy()

    def G(x):
        r = np.sqrt(x)
        th = np.arctan(r)
        return th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8) / r

    def G1(x):
        return G(x + 1e-30j).imag / 1e-30

    np.testing.assert_allclose(out[:, 0], G(s.astype(complex)).real, rtol=1e-15)
    # Not at s = 1e-8: there the references themselves cancel (theta_d / r near the axis, the reason
    # the kernel switches to the series); the points either side of the switch at 1e-4 test the series.
    np.testing.assert_allclose(out[1:, 1], G1(s[1:].astype(complex)), rtol=1e-11)
    big = s >= 0.99e-4  # G1's own rounding (eps / s) over the step 2 h stays below 1e-6 here
    h = np.minimum(0.05 * s[big], 1e-4)
    np.testing.assert_allclose(out[big, 2], (G1(s[big] + h + 0j) - G1(s[big] - h + 0j)) / (2 * h), rtol=2e-5)


def test_fisheye_series_coefficients_are_exact():
    # theta_d / r = sum_j k_j theta^(2j+1) / r (k_0 = 1), theta / r = sum_n (-1)^n s^n / (2n + 1): in exact fractions.
    from fractions import Fraction

    from kernels.lens import SERIES

    n = 5
    t = [Fraction((-1) ** i, 2 * i + 1) for i in range(n)]

    def mul(a, b):
        out = [Fraction(0)] * n
        for i, x in enumerate(a):
            for j, y in enumerate(b[:n - i]):
                out[i + j] += x * y
        return out

    terms = []  # terms[j][m]: the coefficient of k_j in c_m
    for j in range(5):
        p = [Fraction(1)] + [Fraction(0)] * (n - 1)
        for _ in range(2 * j + 1):
            p = mul(p, t)
        terms.append([Fraction(0)] * j + p[:n - j])
    for m in range(1, 5):
        assert terms[m][m] == 1
        assert SERIES[m - 1] == pytest.approx([float(terms[j][m]) for j in range(m)], rel=1e-15)


@pytest.mark.parametrize("model", ["opencv", "fisheye", "orthographic"])
@pytest.mark.parametrize("np_t,tol", [(np.float32, 3e-6), (np.float64, 1e-13)])
@pytest.mark.usefixtures("warp_device")
def test_lens_rays_match_reference(model, np_t, tol):
    lens = {"opencv": Lens("opencv", OPENCV), "fisheye": Lens("fisheye", FISHEYE),
            "orthographic": Lens("orthographic")}[model]
    rng = np.random.default_rng(4)
    w2c = np.linalg.inv(np.array([[1, 0, 0, 0.2], [0, 0, -1, -3.0], [0, 1, 0, 0.5], [0, 0, 0, 1.0]]))
    pixels = rng.uniform(0.0, [320.0, 240.0], (50, 2))
    o, d, z, valid = lens_rays(w2c, [300.0, 310.0, 160.0, 120.0], lens, pixels.astype(np_t))
    assert o.dtype == np_t and valid.dtype == bool and valid.all()
    q, e, vr = ref.unproject(lens, ref.normalised(K, pixels))
    R, t = w2c[:3, :3], w2c[:3, 3]
    np.testing.assert_allclose(o, (q - t) @ R, atol=tol * 10)
    np.testing.assert_allclose(d, e @ R, atol=tol)
    np.testing.assert_allclose(z, e[:, 2], atol=tol)
    o2, d2, z2 = camera_rays(w2c, [300.0, 310.0, 160.0, 120.0], pixels.astype(np_t), lens=lens)
    assert np.array_equal(o2, o) and np.array_equal(d2, d) and np.array_equal(z2, z)


def test_lens_rays_flag_pixels_outside_the_domain():
    # An equidistant fisheye with f = 100 px: theta = r_pixels / 100 passes pi/2 at 157 px from the centre.
    o, d, z, valid = lens_rays(np.eye(4), [100.0, 100.0, 0.0, 0.0], Lens("fisheye"), np.array([[150.0, 0.0],
                                                                                                [160.0, 0.0]]))
    assert valid.tolist() == [True, False]
    np.testing.assert_allclose(d[1], [0.0, 0.0, 1.0])
    g = camera_rays_backward(np.eye(4), [100.0, 100.0, 0.0, 0.0], np.array([[160.0, 0.0]]), np.ones((1, 3)),
                             np.ones((1, 3)), np.ones(1), lens=Lens("fisheye"))
    assert not np.any(g.xi) and not np.any(g.intrinsics)


@pytest.mark.parametrize("model", ["opencv", "fisheye", "orthographic"])
@pytest.mark.parametrize("np_t,tol", [(np.float32, 2e-5), (np.float64, 1e-12)])
@pytest.mark.usefixtures("warp_device")
def test_lens_projection_matches_reference(model, np_t, tol):
    params, camera = lens_scene(model, 5, n=30)
    g = ks.gaussian_inputs(*(params[k].astype(np_t) for k in ("means", "log_scales", "quats", "opacity_logits", "sh")))
    for mode, aa in (("3dgs", False), ("gsplat", True)):
        p = ks.project(g, camera, mode=mode, antialiased=aa)
        r = splat_ref.project(params, camera, mode=mode, antialiased=aa)
        assert p.means2d.dtype == np_t
        np.testing.assert_array_equal(p.radii, r["radii"])
        for k in ("means2d", "conics", "depths", "colors", "opacities"):
            scale = max(1.0, np.abs(r[k]).max())
            np.testing.assert_allclose(getattr(p, k), r[k], rtol=0, atol=tol * scale, err_msg=k)


def test_lens_projection_culls_outside_the_domain():
    lens = Lens("opencv", (-0.3,))  # turns at x/z = 1.054
    cam = ks.SplatCamera(np.eye(4), np.array([[40.0, 0, 32], [0, 40.0, 32], [0, 0, 1]]), 64, 64, lens=lens)
    means = np.array([[0.5, 0.0, 1.0], [1.2, 0.0, 1.0], [0.0, 0.0, -1.0]])
    n = len(means)
    g = ks.gaussian_inputs(means, np.full((n, 3), -3.0), np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros(n),
                           np.zeros((n, 1, 3)))
    assert ks.project(g, cam).radii.tolist()[1:] == [0, 0] and ks.project(g, cam).radii[0] > 0


def test_zero_distortion_matches_the_pinhole():
    # opencv with zero coefficients is the pinhole (no frustum clamp: splats inside it, where it is inactive).
    params, camera = lens_scene("opencv", 6, n=20)
    pin = ks.SplatCamera(camera.viewmat, camera.K, camera.width, camera.height)
    zero = ks.SplatCamera(camera.viewmat, camera.K, camera.width, camera.height, lens=Lens("opencv"))
    g = ks.gaussian_inputs(*(params[k] for k in ("means", "log_scales", "quats", "opacity_logits", "sh")))
    a, b = ks.project(g, pin, mode="gsplat"), ks.project(g, zero, mode="gsplat")
    inside = np.abs(np.asarray(a.means2d) - [24.0, 20.0]).max(axis=1) < 20.0
    assert inside.sum() >= 5
    for k in ("means2d", "conics", "depths", "colors", "opacities"):
        np.testing.assert_allclose(np.asarray(getattr(b, k))[inside], np.asarray(getattr(a, k))[inside], rtol=1e-13,
                                   atol=1e-15)


def test_lens_projection_wp_in_wp_out():
    params, camera = lens_scene("fisheye", 7, n=8)
    g = ks.gaussian_inputs(*(wp.array(params[k], dtype=wp.float64)
                             for k in ("means", "log_scales", "quats", "opacity_logits", "sh")))
    assert isinstance(ks.project(g, camera).means2d, wp.array)


# --------------------------------------------------------------------------- gradients


@pytest.mark.usefixtures("warp_device")
def test_lens_gradchecks():
    assert_gradcheck(run_checks(["lens"]))


def test_lenses_of_the_checks_distort():
    # The checks' coefficients bend the image corner by several percent (so second derivatives matter).
    p = np.array([[0.6, 0.5, 1.0]])
    for name in ("opencv", "fisheye"):
        m, _ = ref.project(LENSES[name], p)
        assert np.abs(m[0] / p[0, :2] - 1).max() > 0.03
