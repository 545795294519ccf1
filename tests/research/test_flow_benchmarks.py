"""Flow benchmarks in: the Sintel, KITTI flow and Middlebury flow readers, their protocols, raft_flow --data.

Fixtures in each exact layout are written by tests/research/flow_fixtures.py; the readers must give
back what was written, the metrics must give hand-computed values, and raft_flow on each fixture
must write the protocol's table (its zero-flow row checked against the ground truth directly).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from flow_fixtures import H, W, kitti_pair, write_kitti, write_middlebury, write_sintel
from research import io
from research.datasets import FlowSequence, detect_flow_format, load_flow_benchmark, open_flow_benchmark
from research.datasets.flow_benchmarks import kitti_decode, kitti_encode
from research.flow.metrics import (FlowTally, angular_error, endpoint_error, kitti_metrics, kitti_outliers,
                                   middlebury_metrics, protocol_regions, sintel_metrics)
from research.flow.raft import srgb


def _u8(frames: np.ndarray) -> np.ndarray:
    """The 8-bit values a sequence's linear frames came from."""
    return np.floor(srgb(frames) * 255 + 0.5).astype(np.uint8)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("flowbench")
    return {"sintel": (root / "sintel", write_sintel(root / "sintel")),
            "kitti": (root / "kitti", write_kitti(root / "kitti")),
            "kitti2012": (root / "kitti2012", write_kitti(root / "kitti2012", year="2012")),
            "kitti_objects": (root / "kitti_objects", write_kitti(root / "kitti_objects", objects=True)),
            "middlebury": (root / "middlebury", write_middlebury(root / "middlebury"))}


# --------------------------------------------------------------------------- readers


@pytest.mark.parametrize("pass_", ["clean", "final"])
def test_sintel_round_trip(folders, pass_):
    root, written = folders["sintel"]
    bench = open_flow_benchmark(root, pass_=pass_)
    assert bench.format == "sintel" and bench.pass_ == pass_ and f"({pass_} pass)" in bench.dataset
    assert [i.name for i in bench.items] == ["alley_1", "cave_2"] and bench.pairs == 3
    for item in bench.items:
        seq = bench.load(item)
        rec = written[item.name]
        assert isinstance(seq, FlowSequence) and seq.name == item.name and seq.cameras == [] and seq.depth is None
        assert seq.frames.shape == (len(rec[pass_]), H, W, 4) and np.all(seq.frames[..., 3] == 1)
        np.testing.assert_array_equal(_u8(seq.frames[..., :3]), np.stack(rec[pass_]))
        np.testing.assert_array_equal(seq.flow, np.stack(rec["flow"]))
        occ, inv = np.stack(rec["occluded"]), np.stack(rec["invalid"])
        np.testing.assert_array_equal(seq.invalid, inv)
        np.testing.assert_array_equal(seq.occluded, occ & ~inv)
        np.testing.assert_array_equal(seq.valid, ~occ & ~inv)
        np.testing.assert_array_equal(seq.valid_all, ~inv)


def test_sintel_without_invalid_folder(tmp_path):
    write_sintel(tmp_path, {"market_2": 2}, invalid=False)
    (seq,) = load_flow_benchmark(tmp_path)
    assert not seq.invalid.any() and seq.valid_all.all()


@pytest.mark.parametrize("key, year, image_dir", [("kitti", "2015", "image_2"), ("kitti2012", "2012", "colored_0")])
def test_kitti_round_trip(folders, key, year, image_dir):
    root, written = folders[key]
    bench = open_flow_benchmark(root / "training")  # the training folder itself is accepted too
    assert bench.format == "kitti" and bench.dataset == f"KITTI {year} flow training ({image_dir})"
    assert [i.name for i in bench.items] == ["000000", "000001"]
    for item in bench.items:
        seq, rec = bench.load(item), written[item.name]
        np.testing.assert_array_equal(_u8(seq.frames[..., :3]), np.stack(rec["frames"]))
        np.testing.assert_array_equal(seq.valid_all[0], rec["known_occ"])
        np.testing.assert_array_equal(seq.valid[0], rec["known_noc"])
        np.testing.assert_array_equal(seq.occluded[0], rec["known_occ"] & ~rec["known_noc"])
        np.testing.assert_array_equal(seq.flow[0][rec["known_occ"]], rec["flow"][rec["known_occ"]])  # 1/64 px exact
        assert np.all(seq.flow[0][~rec["known_occ"]] == 0)


