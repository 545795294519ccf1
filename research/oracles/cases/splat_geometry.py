"""Splat geometry (kernels/splat/normals.py, depth.py) against its Dr.Jit oracles (research/oracles/geometry.py):
normals from a depth map, the splats' shortest-axis normals and the expected depth, with their VJPs.

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: geometry_img, the side of the depth map; geometry_splats, the Gaussians.
SIZES = {
    "full": dict(geometry_img=256, geometry_splats=100_000),
    "quick": dict(geometry_img=128, geometry_splats=10_000),
    "smoke": dict(geometry_img=24, geometry_splats=100),
}


def _camera(side: int):
    from kernels import splat as ks

    K = np.array([[1.1 * side, 0.0, side / 2 + 0.3], [0.0, 1.05 * side, side / 2 - 0.2], [0.0, 0.0, 1.0]])
    view = np.eye(4)
    view[:3, 3] = [0.1, -0.05, 3.0]
    return ks.SplatCamera(view, K, side, side)


def case_depth_normals(dt, S, seed):
    from kernels.splat import normals as kn
    from research.oracles.geometry import depth_normals_oracle

    rng = Rounded(seed)
    n = S["geometry_img"]
    cam = _camera(n)
    yy, xx = np.mgrid[0:n, 0:n] / n
    depth = 2.0 + 0.6 * xx + 0.3 * yy + rng.normal(0.0, 0.01, (n, n))  # a slanted, rough surface
    depth = depth.astype(np.float32).astype(np.float64)
    cot = rng.normal(size=(n, n, 3))
    K = cam.K
    intr = (K[0, 0], K[1, 1], K[0, 2], K[1, 2])

    def drlab(t):
        d = depth.astype(t)
        return [kn.normals_from_depth(d, cam)], [kn.normals_from_depth_backward(d, cam, cot.astype(t))]

    def oracle(t):
        normals, g = depth_normals_oracle(depth.astype(dt).astype(t), intr, cot.astype(dt).astype(t))
        return [normals], [g]

    return f"{n}x{n} depth", drlab, oracle


def case_splat_normals(dt, S, seed):
    from kernels.splat import normals as kn
    from research.oracles.geometry import splat_normals_oracle

    rng = Rounded(seed)
    n = S["geometry_splats"]
    cam = _camera(64)
    means, quats = rng.normal(size=(n, 3)), rng.normal(size=(n, 4))
    log_scales, cot = rng.uniform(-4.0, -1.0, (n, 3)), rng.normal(size=(n, 3))

    def drlab(t):
        args = (means.astype(t), quats.astype(t), log_scales.astype(t), cam)
        return [kn.splat_normals(*args)], [kn.splat_normals_backward(*args, cot.astype(t))]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        normals, g = splat_normals_oracle(c(means), c(quats), c(log_scales), cam.viewmat, c(cot))
        return [normals], [g]

    return f"{n} Gaussians", drlab, oracle


def case_expected_depth(dt, S, seed):
    from kernels.splat import depth as kd
    from research.oracles.geometry import expected_depth_oracle

    rng = Rounded(seed)
    n = S["geometry_img"]
    alpha = rng.uniform(0.05, 1.0, (n, n))
    depth, cot = alpha * rng.uniform(1.0, 5.0, (n, n)), rng.normal(size=(n, n))

    def drlab(t):
        d, a = depth.astype(t), alpha.astype(t)
        return [kd.expected_depth(d, a)], list(kd.expected_depth_backward(d, a, cot.astype(t)))

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        e, grads = expected_depth_oracle(c(depth), c(alpha), c(cot))
        return [e], list(grads)

    return f"{n}x{n}", drlab, oracle


CASES = [
    Case("normals from depth", case_depth_normals),
    Case("shortest-axis splat normals", case_splat_normals),
    Case("expected depth", case_expected_depth),
]
