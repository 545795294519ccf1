"""research.bench.corr: the --compare keys (PyTorch reference when importable, else `ref_missing`)."""

from __future__ import annotations

import importlib.util

import pytest

from research.bench import corr as bench


def test_tiny_rows_without_compare_have_no_reference_keys():
    rows = list(bench.cases("cpu", tiny=True))
    assert [r["bench"] for r in rows] == ["corr.build", "corr.lookup", "corr.lookup_onthefly",
                                          "corr.lookup_onthefly_float16"]
    for r in rows:
        assert not any(k.startswith("ref") or k.startswith("speedup") for k in r)
    otf, otf16 = rows[2], rows[3]
    assert otf["max_abs_diff"] < 1e-5 and otf["ratio_to_dense_fwd"] > 0
    assert otf["memory_ratio"] == pytest.approx(rows[1]["bytes"] / otf["bytes"])
    assert (otf["feature_dtype"], otf16["feature_dtype"]) == ("float32", "float16")
    assert "fwd_bwd_s" in otf and "fwd_bwd_s" not in otf16  # forward-only
    assert otf16["bytes"] == otf["bytes"] // 2  # 16 channels: no padding, 2 bytes a value instead of 4
    assert otf16["memory_ratio"] == pytest.approx(2 * otf["memory_ratio"])
    # float16 features: relative error ~2^-11 a value, ~1e-3 of the correlation's scale at most
    assert 0 < otf16["rel_diff_float32"] < 2e-3 and otf16["max_abs_diff_float32"] > 0


def test_tiny_rows_with_compare():
    rows = list(bench.cases("cpu", tiny=True, compare=True))
    if importlib.util.find_spec("torch") is None:
        assert all(r["ref_missing"] == "torch (CPU)" for r in rows)
        return
    build, dense, otf, otf16 = rows
    assert build["ref"].startswith("torch.matmul") and build["speedup_build"] > 0
    for r in (dense, otf, otf16):
        assert r["ref"].startswith("torch.nn.functional.grid_sample")
        assert r["ref_max_abs_diff"] < 1e-4  # the same samples: float32 rounding only
        assert r["speedup_fwd"] == pytest.approx(r["ref_fwd_s"] / r["fwd_s"])
