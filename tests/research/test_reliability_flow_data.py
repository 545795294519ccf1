"""Reliability of the flow-benchmark readers and `raft_flow --data`: each bad input gets one line naming the file.

One table, BAD_INPUTS: a pristine fixture folder (Sintel, KITTI 2015 or Middlebury, written by
tests/research/flow_fixtures.py) is copied, broken in one way, and read. Each case names the step
that must refuse it ("open": the header check of the whole layout, before any pixel is read; "load":
reading a sequence's pixels; "cli": `raft_flow --data ...`, which must exit 2 with that line and leave
no results folder), the file the message must name (relative to the folder) and the message text.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from flow_fixtures import H, W, write_kitti, write_middlebury, write_sintel
from research import io
from research.datasets import DatasetError, load_flow_benchmark, open_flow_benchmark

SINTEL_FLO = "training/flow/alley_1/frame_0001.flo"
KITTI_OCC = "training/flow_occ/000000_10.png"
KITTI_NOC = "training/flow_noc/000000_10.png"


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("pristine")
    write_sintel(root / "sintel")
    write_kitti(root / "kitti", pairs=1)
    write_middlebury(root / "middlebury")
    return {k: root / k for k in ("sintel", "kitti", "middlebury")}


# --------------------------------------------------------------------------- breakages


def _truncate(rel, keep):
    def f(root):
        p = root / rel
        p.write_bytes(p.read_bytes()[:keep])  # keep < 0: all but the last -keep bytes
    return f


def _half(rel):
    def f(root):
        p = root / rel
        p.write_bytes(p.read_bytes()[:p.stat().st_size // 2])
    return f


def _remove(rel):
    return lambda root: (root / rel).unlink()


def _rmtree(rel):
    return lambda root: shutil.rmtree(root / rel)


def _write(rel, data: bytes):
    return lambda root: (root / rel).write_bytes(data)


def _png8(rel, shape):
    return lambda root: io.write_png_u8(root / rel, np.zeros(shape, np.uint8))


def _png16(rel, arr):
    return lambda root: io.write_png_u16(root / rel, arr)


def _flo(rel, arr):
    return lambda root: io.write_flo(root / rel, arr)


def _nan_flo(rel):
    def f(root):
        raw = bytearray((root / rel).read_bytes())
        raw[12 + 8 * 5:12 + 8 * 5 + 4] = np.array([np.nan], "<f4").tobytes()  # u of pixel 5
        (root / rel).write_bytes(bytes(raw))
    return f


def _noc_knows_more():
    """A flow_noc marking a pixel known that flow_occ leaves unknown."""
    def f(root):
        occ = io.read_png_u16(root / KITTI_OCC)
        noc = io.read_png_u16(root / KITTI_NOC)
        y, x = np.argwhere(occ[..., 2] == 0)[0]
        noc[y, x, 2] = 1
        io.write_png_u16(root / KITTI_NOC, noc)
    return f


def _nothing(root):
    pass


BAD_INPUTS = [
    # id, fixture, breakage, step, extra options, file named (relative), message
    ("kitti-flow-png-8-bit", "kitti", _png8(KITTI_OCC, (H, W, 3)), "open", {}, KITTI_OCC,
     "expected a KITTI flow PNG (16-bit, 3 channels), got a 8-bit PNG with 3 channels"),
    ("kitti-flow-png-1-channel", "kitti", _png16(KITTI_OCC, np.zeros((H, W), np.uint16)), "open", {}, KITTI_OCC,
     "expected a KITTI flow PNG (16-bit, 3 channels), got a 16-bit PNG with 1 channel"),
    ("kitti-noc-png-8-bit", "kitti", _png8(KITTI_NOC, (H, W, 3)), "open", {}, KITTI_NOC,
     "expected a KITTI flow PNG (16-bit, 3 channels), got a 8-bit PNG with 3 channels"),
    ("kitti-flow-png-not-png", "kitti", _write(KITTI_OCC, b"not an image at all"), "open", {}, KITTI_OCC,
     "not a readable image"),
    ("kitti-flow-png-wrong-size", "kitti", _png16(KITTI_OCC, np.zeros((H, W + 2, 3), np.uint16)), "open", {},
     KITTI_OCC, f"is {W + 2}x{H}, expected {W}x{H} like"),
    ("kitti-missing-frame-11", "kitti", _remove("training/image_2/000000_11.png"), "open", {},
     "training/image_2/000000_11.png", "missing"),
    ("kitti-frame-16-bit", "kitti", _png16("training/image_2/000000_10.png", np.zeros((H, W, 3), np.uint16)),
     "open", {}, "training/image_2/000000_10.png", "expected an 8-bit image (8-bit, 1/3/4 channels), got a 16-bit"),
    ("kitti-missing-flow-noc-file", "kitti", _remove(KITTI_NOC), "open", {}, KITTI_NOC, "missing"),
    ("kitti-no-flow-noc-folder", "kitti", _rmtree("training/flow_noc"), "open", {}, "training/flow_noc",
     "missing (the noc region needs KITTI's flow_noc maps)"),
    ("kitti-no-image-folder", "kitti", _rmtree("training/image_2"), "open", {}, "training",
     "holds no frame folder (expected image_2/ for KITTI 2015, colored_0/ or image_0/ for KITTI 2012)"),
    ("kitti-empty-flow-occ", "kitti", lambda r: [p.unlink() for p in (r / "training/flow_occ").iterdir()], "open",
     {}, "training/flow_occ", "holds no NNNNNN_10.png flow maps"),
    ("kitti-noc-known-where-occ-unknown", "kitti", _noc_knows_more(), "load", {}, KITTI_NOC,
     "marks 1 pixels known that 000000_10.png in flow_occ does not"),
    ("kitti-obj-map-folder-without-the-pair", "kitti", lambda r: (r / "training/obj_map").mkdir(), "open", {},
     "training/obj_map/000000_10.png", "missing"),
    ("kitti-obj-map-wrong-size", "kitti", _png8("training/obj_map/000000_10.png", (H, W + 2)), "open", {},
     "training/obj_map/000000_10.png", f"is {W + 2}x{H}, expected {W}x{H} like"),
    ("kitti-obj-map-16-bit-colour", "kitti", _png16("training/obj_map/000000_10.png", np.ones((H, W, 3), np.uint16)),
     "load", {}, "training/obj_map/000000_10.png", "a 16-bit colour object map; expected an 8-bit or a grey PNG"),
    ("kitti-pass-option", "kitti", _nothing, "open", {"pass_": "final"}, "",
     "only MPI-Sintel has clean and final passes"),
    ("sintel-truncated-flo", "sintel", _truncate(SINTEL_FLO, -100), "open", {}, SINTEL_FLO,
     f"truncated or padded .flo: {12 + 8 * H * W - 100} bytes, expected {12 + 8 * H * W} for {W}x{H}"),
    ("sintel-flo-header-only-5-bytes", "sintel", _truncate(SINTEL_FLO, 5), "open", {}, SINTEL_FLO,
     "too short for a .flo header (5 bytes)"),
    ("sintel-flo-bad-magic", "sintel", _write(SINTEL_FLO, b"PIEX" + bytes(8 + 8 * H * W)), "open", {}, SINTEL_FLO,
     "not a .flo file (magic b'PIEX', expected b'PIEH')"),
    ("sintel-flo-zero-size", "sintel", _write(SINTEL_FLO, b"PIEH" + bytes(8)), "open", {}, SINTEL_FLO,
     "invalid .flo size 0x0"),
    ("sintel-flo-other-size", "sintel", _flo(SINTEL_FLO, np.zeros((H // 2, W, 2), np.float32)), "open", {},
     SINTEL_FLO, f"is {W}x{H // 2}, expected {W}x{H} like"),
    ("sintel-flo-nan", "sintel", _nan_flo(SINTEL_FLO), "load", {}, SINTEL_FLO, "holds 1 NaN flow values"),
    ("sintel-missing-frame", "sintel", _remove("training/clean/alley_1/frame_0003.png"), "open", {},
     "training/clean/alley_1/frame_0003.png", "missing"),
    ("sintel-missing-final-frame", "sintel", _remove("training/final/cave_2/frame_0002.png"), "open",
     {"pass_": "final"}, "training/final/cave_2/frame_0002.png", "missing"),
    ("sintel-gap-in-flows", "sintel", lambda r: (_flo("training/flow/alley_1/frame_0004.flo",
                                                      np.zeros((H, W, 2), np.float32))(r),
                                                 _remove("training/flow/alley_1/frame_0002.flo")(r)), "open", {},
     "training/flow/alley_1/frame_0002.flo", "missing (the scene's flows run from frame_0001 to frame_0004)"),
    ("sintel-scene-without-flows", "sintel",
     lambda r: [p.unlink() for p in (r / "training/flow/cave_2").iterdir()], "open", {}, "training/flow/cave_2",
     "holds no frame_NNNN.flo"),
    ("sintel-frame-sizes-differ", "sintel", _png8("training/clean/alley_1/frame_0002.png", (H, W - 4, 3)), "open",
     {}, "training/clean/alley_1/frame_0002.png", f"is {W - 4}x{H}, expected {W}x{H} like"),
    ("sintel-occlusion-mask-rgb", "sintel", _png8("training/occlusions/alley_1/frame_0001.png", (H, W, 3)), "open",
     {}, "training/occlusions/alley_1/frame_0001.png",
     "expected an 8-bit grey mask (8-bit, 1 channel), got a 8-bit PNG with 3 channels"),
    ("sintel-occlusion-mask-16-bit", "sintel",
     _png16("training/occlusions/alley_1/frame_0001.png", np.zeros((H, W), np.uint16)), "open", {},
     "training/occlusions/alley_1/frame_0001.png", "expected an 8-bit grey mask (8-bit, 1 channel), got a 16-bit"),
    ("sintel-occlusion-mask-wrong-size", "sintel", _png8("training/occlusions/cave_2/frame_0001.png", (H + 1, W)),
     "open", {}, "training/occlusions/cave_2/frame_0001.png", f"is {W}x{H + 1}, expected {W}x{H} like"),
    ("sintel-missing-occlusion-mask", "sintel", _remove("training/occlusions/alley_1/frame_0002.png"), "open", {},
     "training/occlusions/alley_1/frame_0002.png", "missing"),
    ("sintel-no-occlusions-folder", "sintel", _rmtree("training/occlusions"), "open", {}, "training/occlusions",
     "missing (the matched / unmatched regions need Sintel's occlusion masks)"),
    ("sintel-missing-invalid-mask", "sintel", _remove("training/invalid/cave_2/frame_0001.png"), "open", {},
     "training/invalid/cave_2/frame_0001.png", "missing"),
    ("sintel-no-final-pass", "sintel", _rmtree("training/final"), "open", {"pass_": "final"}, "training/final",
     "missing (the final pass's frames)"),
    ("sintel-format-kitti", "sintel", _nothing, "open", {"fmt": "kitti"}, "",
     "not a kitti folder (expected training/flow_occ/NNNNNN_10.png)"),
    ("middlebury-missing-frame11", "middlebury", _remove("other-data/Venus/frame11.png"), "open", {},
     "other-data/Venus/frame11.png", "missing"),
    ("middlebury-missing-gt", "middlebury", _remove("other-gt-flow/Grove2/flow10.flo"), "open", {},
     "other-gt-flow/Grove2/flow10.flo", "missing"),
    ("middlebury-no-other-data", "middlebury", _rmtree("other-data"), "open", {}, "other-data",
     "missing (the frames of the other-gt-flow sequences)"),
    ("middlebury-truncated-flo", "middlebury", _truncate("other-gt-flow/Venus/flow10.flo", 1000), "open", {},
     "other-gt-flow/Venus/flow10.flo", "truncated or padded .flo: 1000 bytes"),
    ("sintel-frame-png-header-cut", "sintel", _truncate("training/clean/alley_1/frame_0002.png", 200), "open", {},
     "training/clean/alley_1/frame_0002.png", "not a readable image (Read error: hit end of file in png reader)"),
    ("sintel-frame-png-body-cut", "sintel", _half("training/clean/alley_1/frame_0002.png"), "load", {},
     "training/clean/alley_1/frame_0002.png", "corrupt or truncated image"),
    ("kitti-flow-png-cut-short", "kitti", _truncate(KITTI_OCC, 300), "load", {}, KITTI_OCC,
     "corrupt or truncated image"),
    ("not-a-benchmark", "middlebury", _rmtree("other-gt-flow"), "open", {}, "",
     "not a Sintel, KITTI flow or Middlebury flow folder"),
    # raft_flow --data: the same checks, as one line and exit status 2, before any results folder appears.
    ("cli-kitti-flow-png-8-bit", "kitti", _png8(KITTI_OCC, (H, W, 3)), "cli", {}, KITTI_OCC,
     "expected a KITTI flow PNG (16-bit, 3 channels), got a 8-bit PNG with 3 channels"),
    ("cli-sintel-truncated-flo", "sintel", _truncate(SINTEL_FLO, 64), "cli", {}, SINTEL_FLO,
     "truncated or padded .flo: 64 bytes"),
    ("cli-sintel-flo-nan", "sintel", _nan_flo(SINTEL_FLO), "cli", {}, SINTEL_FLO, "holds 1 NaN flow values"),
    ("cli-nan-in-last-sequence", "sintel", _nan_flo("training/flow/cave_2/frame_0001.flo"), "cli", {},
     "training/flow/cave_2/frame_0001.flo", "holds 1 NaN flow values"),  # found before the first pair runs
    ("cli-pass-on-kitti", "kitti", _nothing, "cli", {"--pass": "clean"}, "",
     "--pass: only MPI-Sintel has clean and final passes;"),
    ("cli-format-middlebury-on-sintel", "sintel", _nothing, "cli", {"--format": "middlebury"}, "",
     "not a middlebury folder (expected other-gt-flow/<scene>/flow10.flo)"),
    ("cli-pass-without-benchmark", "middlebury", _rmtree("other-gt-flow"), "cli", {"--pass": "final"}, "",
     "--pass: needs --data naming an MPI-Sintel folder"),
    ("cli-unknown-format", "kitti", _nothing, "cli", {"--format": "eth3d"}, None,
     "--format: invalid choice: 'eth3d' (choose from 'sintel', 'kitti', 'middlebury')"),
]


@pytest.mark.parametrize("fixture, breakage, step, options, named, message",
                         [c[1:] for c in BAD_INPUTS], ids=[c[0] for c in BAD_INPUTS])
def test_bad_input(pristine, tmp_path, capsys, fixture, breakage, step, options, named, message):
    root = tmp_path / fixture
    shutil.copytree(pristine[fixture], root)
    breakage(root)
    named_path = str(root / named) if named else str(root) if named is not None else ""  # None: an option
    if step == "cli":
        from experiments.raft_flow import main

        out = tmp_path / "results"
        argv = ["--no-progress", "--quick", "--data", str(root), "--out", str(out)]
        for k, v in options.items():
            argv += [k, v]
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err, err
        assert err.startswith("python -m experiments.raft_flow: ") or err.startswith("drlab run raft_flow: "), err
        assert message in err and named_path in err, err
        assert not out.exists() and not list(tmp_path.glob("results.partial-*"))
        return
    with pytest.raises(ValueError) as info:
        if step == "open":
            open_flow_benchmark(root, **options)
        else:
            bench = open_flow_benchmark(root, **options)  # the header check passes ...
            for item in bench.items:
                bench.load(item)  # ... and reading the pixels refuses
    text = str(info.value)
    assert "\n" not in text, text
    assert message in text, text
    assert named_path in text, text
    if named:
        assert text.startswith(named_path + ":"), text


def test_every_case_is_one_breakage():
    ids = [c[0] for c in BAD_INPUTS]
    assert len(ids) == len(set(ids))


def test_pristine_folders_read(pristine):
    """The unbroken fixtures read without error: every failure above comes from its breakage."""
    for key, root in pristine.items():
        assert load_flow_benchmark(root), key
        assert isinstance(DatasetError("x"), ValueError)
