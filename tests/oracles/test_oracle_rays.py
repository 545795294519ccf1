"""kernels/volume/rays.py against its Dr.Jit oracle (research/oracles/rays.py): the pinhole rays and
their VJPs with respect to the left se(3) perturbation xi of world-to-camera and (fx, fy, cx, cy);
the render through those rays (soft spheres, the dense grid with RGB and degree-2 SH colour), with
and without early termination, its colour, depth and opacity and the VJPs with respect to the rays
(render_backward_rays) and to the camera (render_backward_camera). float64 to 1e-10 relative;
float32 against the float64 oracle within a bound derived in each test."""

from __future__ import annotations

import numpy as np
import pytest

from kernels.volume import render_samples
from kernels.volume.rays import camera_rays, camera_rays_backward, render_backward_camera, render_backward_rays
from kernels.volume.sampling import dense_samples, sample_rays
from research.checks.volume import BOX, camera_field, camera_setup
from research.oracles.rays import camera_rays_oracle, render_camera_oracle, render_rays_oracle
from tests.oracles.conftest import U32, close64, within

BG = (0.3, 0.2, 0.1)
N = lambda x: x.numpy() if hasattr(x, "numpy") else np.asarray(x)  # noqa: E731


def _field_dict(kind: str, field) -> dict:
    P = field.params_numpy()
    if kind == "spheres":
        return dict(kind="spheres", **P)
    return dict(kind="grid", bbox=field.bbox, resolution=field.resolution, sh_degree=None if kind == "grid_rgb" else 2,
                density=P["density"], color=P["color"], density_bias=0.0, density_scale=1.0, activation="softplus")


def _pixels(rng, n):
    """Random continuous pixel coordinates in a 24x20 image, 2 px from its edges (every ray meets BOX)."""
    return rng.uniform([2.0, 2.0], [22.0, 18.0], (n, 2))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_camera_rays_float64(seed):
    w2c, K, _ = camera_setup(seed)
    rng = np.random.default_rng(seed)
    px = _pixels(rng, 64)
    go, gd, gz = rng.normal(size=(64, 3)), rng.normal(size=(64, 3)), rng.normal(size=64)
    o, d, z = camera_rays(w2c, K, px)
    g = camera_rays_backward(w2c, K, px, go, gd, gz)
    (oo, od, oz), og = camera_rays_oracle(w2c, K, px, go, gd, gz)
    close64("origins", o, oo)
    close64("dirs", d, od)
    close64("z_scale", z, oz)
    close64("d xi", g.xi, og["xi"])
    close64("d intrinsics", g.intrinsics, og["intrinsics"])


def test_camera_rays_float32_within_the_rounding_bound():
    """drlab rounds R, t, the intrinsics and the pixels to float32 (relative u each) and forms
    c, n, e, o, d in at most 12 rounded operations: |error| <= 16 u max(|t|, 1) for o (a 3-term
    sum of |R||t|), 16 u for the unit d and z_scale. Per pixel, the 10 gradient terms take at most
    30 more rounded operations on (g_o, g_d, g_z), each bounded by m_p = |g_o|_1 + |g_d|_1 + |g_z|
    (|e| = 1, R orthonormal) for xi, and by m_p (1 + max|c|) / min(fx, fy) for the intrinsics
    (dL/dc is divided by fx or fy and multiplied by at most 1 + |c|): with the float32 inputs,
    46 u per pixel times those, summed (in float64 on the host) over the pixels."""
    w2c, K, _ = camera_setup(5)
    rng = np.random.default_rng(5)
    px = _pixels(rng, 200).astype(np.float32)
    go, gd, gz = (rng.normal(size=s).astype(np.float32) for s in ((200, 3), (200, 3), 200))
    o, d, z = camera_rays(w2c, K, px)
    g = camera_rays_backward(w2c, K, px, go, gd, gz)
    a64 = [a.astype(np.float64) for a in (px, go, gd, gz)]
    (oo, od, oz), og = camera_rays_oracle(w2c, K, *a64)
    within("origins", o, oo, 16 * U32 * max(1.0, np.abs(w2c[:3, 3]).max()))
    within("dirs", d, od, 16 * U32)
    within("z_scale", z, oz, 16 * U32)
    c = np.abs((a64[0] - K[2:]) / K[:2]).max()
    m = (np.abs(a64[1]).sum(1) + np.abs(a64[2]).sum(1) + np.abs(a64[3])).sum()
    within("d xi", g.xi, og["xi"], 46 * U32 * m)
    within("d intrinsics", g.intrinsics, og["intrinsics"], 46 * U32 * m * (1 + c) / K[:2].min())


