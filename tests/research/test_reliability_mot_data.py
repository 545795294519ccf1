"""Reliability of the MOTChallenge reader and `mot_tracking --data`.

Bad inputs: each case writes a valid MOT17 sequence folder (tests/research/mot_fixtures.py), spoils
one line of one file, and expects the one-line DatasetError (a ValueError) that names the file and the
line, raised when the sequence is loaded (before any tracker runs). At the CLI the same inputs exit 2
with that line and create no results folder. Faults: inputs the experiment must get through (no
frames for the appearance tracker, a test-split sequence without gt.txt) and what it does instead.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from mot_fixtures import write_sequence

from experiments import mot_tracking
from research.tracking import motchallenge as mc


def _replace_line(path: Path, lineno: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[lineno - 1] = text
    path.write_text("\n".join(lines) + "\n")


def _seqinfo(drop: str | None = None, **values: str) -> str:
    fields = {"name": "MOT17-02-FRCNN", "imDir": "img1", "frameRate": "30", "seqLength": "12", "imWidth": "320",
              "imHeight": "240", "imExt": ".jpg"}
    fields.update(values)
    if drop:
        del fields[drop]
    return "[Sequence]\n" + "".join(f"{k}={v}\n" for k, v in fields.items())


def _edit(file: str, line: int, text: str):
    return lambda seq: _replace_line(seq / file, line, text)


def _write(file: str, text: str):
    return lambda seq: (seq / file).write_text(text)


def _remove(file: str):
    return lambda seq: (seq / file).unlink()


# (id, how the folder is spoilt, file named, expected message after "<file>[:line]: " (regex))
CASES = [
    ("det-nan-score", _edit("det/det.txt", 3, "2,-1,10,20,30,40,nan,-1,-1,-1"), "det/det.txt:3",
     r"conf expected a finite number, got nan"),
    ("det-nan-left", _edit("det/det.txt", 1, "1,-1,NaN,20,30,40,0.9,-1,-1,-1"), "det/det.txt:1",
     r"bb_left expected a finite number, got nan"),
    ("det-inf-height", _edit("det/det.txt", 2, "1,-1,10,20,30,inf,0.9,-1,-1,-1"), "det/det.txt:2",
     r"bb_height expected a finite number, got inf"),
    ("det-text-value", _edit("det/det.txt", 4, "2,-1,abc,20,30,40,0.9,-1,-1,-1"), "det/det.txt:4",
     r"column 3 \(bb_left\) expected a number, got 'abc'"),
    ("det-6-columns", _edit("det/det.txt", 2, "1,-1,10,20,30,40"), "det/det.txt:2",
     r"expected 7 to 10 comma-separated columns .* in a det.txt, got 6"),
    ("det-11-columns", _edit("det/det.txt", 2, "1,-1,10,20,30,40,0.5,-1,-1,-1,7"), "det/det.txt:2",
     r"expected 7 to 10 comma-separated columns .*, got 11"),
    ("det-frame-0", _edit("det/det.txt", 1, "0,-1,10,20,30,40,0.9,-1,-1,-1"), "det/det.txt:1",
     r"frame expected an integer in \[1, 12\] \(seqLength\), got 0"),
    ("det-frame-past-seqlength", _edit("det/det.txt", 5, "13,-1,10,20,30,40,0.9,-1,-1,-1"), "det/det.txt:5",
     r"frame expected an integer in \[1, 12\] \(seqLength\), got 13"),
    ("det-frame-fraction", _edit("det/det.txt", 5, "2.5,-1,10,20,30,40,0.9,-1,-1,-1"), "det/det.txt:5",
     r"frame expected an integer .*, got 2.5"),
    ("det-zero-width", _edit("det/det.txt", 6, "3,-1,10,20,0,40,0.9,-1,-1,-1"), "det/det.txt:6",
     r"bb_width and bb_height expected > 0, got 0 x 40"),
    ("det-missing", _remove("det/det.txt"), "det/det.txt", r"missing"),
    ("gt-7-columns", _edit("gt/gt.txt", 2, "1,2,10,20,30,40,1"), "gt/gt.txt:2",
     r"expected 8 to 9 comma-separated columns \(frame, id, .*, class, \.\.\.\) in a gt.txt, got 7"),
    # A first row of 9 columns makes the sequence MOT16/17's, so a later row of MOT15's 10 is refused.
    ("gt-10-columns", _edit("gt/gt.txt", 3, "1,2,10,20,30,40,1,1,0.5,-1"), "gt/gt.txt:3",
     r"expected 8 to 9 comma-separated columns .*, got 10"),
    ("gt-nan-top", _edit("gt/gt.txt", 4, "1,2,10,nan,30,40,1,1,0.5"), "gt/gt.txt:4",
     r"bb_top expected a finite number, got nan"),
    ("gt-id-fraction", _edit("gt/gt.txt", 4, "1,2.5,10,20,30,40,1,1,0.5"), "gt/gt.txt:4",
     r"id expected an integer, got 2.5"),
    ("gt-class-14", _edit("gt/gt.txt", 1, "1,1,10,20,30,40,1,14,0.5"), "gt/gt.txt:1",
     r"class expected an integer in 1..13, got 14"),
    ("gt-consider-2", _edit("gt/gt.txt", 2, "1,2,10,20,30,40,2,1,0.5"), "gt/gt.txt:2",
     r"consider expected 0 or 1, got 2"),
    ("gt-visibility-1.5", _edit("gt/gt.txt", 2, "1,2,10,20,30,40,1,1,1.5"), "gt/gt.txt:2",
     r"visibility expected a number in \[0, 1\], got 1.5"),
    ("gt-duplicate-id", _edit("gt/gt.txt", 2, "1,1,10,20,30,40,1,1,0.5"), "gt/gt.txt:2",
     r"id 1 appears twice in frame 1"),
    ("seqinfo-missing", _remove("seqinfo.ini"), "seqinfo.ini",
     r"missing \(a MOTChallenge sequence folder has seqinfo.ini\)"),
    ("seqinfo-no-frameRate", _write("seqinfo.ini", _seqinfo(drop="frameRate")), "seqinfo.ini:1",
     r"\[Sequence\] has no key 'frameRate' \(expected name, imDir, frameRate, seqLength, imWidth, imHeight\)"),
    ("seqinfo-no-seqLength", _write("seqinfo.ini", _seqinfo(drop="seqLength")), "seqinfo.ini:1",
     r"\[Sequence\] has no key 'seqLength' \(expected name, .*\)"),
    ("seqinfo-no-imDir", _write("seqinfo.ini", _seqinfo(drop="imDir")), "seqinfo.ini:1",
     r"\[Sequence\] has no key 'imDir' \(expected name, .*\)"),
    ("seqinfo-seqLength-text", _write("seqinfo.ini", _seqinfo(seqLength="twelve")), "seqinfo.ini:5",
     r"seqLength expected an integer > 0, got 'twelve'"),
    ("seqinfo-seqLength-0", _write("seqinfo.ini", _seqinfo(seqLength="0")), "seqinfo.ini:5",
     r"seqLength expected an integer > 0, got '0'"),
    ("seqinfo-frameRate-nan", _write("seqinfo.ini", _seqinfo(frameRate="nan")), "seqinfo.ini:4",
     r"frameRate expected a number > 0, got 'nan'"),
    ("seqinfo-empty-name", _write("seqinfo.ini", _seqinfo(name="")), "seqinfo.ini:2",
     r"name expected a non-empty value"),
    ("seqinfo-no-section", _write("seqinfo.ini", "[Seq]\nname=x\n"), "seqinfo.ini",
     r"expected a \[Sequence\] section"),
    ("seqinfo-no-header", _write("seqinfo.ini", "name=x\n[Sequence]\n"), "seqinfo.ini:1",
     r"not a valid ini file \(no \[section\] header before this line\)"),
    ("seqinfo-line-without-equals", _write("seqinfo.ini", _seqinfo() + "garbage line\n"), "seqinfo.ini:9",
     r"not a valid ini file \(expected key=value\)"),
]


def _spoilt(tmp_path: Path, spoil) -> Path:
    seq, _, _ = write_sequence(tmp_path, n_frames=12, seed=4)
    # the first lines of the fixture's files are edited: make sure they exist
    assert len((seq / "det" / "det.txt").read_text().splitlines()) > 6
    spoil(seq)
    return seq


@pytest.mark.parametrize("spoil,file,message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_sequence_folder(tmp_path, spoil, file, message):
    seq = _spoilt(tmp_path, spoil)
    with pytest.raises(ValueError) as info:
        mc.load_sequence(seq)
    text = str(info.value)
    assert "\n" not in text
    assert re.fullmatch(re.escape(f"{seq / file}: ") + message, text), text


CLI_CASES = ["det-nan-score", "gt-7-columns", "seqinfo-no-frameRate"]


@pytest.mark.parametrize("case", CLI_CASES)
def test_bad_sequence_folder_at_the_cli(tmp_path, capsys, case):
    _, spoil, file, message = next(c for c in CASES if c[0] == case)
    seq = _spoilt(tmp_path / "data", spoil)
    out = tmp_path / "out"
    assert mot_tracking.main(["--data", str(tmp_path / "data"), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert re.fullmatch(r"python -m experiments\.mot_tracking: " + re.escape(f"{seq / file}: ") + message, err), err
    assert not out.exists() and not list(tmp_path.glob("out.partial-*"))


# (id, what --data names, expected one line after "python -m experiments.mot_tracking: " (regex))
DATA_CASES = [
    ("data-missing", lambda d: d / "nowhere", r"--data: .*nowhere does not exist; expected a MOTChallenge sequence "
                                              r"folder \(with seqinfo.ini\) or a folder of them"),
    ("data-a-file", lambda d: (d / "f.txt", (d / "f.txt").write_text("x"))[0],
     r"--data: expected a folder, but .*f.txt is a file"),
]


@pytest.mark.parametrize("target,message", [c[1:] for c in DATA_CASES], ids=[c[0] for c in DATA_CASES])
def test_bad_data_option(tmp_path, capsys, target, message):
    data = tmp_path / "data"
    data.mkdir()
    path = target(data)
    out = tmp_path / "out"
    assert mot_tracking.main(["--data", str(path), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert re.fullmatch(r"python -m experiments\.mot_tracking: " + message, err), err
    assert not out.exists()


def test_result_file_duplicate_id(tmp_path):
    path = tmp_path / "res.txt"
    path.write_text("1,5,0,0,10,10,-1,-1,-1,-1\n1,6,0,0,10,10,-1,-1,-1,-1\n1,5,3,0,10,10,-1,-1,-1,-1\n")
    with pytest.raises(ValueError, match=re.escape(f"{path}:3: id 5 appears twice in frame 1")):
        mc.read_results(path, 1)


# --------------------------------------------------------------------------- faults the run gets through


def _fault_no_frames(data: Path) -> None:
    write_sequence(data, "MOT17-02-FRCNN", n_frames=12, seed=5)  # no img1/


def _fault_one_frame_missing(data: Path) -> None:
    seq, _, _ = write_sequence(data, "MOT17-02-FRCNN", n_frames=12, seed=5, images=True, width=96, height=72)
    (seq / "img1" / "000007.jpg").unlink()


def _fault_test_split_sequence(data: Path) -> None:
    write_sequence(data, "MOT17-02-FRCNN", n_frames=12, seed=5)
    seq, _, _ = write_sequence(data, "MOT17-01-FRCNN", n_frames=12, seed=6)
    (seq / "gt" / "gt.txt").unlink()


# (id, how the data is made, trackers expected, text the table must hold)
FAULTS = [
    ("no-image-folder", _fault_no_frames, {"sort", "bytetrack"},
     r"ByteTrack \+ appearance skipped: no frames to read appearance from: .*img1/000001\.jpg is missing"),
    ("one-frame-missing", _fault_one_frame_missing, {"sort", "bytetrack"},
     r"ByteTrack \+ appearance skipped: .*img1/000007\.jpg is missing"),
    ("test-split-sequence-without-gt", _fault_test_split_sequence, {"sort", "bytetrack"},
     r"Not scored \(no gt/gt.txt\): MOT17-01-FRCNN\."),
]


@pytest.mark.parametrize("make,trackers,note", [f[1:] for f in FAULTS], ids=[f[0] for f in FAULTS])
def test_data_faults_are_reported(tmp_path, make, trackers, note):
    data = tmp_path / "data"
    make(data)
    out = tmp_path / "out"
    assert mot_tracking.main(["--data", str(data), "--out", str(out), "--no-progress"]) == 0
    m = json.loads((out / "metrics.json").read_text())["metrics"]
    assert set(m["trackers"]) == trackers
    assert re.search(note, (out / "table.md").read_text())
    for t in m["trackers"].values():
        assert 0.0 <= t["hota"] <= 1.0 and np.isfinite(t["mota"])


def test_data_without_sequences_runs_the_synthetic_sequences(tmp_path, capsys):
    """--data naming a folder with no seqinfo.ini (every experiment is handed the shared dataset cache)
    falls back to the synthetic sequences, and says so."""
    data = tmp_path / "data"
    (data / "objects-smoke").mkdir(parents=True)
    out = tmp_path / "out"
    assert mot_tracking.main(["--smoke", "--frames", "20", "--data", str(data), "--out", str(out),
                              "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert f"note: no MOTChallenge sequence (seqinfo.ini) in {data}" in said
    assert (out / "table.md").read_text().startswith("# Multi-object tracking: SORT vs ByteTrack")
    assert (out / "tracks.png").is_file()


def test_frame_of_another_size(tmp_path):
    """A frame whose size disagrees with seqinfo.ini is a one-line error naming the frame."""
    seq_dir, _, _ = write_sequence(tmp_path, n_frames=3, seed=7, images=True, width=96, height=72)
    ini = seq_dir / "seqinfo.ini"
    ini.write_text(ini.read_text().replace("imWidth=96", "imWidth=100"))
    seq = mc.load_sequence(seq_dir)
    with pytest.raises(ValueError) as info:
        seq.read_image(1)
    assert str(info.value) == f"{seq_dir / 'img1' / '000002.jpg'}: image is 96x72, seqinfo.ini says 100x72"