def test_kitti_codes_by_hand():
    codes = np.array([[[32768, 32768, 1], [32768 + 64, 32768 - 128, 1], [40000, 1, 0]]], np.uint16)
    flow, known = kitti_decode(codes)
    np.testing.assert_array_equal(flow, [[[0, 0], [1, -2], [0, 0]]])  # unknown: flow 0
    np.testing.assert_array_equal(known, [[True, True, False]])
    np.testing.assert_array_equal(kitti_encode(flow, known), [[[32768, 32768, 1], [32832, 32640, 1],
                                                               [32768, 32768, 0]]])
    # Any B > 0 is known, as the KITTI devkit's readFlowField tests it (KITTI itself writes 1).
    flow7, known7 = kitti_decode(np.array([[[32768 + 32, 32768, 7], [32768, 32768, 65535]]], np.uint16))
    np.testing.assert_array_equal(known7, [[True, True]])
    np.testing.assert_array_equal(flow7, [[[0.5, 0], [0, 0]]])
    rec = kitti_pair(7)
    f2, k2 = kitti_decode(kitti_encode(rec["flow"], rec["known_occ"]))
    np.testing.assert_array_equal(k2, rec["known_occ"])
    np.testing.assert_array_equal(f2[k2], rec["flow"][k2])


def test_kitti_flow_png_is_16_bit_rgb_on_disk(folders):
    root, _ = folders["kitti"]
    codes = io.read_png_u16(root / "training" / "flow_occ" / "000000_10.png")
    assert codes.dtype == np.uint16 and codes.shape == (H, W, 3) and set(np.unique(codes[..., 2])) <= {0, 1}


def test_middlebury_round_trip(folders):
    root, written = folders["middlebury"]
    bench = open_flow_benchmark(root)
    assert bench.format == "middlebury" and [i.name for i in bench.items] == ["Grove2", "Venus"]
    for item in bench.items:
        seq, rec = bench.load(item), written[item.name]
        frames = _u8(seq.frames[..., :3])
        want = np.stack(rec["frames"])
        if want.ndim == 3:  # the grey sequence comes back as three equal channels
            want = np.repeat(want[..., None], 3, axis=3)
        np.testing.assert_array_equal(frames, want)
        np.testing.assert_array_equal(seq.valid[0], ~rec["unknown"])
        np.testing.assert_array_equal(seq.flow[0][~rec["unknown"]], rec["flow"][~rec["unknown"]])
        assert np.all(seq.flow[0][rec["unknown"]] == 0)


def test_detect_format(folders, tmp_path):
    assert detect_flow_format(folders["sintel"][0]) == "sintel"
    assert detect_flow_format(folders["kitti"][0]) == "kitti"
    assert detect_flow_format(folders["kitti2012"][0] / "training") == "kitti"
    assert detect_flow_format(folders["middlebury"][0]) == "middlebury"
    assert detect_flow_format(tmp_path) is None  # e.g. drlab's dataset cache root


# --------------------------------------------------------------------------- metrics, by hand


