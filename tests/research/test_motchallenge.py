"""research.tracking.motchallenge and HOTA: reader round trips, the MOTChallenge preprocessing, and
HOTA / DetA / AssA / LocA against the `trackeval` package (a test-only dependency) on sequence
folders the tests write in the benchmark's layout, evaluated by trackeval's MotChallenge2DBox.
"""

from __future__ import annotations

import numpy as np
import pytest
from mot_fixtures import CLASSES, tracker_output, write_sequence
from mot_fixtures import fmt as mot_fmt

from research.tracking import motchallenge as mc
from research.tracking.metrics import HOTA_ALPHAS, HOTACounts, evaluate_sequence, hota_sequence


def test_reader_round_trip(tmp_path):
    seq_dir, gt, dets = write_sequence(tmp_path, n_frames=12, seed=1)
    seq = mc.load_sequence(seq_dir)
    assert seq.info == mc.SeqInfo("MOT17-02-FRCNN", "img1", 30.0, 12, 320, 240, ".jpg")
    assert seq.benchmark == "MOT17" and seq.n_frames == 12
    for t in range(12):
        d = dets[dets[:, 0] == t + 1]
        want = np.stack([d[:, 2], d[:, 3], d[:, 2] + d[:, 4], d[:, 3] + d[:, 5], d[:, 6]], axis=1)
        np.testing.assert_array_equal(seq.dets[t], want)  # the sums the evaluation does, bit for bit
        g = gt[gt[:, 0] == t + 1]
        np.testing.assert_array_equal(seq.gt.ids[t], g[:, 1])
        np.testing.assert_array_equal(seq.gt.boxes[t][:, 2:], g[:, 2:4] + g[:, 4:6])
        np.testing.assert_array_equal(seq.gt.classes[t], g[:, 7])
        np.testing.assert_array_equal(seq.gt.consider[t], g[:, 6])
        np.testing.assert_array_equal(seq.gt.visibility[t], g[:, 8])
    assert sorted(set(np.concatenate(seq.gt.classes).tolist())) == sorted(set(CLASSES))


def test_result_file_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    outputs = [np.concatenate([rng.uniform(0, 100, (k, 2)), rng.uniform(100, 200, (k, 2)),
                               rng.permutation(50)[:k, None]], axis=1) for k in (3, 0, 5, 1)]
    path = tmp_path / "res" / "MOT17-02-FRCNN.txt"
    mc.write_results(path, outputs)
    first = path.read_text().splitlines()[0].split(",")
    assert len(first) == 10 and first[0] == "1" and first[6:] == ["-1"] * 4
    back = mc.read_results(path, 4)
    assert [len(b) for b in back] == [3, 0, 5, 1]
    for a, b in zip(outputs, back):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)


def test_mot20_benchmark_and_sequence_discovery(tmp_path):
    write_sequence(tmp_path / "MOT20" / "train", name="MOT20-01", n_frames=5)
    write_sequence(tmp_path / "MOT20" / "train", name="MOT20-02", n_frames=5, seed=2)
    found = mc.find_sequences(tmp_path / "MOT20")
    assert [p.name for p in found] == ["MOT20-01", "MOT20-02"]
    assert mc.find_sequences(found[0]) == [found[0]]
    assert mc.load_sequence(found[0]).benchmark == "MOT20"


