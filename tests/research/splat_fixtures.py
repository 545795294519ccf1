"""The small splat training scene the splat training tests share (tests/research/test_splats*.py).

`ring_cameras` are square pinhole cameras (50 degree field of view) at distance 3 from the origin,
0.6 x 3 above the ground plane, looking at the origin; `training_scene` makes a model the target of a
training test (every splat of scale 0.15 and opacity logit 3) and renders it from six of them at
32x32, SH degree 0; `moved_copy` is the start of a training test: the target with its means moved.
"""

from __future__ import annotations

import math

import numpy as np

from research.cameras import Camera, look_at
from research.splats import model as sm

RING = np.linspace(0, 2 * math.pi, 6, endpoint=False)


def ring_cameras(size: int = 32, angles=RING) -> list[Camera]:
    """`size` x `size` cameras on the ring at `angles` (radians), looking at the origin."""
    return [Camera.from_fov(50.0, size, size, look_at(3.0 * np.array([math.cos(a), math.sin(a), 0.6]), [0, 0, 0]))
            for a in angles]


def point_splats(rng: np.random.Generator, n: int = 40) -> sm.GaussianModel:
    """`n` splats at points uniform in [-0.4, 0.4]^3 with colours uniform in [0.1, 0.9] (sm.from_points)."""
    return sm.from_points(rng.uniform(-0.4, 0.4, (n, 3)), rng.uniform(0.1, 0.9, (n, 3)))


def training_scene(truth: sm.GaussianModel) -> tuple[list[Camera], np.ndarray]:
    """(the six ring cameras at 32x32, their images of `truth` at SH degree 0), after setting every splat of
    `truth` (in place) to scale 0.15 and opacity logit 3."""
    truth.log_scales[:] = np.log(0.15)
    truth.opacity_logits[:] = 3.0
    cams = ring_cameras()
    return cams, np.stack([sm.render(truth, c, sh_degree=0).rgb.numpy() for c in cams])


def moved_copy(truth: sm.GaussianModel, rng: np.random.Generator, sigma: float) -> sm.GaussianModel:
    """A copy of `truth` whose means are moved by normal noise of standard deviation `sigma` (float32)."""
    start = truth.copy()
    start.means += rng.normal(0, sigma, start.means.shape).astype(np.float32)
    return start
