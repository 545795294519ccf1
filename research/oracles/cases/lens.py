"""The splat projection through each lens model (kernels/splat/lens_projection.py) against its Dr.Jit
oracle (research/oracles/lens.py): means2d, conics, depths, colours (SH degree 3) and opacities, and the
VJPs of the splat parameters, the camera pose (6) and the intrinsics (4).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: splats, the Gaussians (a 96x80 image).
SIZES = {
    "full": dict(lens_splats=4000),
    "quick": dict(lens_splats=800),
    "smoke": dict(lens_splats=40),
}
PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh")
OUTPUTS = ("means2d", "conics", "depths", "colors", "opacities")


def _case(model: str):
    def build(dt, S, seed):
        from kernels import splat as ks
        from kernels.lens import Lens
        from research.checks.lens import LENSES
        from research.oracles.lens import lens_project_oracle

        rng = Rounded(seed)
        lens: Lens = LENSES[model]
        N, W, H = S["lens_splats"], 96, 80
        f = (60.0, 58.0) if lens.central else (40.0, 41.0)
        K = np.array([[f[0], 0.0, W / 2 + 0.3], [0.0, f[1], H / 2 - 0.4], [0.0, 0.0, 1.0]])
        view = np.eye(4)
        view[:3, 3] = [0.02, -0.01, 4.0]
        cam = ks.SplatCamera(view, K, W, H, lens=lens)
        z = rng.uniform(3.2, 4.8, N)
        if lens.central:  # off the axis (|w| > 0.02) and inside the image
            ab = rng.uniform([0.03, 0.03], [0.6, 0.5], (N, 2)) * np.sign(rng.uniform(-1, 1, (N, 2)))
            pc = np.column_stack([ab * z[:, None], z])
        else:
            pc = np.column_stack([rng.uniform(-1.0, 1.0, N), rng.uniform(-0.8, 0.8, N), z])
        means = pc - view[:3, 3]
        log_scales = rng.uniform(-3.4, -2.4, (N, 3))
        quats, logits = rng.normal(size=(N, 4)), rng.uniform(-2.0, 3.0, N)
        sh = rng.normal(0.0, 0.1, (N, 16, 3))
        sh[:, 0, :] = (rng.uniform(0.3, 0.8, (N, 3)) - 0.5) / ks.SH_C0
        params = (means, log_scales, quats, logits, sh)
        shapes = {"means2d": (N, 2), "conics": (N, 3), "depths": (N,), "colors": (N, 3), "opacities": (N,)}
        cot = {k: rng.normal(size=s) for k, s in shapes.items()}

        def drlab(t):
            g = ks.gaussian_inputs(*(v.astype(t) for v in params))
            p = ks.project(g, cam)
            if not np.all(np.asarray(p.radii) > 0):
                raise RuntimeError("lens oracle case: a splat was culled (the inputs are meant to be all visible)")
            gg = ks.project_backward(g, cam, p.radii, *(cot[k].astype(t) for k in OUTPUTS), want_camera=True)
            return [getattr(p, k) for k in OUTPUTS], [gg[k] for k in (*PARAMS, "pose", "intrinsics")]

        def oracle(t):
            c = lambda v: v.astype(dt).astype(t)  # noqa: E731
            values, gg = lens_project_oracle(*(c(v) for v in params), view, K, lens.model, lens.coeffs,
                                             {k: c(v) for k, v in cot.items()})
            return [values[k] for k in OUTPUTS], [gg[k] for k in (*PARAMS, "pose", "intrinsics")]

        return f"{N} Gaussians through the {model} lens, 96x80, SH 3", drlab, oracle

    return build


CASES = [Case(f"splat projection, {m} lens (mean, EWA Jacobian, SH, camera)", _case(m))
         for m in ("opencv", "fisheye", "orthographic")]
