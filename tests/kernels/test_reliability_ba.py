"""Bad input to kernels.ba.reproject: one ValueError naming the argument, before any kernel runs."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import ba as kba

P = np.tile(np.eye(4), (2, 1, 1))
P[:, 2, 3] = 3.0
X = np.zeros((3, 3))
O = np.zeros((4, 2))
CI = np.array([0, 1, 0, 1])
PI = np.array([0, 1, 2, 0])
K = (50.0, 50.0, 16.0, 16.0)

CASES = [
    ("poses_shape", dict(poses=np.zeros((2, 4))), "poses"),
    ("poses_nan", dict(poses=np.where(P == 3.0, np.nan, P)), "poses"),
    ("points_shape", dict(points=np.zeros((3, 2))), "points"),
    ("points_dtype_mismatch", dict(points=np.zeros((3, 3), np.float32)), "points"),
    ("observations_shape", dict(observations=np.zeros((4, 3))), "observations"),
    ("cam_idx_length", dict(cam_idx=np.array([0, 1])), "cam_idx"),
    ("cam_idx_out_of_range", dict(cam_idx=np.array([0, 1, 2, 0])), "cam_idx"),
    ("cam_idx_negative", dict(cam_idx=np.array([0, -1, 0, 0])), "cam_idx"),
    ("cam_idx_float", dict(cam_idx=np.array([0.0, 1.0, 0.0, 1.0])), "cam_idx"),
    ("pt_idx_out_of_range", dict(pt_idx=np.array([0, 1, 3, 0])), "pt_idx"),
    ("intrinsics_length", dict(intrinsics=(50.0, 50.0, 16.0)), "intrinsics"),
    ("intrinsics_negative_focal", dict(intrinsics=(-50.0, 50.0, 16.0, 16.0)), "intrinsics"),
]


@pytest.mark.parametrize("override, name", [(c[1], c[2]) for c in CASES], ids=[c[0] for c in CASES])
def test_reproject_bad_input(override, name):
    args = dict(poses=P, points=X, observations=O, cam_idx=CI, pt_idx=PI, intrinsics=K)
    args.update(override)
    with pytest.raises(ValueError, match=rf"^{name}"):
        kba.reproject(**args)
