"""research/splats/geometry.py in training: TrainConfig(normal_weight=...) lowers the depth-normal
consistency loss it adds, and bad settings are refused."""

from __future__ import annotations


import numpy as np

from kernels import splat as ks
from research.splats import geometry, model as sm, train as st
from tests.bad_input import assert_refused
from tests.research.splat_fixtures import moved_copy, point_splats, training_scene


def _consistency(model, cams, depth):
    g = model.inputs(None)
    losses = []
    for c in cams:
        geo = geometry.render_geometry(g, sm.splat_camera(c), None, depth=depth, sh_degree=0)
        losses.append(geometry.consistency_loss(geo))
    return float(np.mean(losses))


def test_the_consistency_loss_trains_down():
    rng = np.random.default_rng(5)
    truth = point_splats(rng)
    cams, images = training_scene(truth)
    start = moved_copy(truth, rng, 0.05)
    start.log_scales += rng.normal(0, 0.3, start.log_scales.shape).astype(np.float32)  # distinct shortest axes
    out = {}
    for weight in (0.0, 1.0):
        cfg = st.TrainConfig(iterations=60, max_sh_degree=0, log_every=10, normal_weight=weight, normal_depth="median")
        out[weight] = st.train(start, cams, images, extent=sm.scene_extent(cams), cfg=cfg, progress=False)
    assert "normal" in out[1.0].history[-1] and "normal" not in out[0.0].history[-1]
    assert out[1.0].history[-1]["normal"] > 0
    before = _consistency(start, cams, "median")
    plain, trained = (_consistency(out[w].model, cams, "median") for w in (0.0, 1.0))
    assert trained < plain and trained < before


def test_bad_settings():
    assert_refused(lambda: st.TrainConfig(normal_weight=-1.0), r"^normal_weight: expected a weight >= 0")
    assert_refused(lambda: st.TrainConfig(normal_depth="mean"), r"^normal_depth: expected one of expected, median")
    cam = ks.SplatCamera(np.eye(4), np.array([[30.0, 0, 8], [0, 30.0, 7], [0, 0, 1]]), 16, 14)
    g = sm.from_points(np.random.default_rng(0).uniform(-1, 1, (6, 3)) + [0, 0, 3], np.full((6, 3), 0.5)).inputs(None)
    assert_refused(lambda: geometry.render_geometry(g, cam, depth="mean"), r"^depth: expected one of expected, median")
