"""The 3DGS render against its Dr.Jit oracle (research/oracles/splat.py, after the original 3DGS code):
Gaussians with SH degree 3 in the default ("3dgs") mode (rgb, alpha, depth, d means, log-scales,
quaternions, opacity logits, SH, background, and the camera's pose (6) and intrinsics (4)).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: splats, the Gaussians; splat_px, the image side.
SIZES = {
    "full": dict(splats=3000, splat_px=256),
    "quick": dict(splats=600, splat_px=128),
    "smoke": dict(splats=30, splat_px=32),
}


def case_splat(dt, S, seed):
    from kernels import splat as ks
    from research.oracles.splat import render_oracle

    rng = Rounded(seed)
    N, px = S["splats"], S["splat_px"]
    f = 0.86 * px
    K = np.array([[f, 0.0, px / 2 + 0.3], [0.0, f, px / 2 - 0.4], [0.0, 0.0, 1.0]])
    view = np.eye(4)
    view[:3, 3] = [0.02, -0.01, 4.0]
    cam = ks.SplatCamera(view, K, px, px)
    means = np.column_stack([rng.uniform(-2.4, 2.4, N), rng.uniform(-2.4, 2.4, N), rng.uniform(-1.0, 1.0, N)])
    log_scales = rng.uniform(-4.2, -2.8, (N, 3)) + np.log(256 / px) * (px < 256)
    quats, logits = rng.normal(size=(N, 4)), rng.uniform(-2.0, 3.0, N)
    sh = rng.normal(0.0, 0.15, (N, 16, 3))
    sh[:, 0, :] = (rng.uniform(0.2, 0.8, (N, 3)) - 0.5) / ks.SH_C0
    bg = np.array([0.3, 0.5, 0.7])
    cot = (rng.normal(size=(px, px, 3)), rng.normal(size=(px, px)), rng.normal(size=(px, px)))
    names = ("means", "log_scales", "quats", "opacity_logits", "sh")
    params = (means, log_scales, quats, logits, sh)

    def drlab(t):
        g = ks.gaussian_inputs(*(v.astype(t) for v in params))
        res = ks.render(g, cam, bg.astype(t))
        gg = ks.render_backward(g, res, *(c.astype(t) for c in cot), want_camera=True)
        return [res.rgb, res.alpha, res.depth], [gg[k] for k in (*names, "background", "pose", "intrinsics")]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        img, gg, _ = render_oracle(*(c(v) for v in params), view, K, px, px, cam.near, cam.far, c(bg),
                                   *(c(v) for v in cot), want_camera=True)
        return list(img), [gg[k] for k in (*names, "background", "pose", "intrinsics")]

    return f"{N} Gaussians, {px}x{px}, SH 3", drlab, oracle


CASES = [
    Case("3DGS render (projection, SH, raster, depth, camera)", case_splat),
]
