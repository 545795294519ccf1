"""Finite-difference checks (float64) of the lens models' backward passes (kernels/lens.py).

Registered for `drlab gradcheck lens`; tests/kernels/test_lens*.py run them.
  * lens.rays: kernels.volume.lens_rays (origins, directions, z_scale) with respect to the left se(3)
    perturbation xi of world-to-camera (at xi = 0 of a random pose) and (fx, fy, cx, cy), per model.
  * lens.project: the splat projection through each model (kernels.splat.lens_projection) with
    respect to every splat parameter, xi and the intrinsics, in both modes, with and without the
    antialiasing compensation; the outputs checked are the screen means, conics, depths, colours
    and opacities (the radius is an integer and not differentiable).
Inputs are kept away from the kinks: every splat projects well inside the image and the lens's
domain (so no culling decision moves under a step of 1e-6), colours stay away from the clamp at 0,
and for the fisheye one splat sits within r = 0.004 of the axis, where G(s) switches to its series.
The distortions are strong (opencv k1 = -0.25: 10% at the image corner) so that the second
derivatives in lens_project_vjp carry real weight.
"""

from __future__ import annotations

import numpy as np

import kernels.splat as ks
from kernels.lens import Lens
from research.gradcheck import GradcheckResult, check_vjp, register_check

LENSES = {
    "opencv": Lens("opencv", (-0.25, 0.08, 0.004, -0.003, 0.01)),
    "fisheye": Lens("fisheye", (0.08, -0.02, 0.005, -0.001)),
    "orthographic": Lens("orthographic"),
}
PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh")


def _camera(rng: np.random.Generator, central: bool) -> tuple[np.ndarray, np.ndarray]:
    """(w2c, intrinsics): a camera 4 units from the origin looking at it; fx != fy, an off-centre
    principal point; about 30 px per unit of x/z for the central models (a 48x40 image spans
    |x/z| < 0.8), about 20 px per world unit for the orthographic one."""
    from research.cameras import look_at

    eye = rng.normal(0.0, 0.2, 3) + np.array([0.1, -0.2, -4.0])
    c2w = look_at(eye, rng.normal(0.0, 0.05, 3), up=(0.0, -1.0, 0.0))
    f = (rng.uniform(30.0, 33.0), rng.uniform(28.0, 31.0)) if central else (rng.uniform(20.0, 22.0),
                                                                             rng.uniform(19.0, 21.0))
    return np.linalg.inv(c2w), np.array([*f, 24.0 + rng.uniform(-1, 1), 20.0 + rng.uniform(-1, 1)])


# --------------------------------------------------------------------------- rays


def check_lens_rays(model: str, seed: int) -> list[GradcheckResult]:
    from kernels.splat.camera import se3_exp
    from kernels.volume.lens_rays import lens_rays, lens_rays_backward

    rng = np.random.default_rng(seed)
    lens = LENSES[model]
    w2c, intrinsics = _camera(rng, lens.central)
    pixels = rng.uniform([1.0, 1.0], [47.0, 39.0], (10, 2))

    def f(xi, intrinsics):
        o, d, z, valid = lens_rays(se3_exp(xi) @ w2c, intrinsics, lens, pixels)
        assert valid.all()
        return {"origins": o, "dirs": d, "z_scale": z}

    def vjp(inp, cot):
        g = lens_rays_backward(se3_exp(inp["xi"]) @ w2c, inp["intrinsics"], lens, pixels, cot["origins"], cot["dirs"],
                               cot["z_scale"])
        return {"xi": g.xi, "intrinsics": g.intrinsics}

    return check_vjp(f, vjp, {"xi": np.zeros(6), "intrinsics": intrinsics}, seed=seed,
                     name=f"lens.rays[{model},seed={seed}]")


@register_check("lens.rays")
def rays_checks() -> list[GradcheckResult]:
    return [r for model in LENSES for seed in (0, 1) for r in check_lens_rays(model, seed)]


