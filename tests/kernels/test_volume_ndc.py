"""kernels.volume.ndc_rays: NeRF's forward-facing NDC map against the NumPy reference (float32 and
float64, both direction forms), its backward against float64 finite differences (research.gradcheck),
and its argument checks."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.reference import volume as ref
from kernels.volume import ndc_rays, ndc_rays_backward
from research.checks.volume import check_ndc_rays, ndc_setup
from research.gradcheck import assert_gradcheck, check_vjp


@pytest.mark.parametrize("normalize", [False, True])
@pytest.mark.parametrize("np_t,tol", [(np.float32, 2e-6), (np.float64, 1e-14)])
@pytest.mark.usefixtures("warp_device")
def test_ndc_rays_match_reference(np_t, tol, normalize):
    o, d, near, focal, size = ndc_setup(0)
    on, dn = ndc_rays(o.astype(np_t), d.astype(np_t), near, focal, size, normalize=normalize)
    assert on.dtype == np_t and isinstance(on, np.ndarray)
    ro, rd = ref.ndc_rays(o, d, near, focal, size, normalize=normalize)
    np.testing.assert_allclose(on, ro, atol=tol, rtol=0)
    np.testing.assert_allclose(dn, rd, atol=tol, rtol=0)


def test_ndc_geometry_near_plane_to_infinity_and_the_reference_camera_box():
    """t = 0 is the near plane (z' = -1), t = 1 infinite depth (z' = 1); a reference camera at the
    origin sees x', y' in [-1, 1] exactly at its image border, at every depth."""
    W, H, f, near = 40.0, 30.0, 35.0, 1.0
    u = np.array([0.0, W, 0.0, W, W / 2])
    v = np.array([0.0, 0.0, H, H, H / 2])
    dirs = np.stack([(u - W / 2) / f, -(v - H / 2) / f, -np.ones_like(u)], 1)  # OpenGL camera at the origin
    o = np.zeros_like(dirs)
    on, dn = ndc_rays(o, dirs, near, f, (W, H))
    np.testing.assert_allclose(on[:, 2], -1.0, atol=1e-15)
    np.testing.assert_allclose(dn[:, 2], 2.0, atol=1e-15)
    end = on + dn
    np.testing.assert_allclose(np.abs(end[:4, :2]), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.abs(on[:4, :2]), 1.0, atol=1e-14)
    np.testing.assert_allclose(on[4], [0, 0, -1], atol=1e-15)
    # origins anywhere on the ray give the same NDC ray (the shift to the near plane)
    on2, dn2 = ndc_rays(o + 0.7 * dirs, dirs, near, f, (W, H))
    np.testing.assert_allclose(on2, on, atol=1e-14)
    np.testing.assert_allclose(dn2, dn, atol=1e-14)


def test_ndc_wp_in_wp_out():
    o, d, near, focal, size = ndc_setup(1)
    on, dn = ndc_rays(wp.array(o, dtype=wp.float64), wp.array(d, dtype=wp.float64), near, focal, size)
    assert isinstance(on, wp.array) and isinstance(dn, wp.array)
    ro, rd = ref.ndc_rays(o, d, near, focal, size)
    np.testing.assert_allclose(on.numpy(), ro, atol=1e-14)
    go, gd = ndc_rays_backward(wp.array(o, dtype=wp.float64), wp.array(d, dtype=wp.float64), near, focal, size,
                               grad_dirs=wp.array(np.ones_like(d), dtype=wp.float64))
    assert isinstance(go, wp.array) and isinstance(gd, wp.array)


@pytest.mark.usefixtures("warp_device")
def test_ndc_rays_gradients():
    assert_gradcheck(check_ndc_rays(seeds=(0, 1, 2)))


def test_a_wrong_ndc_gradient_is_caught():
    o, d, near, focal, size = ndc_setup(0)

    def f(origins, dirs):
        on, dn = ndc_rays(origins, dirs, near, focal, size)
        return {"origins": on, "dirs": dn}

    def wrong(inp, cot):  # the focal of the other axis
        go, gd = ndc_rays_backward(inp["origins"], inp["dirs"], near, focal[::-1], size, cot["origins"], cot["dirs"])
        return {"origins": go, "dirs": gd}

    assert not all(r.passed for r in check_vjp(f, wrong, {"origins": o, "dirs": d}))


@pytest.mark.parametrize("bad,match", [
    (dict(near=0.0), "near"), (dict(focal=(-1.0, 2.0)), "focal"), (dict(size=(504.0,)), "size"),
    (dict(flip=True), r"dirs: NDC needs every ray to point into the scene"),
    (dict(shape=True), "dirs")])
def test_ndc_bad_input(bad, match):
    o, d, near, focal, size = ndc_setup(0)
    if bad.get("flip"):
        d = d.copy()
        d[3, 2] = 0.1
    if bad.get("shape"):
        d = d[:5]
    kw = dict(near=bad.get("near", near), focal=bad.get("focal", focal), size=bad.get("size", size))
    with pytest.raises(ValueError, match=match):
        ndc_rays(o, d, **kw)
    with pytest.raises(ValueError, match=match):
        ndc_rays_backward(o, d, **kw)
