"""Unbounded scenes (kernels/volume/contract.py, kernels/volume/proposal.py): forwards against the NumPy
references in float32 and float64, the float64 gradient checks, bad inputs, and the contracted field."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.reference import volume_unbounded as ref
from kernels.volume import HashGridField
from kernels.volume.contract import CONTRACTED_BOX, ContractedField, contract, contract_backward, s_to_t
from kernels.volume.proposal import (interlevel_loss, interlevel_loss_backward, interval_weights,
                                     interval_weights_backward, resample)
from research.checks import unbounded as checks
from research.gradcheck import assert_gradcheck

TOL = {np.float64: 1e-12, np.float32: 2e-6}


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_contraction_matches_the_reference_and_fills_the_ball_of_radius_2(dtype):
    p = checks.contract_points(0, 200)
    y = contract(p.astype(dtype), checks.CENTER, checks.RADIUS)
    assert y.dtype == dtype
    np.testing.assert_allclose(y, ref.contract(p, checks.CENTER, checks.RADIUS), rtol=TOL[dtype], atol=TOL[dtype])
    r_in = np.linalg.norm((p - checks.CENTER) / checks.RADIUS, axis=1)
    r_out = np.linalg.norm(ref.contract(p, checks.CENTER, checks.RADIUS), axis=1)
    np.testing.assert_allclose(r_out, np.where(r_in <= 1, r_in, 2 - 1 / r_in), rtol=1e-12)  # radial law
    far = contract(np.array([[1e12, 0.0, 0.0], [0.0, -1e30, 0.0]]))
    assert np.all(np.linalg.norm(far, axis=1) < 2.0) and np.allclose(np.linalg.norm(far, axis=1), 2.0)
    yw = contract(wp.array(p.astype(dtype)), checks.CENTER, checks.RADIUS)  # wp.array in -> wp.array out
    assert isinstance(yw, wp.array) and np.array_equal(yw.numpy(), y)


@pytest.mark.parametrize("seed", [3, 4])
def test_backwards_pass_the_float64_gradient_checks(seed):
    assert_gradcheck(checks.check_contract(seed) + checks.check_weights(seed) + checks.check_interlevel(seed)
                     + checks.check_interlevel_through_weights(seed))


def test_contraction_backward_is_the_identity_over_r_inside_the_ball():
    p = np.array([[0.1, 0.2, -0.3]])
    g = np.array([[1.0, -2.0, 0.5]])
    np.testing.assert_allclose(contract_backward(p, g, radius=2.0), g / 2.0, rtol=1e-15)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_spacing_is_linear_then_disparity_and_reaches_infinity(dtype):
    s = np.linspace(0.0, 1.0, 11, dtype=dtype)[None].repeat(2, 0)
    t = s_to_t(s, 0.2, np.inf, 2.0)
    want = ref.s_to_t(s.astype(np.float64), 0.2, np.inf, 2.0)
    np.testing.assert_allclose(t[:, :-1], want[:, :-1], rtol=TOL[dtype] * 10)
    assert np.isinf(t[0, -1]) and t[0, 0] == pytest.approx(0.2)
    # beyond tau, equal steps in s are equal steps in disparity 1/t
    tf = ref.s_to_t(np.linspace(0.0, 1.0, 9)[None], 0.0, 1e6, 1.0)[0]
    beyond = tf[tf > 1.0]
    assert np.allclose(np.diff(1.0 / beyond), np.diff(1.0 / beyond)[0], rtol=1e-5)
    np.testing.assert_allclose(s_to_t(np.array([[0.0, 1.0]]), 0.5, 40.0), [[0.5, 40.0]], rtol=1e-12)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_weights_resampling_and_interlevel_loss_match_the_references(dtype):
    rng = np.random.default_rng(0)
    sigma, delta = rng.uniform(0, 3, (6, 12)), rng.uniform(0.01, 0.4, (6, 12))
    w = interval_weights(sigma.astype(dtype), delta.astype(dtype))
    np.testing.assert_allclose(w, ref.interval_weights(sigma, delta), rtol=10 * TOL[dtype], atol=TOL[dtype])
    x = checks.interlevel_inputs(1)
    e = resample(x["proposal_edges"].astype(dtype), x["proposal_weights"].astype(dtype), 7)
    np.testing.assert_allclose(e, ref.resample(x["proposal_edges"], x["proposal_weights"], 7), atol=TOL[dtype] * 10)
    loss = interlevel_loss(*(x[k].astype(dtype) for k in ("edges", "weights", "proposal_edges", "proposal_weights")))
    np.testing.assert_allclose(loss, ref.interlevel_loss(x["edges"], x["weights"], x["proposal_edges"],
                                                         x["proposal_weights"]), rtol=100 * TOL[dtype])


def test_jittered_resampling_is_stratified_and_follows_the_weights():
    edges = np.linspace(0.0, 1.0, 33)[None].repeat(500, 0)
    weights = np.zeros((500, 32))
    weights[:, 20] = 1.0  # all the mass in [20/32, 21/32]
    new = resample(edges, weights, 16, jitter=True, seed=7)
    assert np.all(np.diff(new, axis=1) >= 0) and new.min() >= 0 and new.max() <= 1
    inside = (new >= 20 / 32) & (new <= 21 / 32)
    # the padded CDF puts 1 / (1 + 32 * 0.01) of the probability in the peak
    assert abs(inside.mean() - 1 / 1.32) < 0.03
    assert not np.array_equal(new, resample(edges, weights, 16, jitter=True, seed=8))
    again = resample(edges, weights, 16, jitter=True, seed=7)
    assert np.array_equal(new, again)


def test_interlevel_loss_is_zero_when_the_proposal_bounds_the_weights():
    h = np.linspace(0.0, 1.0, 9)[None]
    q = np.full((1, 8), 0.1)
    e = np.array([[0.0, 0.3, 0.7, 1.0]])
    assert interlevel_loss(e, np.array([[0.2, 0.3, 0.25]]), h, q)[0] == 0.0  # bounds: 0.3, 0.4, 0.3
    loss = interlevel_loss(e, np.array([[0.5, 0.3, 0.25]]), h, q)[0]
    assert loss == pytest.approx(0.2**2 / (0.5 + 1e-7))
    g = interlevel_loss_backward(e, np.array([[0.5, 0.3, 0.25]]), h, q, np.ones(1))
    np.testing.assert_allclose(g[0, :3], -2 * 0.2 / (0.5 + 1e-7))
    assert np.all(g[0, 3:] == 0.0)


def test_contracted_field_covers_all_of_space():
    inner = HashGridField(CONTRACTED_BOX, n_levels=2, log2_table_size=8, base_resolution=4, max_resolution=8,
                          hidden=(8,), seed=1, table_init_scale=0.5)
    field = ContractedField(inner, center=(1.0, 0.0, 0.0), radius=2.0)
    assert field.params is inner.params and field.name == "contracted_hashgrid"
    p = np.array([[1.0, 0.0, 0.0], [1e4, 3e3, -2e4], [-1e9, 0.0, 0.0]], dtype=np.float32)
    out = field.forward(p)
    assert np.all(out.sigma > 0) and isinstance(out.sigma, np.ndarray)
    np.testing.assert_array_equal(out.sigma, inner.forward(contract(p, (1.0, 0.0, 0.0), 2.0)).sigma)
    grads = field.backward(p, None, out, np.ones(3, np.float32), None)
    want = inner.backward(contract(p, (1.0, 0.0, 0.0), 2.0), None, inner.forward(contract(p, (1.0, 0.0, 0.0), 2.0)),
                          np.ones(3, np.float32), None)
    for k in inner.params:
        np.testing.assert_array_equal(grads[k].numpy(), want[k].numpy())


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="^points"):
        contract(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="^radius"):
        contract(np.zeros((3, 3)), radius=0.0)
    with pytest.raises(ValueError, match="^center"):
        contract(np.zeros((3, 3)), center=(0.0, 1.0))
    with pytest.raises(ValueError, match="^grad_out"):
        contract_backward(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="^far"):
        s_to_t(np.zeros((1, 2)), 1.0, 0.5)
    with pytest.raises(ValueError, match="^s:"):
        s_to_t(np.full((1, 2), 1.5), 0.0, 2.0)
    with pytest.raises(ValueError, match="^sigma"):
        interval_weights(-np.ones((2, 3)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="^delta"):
        interval_weights(np.ones((2, 3)), np.full((2, 3), np.inf))
    with pytest.raises(ValueError, match="^grad_w"):
        interval_weights_backward(np.ones((2, 3)), np.ones((2, 3)), np.ones((2, 2)))
    with pytest.raises(ValueError, match="^edges: expected non-decreasing"):
        resample(np.array([[0.0, 0.5, 0.2]]), np.ones((1, 2)), 4)
    with pytest.raises(ValueError, match="^padding"):
        resample(np.array([[0.0, 0.5, 1.0]]), np.ones((1, 2)), 4, padding=0.0)
    with pytest.raises(ValueError, match="^weights"):
        resample(np.array([[0.0, 0.5, 1.0]]), np.ones((1, 3)), 4)
    with pytest.raises(ValueError, match="^proposal_edges"):
        interlevel_loss(np.zeros((1, 3)), np.zeros((1, 2)), np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="^inner: expected a field on the box"):
        ContractedField(HashGridField(np.array([[-1.0] * 3, [1.0] * 3]), n_levels=1, log2_table_size=6))
