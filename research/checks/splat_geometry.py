"""Finite-difference checks (float64) of the splat depth and normal backwards (kernels/splat/depth.py,
kernels/splat/normals.py) and of the depth-normal consistency loss end to end (research/splats/geometry.py).

Registered for `drlab gradcheck splat_geometry`. Scenes are research.checks.splat's screened scenes
(every discontinuity of the rasteriser at least its margins from the inputs), and for the median
depth also at least CROSSING_MARGIN from a transmittance of exactly 1/2 (where the median's splat
changes). Depth maps for the depth normals are a tilted plane with smooth bumps, positive everywhere;
the expected depth's alphas lie in [0.05, 1]. The splat normals' scales differ by at least a factor
e^0.3 between axes (the argmin is stable) and their means lie in front of the camera.
"""

from __future__ import annotations

import numpy as np

from kernels import splat as ks
from kernels.reference import splat_geometry as rg
from kernels.splat import depth as kd
from kernels.splat import normals as kn
from research.checks import splat as cs
from research.gradcheck import GradcheckResult, check_vjp, register_check
from research.splats import geometry

CROSSING_MARGIN = 1e-4
KEYS = ("means2d", "conics", "colors", "opacities", "depths")


def median_scene(seed: int, mode: str = ks.DEFAULT_MODE) -> tuple[cs.Scene, ks.Projection]:
    """The first screened scene from `seed`'s sub-seeds whose pixels keep every T CROSSING_MARGIN from 1/2."""
    for k in range(cs.MAX_REDRAWS):
        scene = cs.smooth_scene(seed * 1000 + k, require_events=True, mode=mode)
        g = ks.gaussian_inputs(*(scene.params[k2] for k2 in cs.PARAMS))
        p = ks.project(g, scene.camera, mode=mode)
        W, H = scene.camera.width, scene.camera.height
        if rg.crossing_margin(p.means2d, p.conics, p.opacities, p.depths, p.radii, W, H, mode) >= CROSSING_MARGIN:
            return scene, p
    raise RuntimeError(f"no scene clear of T = 1/2 in {cs.MAX_REDRAWS} draws (seed {seed})")


def check_median(seed: int, mode: str = ks.DEFAULT_MODE) -> list[GradcheckResult]:
    scene, p = median_scene(seed, mode)
    W, H = scene.camera.width, scene.camera.height

    def run(inputs):
        s = ks.splats_2d(*(inputs[k] for k in KEYS), p.radii)
        r, tiles = ks.rasterize(s, W, H, None, mode=mode)
        return s, tiles, kd.median_depth(s, tiles, r, mode=mode)

    def f(**inputs):
        return {"median": run(inputs)[2].depth}

    def vjp(inputs, cot):
        s, tiles, med = run(inputs)
        out = {k: np.zeros_like(inputs[k]) for k in KEYS}
        out["depths"] = kd.median_depth_backward(s, tiles, med, cot["median"])
        return out

    return check_vjp(f, vjp, {k: getattr(p, k) for k in KEYS}, seed=seed,
                     name=f"splat_geometry.median[{mode},seed={seed}]")


def check_expected(seed: int) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    depth, alpha = rng.uniform(0.1, 5.0, (9, 11)), rng.uniform(0.05, 1.0, (9, 11))

    def f(depth, alpha):
        return {"e": kd.expected_depth(depth, alpha)}

    def vjp(inputs, cot):
        gd, ga = kd.expected_depth_backward(inputs["depth"], inputs["alpha"], cot["e"])
        return {"depth": gd, "alpha": ga}

    return check_vjp(f, vjp, {"depth": depth, "alpha": alpha}, seed=seed, name=f"splat_geometry.expected[seed={seed}]")