def test_epe_and_angular_error_by_hand():
    flow = np.array([[[3.0, 4.0], [1.0, 0.0], [1.0, 0.0], [2.0, 2.0]]])
    gt = np.array([[[0.0, 0.0], [0.0, 0.0], [0.0, 1.0], [2.0, 2.0]]])
    np.testing.assert_allclose(endpoint_error(flow, gt), [[5.0, 1.0, math.sqrt(2), 0.0]])
    # (1,0,1).(0,0,1) = 1 over sqrt(2) * 1: 45 deg; (1,0,1).(0,1,1) = 1 over sqrt(2) sqrt(2): 60 deg
    np.testing.assert_allclose(angular_error(flow, gt)[0, 1:], [45.0, 60.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(angular_error(flow, gt)[0, 0], math.degrees(math.acos(1 / math.sqrt(26))))


def test_kitti_outlier_rule_by_hand():
    gt = np.array([[[100.0, 0.0], [100.0, 0.0], [0.0, 0.0], [0.0, 0.0]]])
    epe = np.array([[4.0, 6.0, 3.5, 3.0]])  # 4 < 5% of 100; 6 > both; 3.5 > 3 and > 0; 3 is not > 3
    np.testing.assert_array_equal(kitti_outliers(epe, gt), [[False, True, True, False]])


def test_sintel_metrics_by_hand():
    gt = np.zeros((2, 2, 2))
    flow = np.array([[[1.0, 0.0], [2.0, 0.0]], [[4.0, 0.0], [8.0, 0.0]]])  # EPE 1 2 / 4 8
    occluded = np.array([[False, True], [False, False]])
    invalid = np.array([[False, False], [False, True]])
    m = sintel_metrics(flow, gt, occluded, invalid)
    assert m["epe_all"] == pytest.approx(7 / 3) and m["epe_matched"] == pytest.approx(2.5)
    assert m["epe_unmatched"] == pytest.approx(2.0)
    assert (m["pixels_all"], m["pixels_matched"], m["pixels_unmatched"]) == (3, 2, 1)
    none = sintel_metrics(flow, gt, np.zeros((2, 2), bool))
    assert none["epe_unmatched"] is None and none["pixels_unmatched"] == 0 and none["epe_all"] == pytest.approx(3.75)


def _kitti_hand_case() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(flow, gt, noc, occ) of four pixels whose KITTI outliers are no, yes, no, yes."""
    gt = np.zeros((1, 4, 2))
    gt[0, 0] = (100.0, 0.0)
    flow = gt + np.array([[[4.0, 0.0], [0.0, 3.5], [0.0, 1.0], [10.0, 0.0]]])
    return flow, gt, np.array([[True, True, True, False]]), np.ones((1, 4), bool)


def test_kitti_metrics_by_hand_and_pooled_over_pixels():
    flow, gt, noc, occ = _kitti_hand_case()
    m = kitti_metrics(flow, gt, noc, occ)
    assert m["fl_noc"] == pytest.approx(100 / 3) and m["fl_occ"] == pytest.approx(50.0)
    assert m["epe_noc"] == pytest.approx(8.5 / 3) and m["epe_occ"] == pytest.approx(18.5 / 4)
    assert m["out3_noc"] == pytest.approx(200 / 3) and m["out3_occ"] == pytest.approx(75.0)  # EPE > 3 px alone
    # Pooled over pixels, not averaged over pairs: 1 of 3 and 1 of 1 noc outliers -> 2 of 4 = 50%, not 66.7%.
    tally = FlowTally()
    tally.add(flow, gt, {"noc": noc, "occ": occ})
    tally.add(np.array([[[5.0, 0.0]]]), np.zeros((1, 1, 2)), {"noc": np.ones((1, 1), bool),
                                                              "occ": np.ones((1, 1), bool)})
    s = tally.summary()
    assert s["noc"]["fl_percent"] == pytest.approx(50.0) and s["noc"]["pixels"] == 4
    assert s["occ"]["fl_percent"] == pytest.approx(60.0)


def test_kitti_metrics_split_by_the_object_map():
    """Fl-bg / Fl-fg: the noc and occ regions split by obj_map's objects, each pooled over its own pixels."""
    flow, gt, noc, occ = _kitti_hand_case()
    fg = np.array([[False, True, False, True]])
    m = kitti_metrics(flow, gt, noc, occ, fg)
    assert m["fl_noc_bg"] == 0.0 and m["fl_noc_fg"] == 100.0 and m["pixels_noc_fg"] == 1
    assert m["fl_occ_bg"] == 0.0 and m["fl_occ_fg"] == 100.0 and m["pixels_occ_bg"] == 2
    assert m["epe_occ_fg"] == pytest.approx((3.5 + 10.0) / 2)
    assert m["fl_noc"] == pytest.approx(100 / 3) and "fl_noc_bg" not in kitti_metrics(flow, gt, noc, occ)


def test_kitti_object_map_read_as_the_foreground(folders):
    root, written = folders["kitti_objects"]
    bench = open_flow_benchmark(root)
    assert "Fl-bg and Fl-fg" in bench.protocol and all(i.objects for i in bench.items)
    for item in bench.items:
        seq = bench.load(item)
        np.testing.assert_array_equal(seq.foreground[0], written[item.name]["foreground"])
        r = protocol_regions("kitti", seq, 0)
        np.testing.assert_array_equal(r["noc_fg"], written[item.name]["known_noc"] & written[item.name]["foreground"])
        np.testing.assert_array_equal(r["occ_bg"] | r["occ_fg"], r["occ"])
    assert load_flow_benchmark(folders["kitti"][0])[0].foreground is None


def test_middlebury_metrics_by_hand():
    gt = np.array([[[0.0, 0.0], [0.0, 1.0], [5.0, 5.0]]])
    flow = np.array([[[1.0, 0.0], [1.0, 0.0], [0.0, 0.0]]])
    m = middlebury_metrics(flow, gt, np.array([[True, True, False]]))
    assert m["epe"] == pytest.approx((1 + math.sqrt(2)) / 2) and m["ae_deg"] == pytest.approx(52.5)
    assert m["pixels"] == 2


def test_protocol_regions_of_read_sequences(folders):
    root, written = folders["sintel"]
    seq = load_flow_benchmark(root)[0]
    r = protocol_regions("sintel", seq, 0)
    occ, inv = written["alley_1"]["occluded"][0], written["alley_1"]["invalid"][0]
    np.testing.assert_array_equal(r["all"], ~inv)
    np.testing.assert_array_equal(r["matched"], ~inv & ~occ)
    np.testing.assert_array_equal(r["unmatched"], ~inv & occ)
    kseq = load_flow_benchmark(folders["kitti"][0])[0]
    k = protocol_regions("kitti", kseq, 0)
    np.testing.assert_array_equal(k["noc"], written_kitti := folders["kitti"][1]["000000"]["known_noc"])
    assert k["occ"].sum() > written_kitti.sum()
    with pytest.raises(ValueError, match="^fmt: expected"):
        protocol_regions("eth3d", seq, 0)


_Z = np.zeros((4, 5, 2))
_NAN = np.where(np.arange(40).reshape(4, 5, 2) == 3, np.nan, 0.0)


@pytest.mark.parametrize("call, message", [
    (lambda: endpoint_error(np.zeros((4, 5)), np.zeros((4, 5))), r"^flow: expected shape \(H, W, 2\)"),
    (lambda: angular_error(_Z, np.zeros((4, 6, 2))), r"^gt: expected the shape of flow"),
    (lambda: endpoint_error(_NAN, _Z), r"^flow: expected finite values, got 1 NaN or infinite"),
    (lambda: FlowTally().add(_Z, _Z, {"all": np.ones((4, 5))}), r"^regions\['all'\]: expected a bool mask"),
    (lambda: FlowTally().add(_Z, _Z, {"all": np.ones((4, 6), bool)}), r"^regions\['all'\]: expected a bool mask"),
    (lambda: sintel_metrics(_Z, _Z, np.zeros((4, 6), bool)), r"^occluded: expected shape"),
    (lambda: kitti_metrics(_Z, _Z, np.ones((4, 5), bool), np.ones((3, 5), bool)), r"^valid_occ: expected shape"),
    (lambda: middlebury_metrics(_Z, _Z, np.ones((5, 4), bool)), r"^valid: expected shape"),
])
def test_flow_metrics_bad_inputs_name_the_argument(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# --------------------------------------------------------------------------- raft_flow --data


@pytest.mark.parametrize("key, extra, dataset, columns", [
    ("sintel", ["--pass", "final"], "MPI-Sintel training (final pass)", ["EPE all", "EPE matched", "EPE unmatched"]),
    ("kitti", ["--format", "kitti"], "KITTI 2015 flow training (image_2)",
     ["Fl-all noc %", "Fl-all occ %", "EPE noc", "EPE occ"]),
    ("kitti_objects", [], "KITTI 2015 flow training (image_2)",
     ["Fl-all noc %", "Fl-all occ %", "Fl-bg noc %", "Fl-fg noc %", "Fl-bg occ %", "Fl-fg occ %", "EPE noc"]),
    ("kitti2012", [], "KITTI 2012 flow training (colored_0)",
     ["Fl-all noc %", "Fl-all occ %", "Out-Noc (> 3 px) %", "Out-All (> 3 px) %", "EPE noc", "EPE occ"]),
    ("middlebury", [], "Middlebury flow (other-data, other-gt-flow)", ["EPE", "AE (deg)"]),
])
def test_raft_flow_on_benchmark_folders(folders, tmp_path, key, extra, dataset, columns):
    from experiments.raft_flow import main

    root, written = folders[key]
    out = tmp_path / "out"
    assert main(["--quick", "--no-progress", "--data", str(root), "--out", str(out), *extra]) == 0
    table = (out / "table.md").read_text()
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    assert f"Dataset: {dataset}" in table and "Protocol: " in table and all(c in table for c in columns)
    bench = metrics["benchmark"]
    assert bench["format"] == key.removesuffix("2012").removesuffix("_objects") and bench["dataset"] == dataset
    assert bench["pairs_evaluated"] == len(written)  # quick: the first pair of each sequence
    methods = metrics["methods"]
    assert set(methods) == {"CorrFlow (L=4, r=4)", "C2F correlation flow (default)", "pyramidal LK (4 levels, 9x9)",
                            "OpenCV Farneback", "OpenCV DIS (medium)", "zero flow"}
    # Zero flow's error is |gt| over each region: computed here from what the fixture wrote.
    zero = methods["zero flow"]
    if key == "sintel":
        mags = [(np.linalg.norm(r["flow"][0], axis=-1), r["occluded"][0], r["invalid"][0]) for r in written.values()]
        all_ = np.concatenate([m[~inv] for m, _, inv in mags])
        unm = np.concatenate([m[~inv & occ] for m, occ, inv in mags])
        assert zero["pooled"]["all"]["epe"] == pytest.approx(all_.mean(), rel=1e-9)
        assert zero["pooled"]["unmatched"]["epe"] == pytest.approx(unm.mean(), rel=1e-9)
        assert "Per sequence" in table and "alley_1" in table
    elif key.startswith("kitti"):
        noc = np.concatenate([np.linalg.norm(r["flow"], axis=-1)[r["known_noc"]] for r in written.values()])
        assert zero["pooled"]["noc"]["epe"] == pytest.approx(noc.mean(), rel=1e-6)
        assert zero["pooled"]["noc"]["fl_percent"] == pytest.approx(100 * (noc > 3).mean())
        assert zero["pooled"]["noc"]["out3_percent"] == pytest.approx(100 * (noc > 3).mean())
        assert ("Out-Noc" in table) == (key == "kitti2012") and ("Fl-fg" in table) == (key == "kitti_objects")
        if key == "kitti_objects":
            fg = np.concatenate([np.linalg.norm(r["flow"], axis=-1)[r["known_occ"] & r["foreground"]]
                                 for r in written.values()])
            assert zero["pooled"]["occ_fg"]["fl_percent"] == pytest.approx(100 * (fg > 3).mean())
    else:
        means = [np.linalg.norm(r["flow"], axis=-1)[~r["unknown"]].mean() for r in written.values()]
        assert zero["sequence_mean"]["epe"] == pytest.approx(np.mean(means), rel=1e-6)
        assert zero["sequence_mean"]["ae_deg"] > 0
    for entry in methods.values():
        for region in entry["pooled"].values():
            assert region["pixels"] > 0 and math.isfinite(region["epe"]) and region["epe"] >= 0


def test_raft_flow_uses_the_onthefly_lookup_above_the_memory_budget(folders, tmp_path, monkeypatch):
    """With a zero budget the on-the-fly lookup runs instead of the dense pyramid, says so, and scores the same."""
    import experiments.raft_flow as rf

    root, _ = folders["middlebury"]
    runs = {}
    for name, budget in (("dense", rf.MEMORY_BUDGET_MIB), ("onthefly", 0)):
        monkeypatch.setattr(rf, "MEMORY_BUDGET_MIB", budget)
        out = tmp_path / name
        assert rf.main(["--smoke", "--no-progress", "--data", str(root), "--out", str(out)]) == 0
        runs[name] = json.loads((out / "metrics.json").read_text())["metrics"]
        assert runs[name]["lookup"] == (["dense pyramid"] if name == "dense" else ["on the fly"])
        assert ("on the fly" in (out / "table.md").read_text()) == (name == "onthefly")
    ours = "CorrFlow (L=4, r=4)"
    dense, onthefly = (runs[n]["methods"][ours]["pooled"]["all"]["epe"] for n in ("dense", "onthefly"))
    # The two paths sum the same products in another order (float32): their flows differ by ~1e-4 px at most.
    assert onthefly == pytest.approx(dense, abs=1e-3)
