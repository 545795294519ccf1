"""3DGS-MCMC densification (research/splats/mcmc.py): the relocation formula against the paper's
double sum and its compositing property, relocation / growth / noise / regularisers, and training."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.spatial.transform import Rotation

from kernels.optim import Adam
from research.checks.mcmc import check_regularizer
from research.gradcheck import assert_gradcheck
from research.splats import mcmc, model as sm, train as st
from tests.research.splat_fixtures import moved_copy, training_scene


def paper_eq9(o_old: float, s_old: float, n: int) -> tuple[float, float]:
    """Eq. 9 of Kheradmand et al. 2024, written out literally (Python floats, exact binomials)."""
    o_new = 1.0 - (1.0 - o_old) ** (1.0 / n)
    denom = sum(math.comb(i - 1, k) * (-1) ** k / math.sqrt(k + 1) * o_new ** (k + 1)
                for i in range(1, n + 1) for k in range(i))
    return o_new, o_old / denom * s_old


def test_relocation_is_the_papers_formula():
    opac = np.array([0.006, 0.05, 0.3, 0.5, 0.8, 0.97, 0.999])
    for n in (1, 2, 3, 7, 20, mcmc.N_MAX):
        o_new, s_new = mcmc.relocation(opac, np.outer(opac * 0 + 1, [0.1, 0.2, 0.03]), np.full(len(opac), n))
        for i, o in enumerate(opac):
            want_o, want_s = paper_eq9(float(o), 1.0, n)
            assert o_new[i] == pytest.approx(want_o, rel=1e-12)
            # the paper's double sum alternates in sign: at n = 51 its terms reach ~1e3 for a sum of ~1
            np.testing.assert_allclose(s_new[i], want_s * np.array([0.1, 0.2, 0.03]), rtol=1e-10)
    o1, s1 = mcmc.relocation(opac, np.ones((len(opac), 3)), np.ones(len(opac), dtype=int))
    np.testing.assert_allclose(o1, opac, rtol=1e-15)  # one copy is the splat itself
    np.testing.assert_allclose(s1, 1.0, rtol=1e-15)


@pytest.mark.parametrize("o, n", [(0.02, 2), (0.4, 3), (0.9, 5), (0.99, 12), (0.7, mcmc.N_MAX)])
def test_n_copies_composite_to_the_original(o, n):
    s = 0.3
    (o_new,), s_new = mcmc.relocation(np.array([o]), np.full((1, 3), s), np.array([n]))
    s_new = s_new[0, 0]
    assert 1.0 - (1.0 - o_new) ** n == pytest.approx(o, rel=1e-13)  # along the ray through the centre
    copies = quad(lambda x: 1.0 - (1.0 - o_new * math.exp(-0.5 * (x / s_new) ** 2)) ** n, -np.inf, np.inf,
                  epsabs=0, epsrel=1e-12)[0]
    assert copies == pytest.approx(o * s * math.sqrt(2 * math.pi), rel=1e-9)  # and across it
    assert s_new < s if n > 1 else True


def test_relocation_rejects_bad_input():
    with pytest.raises(ValueError, match="n: expected integers"):
        mcmc.relocation(np.array([0.5]), np.ones((1, 3)), np.array([mcmc.N_MAX + 1]))
    with pytest.raises(ValueError, match="opacity, scales"):
        mcmc.relocation(np.array([0.0]), np.ones((1, 3)), np.array([2]))
    with pytest.raises(ValueError, match="expected shapes"):
        mcmc.relocation(np.array([0.5]), np.ones((1, 2)), np.array([2]))
    with pytest.raises(ValueError, match="cap_max"):
        mcmc.MCMCConfig(cap_max=0)
    with pytest.raises(ValueError, match="strategy"):
        st.TrainConfig(strategy="abs")


def _model(n: int, seed: int = 0) -> sm.GaussianModel:
    rng = np.random.default_rng(seed)
    logits = rng.uniform(-2.0, 3.0, n)
    return sm.GaussianModel(means=rng.normal(size=(n, 3)), log_scales=rng.uniform(-4, -1, (n, 3)),
                            quats=rng.normal(size=(n, 4)), opacity_logits=logits, sh_dc=rng.normal(size=(n, 1, 3)),
                            sh_rest=rng.normal(size=(n, 15, 3)))


def _adam(model: sm.GaussianModel) -> Adam:
    adam = Adam(model.arrays(), lr=1e-3)
    for k in adam.m:
        adam.m[k][:] = 1.0
        adam.v[k][:] = 2.0
    return adam


def test_relocate_dead_moves_them_onto_live_splats_with_the_correction():
    m = _model(60)
    dead = np.array([3, 10, 11, 40, 59])
    m.opacity_logits[dead] = sm.logit(0.004)
    m.opacity_logits[7] = sm.logit(0.005)  # exactly at the threshold: dead too (opacity <= min_opacity)
    dead = np.sort(np.append(dead, 7))
    before = m.copy()
    adam = _adam(m)
    cfg = mcmc.MCMCConfig()
    moved = mcmc.relocate_dead(m, adam, cfg, np.random.default_rng(1))
    assert moved == len(dead) and m.n == before.n
    assert np.all(m.opacities > cfg.min_opacity)
    live = np.setdiff1d(np.arange(m.n), dead)
    groups = {}  # source row -> its copies among the dead rows
    for d in dead:
        src = [i for i in live if np.array_equal(m.means[i], m.means[d]) and np.array_equal(m.sh_rest[i], m.sh_rest[d])]
        assert len(src) == 1
        groups.setdefault(src[0], []).append(d)
    for src, copies in groups.items():
        n = len(copies) + 1
        o_want, s_want = mcmc.relocation(before.opacities[[src]].astype(np.float64),
                                         np.exp(before.log_scales[[src]].astype(np.float64)), np.array([n]))
        for row in [src, *copies]:
            assert m.opacities[row] == pytest.approx(o_want[0], rel=1e-5)
            np.testing.assert_allclose(np.exp(m.log_scales[row]), s_want[0], rtol=1e-5)
            np.testing.assert_array_equal(m.quats[row], before.quats[src])
            for k in adam.m:
                assert not adam.m[k][row].any() and not adam.v[k][row].any()
    untouched = np.setdiff1d(live, list(groups))
    np.testing.assert_array_equal(m.opacity_logits[untouched], before.opacity_logits[untouched])
    assert np.all(adam.m["means"][untouched] == 1.0) and np.all(adam.v["quats"][untouched] == 2.0)


def test_add_new_grows_by_the_rate_up_to_the_cap():
    m = _model(100, seed=2)
    adam = _adam(m)
    m2, added = mcmc.add_new(m, adam, mcmc.MCMCConfig(cap_max=1000), np.random.default_rng(0))
    assert added == 5 and m2.n == 105 and adam.m["means"].shape == (105, 3)
    assert not adam.m["sh_rest"][100:].any() and np.all(adam.m["sh_rest"][:100] == 1.0)
    for row in range(100, 105):  # each new row is a corrected copy of a row in the model
        assert any(np.array_equal(m2.means[row], m2.means[i]) and np.array_equal(m2.log_scales[row], m2.log_scales[i])
                   for i in range(100))
    m3, added = mcmc.add_new(m2, adam, mcmc.MCMCConfig(cap_max=107), np.random.default_rng(0))
    assert added == 2 and m3.n == 107
    m4, added = mcmc.add_new(m3, adam, mcmc.MCMCConfig(cap_max=107), np.random.default_rng(0))
    assert added == 0 and m4.n == 107


def test_position_noise_is_the_covariance_times_the_gated_normal():
    m = _model(30, seed=3)
    m.opacity_logits[:3] = [sm.logit(0.005), sm.logit(0.5), sm.logit(0.99)]
    gate = mcmc.noise_gate(1.0 / (1.0 + np.exp(-m.opacity_logits.astype(np.float64))))
    assert gate[0] == pytest.approx(0.5, abs=1e-6)  # the threshold: (1 - o) = t
    assert gate[1] < 1e-20 and gate[2] < 1e-20  # opaque splats stay put
    q = m.quats.astype(np.float64)
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy: (x, y, z, w)
    cov = R @ (np.exp(2.0 * m.log_scales.astype(np.float64))[:, :, None] * np.transpose(R, (0, 2, 1)))
    np.testing.assert_allclose(mcmc.covariances(m.log_scales, m.quats), cov, rtol=1e-12, atol=1e-17)
    eps = np.random.default_rng(4).standard_normal((m.n, 3))
    want = np.einsum("nij,nj->ni", cov, eps * (gate * 1e-4 * 5e5)[:, None])
    got = mcmc.position_noise(m, 1e-4, 5e5, np.random.default_rng(4))
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-20)


def test_regularizer_value_and_gradient():
    logits, ls = np.array([-1.0, 0.5]), np.log(np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]))
    loss, _, _ = mcmc.regularizer(logits, ls, 0.01, 0.02)
    o = 1 / (1 + np.exp(-logits))
    assert loss == pytest.approx(0.01 * o.mean() + 0.02 * np.exp(ls).mean(), rel=1e-14)
    assert_gradcheck(check_regularizer(0))


def test_schedule_scales_like_3dgs():
    cfg = mcmc.MCMCConfig()
    assert mcmc.MCMCSchedule.scaled(30_000, cfg) == mcmc.MCMCSchedule(500, 25_000, 100)
    s = mcmc.MCMCSchedule.scaled(3000, cfg)
    assert s == mcmc.MCMCSchedule(50, 2500, 50)
    assert [i for i in range(1, 3001) if s.refine_now(i)][:2] == [100, 150] and not s.refine_now(2500)


def test_adam_reset_rows():
    adam = _adam(_model(4))
    adam.reset_rows(np.array([1, 3]))
    assert not adam.m["means"][[1, 3]].any() and np.all(adam.m["means"][[0, 2]] == 1.0)
    assert not adam.v["sh_dc"][[1, 3]].any() and np.all(adam.v["sh_dc"][[0, 2]] == 2.0)


def test_mcmc_training_reaches_the_cap_and_reduces_the_loss():
    rng = np.random.default_rng(5)
    truth = _model(40, seed=5)
    truth.means *= 0.4
    truth.sh_rest[:] = 0.0
    cams, images = training_scene(truth)
    start = moved_copy(truth, rng, 0.1)
    start.sh_dc[:] = 0.0
    start.opacity_logits[:5] = sm.logit(0.001)  # dead from the start: relocated at the first refinement
    cfg = st.TrainConfig(iterations=150, max_sh_degree=1, log_every=10, strategy="mcmc",
                         mcmc=mcmc.MCMCConfig(cap_max=42))
    result = st.train(start, cams, images, extent=sm.scene_extent(cams), cfg=cfg, progress=False)
    assert [e["iteration"] for e in result.events] == [50, 100]
    assert result.events[0]["relocated"] >= 5 and result.events[0]["added"] == 2 and result.model.n == 42
    assert all(h["gaussians"] <= 42 for h in result.history) and result.history[-1]["reg"] > 0
    assert result.history[-1]["loss"] < 0.8 * result.history[0]["loss"]
    assert st.evaluate(result.model, cams, images, 0).psnr > st.evaluate(start, cams, images, 0).psnr + 2.0