def _render_case(kind, seed, dtype, t_threshold, n_pixels=48, n_samples=12):
    field = camera_field(kind, seed)
    w2c, K, _ = camera_setup(seed)
    rng = np.random.default_rng(seed)
    px = _pixels(rng, n_pixels)
    o, d, z = camera_rays(w2c, K, px)
    smp = sample_rays(o, d, BOX, n_samples=n_samples, jitter=True, seed=seed)
    assert np.all(np.diff(smp.ray_offsets) == n_samples)  # every ray crosses BOX: a dense (R, S) layout
    t, delta = smp.t.reshape(-1, n_samples), smp.delta.reshape(-1, n_samples)
    n = len(px)
    cot = (rng.normal(size=(n, 3)), rng.normal(size=n), rng.normal(size=n))
    px, t, delta, cot = px.astype(dtype), t.astype(dtype), delta.astype(dtype), tuple(c.astype(dtype) for c in cot)
    if dtype == np.float32:
        from kernels.volume import GridField, SphereField
        import warp as wp
        P = field.params_numpy()
        field = (SphereField(*P.values(), dtype=wp.float32) if kind == "spheres" else
                 GridField(field.bbox, field.resolution, sh_degree=field.sh_degree, density_bias=0.0, dtype=wp.float32))
        if kind != "spheres":
            field.set_params({k: v.astype(np.float32) for k, v in P.items()})
    o, d, z = camera_rays(w2c, K, px)
    r = render_samples(field, dense_samples(o, d, t, delta, z), background=BG, t_threshold=t_threshold)
    gc = render_backward_camera(field, r, w2c, K, px, *cot)
    gr = render_backward_rays(field, r, *cot)
    return field, (w2c, K, px, t, delta, cot), (o, d, z), r, gc, gr


@pytest.mark.parametrize("kind", ["spheres", "grid_rgb", "grid_sh2"])
@pytest.mark.parametrize("t_threshold", [0.0, 0.3], ids=["no_stop", "early_stop"])
def test_render_camera_float64(kind, t_threshold):
    field, (w2c, K, px, t, delta, cot), (o, d, z), r, gc, gr = _render_case(kind, 3, np.float64, t_threshold)
    if t_threshold:
        assert np.any(r.composite.n_used.numpy() < t.shape[1])  # some rays stop early
    fd = _field_dict(kind, field)
    (C, D, A), og = render_camera_oracle(fd, w2c, K, px, t, delta, BG, t_threshold, *cot)
    close64("rgb", N(r.rgb), C)
    close64("depth", N(r.depth), D)
    close64("opacity", N(r.opacity), A)
    close64("d xi", gc.xi, og["xi"])
    close64("d intrinsics", gc.intrinsics, og["intrinsics"])
    _, orr = render_rays_oracle(fd, N(o), N(d), N(z), t, delta, BG, t_threshold, *cot)
    for name, got in zip(("origins", "dirs", "z_scale"), gr):
        close64(f"d {name}", got.numpy(), orr[name])


@pytest.mark.parametrize("kind", ["spheres", "grid_sh2"])
def test_render_camera_float32_within_the_rounding_bound(kind):
    """Each sample's field value takes at most 60 rounded operations (the grid: 3 u n_max on the
    cell coordinate, 8 corners, 9 SH terms; the spheres: 3 spheres' distance, exp and the colour
    quotient) on inputs of relative error 16 u (the rays, above); the compositing's transmittance
    T_k is a product of k factors (1 + 3 u each) and every output a sum of S terms: with the
    activations' and the exponential's condition factor at most kappa = max(1, max sigma delta,
    max |x| / cell size), forward |error| <= (60 + 4 S) u kappa M with M the outputs' magnitude
    max(1, max|depth|). The VJPs repeat the chain once more (backward of the same operations) and
    sum over S samples and then P pixels, each term bounded by the float64 oracle's VJP for
    |cotangents| evaluated on the rays' magnitudes: (120 + 8 S) u kappa times the sum over pixels
    of the per-pixel magnitude m_p (|g_C|_1 + |g_D| max(1, max depth) + |g_A|) max(1, max t), and
    for the intrinsics times (1 + max|c|) / min(fx, fy) (the rays' gradient divided by fx or fy)."""
    field, (w2c, K, px, t, delta, cot), (o, d, z), r, gc, gr = _render_case(kind, 4, np.float32, 0.0)
    f64 = camera_field(kind, 4)
    fd = _field_dict(kind, f64)
    a64 = [a.astype(np.float64) for a in (px, t, delta)]
    c64 = tuple(c.astype(np.float64) for c in cot)
    (C, D, A), og = render_camera_oracle(fd, w2c, K, a64[0], a64[1], a64[2], BG, 0.0, *c64)
    S = t.shape[1]
    x_max = float(np.abs(a64[1]).max()) + np.abs(w2c[:3, 3]).max()
    cell = 1.0 if kind == "spheres" else float(((f64.bbox[1] - f64.bbox[0]) / (np.array(f64.resolution) - 1)).min())
    sig_delta = float(np.abs(r.field_out.sigma.numpy()).max() * a64[2].max())
    kappa = max(1.0, sig_delta, x_max / cell)
    M = max(1.0, float(np.abs(D).max()))
    fwd = (60 + 4 * S) * U32 * kappa * M
    within("rgb", N(r.rgb), C, fwd)
    within("depth", N(r.depth), D, fwd)
    within("opacity", N(r.opacity), A, fwd)
    m = ((np.abs(c64[0]).sum(1) + np.abs(c64[1]) * M + np.abs(c64[2])) * max(1.0, float(a64[1].max()))).sum()
    vjp = (120 + 8 * S) * U32 * kappa * m
    c = np.abs((a64[0] - K[2:]) / K[:2]).max()
    within("d xi", gc.xi, og["xi"], vjp)
    within("d intrinsics", gc.intrinsics, og["intrinsics"], vjp * (1 + c) / K[:2].min())
