"""Bad input to the Dr.Jit oracles (research/oracles) raises one ValueError naming the argument."""

from __future__ import annotations

import numpy as np
import pytest

from research.oracles import backend
from research.oracles.appearance import bilateral_slice_oracle
from research.oracles.ba import reproject_oracle
from research.oracles.corr import lookup_oracle
from research.oracles.geometry import depth_normals_oracle, expected_depth_oracle, splat_normals_oracle
from research.oracles.icp import icp_oracle
from research.oracles.mip import filter_3d_oracle
from research.oracles.pointnet import group_local_oracle, max_pool_oracle
from research.oracles.proposal import interlevel_loss_oracle, interval_weights_oracle
from research.oracles.rays import camera_rays_oracle, render_camera_oracle
from research.oracles.splat import render_oracle
from research.oracles.ssim import ssim_oracle
from research.oracles.stereo import soft_argmin_oracle, window_cost_oracle
from research.oracles.volume import mlp_oracle

Z = np.zeros
IMG = Z((6, 5, 3))


def _splat(**change):
    args = dict(means=Z((2, 3)), log_scales=Z((2, 3)), quats=np.ones((2, 4)), opacity_logits=Z(2), sh=Z((2, 4, 3)),
                viewmat=np.eye(4), K=np.eye(3), width=4, height=4, near=0.01, far=100.0, background=Z(3),
                grad_rgb=Z((4, 4, 3)))
    args.update(change)
    return lambda: render_oracle(**args)


def _rays(**change):
    args = dict(w2c=np.eye(4), intrinsics=np.array([10.0, 10.0, 2.0, 2.0]), pixels=Z((3, 2)), grad_origins=Z((3, 3)),
                grad_dirs=Z((3, 3)), grad_z_scale=Z(3))
    args.update(change)
    return lambda: camera_rays_oracle(**args)


def _render(**change):
    args = dict(field={"kind": "spheres", "centers": Z((1, 3)), "radii": np.ones(1), "colors": Z((1, 3)),
                       "sharpness": np.ones(1)}, w2c=np.eye(4), intrinsics=np.array([10.0, 10.0, 2.0, 2.0]),
                pixels=Z((3, 2)), t=np.ones((3, 4)), delta=np.ones((3, 4)), background=Z(3), t_threshold=0.0,
                grad_rgb=Z((3, 3)), grad_depth=Z(3), grad_opacity=Z(3))
    args.update(change)
    return lambda: render_camera_oracle(**args)


