"""research.comparison: the 3DGS-Table-1-style table built from fit_splats and fit_nerf metrics."""

import json

import pytest

from research import comparison
from research.metrics import EVAL_PROTOCOL

HASH = "ab" * 32


def splats_doc(**over):
    m = {"method": "3DGS", "test_psnr": 30.123, "test_ssim": 0.95, "train_seconds": 125.0, "render_fps": 12.5,
         "ply_bytes": 2_500_000, "eval_protocol": EVAL_PROTOCOL, "dataset_hash": HASH}
    m.update(over)
    return {"experiment": "fit_splats", "device": "cpu", "metrics": m}


def nerf_doc(content_hash=HASH):
    field = {"params": 1_000_000, "bytes_per_param": 4, "train_s": 30.0,
             "eval": {"mean": {"psnr": 27.5, "ssim": 0.9, "seconds": 0.5}}}
    return {"experiment": "fit_nerf", "device": "cpu", "metrics": {
        "eval_protocol": EVAL_PROTOCOL, "dataset": {"content_hash": content_hash},
        "fields": {"grid": field, "custom": dict(field, params=7748)}}}


def write(tmp_path, name, doc):
    (tmp_path / name).mkdir(exist_ok=True)
    path = tmp_path / name / "metrics.json"
    path.write_text(json.dumps(doc))
    return path


def test_table_has_one_row_per_method(tmp_path):
    write(tmp_path, "fit_splats", splats_doc())
    write(tmp_path, "fit_nerf", nerf_doc())
    assert comparison.update_comparison(tmp_path).endswith("table.md")
    text = (tmp_path / "comparison" / "table.md").read_text()
    assert "| 3DGS | 0.950 | 30.12 | 2.1 min | 12.50 | 2.5 MB (PLY file) | cpu |" in text
    assert f"| {comparison.NERF_METHOD_NAMES['grid']} | 0.900 | 27.50 | 30 s | 2.00 | 4.0 MB (parameters) | cpu |" in text
    assert "| custom | 0.900 | 27.50 | 30 s | 2.00 | 31.0 kB (parameters) | cpu |" in text
    assert HASH[:12] in text


def test_rows_on_different_data_or_protocols_are_refused():
    rows = comparison.rows_fit_splats(splats_doc(), "a") + comparison.rows_fit_nerf(nerf_doc("cd" * 32), "b")
    with pytest.raises(ValueError, match="datasets differ"):
        comparison.comparison_table(rows)
    rows = comparison.rows_fit_splats(splats_doc(eval_protocol="linear"), "a") + comparison.rows_fit_nerf(nerf_doc(), "b")
    with pytest.raises(ValueError, match="evaluation protocols differ"):
        comparison.comparison_table(rows)


def test_missing_keys_and_unknown_experiments_are_named(tmp_path):
    doc = splats_doc()
    del doc["metrics"]["dataset_hash"]
    with pytest.raises(ValueError, match="'dataset_hash'"):
        comparison.read_rows(write(tmp_path, "fit_splats", doc))
    with pytest.raises(ValueError, match="no comparison reader"):
        comparison.read_rows(write(tmp_path, "other", {"experiment": "stereo_depth", "metrics": {}}))


def test_skipped_until_both_runs_exist(tmp_path):
    write(tmp_path, "fit_splats", splats_doc())
    assert "skipped" in comparison.update_comparison(tmp_path)
    assert not (tmp_path / "comparison").exists()


def test_update_reports_incomparable_runs_without_raising(tmp_path):
    write(tmp_path, "fit_splats", splats_doc())
    write(tmp_path, "fit_nerf", nerf_doc("cd" * 32))
    assert "not written" in comparison.update_comparison(tmp_path) and "datasets differ" in comparison.update_comparison(tmp_path)
    assert not (tmp_path / "comparison" / "table.md").exists()
