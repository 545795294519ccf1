"""The performance table labels every line with the sizes of its own bench row."""

from experiments.performance import _lines


def test_each_line_carries_its_own_rows_sizes():
    rows = [{"bench": "stereo.sgm", "threads": 2, "height": h, "width": w, "disparities": 64, "total_s": t,
             "ref": "cv2", "ref_total_s": t / 10, "speedup_total": 0.1}
            for h, w, t in ((256, 256, 0.05), (500, 741, 0.5))]
    lines = [line for row in rows for line in _lines(row)]
    assert [ln["sizes"] for ln in lines] == ["height=256, width=256, disparities=64",
                                             "height=500, width=741, disparities=64"]
    assert [ln["ref_s"] for ln in lines] == [0.005, 0.05]


def test_repeated_runs_merge_to_medians_with_spread_and_count_runs_per_target():
    from experiments.performance import _merge_runs, _target_status

    def run(fwd_bwd_s, speedup):
        return [{"bench": "volume.composite", "threads": 2, "rays": 65536, "samples": 128, "fwd_bwd_s": fwd_bwd_s,
                 "ref": "torch", "ref_fwd_bwd_s": fwd_bwd_s * speedup, "speedup_fwd_bwd": speedup}]

    merged = _merge_runs([run(0.050, 9.0), run(0.060, 11.0), run(0.040, 10.5)])
    assert len(merged) == 1
    row = merged[0]
    assert row["fwd_bwd_s"] == 0.050 and row["speedup_fwd_bwd"] == 10.5  # medians, key by key
    assert row["runs"]["speedup_fwd_bwd"] == [9.0, 11.0, 10.5] and row["rays"] == 65536
    (case, text, shown, status), = _target_status(row, full=True)
    assert shown == "10.5x (runs 9x to 11x)" and status == "met, met in 2 of 3 runs"
    line, = _lines(row)
    assert line["runs"]["fwd_bwd_s"] == [0.050, 0.060, 0.040]


def test_repeated_runs_that_do_not_pair_up_raise():
    import pytest

    from experiments.performance import _merge_runs

    a = [{"bench": "corr.build", "height": 46, "build_s": 0.04}]
    b = [{"bench": "corr.build", "height": 47, "build_s": 0.04}]
    with pytest.raises(ValueError, match="run rows differ"):
        _merge_runs([a, b])
    with pytest.raises(ValueError, match="different numbers of rows"):
        _merge_runs([a, a + a])


def test_both_compositing_forwards_get_their_own_read_bound_line():
    from experiments.performance import _target_status

    row = {"bench": "volume.composite", "threads": 2, "rays": 65536, "samples": 128, "fwd_s": 0.024,
           "fwd_no_factor_s": 0.014, "bound_max_s": 0.008, "fwd_over_bound_max": 3.0,
           "fwd_no_factor_over_bound_max": 1.75}
    found = {text: (shown, status) for _, text, shown, status in _target_status(row, full=True)}
    kept, = [t for t in found if t.startswith("fwd (factors kept for a backward)") and "unsigned-max" in t]
    none, = [t for t in found if t.startswith("fwd_no_factor (keep_factor=False")]
    assert found[kept] == ("3", "NOT met") and found[none] == ("1.75", "met")
    assert found[none] != found[kept]
    quick = {text: status for _, text, _, status in _target_status(row, full=False)}
    assert quick[none] == "n/a (not full size)"
    phases = [ln["phase"] for ln in _lines(row)]
    assert "fwd" in phases and "fwd_no_factor" in phases
