"""The rasteriser backward's AbsGS statistic (`absgrad`, kernels/splat/raster.py) against the NumPy
reference of each pixel's mean2d term (kernels/reference/splat.py: mean2d_pixel_terms), and the other
outputs' bits with and without it."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import splat as ks
from kernels.reference import splat as ref
from kernels.splat.raster import _rasterize_wp, background_array, rasterize_backward_wp
from research.checks import splat as cs
from tests.bad_input import assert_refused

PARAMS = cs.PARAMS
KEYS = ("means2d", "conics", "colors", "opacities", "depths")
TOL = {np.float32: dict(rtol=2e-4, atol=2e-6), np.float64: dict(rtol=1e-10, atol=1e-12)}


def _case(seed: int, mode: str):
    scene = cs.smooth_scene(seed, require_events=True, mode=mode)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    p = ks.project(g, scene.camera, mode=mode)
    W, H = scene.camera.width, scene.camera.height
    rng = np.random.default_rng(seed + 100)
    cot = (rng.normal(size=(H, W, 3)), rng.normal(size=(H, W)), rng.normal(size=(H, W)))
    return scene, p, W, H, cot


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("mode", ks.MODES)
def test_absgrad_matches_the_reference_pixel_terms(dtype, mode):
    scene, p, W, H, cot = _case(3, mode)
    inputs = [getattr(p, k) for k in KEYS]
    total, absolute = ref.mean2d_pixel_terms(*inputs, p.radii, W, H, scene.background, *cot, mode=mode)
    s = ks.splats_2d(*(x.astype(dtype) for x in inputs), p.radii)
    r, tiles = ks.rasterize(s, W, H, scene.background.astype(dtype), mode=mode)
    grads = ks.rasterize_backward(s, W, H, scene.background.astype(dtype), tiles, r,
                                  *(c.astype(dtype) for c in cot), mode=mode, absgrad=True)
    assert grads["means2d_abs"].dtype == dtype and grads["means2d_abs"].shape == (len(p.radii), 2)
    np.testing.assert_allclose(grads["means2d"], total, **TOL[dtype])  # the reference's terms sum to the gradient
    np.testing.assert_allclose(grads["means2d_abs"], absolute, **TOL[dtype])
    # Terms of both signs: the statistic is strictly above the summed gradient's size for some splats.
    assert np.all(np.abs(total) <= absolute + 1e-12)
    assert np.any(np.abs(total) < 0.9 * absolute)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_absgrad_leaves_every_other_output_bit_identical(dtype):
    rng = np.random.default_rng(5)
    scene = cs.random_scene(rng, n=80, width=70, height=52)
    g = ks.gaussian_inputs(*(v.astype(dtype) for v in (scene.params[k] for k in PARAMS)))
    r = ks.render(g, scene.camera, scene.background.astype(dtype))
    cot = [rng.normal(size=s).astype(dtype) for s in ((52, 70, 3), (52, 70), (52, 70))]
    off = ks.render_backward(g, r, *cot, want_camera=True)
    on = ks.render_backward(g, r, *cot, want_camera=True, absgrad=True)
    assert set(on) == set(off) | {"means2d_abs"} and "means2d_abs" not in off
    for k in off:
        np.testing.assert_array_equal(on[k], off[k], err_msg=k)
    assert np.all(np.abs(on["means2d"]) <= on["means2d_abs"] * (1 + 1e-5) + 1e-12)


def test_absgrad_is_the_same_after_either_forward_layout(monkeypatch):
    """The backward reads the forward's per-pixel state: after the CPU's per-tile forward (its 16-lane row
    blend included) and after CUDA's per-pixel one, the same bits; and for any thread count."""
    rng = np.random.default_rng(9)
    scene = cs.random_scene(rng, n=60, width=96, height=80)
    params = {k: v.astype(np.float32) for k, v in scene.params.items()}
    g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    proj = ks.project(g, scene.camera)
    s = ks.splats_2d(*(getattr(proj, k) for k in KEYS), proj.radii)
    a = s.inputs()
    bg = background_array(a, scene.background.astype(np.float32))
    cot = rng.normal(size=(80, 96, 3)).astype(np.float32)
    results = []
    for per_tile, threads in ((True, "1"), (False, "1"), (True, "3")):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        raster, tiles = _rasterize_wp(s, 96, 80, bg, None, ks.DEFAULT_MODE, per_tile=per_tile)
        out = rasterize_backward_wp(a, s, 96, 80, bg, tiles, raster, cot, None, None, absgrad=True)
        results.append({k: v.numpy() for k, v in out.items()})
    assert results[0]["means2d_abs"].max() > 0
    for other in results[1:]:
        for k in results[0]:
            np.testing.assert_array_equal(other[k], results[0][k], err_msg=k)


def test_absgrad_must_be_a_bool():
    scene, p, W, H, cot = _case(3, ks.DEFAULT_MODE)
    s = ks.splats_2d(*(getattr(p, k) for k in KEYS), p.radii)
    r, tiles = ks.rasterize(s, W, H, scene.background)
    assert_refused(lambda: ks.rasterize_backward(s, W, H, scene.background, tiles, r, cot[0], absgrad=1),
                   r"^absgrad: expected True or False, got 1$")
