"""docs/kernels.md's walkthrough on a toy family (tests/research/toy_family.py: y = a x^2 and its backward).

The toy family is registered with research.registry's one call, `register_family`, inside
`registry.temporary_families()` and with a private copy of research.gradcheck.CHECKS, so it is
registered for one test only; the machinery then finds it by module name, as it finds every family:
`drlab gradcheck`, the oracle cases (research.oracles.cases, experiments/oracle_conformance.py) and
`drlab bench`.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import sys

import numpy as np
import pytest
import warp as wp

from kernels import fast_paths
from research import registry

TOY = "toy_family"  # the module (tests/research is on sys.path under pytest)


def _register_toy() -> registry.Family:
    return registry.register_family("toy", "y = a x^2, docs/kernels.md's toy family", kernels=TOY, reference=TOY,
                                    checks=TOY, oracle_cases=TOY, bench=TOY)


@pytest.fixture
def toy(monkeypatch):
    """The toy family registered for this test; yields a function that imports its module."""
    import research.gradcheck as gc

    gc.load_checks()  # the real families' checks, into the real CHECKS (their modules import once)
    monkeypatch.setattr(gc, "CHECKS", dict(gc.CHECKS))  # the toy's check leaves with the test
    sys.modules.pop(TOY, None)  # imported afresh, so its import registers its check into the copy
    with registry.temporary_families():
        _register_toy()
        yield lambda: importlib.import_module(registry.FAMILIES["toy"].kernels)
    sys.modules.pop(TOY, None)


def test_registration_is_lazy_and_temporary():
    sys.modules.pop(TOY, None)
    with registry.temporary_families():
        fam = _register_toy()
        assert registry.FAMILIES["toy"] is fam
        for part in registry.PARTS:
            assert registry.family_modules(part)["toy"] == TOY
        assert TOY not in sys.modules  # registered by name: nothing imported
        with pytest.raises(ValueError, match="registered twice"):
            _register_toy()
    assert "toy" not in registry.FAMILIES
    with pytest.raises(ValueError, match="part"):
        registry.family_modules("oracle")


def test_every_registered_family_names_modules_that_exist():
    assert registry.FAMILIES
    for fam in registry.FAMILIES.values():
        for part in registry.PARTS:
            module = getattr(fam, part)
            if module is not None:
                assert importlib.util.find_spec(module) is not None, f"{fam.name}.{part}: no module {module}"


@pytest.mark.usefixtures("warp_device")
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_forward_matches_the_reference(toy, dtype):
    mod = toy()
    rng = np.random.default_rng(1)
    x, a = rng.normal(size=50).astype(dtype), rng.uniform(0.5, 1.5, 50).astype(dtype)
    y = mod.square(x, a)
    assert isinstance(y, np.ndarray) and y.dtype == dtype
    tol = 1e-6 if dtype == np.float32 else 1e-15
    np.testing.assert_allclose(y, mod.square_reference(x, a), rtol=tol, atol=0)
    yw = mod.square(wp.array(x), wp.array(a))  # wp.array in -> wp.array out
    assert isinstance(yw, wp.array) and np.array_equal(yw.numpy(), y)
    with pytest.raises(ValueError, match="^a: "):
        mod.square(x, a[:-1])


@pytest.mark.cpu_fast_path
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fast_path_is_the_plain_kernel_bit_for_bit(toy, monkeypatch, dtype):
    mod = toy()
    rng = np.random.default_rng(2)
    x, a = rng.normal(size=1000).astype(dtype), rng.uniform(0.5, 1.5, 1000).astype(dtype)
    calls = []
    fast = mod._square_cpu
    monkeypatch.setattr(mod, "_square_cpu", lambda *args: calls.append(1) or fast(*args))
    y_fast = mod.square(x, a)
    assert calls, "the fast path did not run"

    def refuse(*args):
        raise AssertionError("the fast path ran with the switch off")

    monkeypatch.setattr(mod, "_square_cpu", refuse)
    with fast_paths.disabled():
        y_plain = mod.square(x, a)
    assert np.array_equal(y_fast, y_plain)


def test_drlab_gradcheck_finds_the_family_and_passes(toy, capsys):
    from research import cli
    from research.gradcheck import run_checks

    assert cli.main(["gradcheck", "toy"]) == 0
    assert "toy.square" in capsys.readouterr().out
    results = run_checks(["toy"])
    assert len(results) == 6 and all(r.passed for r in results)  # x and a, three seeds, at rtol 1e-6


def test_a_wrong_backward_is_caught(toy, monkeypatch, capsys):
    from research import cli
    from research.gradcheck import run_checks

    mod = toy()

    def forgets_the_two(x, a, grad, device=None):  # d(a x^2)/dx written as a x
        return {"x": a * x * grad, "a": x * x * grad}

    monkeypatch.setattr(mod, "square_backward", forgets_the_two)
    results = run_checks(["toy"])
    assert {r.input for r in results if not r.passed} == {"x"}
    assert min(r.max_rel_err for r in results if r.input == "x") > 0.1  # off by far more than rounding
    assert all(r.passed for r in results if r.input == "a")
    assert cli.main(["gradcheck", "toy"]) == 1
    assert "FAIL" in capsys.readouterr().out


def _oracle_or_skip():
    from research.oracles import OracleUnavailable, backend

    try:
        backend(np.float64)
    except OracleUnavailable as exc:
        pytest.skip(str(exc))


def test_the_oracle_cases_include_the_family_and_agree(toy):
    _oracle_or_skip()
    from research.oracles.cases import compare, registered_cases

    assert "toy" in [fc.family for fc in registered_cases()]
    (fc,) = registered_cases(["toy"])
    assert [c.name for c in fc.cases] == ["toy square"]
    entry, has_vjp = compare("toy", fc.cases[0], fc.sizes["smoke"], fc.sizes["smoke"], seed=0)
    assert has_vjp and entry["size"] == "200 elements"
    assert entry["float64"]["fwd_rel"] <= 1e-15 and entry["float64"]["vjp_rel"] <= 1e-15
    assert entry["float32"]["fwd_rel"] < 1e-6 and entry["float32 vs oracle64"]["vjp_rel"] < 1e-6


@pytest.mark.timeout(300)
def test_oracle_conformance_runs_the_family(toy, tmp_path):
    _oracle_or_skip()
    from experiments import oracle_conformance

    out = tmp_path / "oc"
    assert oracle_conformance.main(["--smoke", "--no-progress", "--out", str(out)]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["metrics"]["cases"]["toy square"]["family"] == "toy"
    assert doc["config"]["sizes"]["toy_n"] == 200
    assert "toy square" in (out / "table.md").read_text()


def test_drlab_bench_finds_the_family(toy, capsys):
    from research import cli
    from research.bench import run_bench

    (row,) = run_bench(["toy"], "cpu", quick=True, tiny=True)
    assert row["bench"] == "toy.square" and row["n"] == 1000 and row["fwd_s"] > 0 and row["fwd_bwd_s"] > 0
    capsys.readouterr()
    assert cli.main(["bench", "toy", "--json", "--quick"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert [r["bench"] for r in rows] == ["toy.square"] and rows[0]["n"] == 100_000