def test_preprocessing_hand_case(tmp_path):
    """Frame 1: a pedestrian (kept), a static person (distractor), a car and a zero-marked pedestrian.
    The tracker box on the static person is removed; the one on the car and the one on the zero-marked
    pedestrian stay (false positives); a box overlapping a distractor at IoU < 0.5 stays."""
    seq_dir = tmp_path / "MOT17-09-SDP"
    (seq_dir / "det").mkdir(parents=True)
    (seq_dir / "gt").mkdir()
    (seq_dir / "seqinfo.ini").write_text("[Sequence]\nname=MOT17-09-SDP\nimDir=img1\nframeRate=30\n"
                                         "seqLength=1\nimWidth=100\nimHeight=100\n")
    (seq_dir / "det" / "det.txt").write_text("1,-1,0,0,10,20,0.9,-1,-1,-1\n")
    (seq_dir / "gt" / "gt.txt").write_text("1,1,0,0,10,20,1,1,1\n1,2,30,0,10,20,0,7,1\n"
                                           "1,3,60,0,10,20,0,3,1\n1,4,0,50,10,20,0,1,0.2\n")
    seq = mc.load_sequence(seq_dir)
    out = [np.array([[0, 0, 10, 20, 7], [30, 0, 40, 20, 8], [60, 0, 70, 20, 9], [0, 50, 10, 70, 10],
                     [35, 0, 45, 20, 11]], float)]
    gt_f, hyp_f, removed = mc.evaluation_frames(seq, [out[0][[0, 1, 2, 3]]])
    assert removed == 1
    assert gt_f[0][0].tolist() == [1] and hyp_f[0][0].tolist() == [7, 9, 10]
    # a box that overlaps the static person at IoU 1/3 only is not removed
    _, hyp_f, removed = mc.evaluation_frames(seq, [out[0][[0, 4]]])
    assert removed == 0 and hyp_f[0][0].tolist() == [7, 11]
    # MOT20 also removes boxes on non-motorized vehicles (class 6), MOT17 does not
    seq.gt.classes[0][2] = 6
    assert mc.evaluation_frames(seq, [out[0][[2]]])[2] == 0
    seq.benchmark = "MOT20"
    assert mc.evaluation_frames(seq, [out[0][[2]]])[2] == 1


def test_hota_hand_case():
    """Two objects over two frames, each matched exactly by one hypothesis in both frames: HOTA 1.
    Then the second hypothesis changes id in frame 2: at every alpha TP = 4, and
    AssA = (2 * 2/2 + 1 * 1/2 + 1 * 1/2) / 4 = 0.75, DetA = 1, HOTA = sqrt(0.75)."""
    A, B = [0, 0, 10, 20], [50, 0, 60, 20]
    gt = [([1, 2], [A, B]), ([1, 2], [A, B])]
    perfect = hota_sequence(gt, [([5, 6], [A, B]), ([5, 6], [A, B])])
    assert perfect.hota == pytest.approx(1.0) and perfect.loc_a == pytest.approx(1.0)
    switched = hota_sequence(gt, [([5, 6], [A, B]), ([5, 7], [A, B])])
    assert switched.det_a == pytest.approx(1.0)
    assert switched.ass_a == pytest.approx(0.75)
    assert switched.hota == pytest.approx(np.sqrt(0.75))
    # a box at IoU 0.5 counts for alpha <= 0.5 only: 10 of the 19 alphas
    half = hota_sequence([([1], [A])], [([5], [[0, 0, 10, 10]])])
    np.testing.assert_array_equal(half.tp, (HOTA_ALPHAS <= 0.5 + 1e-12).astype(float))
    assert half.det_a == pytest.approx(10 / 19)
    assert hota_sequence([([1], [A])], [([], np.zeros((0, 4)))]).hota == 0.0
    assert len(HOTA_ALPHAS) == 19 and HOTA_ALPHAS[0] == pytest.approx(0.05) and HOTA_ALPHAS[-1] == pytest.approx(0.95)


# --------------------------------------------------------------------------- against trackeval


def _trackeval():
    """trackeval, imported lazily (test-only); on NumPy 2 it needs no shim at v1.3 (checked by import)."""
    return pytest.importorskip("trackeval")


