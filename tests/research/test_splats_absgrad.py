"""AbsGS densification (research/splats/densify.py, DensifyConfig(absgrad=True)): the config, and the
training loop gathering its statistics from the backward's absolute mean2d gradient."""

from __future__ import annotations


import numpy as np
import pytest

from research.splats import densify, model as sm, train as st
from tests.bad_input import assert_refused
from tests.research.splat_fixtures import moved_copy, point_splats, training_scene


def test_absgs_config():
    cfg = densify.DensifyConfig.absgs(max_gaussians=500)
    assert cfg.absgrad and cfg.grad_threshold == densify.ABSGRAD_GRAD_THRESHOLD == 0.0008
    assert cfg.max_gaussians == 500 and not densify.DensifyConfig().absgrad
    assert densify.DensifyConfig.absgs(grad_threshold=0.001).grad_threshold == 0.001
    assert_refused(lambda: densify.DensifyConfig(absgrad=1), r"^absgrad: expected True or False, got 1$")
    assert_refused(lambda: densify.DensifyConfig(grad_threshold=0.0), r"^grad_threshold: expected a positive")
    assert_refused(lambda: st.TrainConfig(strategy="mcmc", densify=densify.DensifyConfig.absgs()),
                   r"^densify: absgrad=True is 3DGS density control's statistic, expected strategy='3dgs'")


def _scene():
    rng = np.random.default_rng(5)
    truth = point_splats(rng)
    cams, images = training_scene(truth)
    start = moved_copy(truth, rng, 0.1)
    start.sh_dc[:] = 0.0
    return cams, images, start


def test_training_densifies_on_the_absolute_gradient(monkeypatch):
    cams, images, start = _scene()
    seen: list[np.ndarray] = []
    add = densify.DensifyStats.add
    monkeypatch.setattr(densify.DensifyStats, "add", lambda self, g, *a: (seen.append(g.copy()), add(self, g, *a)))
    runs = {}
    for absgrad in (False, True):
        seen.clear()
        # one threshold for both, so that the counts compare the statistics alone
        cfg = st.TrainConfig(iterations=120, max_sh_degree=0, log_every=10,
                             densify=densify.DensifyConfig(grad_threshold=0.002, absgrad=absgrad))
        runs[absgrad] = (st.train(start, cams, images, extent=sm.scene_extent(cams), cfg=cfg, progress=False),
                         seen[0])
    (plain, g_plain), (absg, g_abs) = runs[False], runs[True]
    # The first iteration is the same in both runs: its statistic is the absolute sum, per component at
    # least the size of the summed gradient, larger where pixels pull a splat both ways.
    assert np.all(g_abs >= np.abs(g_plain) * (1 - 1e-5)) and np.any(g_abs > 1.5 * np.abs(g_plain) + 1e-9)
    grown = {k: sum(e.get("cloned", 0) + e.get("split", 0) for e in r.events) for k, r in
             ((False, plain), (True, absg))}
    assert grown[True] > grown[False]
    assert absg.history[-1]["loss"] < 0.8 * absg.history[0]["loss"]
