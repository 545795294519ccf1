"""research.cameras.Camera with a lens model: projection, rays and back-projection through the lens agree
with each other and with the NumPy reference; the lens survives scaling and the dict round trip."""

from __future__ import annotations

import numpy as np
import pytest

from kernels.lens import Lens
from kernels.reference import lens as ref
from research.cameras import Camera, look_at

K = np.array([[40.0, 0.0, 24.5], [0.0, 42.0, 19.5], [0.0, 0.0, 1.0]])
LENSES = [Lens("opencv", (-0.2, 0.05, 0.001, -0.002, 0.01)), Lens("fisheye", (0.05, -0.01, 0.002, -0.0005)),
          Lens("orthographic")]


@pytest.mark.parametrize("lens", LENSES, ids=lambda l: l.model)
def test_project_backproject_and_rays_agree(lens):
    cam = Camera(K if lens.central else np.diag([12.0, 13.0, 1.0]) + [[0, 0, 24.5], [0, 0, 19.5], [0, 0, 0]],
                 look_at([0.5, -4.0, 1.0], [0, 0, 0]), 48, 40, lens)
    depth = np.random.default_rng(0).uniform(3.0, 5.0, (40, 48))
    X = cam.backproject(depth)
    uv, z = cam.project(X.reshape(-1, 3))
    u, v = cam.pixel_centers()
    np.testing.assert_allclose(uv, np.stack([u.ravel(), v.ravel()], axis=1), atol=1e-9)
    np.testing.assert_allclose(z, depth.ravel(), atol=1e-12)
    o, d = cam.rays()
    m = ref.normalised(cam.K, np.stack([u.ravel(), v.ravel()], axis=1))
    q, e, valid = ref.unproject(lens, m)
    assert valid.all()
    np.testing.assert_allclose(d.reshape(-1, 3), e @ cam.R.T, atol=1e-13)
    np.testing.assert_allclose(o.reshape(-1, 3), q @ cam.R.T + cam.center, atol=1e-12)


def test_lens_survives_scaling_and_dicts():
    cam = Camera(K, np.eye(4), 48, 40, LENSES[1])
    assert cam.scaled(0.5).lens == LENSES[1]
    back = Camera.from_dict(cam.to_dict())
    assert back.lens == LENSES[1] and np.array_equal(back.K, cam.K)
    assert "lens" not in Camera(K, np.eye(4), 48, 40).to_dict()
    assert Camera(K, np.eye(4), 48, 40, Lens("pinhole")).lens is None


def test_lens_refusals():
    with pytest.raises(ValueError, match="lens: Mitsuba's perspective sensor is a pinhole"):
        Camera(np.diag([40.0, 40.0, 1.0]), np.eye(4), 48, 40, LENSES[0]).mitsuba_intrinsics()
    with pytest.raises(ValueError, match="lens: an orthographic camera has parallel rays"):
        Camera(K, np.eye(4), 48, 40, LENSES[2]).camera_directions()
    with pytest.raises(ValueError, match="lens: expected a kernels.lens.Lens"):
        Camera(K, np.eye(4), 48, 40, "fisheye")
