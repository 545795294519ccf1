"""The two conventions of kernels/splat (mode="3dgs" and "gsplat", kernels/splat/modes.py) against the
NumPy reference of each mode's equations (kernels/reference/splat.py), to 1e-12 in float64,
with splats centred just outside the image on every side and beyond the frustum clamp, and the
places where the modes differ: the clamp for cx != W/2, the radius floor, the tile rule, the
alpha clamp and the stop rule. Their gradients are FD-checked in research/checks/splat.py
(tests/kernels/test_splat.py runs the checks)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kernels import splat as ks
from kernels.reference import splat as ref
from research.checks import splat as cs

PARAMS = cs.PARAMS
EXACT = dict(rtol=1e-12, atol=1e-12)
W, H = 48, 40


def _camera(cx: float = 20.3, cy: float = 22.1, width: int = W, height: int = H, f: float = 50.0) -> ks.SplatCamera:
    view = np.eye(4)
    view[:3, :3] = cs._rotation(np.random.default_rng(1), 0.2)
    view[:3, 3] = [0.05, -0.03, 4.0]
    K = np.array([[f, 0.0, cx], [0.0, f * 1.04, cy], [0.0, 0.0, 1.0]])
    return ks.SplatCamera(view, K, width, height)


def _edge_scene(cam: ks.SplatCamera, seed: int = 0) -> dict:
    """Random splats inside the image, and splats centred just outside it (left, right, top, bottom,
    a corner) and beyond the frustum clamp on every side, large enough to reach into the image."""
    rng = np.random.default_rng(seed)
    fx, fy, cx, cy = cam.params()[:4]
    z = 4.0 + rng.uniform(-0.5, 0.5, 16)
    uv = np.column_stack([rng.uniform(4, W - 4, 16), rng.uniform(4, H - 4, 16)])
    outside = [(-2.5, 18.0), (W + 3.0, 21.0), (24.0, -3.0), (26.0, H + 2.5), (-4.0, -4.0), (W + 1.5, H + 1.0),
               (-22.0, 15.0), (W + 20.0, 12.0), (20.0, -21.0), (30.0, H + 21.0)]
    uv = np.vstack([uv[: 16 - len(outside)], outside])
    pc = np.column_stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z])
    log_scales = rng.uniform(-2.6, -1.6, (16, 3))
    log_scales[-len(outside):] = rng.uniform(-1.3, -0.6, (len(outside), 3))  # 3 sigma of 10-20 px
    log_scales[-4:] = rng.uniform(-0.4, -0.1, (4, 3))  # those 20 px out: 3 sigma of 25-35 px
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    sh = rng.normal(0.0, 0.15, (16, 16, 3))
    sh[:, 0] = (rng.uniform(0.2, 0.9, (16, 3)) - 0.5) / ks.SH_C0
    return {"means": (pc - t) @ R, "log_scales": log_scales, "quats": rng.normal(size=(16, 4)),
            "opacity_logits": rng.uniform(-1.0, 4.0, 16), "sh": sh}


def _clamped(params: dict, cam: ks.SplatCamera, mode: str) -> np.ndarray:
    p = params["means"] @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    lxn, lxp, lyn, lyp = ref.frustum_limits(cam, mode)
    xr, yr = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    return (xr < -lxn) | (xr > lxp) | (yr < -lyn) | (yr > lyp)


@pytest.mark.parametrize("antialiased", [False, True])
@pytest.mark.parametrize("mode", ["3dgs", "gsplat"])
@pytest.mark.parametrize("cx", [20.3, W / 2])
def test_projection_matches_the_modes_reference(mode, antialiased, cx):
    cam = _camera(cx=cx)
    params = _edge_scene(cam)
    want = ref.project(params, cam, antialiased=antialiased, mode=mode)
    p = ks.project(ks.gaussian_inputs(*(params[k] for k in PARAMS)), cam, antialiased=antialiased, mode=mode)
    np.testing.assert_array_equal(p.radii, want["radii"])
    visible = p.radii > 0
    assert visible[-10:].sum() >= 8  # the splats outside the image reach into it
    assert (_clamped(params, cam, mode) & visible).sum() >= 3  # ... some beyond the Jacobian's clamp
    for key in ("means2d", "conics", "depths", "colors", "opacities"):
        np.testing.assert_allclose(getattr(p, key), want[key], **EXACT, err_msg=key)


@pytest.mark.parametrize("mode", ["3dgs", "gsplat"])
def test_render_matches_the_modes_reference(mode):
    cam = _camera()
    params = _edge_scene(cam, seed=1)
    bg = np.array([0.2, 0.5, 0.7])
    want = ref.render(params, cam, bg, mode=mode)
    r = ks.render(ks.gaussian_inputs(*(params[k] for k in PARAMS)), cam, bg, mode=mode)
    for got, w, key in zip((r.rgb, r.alpha, r.depth), want, ("rgb", "alpha", "depth")):
        np.testing.assert_allclose(got, w, **EXACT, err_msg=key)
    # The splats outside the image colour its border pixels.
    assert np.ptp(r.alpha[:, 0]) > 0.05 and np.ptp(r.alpha[:, -1]) > 0.05
    assert np.ptp(r.alpha[0, :]) > 0.05 and np.ptp(r.alpha[-1, :]) > 0.05


def test_the_clamps_agree_only_for_a_centred_principal_point():
    centred, offset = _camera(cx=W / 2, cy=H / 2), _camera(cx=20.3, cy=22.1)
    np.testing.assert_allclose(ref.frustum_limits(centred, "3dgs"), ref.frustum_limits(centred, "gsplat"),
                               rtol=1e-15)
    assert ref.frustum_limits(centred, "3dgs")[0] == pytest.approx(1.3 * W / (2 * 50.0))
    lim3, limg = ref.frustum_limits(offset, "3dgs"), ref.frustum_limits(offset, "gsplat")
    assert lim3[0] == lim3[1] and limg[0] != limg[1] and abs(lim3[0] - limg[0]) > 0.05
    # The kernels: the off-frustum splats' conics differ between the modes only for the offset camera.
    for cam, differ in ((centred, False), (offset, True)):
        params = _edge_scene(cam)
        g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
        c3, cg = ks.project(g, cam, mode="3dgs"), ks.project(g, cam, mode="gsplat")
        both = (c3.radii > 0) & (cg.radii > 0)
        gap = (np.abs(c3.conics - cg.conics).max(axis=1) / np.abs(cg.conics).max(axis=1))[both].max()
        assert (gap > 0.05) if differ else (gap < 1e-12), gap


def test_the_radius_floor_can_change_an_image():
    """3DGS's floor 0.1 (against gsplat's 0.01) gives a near-isotropic splat with 3 sqrt(lambda) just
    below an integer a radius 1 px larger; the extra tile column then blends pixels at 3 sigma,
    where alpha = 0.99 exp(-4.4) > 1/255 (kernels/splat/modes.py)."""
    f, z = 50.0, 4.0
    cam = ks.SplatCamera(np.eye(4), np.array([[f, 0, 19.0], [0, f, 32.0], [0, 0, 1]]), 64, 64)
    lam = 99.8  # px^2 after the 0.3 dilation: 3 sqrt(lam + 0.1) < 30 < 3 sqrt(lam + sqrt(0.1))
    scale = math.sqrt(lam - ks.DILATION) * z / f
    params = {"means": np.array([[0.0, 0.0, z]]), "log_scales": np.full((1, 3), math.log(scale)),
              "quats": np.array([[1.0, 0.0, 0.0, 0.0]]), "opacity_logits": np.array([math.log(0.99 / 0.01)]),
              "sh": np.full((1, 1, 3), (0.9 - 0.5) / ks.SH_C0)}
    bg = np.zeros(3)
    assert ref.project(params, cam)["radii"][0] == 31
    assert ref.project(params, cam, radius_floor=0.01)["radii"][0] == 30
    rgb_floor_01, _, _ = ref.render(params, cam, bg)
    rgb_floor_001, _, _ = ref.render(params, cam, bg, radius_floor=0.01)
    changed = np.abs(rgb_floor_01 - rgb_floor_001).max(axis=2)
    assert changed.max() > 0.005  # 0.9 * alpha at pixel column 48, 29.5 px from the mean
    # Only in tile column 3 (pixels 48-63), which only the radius-31 square lists, and only where
    # alpha >= 1/255 (29.5-32.5 px from the mean).
    assert set(np.nonzero(changed)[1]) == set(range(48, 52))
    r = ks.render(ks.gaussian_inputs(*(params[k] for k in PARAMS)), cam, bg)
    np.testing.assert_allclose(r.rgb, rgb_floor_01, **EXACT)
    assert ks.project(ks.gaussian_inputs(*(params[k] for k in PARAMS)), cam).radii[0] == 31


def test_the_tile_rules_differ_at_the_image_border():
    """A small splat left of the image whose square ends within 1.5 px of the image: gsplat lists it,
    3DGS's getRect (pixel centres at integers) does not; the kernels agree with each reference."""
    cam = _camera(cx=W / 2, cy=H / 2)
    fx, fy, cx, cy = cam.params()[:4]
    R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    us = np.linspace(-6.0, -1.0, 41) + 0.013  # clear of the rules' exact boundaries
    pc = np.column_stack([(us - cx) / fx * 4.0, np.zeros_like(us), np.full_like(us, 4.0)])
    n = len(us)
    params = {"means": (pc - t) @ R, "log_scales": np.full((n, 3), math.log(0.03)),
              "quats": np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), "opacity_logits": np.zeros(n),
              "sh": np.zeros((n, 1, 3))}
    g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    radii = {}
    for mode in ks.MODES:
        radii[mode] = ks.project(g, cam, mode=mode).radii
        np.testing.assert_array_equal(radii[mode], ref.project(params, cam, mode=mode)["radii"])
    assert np.sum((radii["gsplat"] > 0) & (radii["3dgs"] == 0)) >= 3


