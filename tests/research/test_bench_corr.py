"""research.bench.corr: the --compare keys (PyTorch reference when importable, else `ref_missing`)."""

from __future__ import annotations

import importlib.util

import pytest

from research.bench import corr as bench


def test_tiny_rows_without_compare_have_no_reference_keys():
    rows = list(bench.cases("cpu", tiny=True))
    assert [r["bench"] for r in rows] == ["corr.build", "corr.lookup", "corr.lookup_onthefly"]
    for r in rows:
        assert not any(k.startswith("ref") or k.startswith("speedup") for k in r)
    otf = rows[2]
    assert otf["max_abs_diff"] < 1e-5 and otf["ratio_to_dense_fwd"] > 0
    assert otf["memory_ratio"] == pytest.approx(rows[1]["bytes"] / otf["bytes"])


def test_tiny_rows_with_compare():
    rows = list(bench.cases("cpu", tiny=True, compare=True))
    if importlib.util.find_spec("torch") is None:
        assert all(r["ref_missing"] == "torch (CPU)" for r in rows)
        return
    build, dense, otf = rows
    assert build["ref"].startswith("torch.matmul") and build["speedup_build"] > 0
    for r in (dense, otf):
        assert r["ref"].startswith("torch.nn.functional.grid_sample")
        assert r["ref_max_abs_diff"] < 1e-4  # the same samples: float32 rounding only
        assert r["speedup_fwd"] == pytest.approx(r["ref_fwd_s"] / r["fwd_s"])