# --------------------------------------------------------------------------- splat projection


def lens_scene(model: str, seed: int, n: int = 10) -> tuple[dict, ks.SplatCamera]:
    """Splat parameters and a 48x40 camera with the model's lens (module docstring)."""
    rng = np.random.default_rng(seed)
    lens = LENSES[model]
    w2c, intr = _camera(rng, lens.central)
    K = np.array([[intr[0], 0.0, intr[2]], [0.0, intr[1], intr[3]], [0.0, 0.0, 1.0]])
    camera = ks.SplatCamera(w2c, K, 48, 40, lens=lens)
    z = 4.0 + rng.uniform(-0.5, 0.5, n)
    if lens.central:
        ab = rng.uniform([-0.6, -0.5], [0.6, 0.5], (n, 2))
        ab[0] = rng.uniform(-0.003, 0.003, 2)  # near the axis (the fisheye's series branch)
        pc = np.column_stack([ab * z[:, None], z])
    else:
        pc = np.column_stack([rng.uniform(-0.8, 0.8, n), rng.uniform(-0.7, 0.7, n), z])
    means = (pc - w2c[:3, 3]) @ w2c[:3, :3]
    sh = rng.normal(0.0, 0.1, (n, 4, 3))
    sh[:, 0, :] = (rng.uniform(0.3, 0.8, (n, 3)) - 0.5) / ks.SH_C0
    params = {"means": means, "log_scales": rng.uniform(-2.6, -1.8, (n, 3)),
              "quats": rng.normal(size=(n, 4)) * rng.uniform(0.5, 2.0, (n, 1)),
              "opacity_logits": rng.uniform(-1.0, 2.0, n), "sh": sh}
    return params, camera


def project_camera_fn(camera: ks.SplatCamera, mode: str, antialiased: bool):
    """The projection as a function of the splats, a pose twist xi (at 0) and the intrinsics (4,)."""
    def cam_of(xi, intrinsics):
        return camera.with_intrinsics(*intrinsics).perturbed(xi)

    def f(means, log_scales, quats, opacity_logits, sh, xi, intrinsics):
        g = ks.gaussian_inputs(means, log_scales, quats, opacity_logits, sh)
        p = ks.project(g, cam_of(xi, intrinsics), antialiased=antialiased, mode=mode)
        assert (np.asarray(p.radii) > 0).all(), "a splat is culled: the scene is not smooth"
        return {"means2d": p.means2d, "conics": p.conics, "depths": p.depths, "colors": p.colors,
                "opacities": p.opacities}

    def vjp(inputs, cot):
        g = ks.gaussian_inputs(*(inputs[k] for k in PARAMS))
        cam = cam_of(inputs["xi"], inputs["intrinsics"])
        p = ks.project(g, cam, antialiased=antialiased, mode=mode)
        grads = ks.project_backward(g, cam, p.radii, cot["means2d"], cot["conics"], cot["depths"], cot["colors"],
                                    cot["opacities"], antialiased=antialiased, mode=mode, want_camera=True)
        return {**{k: grads[k] for k in PARAMS}, "xi": grads["pose"], "intrinsics": grads["intrinsics"]}

    return f, vjp


def check_lens_project(model: str, seed: int, mode: str, antialiased: bool) -> list[GradcheckResult]:
    params, camera = lens_scene(model, seed)
    f, vjp = project_camera_fn(camera, mode, antialiased)
    inputs = dict(params, xi=np.zeros(6), intrinsics=camera.params()[:4].copy())
    return check_vjp(f, vjp, inputs, seed=seed,
                     name=f"lens.project[{model},{mode}{',aa' if antialiased else ''},seed={seed}]")


@register_check("lens.project")
def project_checks() -> list[GradcheckResult]:
    out = []
    for model in LENSES:
        for seed, (mode, aa) in enumerate([("3dgs", False), ("gsplat", True)]):
            out += check_lens_project(model, seed, mode, aa)
    return out