def _exact_stop_alphas() -> tuple[float, float, float, float]:
    """Alphas a1..a4 (all below 0.99) with T (1 - a4) == 1e-4 exactly in float64 after blending
    a1..a3, in the rasteriser's own arithmetic (T <- T (1 - a)); found by a random search."""
    alphas = (0.9, 0.9, 0.4999791627375294, 0.9800008334557649)
    t = 1.0
    for a in alphas[:3]:
        t = t * (1.0 - a)
    assert t * (1.0 - alphas[3]) == 1e-4
    return alphas


def test_alpha_clamp_and_stop_rule_of_each_mode():
    """One pixel under its splats' centres (G = 1, so alpha = opacity): 3DGS blends the splat that
    brings T to exactly 1e-4 (it stops only below), gsplat stops before it (<=); an opacity of
    0.995 blends as 0.99 in 3DGS and as 0.995 in gsplat."""
    alphas = _exact_stop_alphas()
    n = len(alphas)
    splats = dict(means2d=np.full((n, 2), 0.5), conics=np.tile([1.0, 0.0, 1.0], (n, 1)),
                  colors=np.tile([[0.2, 0.4, 0.6]], (n, 1)) * np.arange(1, n + 1)[:, None],
                  opacities=np.array(alphas), depths=np.arange(1.0, n + 1), radii=np.full(n, 3, np.int32))
    bg = np.array([0.1, 0.1, 0.1])
    T3 = (1.0 - alphas[0]) * (1.0 - alphas[1]) * (1.0 - alphas[2])
    for mode, final_T in (("3dgs", 1e-4), ("gsplat", T3)):
        r, _ = ks.rasterize(ks.splats_2d(**splats), 1, 1, bg, mode=mode)
        assert r.final_T[0, 0] == pytest.approx(final_T, rel=1e-12), mode
        want = ref.rasterize(*(splats[k] for k in ("means2d", "conics", "colors", "opacities", "depths", "radii")),
                             1, 1, bg, mode=mode)
        for got, w in zip((r.rgb, r.alpha, r.depth), want):
            np.testing.assert_allclose(got, w, **EXACT)
    one = {k: v[:1] for k, v in splats.items()}
    one["opacities"] = np.array([0.995])
    for mode, alpha in (("3dgs", 0.99), ("gsplat", 0.995)):
        r, _ = ks.rasterize(ks.splats_2d(**one), 1, 1, bg, mode=mode)
        assert r.alpha[0, 0] == pytest.approx(alpha, rel=1e-14), mode
