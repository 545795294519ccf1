"""research.gradcheck: passes correct VJPs, catches wrong ones, rejects float32, registry runs."""

from __future__ import annotations

import numpy as np
import pytest

import research.gradcheck as gc
from research.checks import selftest


def _inputs(seed: int, n: int = 10) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"x": rng.uniform(-1.0, 1.0, n), "y": rng.uniform(0.5, 1.5, n)}


# A function with matrix input, dict outputs: f(W, x) = {"lin": W @ x, "sq": (W**2).sum(1) * x}.
def _fm(W: np.ndarray, x: np.ndarray) -> dict[str, np.ndarray]:
    return {"lin": W @ x, "sq": (W**2).sum(axis=1) * x}


def _vjpm(inputs, cot):
    W, x = inputs["W"], inputs["x"]
    a, b = cot["lin"], cot["sq"]
    return {"W": np.outer(a, x) + 2.0 * W * (b * x)[:, None], "x": W.T @ a + b * (W**2).sum(axis=1)}


def _matrix_inputs(seed: int, n: int = 6) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"W": rng.normal(size=(n, n)), "x": rng.normal(size=n)}


# --------------------------------------------------------------------------- correct gradients pass


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_known_gradient_passes(seed):
    results = gc.check_vjp(selftest.f, selftest.vjp, _inputs(seed), seed=seed, name="known")
    assert [r.input for r in results] == ["x", "y"]
    assert all(r.passed for r in results), gc.format_table(results)
    assert all(r.n_checks == 8 + 10 for r in results)
    assert all(r.max_rel_err < 1e-7 for r in results)
    gc.assert_gradcheck(results)


@pytest.mark.parametrize("seed", [0, 1])
def test_dict_outputs_matrix_input_passes(seed):
    results = gc.check_vjp(_fm, _vjpm, _matrix_inputs(seed), seed=seed)
    gc.assert_gradcheck(results)


def test_large_input_uses_coordinate_subset():
    results = gc.check_vjp(selftest.f, selftest.vjp, _inputs(0, n=500), per_coord_limit=16, n_directions=4)
    gc.assert_gradcheck(results)
    assert all(r.n_checks == 4 + 16 for r in results)


def test_non_float_inputs_pass_through_and_wrt_subset():
    def f(x, k, scale):
        return np.sin(x[k]) * scale

    def vjp(inputs, cot):
        g = np.zeros_like(inputs["x"])
        np.add.at(g, inputs["k"], cot * np.cos(inputs["x"][inputs["k"]]) * inputs["scale"])
        return {"x": g}

    inputs = {"x": np.linspace(-1, 1, 7), "k": np.array([0, 3, 3, 6]), "scale": 2.0}
    results = gc.check_vjp(f, vjp, inputs)
    assert [r.input for r in results] == ["x"]
    gc.assert_gradcheck(results)


def test_scalar_output_and_0d_input():
    def f(a, x):
        return np.sum(a * x**3)

    def vjp(inputs, cot):
        a, x = inputs["a"], inputs["x"]
        return {"a": cot * np.sum(x**3), "x": cot * 3 * a * x**2}

    results = gc.check_vjp(f, vjp, {"a": np.array(1.3), "x": np.array([0.5, -0.2, 1.1])})
    gc.assert_gradcheck(results)


# --------------------------------------------------------------------------- wrong gradients fail


def _wrong(transform):
    def vjp(inputs, cot):
        grads = selftest.vjp(inputs, cot)
        transform(grads)
        return grads

    return vjp


def _scale_x(g):
    g["x"] = g["x"] * 1.01


def _one_coord(g):
    g["y"] = g["y"].copy()
    g["y"][3] += 1e-3


def _wrong_sign(g):
    g["y"] = -g["y"]


def _tiny_bias(g):
    g["x"] = g["x"] * (1.0 + 1e-4)


def _nan(g):
    g["x"] = g["x"].copy()
    g["x"][0] = np.nan


@pytest.mark.parametrize(
    "transform, bad_input",
    [(_scale_x, "x"), (_one_coord, "y"), (_wrong_sign, "y"), (_tiny_bias, "x"), (_nan, "x")],
    ids=["factor-1.01", "one-coordinate", "wrong-sign", "factor-1+1e-4", "nan"],
)
def test_wrong_vjp_fails(transform, bad_input):
    results = gc.check_vjp(selftest.f, _wrong(transform), _inputs(0), name="wrong")
    by_input = {r.input: r for r in results}
    assert not by_input[bad_input].passed, gc.format_table(results)
    other = "y" if bad_input == "x" else "x"
    assert by_input[other].passed
    with pytest.raises(AssertionError, match="FAIL"):
        gc.assert_gradcheck(results)


def test_missing_output_term_fails():
    """A VJP that ignores one output's cotangent (the scalar sum(x*y))."""

    def vjp(inputs, cot):
        a, b, c = cot
        return selftest.vjp(inputs, (a, b, np.zeros_like(c)))

    results = gc.check_vjp(selftest.f, vjp, _inputs(1))
    assert not any(r.passed for r in results)


def test_transposed_gradient_fails():
    def vjp(inputs, cot):
        g = _vjpm(inputs, cot)
        g["W"] = g["W"].T
        return g

    results = {r.input: r for r in gc.check_vjp(_fm, vjp, _matrix_inputs(0))}
    assert not results["W"].passed
    assert results["x"].passed


