"""research.bench.ssim: the rows `drlab bench ssim` prints, and its PyTorch reference computes the same SSIM."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from kernels import ssim as kssim
from research.bench import ssim as bench


def test_tiny_rows_time_the_value_the_gradient_and_the_plain_route():
    rows = list(bench.cases("cpu", tiny=True))
    assert [r["bench"] for r in rows] == ["ssim.value_grad"]
    row = rows[0]
    assert (row["height"], row["width"], row["channels"]) == (32, 32, 3)
    for key in ("fwd_s", "fwd_bwd_s", "plain_fwd_bwd_s"):
        assert row[key] > 0
    assert row["speedup_fast_path"] == pytest.approx(row["plain_fwd_bwd_s"] / row["fwd_bwd_s"])
    assert not any(k.startswith("ref") for k in row)


@pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="torch (the [bench] extra) not installed")
def test_torch_reference_is_the_same_ssim_and_gradient():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (24, 20, 3)).astype(np.float32)
    y = np.clip(x + 0.1 * rng.standard_normal(x.shape), 0, 1).astype(np.float32)
    value, grad = kssim.ssim(x, y)
    run = bench._torch_fwd_bwd(x, y, threads=1)
    # float32 sums in another order (conv2d against the separable passes): a few ulps of the mean
    ref_value, ref_grad = run()
    assert ref_value == pytest.approx(value, rel=1e-5)
    np.testing.assert_allclose(ref_grad[0].numpy().transpose(1, 2, 0), grad, rtol=1e-4, atol=1e-7)


def test_compare_without_torch_names_what_is_missing(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "torch" else real(name, *a))
    row = next(bench.cases("cpu", tiny=True, compare=True))
    assert row["ref_missing"] == "torch (CPU)" and "ref_fwd_bwd_s" not in row
