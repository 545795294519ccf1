"""Bad stereo benchmark inputs: each is refused with one line naming the file (and the line of calib.txt or
of a KITTI calibration file where one applies), before any matching; and a refused benchmark run leaves
the previous results folder as it was.

Each case corrupts a valid fixture (tests/research/stereo_fixtures.py) in one way.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

import stereo_fixtures as fx
from research.datasets.stereo_benchmarks import load_benchmark


def _calib(root: Path, text: str) -> None:
    (root / "p" / "calib.txt").write_text(text)


def _replace_calib_line(key: str, line: str | None) -> Callable[[Path], None]:
    def edit(root: Path) -> None:
        lines = fx.calib_text().splitlines()
        out = [line if l.startswith(key + "=") else l for l in lines]
        _calib(root, "\n".join(x for x in out if x is not None) + "\n")
    return edit


def _pfm_bytes(root: Path, data: bytes) -> None:
    (root / "p" / "disp0.pfm").write_bytes(data)


def _truncated_pfm(root: Path) -> None:
    raw = (root / "p" / "disp0.pfm").read_bytes()
    _pfm_bytes(root, raw[:-10])


def _gt(value_at: tuple[int, int], value: float) -> Callable[[Path], None]:
    def edit(root: Path) -> None:
        gt = np.full((fx.H, fx.W), 3.0, np.float32)
        gt[value_at] = value
        fx.write_pfm(root / "p" / "disp0.pfm", gt)
    return edit


def _write(rel: str, make: Callable[[], np.ndarray]) -> Callable[[Path], None]:
    def edit(root: Path) -> None:
        fx.write_png(root / rel, make())
    return edit


def _bytes(rel: str, data: bytes) -> Callable[[Path], None]:
    def edit(root: Path) -> None:
        (root / rel).write_bytes(data)
    return edit


def _remove(rel: str) -> Callable[[Path], None]:
    def edit(root: Path) -> None:
        (root / rel).unlink()
    return edit


def _kitti_calib(text: str) -> Callable[[Path], None]:
    def edit(root: Path) -> None:
        (root / "training" / "calib_cam_to_cam" / "000000.txt").write_text(text)
    return edit


_P = " ".join(["72", "0", "23.5", "4.32", "0", "72", "11.5", "0", "0", "0", "1", "0"])
KD = "training/disp_occ_0/000000_10.png"

# (id, format, corruption, expected message: a regex on the one line, after the file's path)
MIDDLEBURY_CASES = [
    ("pfm-truncated", _truncated_pfm, r"p/disp0\.pfm: expected 4608 bytes of PFM data for 48x24x1, got 4598"),
    ("pfm-bad-header", lambda r: _pfm_bytes(r, b"P7\n48 24\n-1.0\n" + bytes(4608)), r"p/disp0\.pfm: corrupt PFM header"),
    ("pfm-nan", _gt((3, 3), np.nan), r"p/disp0\.pfm: holds NaN \(unknown disparities must be inf\)"),
    ("pfm-negative", _gt((3, 3), -2.0), r"p/disp0\.pfm: disparities must be >= 0 \(or inf where unknown\), found -2"),
    ("pfm-three-channels", lambda r: _pfm_bytes(r, b"PF\n48 24\n-1.0\n" + bytes(48 * 24 * 12)),
     r"p/disp0\.pfm: expected a one-channel \(Pf\) disparity, got 3 channels"),
    ("pfm-wrong-size", lambda r: fx.write_pfm(r / "p" / "disp0.pfm", np.ones((24, 40), np.float32)),
     r"p/disp0\.pfm: is 40x24, but im0\.png is 48x24"),
    ("pfm-missing", _remove("p/disp0.pfm"), r"p/disp0\.pfm: missing \(nor is there a disp0GT\.pfm\)"),
    ("calib-without-ndisp", _replace_calib_line("ndisp", None),
     r"p/calib\.txt: no ndisp= line \(a calib\.txt needs cam0, cam1, doffs, baseline, width, height, ndisp\)"),
    ("calib-without-cam1-and-baseline", lambda r: _calib(r, "\n".join(
        l for l in fx.calib_text().splitlines() if not l.startswith(("cam1", "baseline"))) + "\n"),
     r"p/calib\.txt: no cam1=, baseline= line"),
    ("calib-line-without-equals", _replace_calib_line("doffs", "doffs 2.5"),
     r"p/calib\.txt: line 3: expected key=value, got 'doffs 2\.5'"),
    ("calib-doffs-not-a-number", _replace_calib_line("doffs", "doffs=2.5mm"),
     r"p/calib\.txt: line 3: doffs: expected a number, got '2\.5mm'"),
    ("calib-ndisp-fraction", _replace_calib_line("ndisp", "ndisp=16.5"),
     r"p/calib\.txt: line 7: ndisp: expected a positive integer, got '16\.5'"),
    ("calib-baseline-zero", _replace_calib_line("baseline", "baseline=0"),
     r"p/calib\.txt: line 4: baseline: expected a distance > 0, got '0'"),
    ("calib-cam0-two-rows", _replace_calib_line("cam0", "cam0=[100 0 23.5; 0 100 11.5]"),
     r"p/calib\.txt: line 1: cam0: expected a 3x3 matrix \[f 0 cx; 0 f cy; 0 0 1\] with f > 0"),
    ("calib-cam1-negative-focal", _replace_calib_line("cam1", "cam1=[-100 0 26; 0 100 11.5; 0 0 1]"),
     r"p/calib\.txt: line 2: cam1: expected a 3x3 matrix"),
    ("calib-key-twice", lambda r: _calib(r, fx.calib_text() + "ndisp=32\n"),
     r"p/calib\.txt: line 11: ndisp given twice \(first on line 7\)"),
    ("calib-vmax-below-vmin", lambda r: _calib(r, fx.calib_text(extra="vmin=9\nvmax=4\n")),
     r"p/calib\.txt: line 10: vmax: expected >= vmin = 9, got 4"),
    ("calib-width-disagrees", lambda r: _calib(r, fx.calib_text(width=64)),
     r"p/calib\.txt: says width=64 height=24, but .*p/im0\.png is 48x24"),
    ("calib-not-ascii", lambda r: (r / "p" / "calib.txt").write_bytes("cam0=[1 0 0; 0 1 0; 0 0 1]\nné=1\n".encode()),
     r"p/calib\.txt: not an ASCII calib\.txt"),
    ("calib-missing", _remove("p/calib.txt"), r"p/calib\.txt: missing \(a calib\.txt with cam0"),
    ("im1-missing", _remove("p/im1.png"), r"p/im1\.png: missing"),
    ("im1-wrong-size", _write("p/im1.png", lambda: np.zeros((24, 40, 3), np.uint8)),
     r"p/im1\.png: is 40x24, but im0\.png is 48x24"),
    ("im1-grey-im0-colour", _write("p/im1.png", lambda: np.zeros((24, 48), np.uint8)),
     r"p/im1\.png: grey, but im0\.png is colour"),
    ("im0-not-a-png", _bytes("p/im0.png", b"\xff\xd8\xff\xe0 not a png at all"), r"p/im0\.png: not a readable image"),
    ("mask-wrong-size", _write("p/mask0nocc.png", lambda: np.zeros((12, 48), np.uint8)),
     r"p/mask0nocc\.png: expected a 48x24 mask like im0\.png, got 48x12"),
    ("mask-16-bit", _write("p/mask0nocc.png", lambda: np.zeros((24, 48), np.uint16)),
     r"p/mask0nocc\.png: expected an 8-bit PNG"),
    ("mask-colour", _write("p/mask0nocc.png", lambda: np.zeros((24, 48, 3), np.uint8)),
     r"p/mask0nocc\.png: expected a one-channel mask, got 3 channels"),
]

KITTI_CASES = [
    ("disparity-png-8-bit", _write(KD, lambda: np.full((24, 48), 3, np.uint8)),
     r"disp_occ_0/000000_10\.png: expected a 16-bit grey PNG \(KITTI disparity = value / 256, 0 = invalid\), "
     r"got 8-bit with 1 channel\(s\)"),
    ("disparity-png-three-channels", _write(KD, lambda: np.full((24, 48, 3), 768, np.uint16)),
     r"disp_occ_0/000000_10\.png: expected a 16-bit grey PNG .* got 16-bit with 3 channel\(s\)"),
    ("disparity-png-wrong-size", _write(KD, lambda: np.full((20, 48), 768, np.uint16)),
     r"disp_occ_0/000000_10\.png: is 48x20, but image_2/000000_10\.png is 48x24"),
    ("noc-not-within-occ", _write("training/disp_noc_0/000000_10.png", lambda: np.full((24, 48), 768, np.uint16)),
     r"disp_noc_0/000000_10\.png: 80 pixels valid here are invalid in disp_occ_0/000000_10\.png"),
    ("right-image-missing", _remove("training/image_3/000000_10.png"), r"image_3/000000_10\.png: missing"),
    ("noc-missing", _remove("training/disp_noc_0/000001_10.png"), r"disp_noc_0/000001_10\.png: missing"),
    ("calib-without-P_rect_03", _kitti_calib(f"P_rect_02: {_P}\n"),
     r"calib_cam_to_cam/000000\.txt: no P_rect_03 line \(expected P_rect_02 and P_rect_03\)"),
    ("calib-eleven-numbers", _kitti_calib(f"calib_time: x\nP_rect_02: {_P[:-2]}\nP_rect_03: {_P}\n"),
     r"calib_cam_to_cam/000000\.txt: line 2: P_rect_02: expected 12 numbers of a 3x4 projection matrix"),
    ("calib-zero-baseline", _kitti_calib(f"P_rect_02: {_P}\nP_rect_03: {_P}\n"),
     r"calib_cam_to_cam/000000\.txt: the projection matrices give a baseline of 0, expected > 0"),
    ("calib-file-missing", _remove("training/calib_cam_to_cam/000001.txt"),
     r"calib_cam_to_cam/000001\.txt: missing \(its folder holds the other pairs' calibration\)"),
    ("obj-map-wrong-size", _write("training/obj_map/000000_10.png", lambda: np.zeros((24, 40), np.uint8)),
     r"obj_map/000000_10\.png: expected a 48x24 object map like the left image, got 40x24"),
    ("obj-map-16-bit-colour", _write("training/obj_map/000000_10.png", lambda: np.ones((24, 48, 3), np.uint16)),
     r"obj_map/000000_10\.png: a 16-bit colour object map; expected an 8-bit or a grey PNG"),
]


def _one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text.strip(), f"not one line: {text!r}"
    return text


@pytest.mark.parametrize("case, corrupt, expected", [c for c in MIDDLEBURY_CASES],
                         ids=[c[0] for c in MIDDLEBURY_CASES])
def test_bad_middlebury_input(tmp_path, case, corrupt, expected):
    fx.middlebury_pair(tmp_path / "p")
    corrupt(tmp_path)
    with pytest.raises(ValueError) as e:
        load_benchmark(tmp_path, "middlebury")
    msg = _one_line(e.value)
    assert str(tmp_path) in msg and re.search(expected, msg), msg


@pytest.mark.parametrize("case, corrupt, expected", [c for c in KITTI_CASES], ids=[c[0] for c in KITTI_CASES])
def test_bad_kitti_input(tmp_path, case, corrupt, expected):
    fx.kitti_folder(tmp_path, 2015)
    corrupt(tmp_path)
    with pytest.raises(ValueError) as e:
        load_benchmark(tmp_path, "kitti")
    msg = _one_line(e.value)
    assert str(tmp_path) in msg and re.search(expected, msg), msg


ARGUMENT_CASES = [
    ("format-unknown", dict(fmt="sintel"), r"^format: expected one of \('middlebury', 'kitti', 'eth3d', 'middlebury2003'\), got 'sintel'$"),
    ("resolution-unknown", dict(resolution="double"), r"^resolution: expected one of \('full', 'half', 'quarter'\)"),
    ("kitti-at-half-resolution", dict(fmt="kitti", resolution="half"),
     r"^resolution: KITTI's sparse ground truth is evaluated at full resolution only, got 'half'$"),
    ("not-a-benchmark-folder", dict(empty=True), r": not a stereo benchmark folder \(Middlebury/ETH3D"),
    ("kitti-format-on-middlebury", dict(fmt="kitti"), r": not a KITTI stereo folder"),
    ("middlebury-format-on-empty", dict(fmt="middlebury", empty=True), r": holds no middlebury pair"),
    ("folder-missing", dict(missing=True), r"absent: no such benchmark folder$"),
    ("middeval3-root-with-two-resolutions", dict(middeval3=True),
     r": holds pairs in 2 folders \(trainingH, trainingQ\); pass one of them \(one resolution, with ground truth\)$"),
]


@pytest.mark.parametrize("case, kw, expected", ARGUMENT_CASES, ids=[c[0] for c in ARGUMENT_CASES])
def test_bad_reader_arguments(tmp_path, case, kw, expected):
    if kw.pop("middeval3", False):
        fx.middlebury_pair(tmp_path / "trainingH" / "Adirondack")
        fx.middlebury_pair(tmp_path / "trainingQ" / "Adirondack")
    elif not kw.pop("empty", False):
        fx.middlebury_pair(tmp_path / "p")
    root = tmp_path / "absent" if kw.pop("missing", False) else tmp_path
    with pytest.raises(ValueError) as e:
        load_benchmark(root, kw.get("fmt"), kw.get("resolution", "full"))
    msg = _one_line(e.value)
    assert re.search(expected, msg), msg


# --------------------------------------------------------------------------- Middlebury 2001/2003


def _mb03(corrupt: Callable[[Path], None], name: str = "venus", **kw: object) -> Callable[[Path], Path]:
    def make(root: Path) -> Path:
        fx.middlebury2003_scene(root / name, scale=8, **kw)
        corrupt(root / name)
        return root
    return make


MB2003_CASES = [
    ("unknown-scene-without-scale", _mb03(lambda f: None, name="aloe"), {},
     r"aloe/disp2\.png: unknown scene 'aloe': its disparity scale is not in the table \(tsukuba 16, venus 8, "
     r"teddy 4, cones 4\); give the scale"),
    ("disparity-16-bit", _mb03(lambda f: fx.write_png(f / "disp2.png", np.full((24, 48), 24, np.uint16))), {},
     r"venus/disp2\.png: expected an 8-bit disparity map, got 16-bit"),
    ("disparity-pgm-16-bit", _mb03(lambda f: (f / "disp2.png").unlink() or fx.write_pgm(
        f / "disp2.pgm", np.full((24, 48), 24, np.uint16))), {}, r"venus/disp2\.pgm: expected an 8-bit disparity map, got 16-bit"),
    ("disparity-wrong-size", _mb03(lambda f: fx.write_png(f / "disp2.png", np.full((24, 40), 24, np.uint8))), {},
     r"venus/disp2\.png: is 40x24, but im2\.png is 48x24"),
    ("disparity-colour", _mb03(lambda f: fx.write_png(f / "disp2.png", np.full((24, 48, 3), 24, np.uint8))), {},
     r"venus/disp2\.png: expected a one-channel disparity map, got 3 channels"),
    ("right-wrong-size", _mb03(lambda f: fx.write_png(f / "im6.png", np.zeros((20, 48, 3), np.uint8))), {},
     r"venus/im6\.png: is 48x20 colour, but im2\.png is 48x24 colour"),
    ("image-16-bit", _mb03(lambda f: fx.write_png(f / "im2.png", np.zeros((24, 48, 3), np.uint16))), {},
     r"venus/im2\.png: expected an 8-bit image, got 16-bit"),
    ("disparity-all-unknown", _mb03(lambda f: fx.write_png(f / "disp2.png", np.zeros((24, 48), np.uint8))), {},
     r"venus/disp2\.png: holds no known disparity"),
    ("disparity-truncated", _mb03(lambda f: (f / "disp2.png").write_bytes((f / "disp2.png").read_bytes()[:60])), {},
     r"venus/disp2\.png: "),
    ("scale-zero", _mb03(lambda f: None), {"scale": 0.0}, r"scale: expected a finite number > 0, got 0\.0"),
    ("scale-on-middlebury-2014", lambda root: (fx.middlebury_pair(root / "p"), root)[1], {"scale": 4.0, "fmt": "middlebury"},
     r"scale: applies to the middlebury2003 format only"),
    ("resolution-half", _mb03(lambda f: None), {"resolution": "half"},
     r"resolution: Middlebury 2001/2003 pairs are evaluated at their stored size only, got 'half'"),
]


@pytest.mark.parametrize("case, make, kw, expected", MB2003_CASES, ids=[c[0] for c in MB2003_CASES])
def test_bad_middlebury2003_input(tmp_path, case, make, kw, expected):
    root = make(tmp_path)
    with pytest.raises(ValueError) as e:
        load_benchmark(root, kw.get("fmt"), kw.get("resolution", "full"), scale=kw.get("scale"))
    msg = _one_line(e.value)
    assert re.search(expected, msg), msg


# --------------------------------------------------------------------------- stereo_depth --data

CLI_CASES = [
    ("default-out-refused", ["@full"], r"--out: a benchmark run needs its own results folder; the default .*results/"
                                r"stereo_depth holds the Mitsuba table"),
    ("max-disp-not-multiple-of-16", ["--max-disp", "17", "--out", "{out}"],
     r"--max-disp: expected a positive multiple of 16, got '17'"),
    ("max-disp-wider-than-image", ["--max-disp", "48", "--out", "{out}"],
     r"--max-disp: the disparity range \[0, 48\) must be narrower than the image \(48 px wide\)"),
    ("ndisp-wider-than-image", ["--out", "{out}", "@ndisp=64"],
     r"p/calib\.txt: ndisp=64: the disparity range \[0, 64\) must be narrower than the image \(48 px wide\)"),
    ("resolution-without-benchmark", ["--resolution", "half", "--out", "{out}", "@nodata"],
     r"--resolution, --max-disp, --gt-scale: apply to a benchmark --data folder only"),
    ("format-on-a-cache-root", ["--format", "eth3d", "--out", "{out}", "@nodata"],
     r": holds no eth3d pair"),
    ("volume-exceeds-free-memory", ["--out", "{out}", "@lowmem"],
     r"p: drlab's volumes for 48x24 x 16 disparities need about 0\.0 GiB, more than the 0\.0 GiB "
     r"available; use --resolution half or quarter, or --max-disp"),
    ("kitti-at-half-resolution", ["--resolution", "half", "--out", "{out}", "@kitti"],
     r"--resolution: KITTI's sparse ground truth is evaluated at full resolution only, got 'half'"),
    ("corrupt-pair-keeps-old-results", ["--out", "{out}", "@corrupt"], r"p/disp0\.pfm: expected 4608 bytes"),
    ("gt-scale-on-middlebury-2014", ["--gt-scale", "4", "--out", "{out}"],
     r"--gt-scale: applies to --format middlebury2003 only, got middlebury"),
    ("gt-scale-zero", ["--gt-scale", "0", "--out", "{out}"], r"--gt-scale: expected a finite number > 0, got '0'"),
]


@pytest.mark.parametrize("case, argv, expected", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_bad_stereo_depth_benchmark_run(tmp_path, capsys, monkeypatch, case, argv, expected):
    """One line `<prog>: <message>`, exit status 2; the previous --out folder is left as it was."""
    from experiments.stereo_depth import main
    from research.stereo import benchmark as stereo_benchmark

    if "@lowmem" in argv:
        monkeypatch.setattr(stereo_benchmark, "_free_memory", lambda: 1000)

    data = tmp_path / "data"
    out = tmp_path / "out"
    out.mkdir()
    (out / "metrics.json").write_text(json.dumps({"previous": True}))
    if "@nodata" in argv:
        data.mkdir()
    elif "@kitti" in argv:
        fx.kitti_folder(data)
    else:
        fx.middlebury_pair(data / "p")
    if "@ndisp=64" in argv:
        (data / "p" / "calib.txt").write_text(fx.calib_text(ndisp=64))
    if "@corrupt" in argv:
        fx.middlebury_pair(data / "q")
        _truncated_pfm(data)
    args = [a.format(out=out) for a in argv if not a.startswith("@")]
    size = [] if "@full" in argv else ["--smoke"]  # the full run's default --out is the committed results/
    rc = main([*size, "--no-progress", "--data", str(data), *args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and re.search(expected, err), err
    assert json.loads((out / "metrics.json").read_text()) == {"previous": True}
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]
    assert not list(tmp_path.glob("out.partial-*")) and not list(tmp_path.glob("out.old-*"))