def _run_trackeval(tmp_path, benchmark: str, seqs: dict[str, int]):
    trackeval = _trackeval()
    ds_cfg = {
        "GT_FOLDER": str(tmp_path / "gt"), "TRACKERS_FOLDER": str(tmp_path / "trackers"),
        "OUTPUT_FOLDER": str(tmp_path / "te_out"), "TRACKERS_TO_EVAL": ["drlab"], "BENCHMARK": benchmark,
        "SKIP_SPLIT_FOL": True, "SEQ_INFO": dict(seqs), "PRINT_CONFIG": False, "TRACKER_SUB_FOLDER": "data",
    }
    ev_cfg = {"USE_PARALLEL": False, "PRINT_RESULTS": False, "PRINT_CONFIG": False, "TIME_PROGRESS": False,
              "OUTPUT_SUMMARY": False, "OUTPUT_DETAILED": False, "PLOT_CURVES": False,
              "OUTPUT_EMPTY_CLASSES": False, "DISPLAY_LESS_PROGRESS": True, "PRINT_ONLY_COMBINED": True}
    evaluator = trackeval.Evaluator(ev_cfg)
    metrics = [trackeval.metrics.HOTA({"PRINT_CONFIG": False}), trackeval.metrics.CLEAR({"PRINT_CONFIG": False}),
               trackeval.metrics.Identity({"PRINT_CONFIG": False})]
    res, msg = evaluator.evaluate([trackeval.datasets.MotChallenge2DBox(ds_cfg)], metrics)
    assert msg["MotChallenge2DBox"]["drlab"] == "Success", msg
    return res["MotChallenge2DBox"]["drlab"]


def _ours(tmp_path, names: list[str]):
    per_seq, total = {}, HOTACounts()
    for name in names:
        seq = mc.load_sequence(tmp_path / "gt" / name)
        outputs = mc.read_results(tmp_path / "trackers" / "drlab" / "data" / f"{name}.txt", seq.n_frames)
        gt_f, hyp_f, _ = mc.evaluation_frames(seq, outputs)
        h = hota_sequence(gt_f, hyp_f)
        per_seq[name] = (h, evaluate_sequence(gt_f, hyp_f))
        total = total + h
    return per_seq, total


