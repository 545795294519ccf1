"""Reliability of the splatting kernels (kernels/splat): bad inputs and splats at the edge of the range.

Bad inputs must raise ONE-line ValueErrors naming the argument before any kernel runs. Huge
splats, which used to overflow the int32 radius and vanish with a zero gradient, must render
over the whole image with finite, non-zero gradients (kernels/splat/projection.py docstring).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from kernels import splat as ks
from tests.bad_input import assert_refused

PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh")
W, H = 32, 24


def _camera(**kw) -> ks.SplatCamera:
    view = np.eye(4)
    view[2, 3] = 4.0
    args = dict(viewmat=view, K=np.array([[40.0, 0, 16], [0, 40.0, 12], [0, 0, 1]]), width=W, height=H)
    args.update(kw)
    return ks.SplatCamera(**args)


def _params(n: int = 4, dtype=np.float64) -> dict:
    rng = np.random.default_rng(0)
    p = {"means": rng.uniform(-0.3, 0.3, (n, 3)), "log_scales": rng.uniform(-2.5, -1.5, (n, 3)),
         "quats": rng.normal(size=(n, 4)), "opacity_logits": rng.normal(size=n), "sh": rng.normal(0, 0.2, (n, 16, 3))}
    return {k: v.astype(dtype) for k, v in p.items()}


def _set(key, index, value):
    def edit(p):
        p[key] = p[key].copy()
        p[key][index] = value
        return p
    return edit


def _replace(key, value):
    def edit(p):
        p[key] = value
        return p
    return edit


BAD_GAUSSIANS = {
    "log_scale_81": (_set("log_scales", (1, 0), 81.0), r"^log_scales: \|log-scale\| up to 81; expected values in "
                                                       r"\[-80, 80\]"),
    "log_scale_minus_81": (_set("log_scales", (2, 2), -81.0), r"^log_scales: \|log-scale\| up to 81"),
    "log_scale_nan": (_set("log_scales", (0, 1), np.nan), r"^log_scales: expected finite values"),
    "log_scale_inf": (_set("log_scales", (0, 1), np.inf), r"^log_scales: expected finite values"),
    "quat_zero": (_set("quats", 3, 0.0), r"^quats: quaternion 3 has zero norm"),
    "quat_nan": (_set("quats", (0, 0), np.nan), r"^quats: expected finite values"),
    "mean_inf": (_set("means", (1, 2), -np.inf), r"^means: expected finite values"),
    "opacity_nan": (_set("opacity_logits", 0, np.nan), r"^opacity_logits: expected finite values"),
    "sh_nan": (_set("sh", (0, 3, 1), np.nan), r"^sh: expected finite values"),
    "sh_5_coefficients": (_replace("sh", np.zeros((4, 5, 3))), r"^sh: expected \(N, K, 3\) with K in"),
    "sh_2d": (_replace("sh", np.zeros((4, 16))), r"^sh: expected shape"),
    "means_2_columns": (_replace("means", np.zeros((4, 2))), r"^means: expected shape"),
    "log_scales_wrong_n": (_replace("log_scales", np.zeros((3, 3))), r"^log_scales: expected shape"),
    "means_int": (_replace("means", np.zeros((4, 3), np.int64)), r"^means: expected dtype float32 or float64"),
    "mixed_float32": (_replace("quats", np.ones((4, 4), np.float32)), r"^quats: expected dtype float64"),
}


@pytest.mark.parametrize("case", list(BAD_GAUSSIANS))
def test_bad_gaussians(case):
    edit, expected = BAD_GAUSSIANS[case]
    p = edit(_params())
    with pytest.raises(ValueError) as err:
        ks.gaussian_inputs(*(p[k] for k in PARAMS))
    assert "\n" not in str(err.value)
    assert re.search(expected, str(err.value)), str(err.value)


def _render_call(**kw):
    def call():
        g = ks.gaussian_inputs(*(_params()[k] for k in PARAMS))
        args = dict(camera=_camera(), background=None)
        args.update(kw)
        return ks.render(g, args.pop("camera"), args.pop("background"), **args)
    return call


def _backward_call(**kw):
    def call():
        g = ks.gaussian_inputs(*(_params()[k] for k in PARAMS))
        r = ks.render(g, _camera())
        args = dict(grad_rgb=np.ones((H, W, 3)))
        args.update(kw)
        return ks.render_backward(g, r, **args)
    return call


def _splats_2d(**kw):
    n = 3
    args = dict(means2d=np.zeros((n, 2)), conics=np.tile([1.0, 0.0, 1.0], (n, 1)), colors=np.zeros((n, 3)),
                opacities=np.full(n, 0.5), depths=np.ones(n), radii=np.full(n, 3, np.int32))
    args.update(kw)
    return lambda: ks.splats_2d(**args)


BAD_CALLS = {
    "sh_degree_4": (_render_call(sh_degree=4), r"^sh_degree"),
    "sh_degree_minus_1": (_render_call(sh_degree=-1), r"^sh_degree"),
    "background_4": (_render_call(background=np.zeros(4)), r"^background: expected shape"),
    "background_nan": (_render_call(background=np.array([0.0, np.nan, 0.0])), r"^background: expected finite"),
    "camera_string": (_render_call(camera="cam"), r"^camera: expected a SplatCamera"),
    "grad_rgb_2d": (_backward_call(grad_rgb=np.ones((H, W))), r"^grad_rgb: expected shape"),
    "grad_alpha_nan": (_backward_call(grad_alpha=np.full((H, W), np.nan)), r"^grad_alpha: expected finite values"),
    "conic_not_positive_definite": (_splats_2d(conics=np.tile([1.0, 2.0, 1.0], (3, 1))), r"^conics: expected "
                                                                                          r"positive definite"),
    "opacity_1_5": (_splats_2d(opacities=np.full(3, 1.5)), r"^opacities: expected values in \[0, 1\]"),
    "radius_negative": (_splats_2d(radii=np.full(3, -1, np.int32)), r"^radii"),
    "radius_float": (_splats_2d(radii=np.full(3, 1.0)), r"^radii"),
    "mode_unknown": (_render_call(mode="inria"), r"^mode: expected one of '3dgs', 'gsplat'"),
    "mode_not_a_string": (_render_call(mode=0), r"^mode: expected one of"),
    "project_mode_unknown": (lambda: ks.project(ks.gaussian_inputs(**_params()), _camera(), mode="GSPLAT"), r"^mode"),
    "rasterize_mode_unknown": (lambda: ks.rasterize(_splats_2d()(), W, H, mode="gs"), r"^mode"),
    "tiles_of_another_mode": (lambda: ks.rasterize(_splats_2d()(), W, H, tiles=ks.bin_tiles(_splats_2d()(), W, H,
                                                                                            "gsplat")),
                              r"^tiles: binned with mode='gsplat', expected mode='3dgs'"),
    "dilation_negative": (_render_call(dilation=-0.1), r"^dilation: expected a finite number >= 0"),
    "dilation_nan": (_render_call(dilation=float("nan")), r"^dilation: expected a finite number >= 0"),
    "dilation_string": (_render_call(dilation="0.3"), r"^dilation: expected a finite number >= 0"),
    "dilation_0_antialiased": (_render_call(dilation=0.0, antialiased=True), r"^dilation: expected > 0 with "
                                                                             r"antialiased=True"),
    "project_dilation_inf": (lambda: ks.project(ks.gaussian_inputs(**_params()), _camera(), dilation=float("inf")),
                             r"^dilation"),
    "camera_width_0": (lambda: _camera(width=0), r"^width"),
    "camera_near_negative": (lambda: _camera(near=-1.0), r"^near, far: expected 0 < near < far"),
    "camera_skew": (lambda: _camera(K=np.array([[40.0, 1.0, 16], [0, 40.0, 12], [0, 0, 1]])), r"^K: expected"),
    "camera_reflection": (lambda: _camera(viewmat=np.diag([1.0, 1.0, -1.0, 1.0])), r"^viewmat: expected a rigid"),
}


@pytest.mark.parametrize("case", list(BAD_CALLS))
def test_bad_calls(case):
    assert_refused(*BAD_CALLS[case])


# --------------------------------------------------------------------------- huge splats (recovery)


def _huge(log_scale: float, dtype, mean=(0.05, -0.02, 0.0)) -> dict:
    p = _params(4, np.float64)
    p["means"][0] = mean
    p["log_scales"][0] = [log_scale, log_scale - 0.5, log_scale - 0.2]
    p["opacity_logits"][0] = 0.0  # opacity 1/2
    return {k: v.astype(dtype) for k, v in p.items()}


HUGE = {
    # id: (log-scale, dtype, mean of splat 0, conic gradients representable)
    "log_scale_20_float64": (20.0, np.float64, (0.05, -0.02, 0.0), True),
    "log_scale_30_float64": (30.0, np.float64, (0.05, -0.02, 0.0), True),
    "log_scale_80_float64": (80.0, np.float64, (0.05, -0.02, 0.0), True),
    "log_scale_20_float32": (20.0, np.float32, (0.05, -0.02, 0.0), True),
    "log_scale_30_float32": (30.0, np.float32, (0.05, -0.02, 0.0), True),
    "log_scale_80_float32": (80.0, np.float32, (0.05, -0.02, 0.0), False),
    "log_scale_30_mean_far_left": (30.0, np.float64, (-500.0, 0.0, 0.0), True),  # mean2d 5000 px off the image
    "log_scale_30_mean_far_left_float32": (30.0, np.float32, (-500.0, 0.0, 0.0), True),
}


@pytest.mark.parametrize("case", list(HUGE))
def test_huge_splat_covers_the_image_and_keeps_its_gradient(case):
    log_scale, dtype, mean, conic_grads = HUGE[case]
    p = _huge(log_scale, dtype, mean)
    g = ks.gaussian_inputs(*(p[k] for k in PARAMS))
    r = ks.render(g, _camera())
    radius = int(r.projection.radii.numpy()[0])
    u = float(r.projection.means2d.numpy()[0, 0])
    assert 0 < radius <= 2 * max(abs(u), abs(u - W), H) + ks.TILE  # clamped to its reach, no int32 overflow
    assert np.all(r.alpha >= 0.5 - 1e-6)  # the opacity-1/2 splat covers every pixel
    grads = ks.render_backward(g, r, np.ones((H, W, 3), dtype))
    for k in PARAMS:
        assert np.all(np.isfinite(grads[k])), k
    assert grads["opacity_logits"][0] != 0 and np.all(grads["sh"][0, 0] != 0)
    assert np.all(grads["log_scales"][0] != 0) == conic_grads


def test_splat_beyond_the_radius_cap_is_culled_not_corrupted():
    """A mean2d 2^30+ px off the image with a radius larger still: culled (documented), nothing NaN."""
    p = _huge(60.0, np.float64, (-2e8, 0.0, 0.0))  # u = 40 * -2e8 / 4 = -2e9 px
    g = ks.gaussian_inputs(*(p[k] for k in PARAMS))
    r = ks.render(g, _camera())
    assert r.projection.radii.numpy()[0] == 0
    grads = ks.render_backward(g, r, np.ones((H, W, 3)))
    assert np.all(np.isfinite(r.rgb)) and all(np.all(np.isfinite(v)) for v in grads.values())
