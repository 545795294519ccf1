"""kernels.optim.Adam against a plain NumPy Adam (PyTorch's update), and its bad-input errors."""

import numpy as np
import pytest
import warp as wp

from kernels.optim import Adam


def numpy_adam(p, grads, lr, b1=0.9, b2=0.999, eps=1e-8):
    m = np.zeros_like(p)
    v = np.zeros_like(p)
    for t, g in enumerate(grads, start=1):
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        p = p - lr * (m / (1 - b1**t)) / (np.sqrt(v / (1 - b2**t)) + eps)
    return p


# The float32 tolerance covers float32 rounding of five steps (the reference runs in float32 too).
@pytest.mark.parametrize("dtype, rtol, atol", [(np.float64, 1e-12, 1e-14), (np.float32, 1e-5, 1e-6)])
@pytest.mark.parametrize("kind", ["numpy", "warp"])
@pytest.mark.usefixtures("warp_device")
def test_adam_matches_numpy(dtype, rtol, atol, kind):
    rng = np.random.default_rng(0)
    p0 = rng.normal(size=(300, 3)).astype(dtype)
    grads = [rng.normal(size=p0.shape).astype(dtype) for _ in range(5)]
    p = p0.copy() if kind == "numpy" else wp.array(p0)
    opt = Adam({"x": p}, lr=0.01)
    for g in grads:
        opt.step({"x": g if kind == "numpy" else wp.array(g)})
    got = p if kind == "numpy" else p.numpy()
    np.testing.assert_allclose(got, numpy_adam(p0, grads, 0.01), rtol=rtol, atol=atol)
    assert opt.t == {"x": 5}


def test_select_append_reset_and_per_group_steps():
    rng = np.random.default_rng(1)
    params = {"a": rng.normal(size=(4, 2)), "b": rng.normal(size=4)}
    opt = Adam(params, lr={"a": 0.1, "b": 0.2})
    opt.step({"a": np.ones((4, 2)), "b": np.ones(4)})
    keep = np.array([True, False, True, True])
    opt.select(keep)
    opt.append(2)
    assert opt.m["a"].shape == (5, 2) and np.all(opt.m["a"][3:] == 0) and np.all(opt.m["a"][:3] != 0)
    new = {"a": np.zeros((5, 2)), "b": np.zeros(5)}
    opt.step({"a": np.ones((5, 2)), "b": np.ones(5)}, params=new)
    assert opt.params["a"] is new["a"] and opt.t == {"a": 2, "b": 2}
    opt.reset("b")
    assert not opt.v["b"].any()


def test_bad_inputs_name_the_argument():
    p = np.zeros(3)
    with pytest.raises(ValueError, match="lr\\['x'\\]: expected a finite non-negative number"):
        Adam({"x": p}, lr=-1.0)
    with pytest.raises(ValueError, match="betas"):
        Adam({"x": p}, betas=(1.0, 0.9))
    opt = Adam({"x": p})
    with pytest.raises(ValueError, match="grads: missing gradients for \\['x'\\]"):
        opt.step({})
    with pytest.raises(ValueError, match="grads\\['x'\\]: expected shape \\(3,\\)"):
        opt.step({"x": np.zeros(4)})
    with pytest.raises(ValueError, match="grads\\['x'\\]: expected dtype float64"):
        opt.step({"x": np.zeros(3, np.float32)})
    assert opt.t == {"x": 0} and not p.any()  # nothing was updated


def test_more_bad_inputs_name_the_argument():
    p = np.zeros(3)
    with pytest.raises(ValueError, match="params: expected at least one parameter group"):
        Adam({})
    with pytest.raises(ValueError, match="eps: expected a finite non-negative number"):
        Adam({"x": p}, eps=-1.0)
    with pytest.raises(ValueError, match="lr: expected one rate per parameter"):
        Adam({"x": p}, lr={"y": 1e-3})
    with pytest.raises(ValueError, match="params\\['x'\\]: expected a C-contiguous NumPy array"):
        Adam({"x": np.zeros((3, 2))[:, 0]})
    opt = Adam({"x": p})
    with pytest.raises(ValueError, match="params: expected the groups \\['x'\\]"):
        opt.step({"x": np.zeros(3)}, params={"y": np.zeros(3)})
    with pytest.raises(ValueError, match="n: expected an integer >= 0"):
        opt.append(-1)
    with pytest.raises(ValueError, match="name: expected one of \\['x'\\]"):
        opt.reset("y")


def test_adam_float32_is_the_elementwise_float32_update_bit_for_bit():
    # 70001 elements: many runs of BLOCK elements split over the launch threads and a short last run;
    # each element's update is the float32 arithmetic of the module docstring, in its order.
    rng = np.random.default_rng(5)
    p0 = rng.normal(size=70001).astype(np.float32)
    grads = [rng.normal(size=p0.shape).astype(np.float32) for _ in range(3)]
    p = wp.array(p0)
    opt = Adam({"x": p}, lr=0.01, betas=(0.9, 0.99), eps=1e-15)
    f = np.float32
    b1, b2, one, lr, eps = f(0.9), f(0.99), f(1.0), f(0.01), f(1e-15)
    ref, m, v = p0.copy(), np.zeros_like(p0), np.zeros_like(p0)
    for t, g in enumerate(grads, start=1):
        opt.step({"x": wp.array(g)})
        m = b1 * m + (one - b1) * g
        v = b2 * v + (one - b2) * g * g
        ref = ref - lr * (m / f(1.0 - 0.9**t)) / (np.sqrt(v / f(1.0 - 0.99**t)) + eps)
    np.testing.assert_array_equal(p.numpy(), ref)