def _compare(ours: HOTACounts, theirs: dict) -> None:
    # 1e-6 is the agreement the tracking protocol asks for (HOTA equal to trackeval's to 1e-6): the two
    # sum their similarity scores in different orders, so the last bits need not agree; the integer
    # counts (TP, FN, FP) below are compared exactly.
    pairs = {"hota": "HOTA", "det_a": "DetA", "ass_a": "AssA", "loc_a": "LocA", "det_re": "DetRe",
             "det_pr": "DetPr", "ass_re": "AssRe", "ass_pr": "AssPr"}
    for mine, key in pairs.items():
        assert getattr(ours, mine) == pytest.approx(float(np.mean(theirs[key])), abs=1e-6, rel=0), key
    np.testing.assert_allclose(ours.hota_alpha, theirs["HOTA"], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(ours.tp, theirs["HOTA_TP"])
    np.testing.assert_array_equal(ours.fn, theirs["HOTA_FN"])
    np.testing.assert_array_equal(ours.fp, theirs["HOTA_FP"])


@pytest.mark.parametrize("benchmark,names,gt_columns", [
    ("MOT17", ["MOT17-02-FRCNN", "MOT17-04-SDP", "MOT17-05-DPM"], 9),
    ("MOT20", ["MOT20-01", "MOT20-03"], 9),
    ("MOT15", ["ADL-Rundle-6", "TUD-Campus"], 10),
    ("MOT17", ["MOT16-02", "MOT16-09"], 8),
], ids=["mot17-three-sequences", "mot20-two-sequences", "mot15-two-sequences", "mot16-gt-without-visibility"])
def test_hota_equals_trackeval(tmp_path, benchmark, names, gt_columns):
    """Per sequence and combined, HOTA, DetA, AssA, LocA (and their parts) equal trackeval's to 1e-6
    after the same preprocessing (distractors; none for MOT15, whose gt has no classes); TP/FN/FP counts
    are equal. MOTA and IDF1 (py-motmetrics' definitions) equal trackeval's CLEAR and Identity on these
    sequences too. The benchmark is detected from the files (MOT15: its 10-column gt.txt)."""
    seqs = {}
    for k, name in enumerate(names):
        n = 25 + 5 * k
        seq_dir, gt, _ = write_sequence(tmp_path / "gt", name=name, n_frames=n, seed=10 + k, gt_columns=gt_columns)
        assert mc.load_sequence(seq_dir).benchmark == benchmark
        rng = np.random.default_rng(100 + k)
        mc.write_results(tmp_path / "trackers" / "drlab" / "data" / f"{name}.txt", tracker_output(rng, gt, n))
        seqs[name] = n
    theirs = _run_trackeval(tmp_path, benchmark, seqs)
    per_seq, total = _ours(tmp_path, names)
    for name, (h, clear) in per_seq.items():
        te = theirs[name]["pedestrian"]
        _compare(h, te["HOTA"])
        assert h.hota > 0.2  # not a degenerate case
        assert clear.mota == pytest.approx(te["CLEAR"]["MOTA"], abs=1e-12)
        assert clear.num_switches == te["CLEAR"]["IDSW"]
        assert clear.idf1 == pytest.approx(te["Identity"]["IDF1"], abs=1e-12)
    _compare(total, theirs["COMBINED_SEQ"]["pedestrian"]["HOTA"])


def test_hota_equals_trackeval_with_empty_output(tmp_path):
    """A sequence with no tracker box at all and one with boxes only on distractors."""
    names = ["MOT17-10-FRCNN", "MOT17-11-FRCNN"]
    for k, name in enumerate(names):
        _, gt, _ = write_sequence(tmp_path / "gt", name=name, n_frames=10, seed=30 + k)
        if k == 0:
            outputs = [np.zeros((0, 5))] * 10
        else:
            outputs = []
            for f in range(1, 11):
                g = gt[(gt[:, 0] == f) & np.isin(gt[:, 7], (2, 7, 8, 12))]
                outputs.append(np.stack([g[:, 2], g[:, 3], g[:, 2] + g[:, 4], g[:, 3] + g[:, 5], g[:, 1]], 1)
                               .reshape(-1, 5))
        mc.write_results(tmp_path / "trackers" / "drlab" / "data" / f"{name}.txt", outputs)
    theirs = _run_trackeval(tmp_path, "MOT17", {n: 10 for n in names})
    per_seq, total = _ours(tmp_path, names)
    for name, (h, _) in per_seq.items():
        _compare(h, theirs[name]["pedestrian"]["HOTA"])
        assert h.hota == 0.0
    _compare(total, theirs["COMBINED_SEQ"]["pedestrian"]["HOTA"])


# --------------------------------------------------------------------------- mot_tracking --data


def test_mot_tracking_data_end_to_end(tmp_path):
    """`mot_tracking --data` on a folder of two MOT17 sequences with frames: the three trackers run,
    their tracks are written in the MOTChallenge result format, and the HOTA, DetA, AssA and MOTA it
    reports equal trackeval's on those files."""
    import json

    from experiments import mot_tracking

    data = tmp_path / "gt"
    seqs = {}
    for k, name in enumerate(["MOT17-02-FRCNN", "MOT17-13-SDP"]):
        write_sequence(data, name=name, n_frames=20 + 4 * k, seed=40 + k, images=True, width=160, height=120)
        seqs[name] = 20 + 4 * k
    out = tmp_path / "out"
    assert mot_tracking.main(["--data", str(data), "--out", str(out), "--no-progress"]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    m = doc["metrics"]
    assert set(m["trackers"]) == {"sort", "bytetrack", "bytetrack_app"}
    assert m["dataset"]["sequences"] == list(seqs) and m["dataset"]["benchmarks"] == ["MOT17"]
    table = (out / "table.md").read_text()
    assert "TrackEval's MOTChallenge2DBox protocol" in table and str(data) in table
    assert "| tracker | HOTA % | DetA % | AssA % | LocA % | MOTA % | IDF1 % | ID sw. |" in table
    for key, mine in m["trackers"].items():
        assert mine["fps"] > 0 and mine["ass_a"] > 0
        trackers = tmp_path / "trackers" / key / "data"
        trackers.mkdir(parents=True)
        for name in seqs:
            (trackers / f"{name}.txt").write_text((out / "tracks" / key / f"{name}.txt").read_text())
    for key, mine in m["trackers"].items():
        te_root = tmp_path / f"te-{key}"
        (te_root / "trackers" / "drlab").mkdir(parents=True)
        (te_root / "trackers" / "drlab" / "data").symlink_to(tmp_path / "trackers" / key / "data")
        (te_root / "gt").symlink_to(data)
        theirs = _run_trackeval(te_root, "MOT17", seqs)["COMBINED_SEQ"]["pedestrian"]
        for mine_key, their_key in (("hota", "HOTA"), ("det_a", "DetA"), ("ass_a", "AssA"), ("loc_a", "LocA")):
            assert mine[mine_key] == pytest.approx(float(np.mean(theirs["HOTA"][their_key])), abs=1e-6, rel=0), key
        assert mine["mota"] == pytest.approx(theirs["CLEAR"]["MOTA"], abs=1e-9)
        assert mine["idf1"] == pytest.approx(theirs["Identity"]["IDF1"], abs=1e-9)


def test_read_frame(tmp_path):
    seq_dir, _, _ = write_sequence(tmp_path, n_frames=3, seed=7, images=True, width=96, height=72)
    seq = mc.load_sequence(seq_dir)
    img = seq.read_image(2)
    assert img.dtype == np.uint8 and img.shape == (72, 96, 3)
    assert seq.missing_images() == [] and seq.image_path(2).name == "000003.jpg"


def test_files_as_trackeval_reads_them(tmp_path):
    """seqinfo.ini keys in another case and extra keys and sections; det.txt of 7, 9 and 10 columns;
    rows with spaces, a trailing comma, or whitespace-separated: all read as TrackEval reads them."""
    seq_dir, gt, dets = write_sequence(tmp_path, n_frames=12, seed=2)
    (seq_dir / "seqinfo.ini").write_text(
        "[Sequence]\r\nNAME=MOT17-02-FRCNN\r\nimdir = img1\r\nframerate=30\r\nSeqLength=12\r\nimWidth=320\r\n"
        "IMHEIGHT=240\r\nimExt=.jpg\r\ncomment=extra key\r\n\r\n[Extra]\r\nanything=1\r\n")
    rows = [",".join(mot_fmt(v) for v in r) for r in dets]
    styles = [lambda r: r, lambda r: ",".join(r.split(",")[:7]), lambda r: ",".join(r.split(",")[:9]),
              lambda r: r.replace(",", ", "), lambda r: r + ",", lambda r: r.replace(",", " ")]
    (seq_dir / "det" / "det.txt").write_text("".join(styles[i % len(styles)](r) + "\n" for i, r in enumerate(rows)))
    (seq_dir / "gt" / "gt.txt").write_text("".join(",".join(mot_fmt(v) for v in r) + ",\n" for r in gt))
    seq = mc.load_sequence(seq_dir)
    assert seq.info == mc.SeqInfo("MOT17-02-FRCNN", "img1", 30.0, 12, 320, 240, ".jpg")
    for t in range(12):
        d = dets[dets[:, 0] == t + 1]
        np.testing.assert_array_equal(seq.dets[t][:, :4], np.stack([d[:, 2], d[:, 3], d[:, 2] + d[:, 4],
                                                                     d[:, 3] + d[:, 5]], axis=1))
        np.testing.assert_array_equal(seq.dets[t][:, 4], d[:, 6])
        np.testing.assert_array_equal(seq.gt.ids[t], gt[gt[:, 0] == t + 1][:, 1])