def test_single_wrong_coordinate_in_large_input_caught_by_directions():
    """n = 20000 > per_coord_limit: the coordinate subset misses index k, random directions do not."""
    n, k = 20_000, 12_345
    rng = np.random.default_rng(3)
    inputs = {"x": rng.uniform(-1, 1, n), "w": rng.uniform(0.5, 1.5, n)}

    def f(x, w):
        return np.sin(x) * w

    def vjp(inputs, cot):
        gx = cot * np.cos(inputs["x"]) * inputs["w"]
        gx[k] += 0.01  # one wrong coordinate
        return {"x": gx, "w": cot * np.sin(inputs["x"])}

    results = {r.input: r for r in gc.check_vjp(f, vjp, inputs, seed=5, per_coord_limit=64)}
    assert results["w"].passed
    assert not results["x"].passed
    assert results["x"].worst.startswith("direction"), results["x"].worst


def test_wrong_shape_gradient_raises():
    def vjp(inputs, cot):
        g = selftest.vjp(inputs, cot)
        g["x"] = g["x"][:-1]
        return g

    with pytest.raises(ValueError, match="shape"):
        gc.check_vjp(selftest.f, vjp, _inputs(0))


def test_missing_gradient_raises():
    with pytest.raises(ValueError, match="'y'"):
        gc.check_vjp(selftest.f, lambda i, c: {"x": selftest.vjp(i, c)["x"]}, _inputs(0))


# --------------------------------------------------------------------------- dtype rules


def test_rejects_float32_input():
    inputs = _inputs(0)
    inputs["y"] = inputs["y"].astype(np.float32)
    with pytest.raises(ValueError, match=r"input 'y'.*float32"):
        gc.check_vjp(selftest.f, selftest.vjp, inputs)


def test_rejects_float32_input_even_outside_wrt():
    inputs = _inputs(0)
    inputs["y"] = inputs["y"].astype(np.float32)
    with pytest.raises(ValueError, match="'y'"):
        gc.check_vjp(selftest.f, selftest.vjp, inputs, wrt=["x"])


def test_rejects_integer_wrt_input():
    with pytest.raises(ValueError, match="'k'"):
        gc.check_vjp(lambda k: k * 1.0, lambda i, c: {"k": c}, {"k": np.arange(3)}, wrt=["k"])


def test_rejects_float32_output():
    with pytest.raises(ValueError, match="float32"):
        gc.check_vjp(lambda x: (x * 2).astype(np.float32), lambda i, c: {"x": 2 * c}, {"x": np.ones(3)})


# --------------------------------------------------------------------------- tolerances


def test_per_input_overrides_are_used():
    results = {
        r.input: r
        for r in gc.check_vjp(
            selftest.f, _wrong(_tiny_bias), _inputs(0),
            eps={"x": 1e-5}, rtol={"x": 1e-3}, atol={"y": 1e-8},
        )
    }
    assert (results["x"].eps, results["x"].rtol) == (1e-5, 1e-3)
    assert (results["y"].eps, results["y"].rtol, results["y"].atol) == (gc.DEFAULT_EPS, gc.DEFAULT_RTOL, 1e-8)
    assert results["x"].passed  # a 1e-4 error is inside the loosened rtol 1e-3
    assert results["y"].passed


def test_relative_error_matches_pass_rule():
    for r in gc.check_vjp(selftest.f, _wrong(_tiny_bias), _inputs(2)):
        assert r.passed == (r.max_rel_err <= r.rtol)


# --------------------------------------------------------------------------- registry and table


def test_run_checks_selftest():
    results = gc.run_checks(["selftest"])
    assert results and all(r.name == "selftest.known_gradient" for r in results)
    gc.assert_gradcheck(results)
    assert "selftest.known_gradient" in gc.CHECKS


def test_run_checks_all_and_registered(monkeypatch):
    @gc.register_check("zz_test.good")
    def good():
        return gc.check_vjp(selftest.f, selftest.vjp, _inputs(4))

    def boom():
        raise RuntimeError("kaboom")

    monkeypatch.setitem(gc.CHECKS, "zz_test.good", good)
    monkeypatch.setitem(gc.CHECKS, "zz_test.boom", boom)
    results = gc.run_checks(["zz_test"])
    assert {r.name for r in results} == {"zz_test.good", "zz_test.boom"}
    good_rows = [r for r in results if r.name == "zz_test.good"]
    assert good_rows and all(r.passed for r in good_rows)
    (err,) = [r for r in results if r.name == "zz_test.boom"]
    assert not err.passed and "kaboom" in err.worst
    # all when names is None: on a registry cut down to three checks (the families' tests run every
    # real check already, and running all of them here took 45 s)
    small = {k: v for k, v in gc.CHECKS.items() if k.startswith(("selftest.", "zz_test."))}
    assert "selftest.known_gradient" in small and len(gc.CHECKS) > len(small)
    monkeypatch.setattr(gc, "CHECKS", small)
    assert {r.name for r in gc.run_checks()} == {"selftest.known_gradient", "zz_test.good", "zz_test.boom"}
    with pytest.raises(KeyError, match="no_such"):
        gc.run_checks(["no_such"])


def test_register_twice_raises(monkeypatch):
    monkeypatch.setitem(gc.CHECKS, "selftest.known_gradient", gc.CHECKS.get("selftest.known_gradient"))
    with pytest.raises(ValueError, match="twice"):
        gc.register_check("selftest.known_gradient")(lambda: [])


def test_format_table_and_assert():
    results = gc.check_vjp(selftest.f, _wrong(_scale_x), _inputs(0), name="demo")
    table = gc.format_table(results)
    header = table.splitlines()[0]
    for col in ("check", "input", "max abs err", "max rel err", "n", "status"):
        assert col in header
    assert "FAIL" in table and "ok" in table
    with pytest.raises(AssertionError) as info:
        gc.assert_gradcheck(results)
    assert "demo" in str(info.value) and "x" in str(info.value)
    with pytest.raises(AssertionError, match="no results"):
        gc.assert_gradcheck([])
