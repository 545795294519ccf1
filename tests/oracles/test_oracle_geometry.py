"""kernels/splat/normals.py and depth.py against their Dr.Jit oracles (research/oracles/geometry.py): normals
from depth, shortest-axis splat normals and the expected depth with their VJPs, in float64 (float32 is
reported by oracle_conformance)."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import splat as ks
from kernels.splat import depth as kd
from kernels.splat import normals as kn
from research.oracles.geometry import depth_normals_oracle, expected_depth_oracle, splat_normals_oracle
from tests.oracles.conftest import close64


def _camera(w: int, h: int) -> ks.SplatCamera:
    K = np.array([[1.2 * w, 0.0, w / 2 + 0.4], [0.0, 1.1 * w, h / 2 - 0.3], [0.0, 0.0, 1.0]])
    view = np.eye(4)
    view[:3, :3] = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))[0] * [1, 1, -1]
    view[:3, :3] *= np.sign(np.linalg.det(view[:3, :3]))
    view[:3, 3] = [0.2, -0.1, 3.5]
    return ks.SplatCamera(view, K, w, h)


@pytest.mark.parametrize("seed, w, h", [(0, 17, 13), (1, 5, 9)])
def test_float64_normals_from_depth_match_the_oracle(seed, w, h):
    rng = np.random.default_rng(seed)
    cam = _camera(w, h)
    yy, xx = np.mgrid[0:h, 0:w]
    depth = 2.0 + 0.04 * xx - 0.03 * yy + rng.normal(0.0, 0.05, (h, w))
    cot = rng.normal(size=(h, w, 3))
    want_n, want_g = depth_normals_oracle(depth, (cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]), cot)
    close64("normals", kn.normals_from_depth(depth, cam), want_n)
    close64("dL/ddepth", kn.normals_from_depth_backward(depth, cam, cot), want_g)


@pytest.mark.parametrize("seed, n", [(0, 200), (1, 3)])
def test_float64_splat_normals_match_the_oracle(seed, n):
    rng = np.random.default_rng(seed)
    cam = _camera(32, 24)
    means, quats = rng.normal(size=(n, 3)), rng.normal(size=(n, 4))
    log_scales, cot = rng.uniform(-4.0, -1.0, (n, 3)), rng.normal(size=(n, 3))
    want_n, want_g = splat_normals_oracle(means, quats, log_scales, cam.viewmat, cot)
    close64("normals", kn.splat_normals(means, quats, log_scales, cam), want_n)
    close64("dL/dquats", kn.splat_normals_backward(means, quats, log_scales, cam, cot), want_g)


def test_float64_expected_depth_matches_the_oracle():
    rng = np.random.default_rng(3)
    alpha = rng.uniform(0.0, 1.0, (9, 11))
    alpha[0, :3] = [0.0, 1e-12, 1e-9]  # two below the clamp A_MIN = 1e-10, one above
    depth, cot = rng.uniform(0.0, 4.0, (9, 11)), rng.normal(size=(9, 11))
    want_e, (want_gd, want_ga) = expected_depth_oracle(depth, alpha, cot)
    got_gd, got_ga = kd.expected_depth_backward(depth, alpha, cot)
    close64("e", kd.expected_depth(depth, alpha), want_e)
    close64("dL/ddepth", got_gd, want_gd)
    close64("dL/dalpha", got_ga, want_ga)
