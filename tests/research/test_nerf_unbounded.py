"""research/nerf/unbounded.py: the contracted field with its proposal sampler learns a tiny unbounded scene."""

from __future__ import annotations

import numpy as np
import pytest

from research.cameras import Camera, look_at
from research.nerf.train import RayBank
from research.nerf.unbounded import UnboundedConfig, contracted_hashgrid, render_image_unbounded, train_unbounded


def _bank(n_views: int = 6, size: int = 16) -> tuple[RayBank, list[Camera]]:
    """Cameras on a circle looking in at a colour that depends on the ray's direction only (a sky at
    infinity): only samples far out, in the contracted region, can explain it."""
    cams = []
    for k in range(n_views):
        a = 2 * np.pi * k / n_views
        eye = np.array([np.cos(a), np.sin(a), 0.2])
        K = np.array([[size, 0, size / 2], [0, size, size / 2], [0, 0, 1.0]])
        cams.append(Camera(K, look_at(eye, np.zeros(3), up=(0, 0, 1)), size, size))
    o, d, z = [], [], []
    for c in cams:
        oo, dd = c.rays(normalize=True)
        o.append(oo.reshape(-1, 3)), d.append(dd.reshape(-1, 3)), z.append(c.ray_cosines().reshape(-1))
    d = np.concatenate(d)
    rgb = 0.5 + 0.4 * d  # the sky's colour
    rgba = np.concatenate([rgb, np.ones((len(d), 1))], axis=1)
    return RayBank(np.concatenate(o).astype(np.float32), d.astype(np.float32), np.concatenate(z).astype(np.float32),
                   rgba), cams


def _fit(bank, interlevel_weight: float):
    main = contracted_hashgrid((0, 0, 0), 1.0, n_levels=4, log2_table_size=12, max_resolution=32, hidden=(16,))
    prop = contracted_hashgrid((0, 0, 0), 1.0, n_levels=2, log2_table_size=10, max_resolution=16, hidden=(8,), seed=1)
    cfg = UnboundedConfig(iters=60, batch_rays=256, n_proposal=16, n_main=8, seed=2,
                          interlevel_weight=interlevel_weight)
    return main, prop, cfg, train_unbounded(main, prop, bank, cfg, progress=False)


def test_training_lowers_both_losses_and_renders_the_sky():
    bank, cams = _bank()
    main, prop, cfg, log = _fit(bank, 1.0)
    assert len(log["losses"]) == 60 and np.mean(log["losses"][-10:]) < 0.5 * np.mean(log["losses"][:5])
    # the interlevel loss grows as the main field becomes opaque; trained, the proposal keeps it lower
    untrained = _fit(bank, 0.0)[3]
    assert np.mean(log["interlevel"][-10:]) < 0.7 * np.mean(untrained["interlevel"][-10:])
    img = render_image_unbounded(cams[0], main, prop, cfg)
    assert img.rgb.shape == (16, 16, 3) and np.all(np.isfinite(img.rgb)) and img.n_samples == 16 * 16 * 8
    want = bank.rgba[: 16 * 16, :3].reshape(16, 16, 3)
    assert np.mean((np.clip(img.rgb, 0, 1) - want) ** 2) < np.mean((want - want.mean()) ** 2)


def test_bad_configuration_is_named():
    bank, _ = _bank(3, 8)
    main = contracted_hashgrid((0, 0, 0), 1.0, n_levels=1, log2_table_size=8, max_resolution=16, hidden=(4,))
    with pytest.raises(ValueError, match="^near"):
        train_unbounded(main, main, bank, UnboundedConfig(near=2e3), progress=False)
    with pytest.raises(ValueError, match="^n_main"):
        train_unbounded(main, main, bank, UnboundedConfig(n_main=0), progress=False)