@pytest.mark.parametrize("call, match", [
    (lambda: backend(np.int32), "dtype: expected float32 or float64, got int32"),
    (lambda: ssim_oracle(IMG, Z((6, 5, 1)), IMG), r"y: expected shape \(6, 5, 3\), got \(6, 5, 1\)"),
    (lambda: ssim_oracle(IMG.tolist(), IMG, IMG), "x: expected a NumPy array, got list"),
    (lambda: ssim_oracle(np.full((6, 5, 3), np.nan), IMG, IMG), "x: expected finite values"),
    (lambda: ssim_oracle(IMG.astype(np.int64), IMG, IMG), "x: expected dtype float32 or float64, got int64"),
    (lambda: window_cost_oracle(Z((4, 5)), Z((4, 5)), 0, 3, 1, "census"), "kind: expected 'sad' or 'zncc'"),
    (lambda: window_cost_oracle(Z((4, 5)), Z((4, 5)), 3, 3, 1, "sad"), r"dmax: expected > dmin \(3\), got 3"),
    (lambda: soft_argmin_oracle(Z((4, 5, 3)), 0, Z((4, 5)), 0.0), "temperature: expected > 0, got 0.0"),
    (lambda: soft_argmin_oracle(Z((4, 5, 3)), 0, Z((5, 4))), r"grad: expected shape \(4, 5\)"),
    (lambda: lookup_oracle(Z((2, 4, 4)), Z((2, 4, 4)), Z((2, 4, 4)), 4, 1, Z((36, 4, 4))), "levels: expected"),
    (lambda: lookup_oracle(Z((2, 4, 4)), Z((2, 4, 4)), Z((2, 4, 4)), 1, -1, Z((9, 4, 4))), "radius: expected"),
    (lambda: lookup_oracle(Z((2, 4, 4)), Z((2, 4, 4)), Z((2, 4, 3)), 1, 1, Z((9, 4, 4))), "coords: expected shape"),
    (lambda: mlp_oracle(Z((3, 2)), {"W0": Z((4, 2))}, (2, 4), Z((3, 4))), "b0: expected a NumPy array, got NoneType"),
    (_splat(quats=Z((2, 3))), r"quats: expected shape \(2, 4\), got \(2, 3\)"),
    (_splat(sh=Z((2, 5, 3))), "sh: expected \\(L\\+1\\)\\^2 <= 16 coefficients per channel, got 5"),
    (_splat(tile_rule="tiles"), "tile_rule: expected '3dgs' or 'square', got 'tiles'"),
    (_splat(grad_rgb=Z((4, 4))), r"grad_rgb: expected shape \(4, 4, 3\), got \(4, 4\)"),
    (_rays(intrinsics=np.array([0.0, 10.0, 2.0, 2.0])), "intrinsics: expected fx, fy > 0"),
    (_rays(w2c=np.eye(3)), r"w2c: expected shape \(4, 4\), got \(3, 3\)"),
    (_rays(grad_dirs=Z((2, 3))), r"grad_dirs: expected shape \(3, 3\), got \(2, 3\)"),
    (_render(field={"kind": "hash"}), "field: expected a dict with kind 'spheres' or 'grid'"),
    (_render(delta=-np.ones((3, 4))), "delta: expected interval lengths >= 0"),
    (_render(t_threshold=1.0), r"t_threshold: expected a value in \[0, 1\), got 1.0"),
    (lambda: bilateral_slice_oracle(Z((1, 1, 1, 9)), IMG, IMG), r"grid: expected shape \(N, N, N, 12\)"),
    (lambda: bilateral_slice_oracle(Z((1, 1, 1, 12)), IMG, Z((6, 5))), r"grad_out: expected shape \(6, 5, 3\)"),
    (lambda: filter_3d_oracle(Z((2, 3)), Z(2), -np.ones(2), Z((2, 3)), Z(2)), "sigma: expected values >= 0"),
    (lambda: interval_weights_oracle(Z((2, 3)), -np.ones((2, 3)), Z((2, 3))), "delta: expected values >= 0"),
    (lambda: interlevel_loss_oracle(Z((2, 4)), Z((2, 2)), Z((2, 5)), Z((2, 4)), Z(2)),
     r"weights: expected shape \(2, 3\), got \(2, 2\)"),
    (lambda: depth_normals_oracle(Z((4, 5)), (0.0, 1.0, 2.0, 2.0), Z((4, 5, 3))), "intrinsics: expected fx, fy > 0"),
    (lambda: splat_normals_oracle(Z((2, 3)), Z((2, 3)), Z((2, 3)), np.eye(4), Z((2, 3))),
     r"quats: expected shape \(2, 4\), got \(2, 3\)"),
    (lambda: expected_depth_oracle(Z((2, 3)), -np.ones((2, 3)), Z((2, 3))), "alpha: expected values >= 0"),
    (lambda: reproject_oracle(Z((1, 2, 4)), Z((2, 3)), Z((1, 2)), [0], [0], (1, 1, 0, 0)),
     r"poses: expected shape \(C, 3, 4\) or \(C, 4, 4\)"),
    (lambda: reproject_oracle(Z((1, 3, 4)), Z((2, 3)), Z((1, 2)), [0], [0], (1, -1, 0, 0)),
     "intrinsics: expected fx, fy > 0"),
    (lambda: max_pool_oracle(Z((2, 3, 4)), Z((2, 3))), r"grad: expected shape \(2, 4\), got \(2, 3\)"),
    (lambda: group_local_oracle(Z((1, 5, 3)), [[0]], [[[1, 2]]], 0.0, Z((1, 1, 2, 3))), "radius: expected > 0"),
    (lambda: icp_oracle(Z((0, 3)), Z((0, 3))), "source: expected at least one correspondence"),
    (lambda: icp_oracle(Z((2, 3)), Z((3, 3))), r"target: expected shape \(2, 3\), got \(3, 3\)"),
    (lambda: icp_oracle(Z((2, 3)), Z((2, 3)), Z((2, 3))), "normals: expected unit vectors"),
    (lambda: icp_oracle(Z((2, 3)), Z((2, 3)), robust="cauchy"), "robust: expected one of none, huber, gm"),
    (lambda: icp_oracle(Z((2, 3)), Z((2, 3)), robust="huber", scale=0.0), "scale: expected a finite value > 0"),
], ids=["dtype", "ssim-y-shape", "ssim-x-list", "ssim-x-nan", "ssim-x-int", "cost-kind", "cost-dmax",
        "softargmin-temperature", "softargmin-grad-shape", "corr-levels", "corr-radius", "corr-coords",
        "mlp-missing-bias", "splat-quats", "splat-sh", "splat-tile-rule", "splat-grad-rgb",
        "rays-fx", "rays-w2c-shape", "rays-grad-dirs", "render-field-kind", "render-delta", "render-t-threshold",
        "slice-grid-entries", "slice-grad-shape", "mip-sigma", "weights-delta", "interlevel-weights-shape",
        "depth-normals-fx", "splat-normals-quats", "expected-depth-alpha",
        "ba-poses-shape", "ba-intrinsics", "maxpool-grad-shape", "group-radius",
        "icp-empty", "icp-target-shape", "icp-normals-unit", "icp-robust", "icp-scale"])
def test_bad_input_raises_one_line_naming_the_argument(call, match):
    with pytest.raises(ValueError, match=match) as info:
        call()
    assert "\n" not in str(info.value)
