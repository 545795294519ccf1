"""research.nerf.train: the NeRF training loop fits, is deterministic, and its helpers are exact."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from threadpoolctl import threadpool_info

from kernels.volume import GridField, OccupancyGrid, SphereField
from research.cameras import Camera, look_at
from research.nerf.render import render_image
from research.nerf.train import RayBank, TrainConfig, train, upsample_grid

BBOX = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


@pytest.fixture(scope="module")
def bank():
    """Four 24x24 views of one soft sphere, as linear premultiplied RGBA (rendered over black)."""
    scene = SphereField([(0.0, 0.0, 0.0)], [0.5], [(0.9, 0.3, 0.1)], [8.0], dtype=wp.float32)
    cams, images = [], []
    for k in range(4):
        a = 2 * np.pi * k / 4
        cam = Camera.from_fov(50.0, 24, 24, look_at((3 * np.cos(a), 3 * np.sin(a), 1.0), (0.0, 0.0, 0.0)))
        img = render_image(cam, scene, BBOX, step=0.02)
        cams.append(cam)
        images.append(np.concatenate([img.rgb, img.opacity[..., None]], axis=-1))
    return RayBank.from_views(cams, np.stack(images).astype(np.float32))


def _fit(bank, iters=80):
    field = GridField(BBOX, (9, 9, 9), density_bias=-1.0, seed=0)
    cfg = TrainConfig(iters=iters, batch_rays=256, lr=0.1, step=0.04, occupancy_res=(8, 8, 8),
                      occupancy_start=20, occupancy_threshold=0.01, random_background=False, seed=3)
    log = train(field, bank, BBOX, cfg, OccupancyGrid(BBOX, (8, 8, 8), threshold=0.01), progress=False)
    return field, log


def test_training_fits_the_views_and_is_deterministic(bank):
    blas_before = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
    _, log = _fit(bank)
    assert len(log.losses) == 80 and all(np.isfinite(log.losses))
    first, last = np.mean(log.losses[:10]), np.mean(log.losses[-10:])
    assert last < 0.3 * first, (first, last)
    assert 0 < min(log.samples_per_ray) and max(log.occupied_fraction) <= 1.0
    _, again = _fit(bank)
    assert again.losses == log.losses  # same seed, same arithmetic
    # train() runs BLAS on one thread and gives the default back afterwards.
    assert [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"] == blas_before


def test_ray_bank_holds_every_pixel(bank):
    assert len(bank) == 4 * 24 * 24
    np.testing.assert_allclose(np.linalg.norm(bank.dirs, axis=1), 1.0, rtol=1e-6)
    assert bank.rgba.shape == (len(bank), 4) and 0.0 <= bank.rgba.min() and bank.rgba.max() <= 1.0
    assert 0.05 < (bank.rgba[:, 3] > 0.5).mean() < 0.6  # the sphere covers part of every view


def test_upsample_grid_keeps_the_field():
    rng = np.random.default_rng(0)
    coarse = GridField(BBOX, (3, 4, 5), dtype=wp.float64)
    coarse.set_params({"density": rng.normal(size=60), "color": rng.normal(size=(60, 3))})
    fine = upsample_grid(coarse, (5, 7, 9))  # every coarse vertex is a fine vertex
    pts = rng.uniform(BBOX[0], BBOX[1], (200, 3))
    a, b = coarse.forward(pts), fine.forward(pts)
    np.testing.assert_allclose(b.sigma, a.sigma, rtol=1e-12)
    np.testing.assert_allclose(b.rgb, a.rgb, rtol=1e-12, atol=1e-14)


def test_training_checks_values_on_the_first_iteration_only(bank, monkeypatch):
    import research.nerf.train as train_module
    from kernels._arrays import values_checked

    seen = []

    def recording(*args, **kwargs):
        seen.append(values_checked())
        return train_module.render_rays.__wrapped__(*args, **kwargs)

    recording.__wrapped__ = train_module.render_rays
    monkeypatch.setattr(train_module, "render_rays", recording)
    _fit(bank, iters=4)
    assert seen == [True, False, False, False]
    assert values_checked()  # restored after the loop


def test_training_rejects_a_bank_with_nan(bank):
    bad = RayBank(bank.origins.copy(), bank.dirs, bank.z_scale, bank.rgba)
    bad.origins[5, 1] = np.nan
    field = GridField(BBOX, (5, 5, 5))
    with pytest.raises(ValueError, match="bank.origins: expected finite values"):
        train(field, bad, BBOX, TrainConfig(iters=2, batch_rays=16), OccupancyGrid(BBOX, (4, 4, 4)), progress=False)
