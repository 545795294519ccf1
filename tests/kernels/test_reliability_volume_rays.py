"""Reliability of kernels.volume.rays: a pose that is not a rotation, bad intrinsics and pixels, and a field
without point gradients each raise one ValueError naming the argument, before any kernel runs."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.volume import PEMLPField, render_rays
from kernels.volume.rays import camera_rays, camera_rays_backward, render_backward_camera, render_backward_rays
from research.checks.volume import BOX, camera_setup

W2C, K, PIX = camera_setup(0)
SCALED = W2C.copy()
SCALED[:3, :3] *= 1.01
REFLECT = W2C.copy()
REFLECT[:3, :3] = REFLECT[:3, :3] @ np.diag([1.0, 1.0, -1.0])
ROW = W2C.copy()
ROW[3, 2] = 1.0
NAN = W2C.copy()
NAN[0, 3] = np.nan

CASES = [
    ("w2c-scaled", camera_rays, (SCALED, K, PIX), r"w2c: rotation part is not orthonormal \(max \|R\^T R - I\|"),
    ("w2c-reflection", camera_rays, (REFLECT, K, PIX), r"w2c: rotation part has determinant -1, expected \+1 \(a reflection"),
    ("w2c-last-row", camera_rays, (ROW, K, PIX), r"w2c: last row must be \[0, 0, 0, 1\]"),
    ("w2c-nan", camera_rays, (NAN, K, PIX), r"w2c: contains non-finite values"),
    ("w2c-3x4", camera_rays, (W2C[:3], K, PIX), r"w2c: expected a 4x4 world-to-camera matrix"),
    ("intrinsics-3", camera_rays, (W2C, K[:3], PIX), r"intrinsics: expected \(fx, fy, cx, cy\), got shape \(3,\)"),
    ("intrinsics-fx-0", camera_rays, (W2C, np.array([0.0, 40.0, 12.0, 10.0]), PIX), r"intrinsics: expected finite"),
    ("intrinsics-fy-neg", camera_rays, (W2C, np.array([40.0, -1.0, 12.0, 10.0]), PIX), r"fx, fy > 0"),
    ("pixels-shape", camera_rays, (W2C, K, PIX[:, :1]), r"pixels: "),
    ("pixels-int", camera_rays, (W2C, K, PIX.astype(np.int64)), r"pixels: "),
    ("backward-grad-shape", camera_rays_backward, (W2C, K, PIX, np.ones((3, 3))), r"grad_origins: "),
    ("backward-not-rotation", camera_rays_backward, (SCALED, K, PIX), r"w2c: rotation part is not orthonormal"),
]


@pytest.mark.parametrize("fn,args,message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_camera_input_raises_one_line(fn, args, message):
    with pytest.raises(ValueError, match=message) as info:
        fn(*args)
    assert "\n" not in str(info.value)


def test_field_without_point_gradient_is_named():
    field = PEMLPField(BOX, n_freqs=2, hidden=(8,), dtype=wp.float64)
    o, d, z = camera_rays(W2C, K, PIX)
    r = render_rays(field, o, d, BOX, n_samples=4, z_scale=z)
    for fn, args in ((render_backward_rays, (field, r)), (render_backward_camera, (field, r, W2C, K, PIX))):
        with pytest.raises(ValueError, match=r"field: point and camera gradients exist for the spheres and grid "
                                             r"fields, not for PEMLPField") as info:
            fn(*args)
        assert "\n" not in str(info.value)


def test_result_must_be_a_render_result():
    from research.checks.volume import camera_field
    with pytest.raises(ValueError, match=r"result: expected the RenderResult of render_rays, got dict"):
        render_backward_rays(camera_field("spheres", 0), {})