def bumpy_depth(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """A tilted plane at z ~ 3 with a few smooth bumps (all positive)."""
    x, y = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    z = 3.0 + rng.uniform(-0.02, 0.02) * x + rng.uniform(-0.02, 0.02) * y
    for _ in range(3):
        cx, cy, s = rng.uniform(0, width), rng.uniform(0, height), rng.uniform(2.0, 4.0)
        z += rng.uniform(-0.3, 0.3) * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    return z


def _camera(width: int, height: int, rng: np.random.Generator) -> ks.SplatCamera:
    view = np.eye(4)
    view[:3, :3] = cs._rotation(rng, 0.3)
    view[:3, 3] = [0.1, -0.05, 4.0]
    K = np.array([[20.0, 0.0, width / 2 + 0.3], [0.0, 19.0, height / 2 - 0.2], [0.0, 0.0, 1.0]])
    return ks.SplatCamera(view, K, width, height)


def check_depth_normals(seed: int) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    cam = _camera(13, 11, rng)
    depth = bumpy_depth(rng, 13, 11)

    def f(depth):
        return {"n": kn.normals_from_depth(depth, cam)}

    def vjp(inputs, cot):
        return {"depth": kn.normals_from_depth_backward(inputs["depth"], cam, cot["n"])}

    return check_vjp(f, vjp, {"depth": depth}, seed=seed, name=f"splat_geometry.depth_normals[seed={seed}]")


def check_splat_normals(seed: int, n: int = 16) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    cam = _camera(20, 20, rng)
    means = rng.uniform(-0.5, 0.5, (n, 3))
    quats = rng.normal(size=(n, 4))
    # the three log-scales 0.3 or more apart, in a random order
    log_scales = np.array([rng.permutation([-2.0, -1.6, -1.1]) + rng.uniform(-0.05, 0.05, 3) for _ in range(n)])

    def f(means, quats, log_scales):
        return {"n": kn.splat_normals(means, quats, log_scales, cam)}

    def vjp(inputs, cot):
        gq = kn.splat_normals_backward(inputs["means"], inputs["quats"], inputs["log_scales"], cam, cot["n"])
        return {"means": np.zeros_like(means), "quats": gq, "log_scales": np.zeros_like(log_scales)}

    return check_vjp(f, vjp, {"means": means, "quats": quats, "log_scales": log_scales}, seed=seed,
                     name=f"splat_geometry.splat_normals[seed={seed}]")


def check_consistency(seed: int, depth: str, mode: str = ks.DEFAULT_MODE) -> list[GradcheckResult]:
    """L_n (research/splats/geometry.py) of the whole chain, with respect to every splat parameter."""
    scene, _ = median_scene(seed, mode) if depth == "median" else (cs.smooth_scene(seed, mode=mode), None)

    def f(**params):
        g = ks.gaussian_inputs(*(params[k] for k in cs.PARAMS))
        geo = geometry.render_geometry(g, scene.camera, scene.background, depth=depth, mode=mode)
        return {"loss": np.array([geometry.consistency_loss(geo)])}

    def vjp(inputs, cot):
        g = ks.gaussian_inputs(*(inputs[k] for k in cs.PARAMS))
        geo = geometry.render_geometry(g, scene.camera, scene.background, depth=depth, mode=mode)
        extra = geometry.consistency_backward(g, geo, float(cot["loss"][0]))
        h, w = scene.camera.height, scene.camera.width
        grads = geometry.render_backward_with(g, geo.render, np.zeros((h, w, 3)), extra)
        return {k: grads[k] for k in cs.PARAMS}

    return check_vjp(f, vjp, dict(scene.params), seed=seed,
                     name=f"splat_geometry.consistency[{depth},{mode},seed={seed}]")


@register_check("splat_geometry.median")
def median_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for mode in ks.MODES for r in check_median(seed, mode)]


@register_check("splat_geometry.expected")
def expected_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_expected(seed)]


@register_check("splat_geometry.depth_normals")
def depth_normals_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_depth_normals(seed)]


@register_check("splat_geometry.splat_normals")
def splat_normals_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_splat_normals(seed)]


@register_check("splat_geometry.consistency")
def consistency_checks() -> list[GradcheckResult]:
    return [r for depth in geometry.DEPTHS for seed in (0, 1) for r in check_consistency(seed, depth)]
