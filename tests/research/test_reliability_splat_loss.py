"""Bad inputs of the splat depth loss (research.splats.loss.depth_loss) and of the pose twist
(kernels.splat.se3_exp, SplatCamera.perturbed): one-line ValueErrors naming the argument."""

from __future__ import annotations


import numpy as np
import pytest

from kernels import splat as ks
from research.splats.loss import depth_loss
from tests.bad_input import assert_refused

D = np.full((4, 5), 2.0)
A = np.full((4, 5), 0.8)


def _loss(**kw):
    args = dict(depth=D, alpha=A, measured=np.full((4, 5), 2.5), mask=None)
    args.update(kw)
    return lambda: depth_loss(args.pop("depth"), args.pop("alpha"), args.pop("measured"), args.pop("mask"), **args)


def _camera() -> ks.SplatCamera:
    return ks.SplatCamera(np.eye(4), np.array([[40.0, 0, 16], [0, 40.0, 12], [0, 0, 1]]), 32, 24)


BAD = {
    "depth_3d": (_loss(depth=np.ones((4, 5, 1))), r"^depth: expected a float32 or float64 \(H, W\)"),
    "depth_int": (_loss(depth=np.ones((4, 5), int)), r"^depth: expected"),
    "depth_nan": (_loss(depth=np.where(D > 0, np.nan, 0.0)), r"^depth, alpha: expected finite"),
    "alpha_shape": (_loss(alpha=np.ones((5, 4))), r"^alpha: expected float64 \(4, 5\) like depth"),
    "alpha_float32": (_loss(alpha=A.astype(np.float32)), r"^alpha: expected float64"),
    "measured_shape": (_loss(measured=np.ones((4, 4))), r"^measured: expected a float \(4, 5\) depth map"),
    "measured_int": (_loss(measured=np.ones((4, 5), int)), r"^measured: expected a float"),
    "mask_not_bool": (_loss(mask=np.ones((4, 5))), r"^mask: expected a bool \(4, 5\) array"),
    "mask_shape": (_loss(mask=np.ones((4, 4), bool)), r"^mask: expected a bool"),
    "min_alpha_1": (_loss(min_alpha=1.0), r"^min_alpha: expected a number in \[0, 1\)"),
    "min_alpha_string": (_loss(min_alpha="0.5"), r"^min_alpha: expected"),
    "kind_huber": (_loss(kind="huber"), r"^kind: expected one of 'l1', 'l2'"),
    "xi_5": (lambda: ks.se3_exp(np.zeros(5)), r"^xi: expected a finite 6-vector"),
    "xi_nan": (lambda: ks.se3_exp(np.array([0, 0, 0, np.nan, 0, 0])), r"^xi: expected a finite 6-vector"),
    "perturbed_xi_2d": (lambda: _camera().perturbed(np.zeros((2, 3))), r"^xi: expected a finite 6-vector"),
    "with_intrinsics_negative_fx": (lambda: _camera().with_intrinsics(-1.0, 40.0, 16.0, 12.0), r"^K: expected"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input(case):
    assert_refused(*BAD[case])
