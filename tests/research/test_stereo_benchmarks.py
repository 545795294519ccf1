"""Stereo benchmarks: the Middlebury / KITTI / ETH3D readers on fixtures in their exact formats (written
by tests/research/stereo_fixtures.py), the protocol metrics against hand-computed cases, and
`stereo_depth --data` on each layout."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

import stereo_fixtures as fx
from research.datasets import detect_stereo_format, load_stereo_benchmark
from research.datasets.stereo_benchmarks import (detect_format, load_benchmark, load_eth3d, load_kitti,
                                                 load_middlebury, read_calib, read_kitti_disparity)
from research.registry import REPO_ROOT
from research.stereo.matching import bad_pixel_metrics, d1_outliers, kitti_d1, pool_protocol, protocol_metrics

# --------------------------------------------------------------------------- readers


@pytest.mark.parametrize("tsukuba_names, pgm", [(False, False), (True, True)], ids=["im2-png", "im3-pgm"])
def test_middlebury2003_round_trip(tmp_path, tsukuba_names, pgm):
    from research.datasets.middlebury2003 import SCALES, load_middlebury2003

    name = "tsukuba" if tsukuba_names else "venus"
    truth = fx.middlebury2003_scene(tmp_path / name, scale=SCALES[name], tsukuba_names=tsukuba_names, pgm=pgm)
    fx.middlebury2003_scene(tmp_path / "other", seed=1, scale=5)
    assert detect_format(tmp_path) == "middlebury2003" and detect_format(tmp_path / name) == "middlebury2003"
    (p,) = load_middlebury2003(tmp_path / name)
    assert p.benchmark == "middlebury2003" and p.name == name and not p.has_noc_mask
    np.testing.assert_array_equal(p.left_image, truth["left"])
    np.testing.assert_array_equal(p.right_image, truth["right"])
    np.testing.assert_array_equal(p.mask, truth["known"])
    np.testing.assert_array_equal(p.noc, truth["known"])
    np.testing.assert_allclose(p.disparity, truth["disparity"], rtol=0, atol=1e-6)
    assert p.ndisp == {"tsukuba": 16, "venus": 20}[name]
    # A folder of scenes: every scene, sorted; an unknown scene needs the scale, which then applies to all.
    pairs = load_benchmark(tmp_path, scale=5.0)
    assert [q.name for q in pairs] == sorted(["other", name])
    np.testing.assert_allclose(pairs[0].disparity[:, 2:], 6.0 * (pairs[0].disparity[:, 2:] > 3.5)
                               + 3.0 * (pairs[0].disparity[:, 2:] <= 3.5), atol=0.2)


def test_middlebury2003_protocol_by_hand():
    gt = np.array([[1.0, 2.0, 10.0, 80.0]])
    pred = np.array([[1.4, 3.5, 14.0, 84.5]])
    known = np.array([[True, True, True, False]])
    row = protocol_metrics("middlebury2003", pred, np.ones_like(known), gt, known, known)
    assert set(row) == {"all"}
    r = row["all"]
    # errors 0.4, 1.5, 4.0 on the three known pixels (the fourth, 4.5 px off, is unknown)
    assert r["bad0.5"] == pytest.approx(2 / 3) and r["bad1"] == pytest.approx(2 / 3)
    assert r["bad2"] == pytest.approx(1 / 3) and r["bad4"] == 0.0
    assert r["d1"] == pytest.approx(1 / 3) and r["avgerr"] == pytest.approx((0.4 + 1.5 + 4.0) / 3)
    assert r["pixels"] == 3 and r["density"] == 1.0
    pooled = pool_protocol("middlebury2003", [row, row])
    assert pooled["all"]["d1"] == pytest.approx(1 / 3)


def test_calib_txt_is_read_exactly(tmp_path):
    (tmp_path / "calib.txt").write_text(
        "cam0=[3997.684 0 1176.728; 0 3997.684 1011.728; 0 0 1]\n"
        "cam1=[3997.684 0 1307.839; 0 3997.684 1011.728; 0 0 1]\n"
        "doffs=131.111\nbaseline=193.001\nwidth=2964\nheight=1988\nndisp=280\nisint=0\nvmin=31\nvmax=257\n"
        "dyavg=0.918\ndymax=1.516\n")
    c = read_calib(tmp_path / "calib.txt")
    assert c.cam0[0, 0] == 3997.684 and c.cam0[0, 2] == 1176.728 and c.cam1[0, 2] == 1307.839
    assert (c.doffs, c.baseline, c.width, c.height, c.ndisp, c.vmin, c.vmax, c.isint) == \
        (131.111, 193.001, 2964, 1988, 280, 31.0, 257.0, 0)
    half = c.scaled(2)  # as MiddEval3's trainingH calibration: f, cx, cy, doffs halved, ndisp 140
    assert half.cam0[0, 0] == 3997.684 / 2 and half.cam0[1, 2] == 1011.728 / 2 and half.cam0[2, 2] == 1.0
    assert (half.doffs, half.width, half.height, half.ndisp, half.baseline) == (131.111 / 2, 1482, 994, 140, 193.001)


@pytest.mark.parametrize("little_endian", [True, False], ids=["pfm-little-endian", "pfm-big-endian"])
def test_middlebury_round_trip(tmp_path, little_endian):
    w = fx.middlebury_pair(tmp_path / "Adirondack")
    if not little_endian:
        fx.write_pfm(tmp_path / "Adirondack" / "disp0.pfm", w["gt"], little_endian=False)
    (p,) = load_middlebury(tmp_path / "Adirondack")
    assert p.benchmark == "middlebury" and p.name == "Adirondack" and p.resolution == "full"
    assert np.array_equal(p.left_image, w["left"]) and np.array_equal(p.right_image, w["right"])
    assert p.left_image.dtype == np.uint8 and p.left.shape == (fx.H, fx.W, 4) and np.all(p.left[..., 3] == 1)
    known = np.isfinite(w["gt"])
    assert np.array_equal(p.mask, known) and np.array_equal(p.noc, w["mask"] == 255)
    assert np.array_equal(p.disparity, np.where(known, w["gt"], 0))
    assert p.has_noc_mask and p.ndisp == fx.NDISP and (p.vmin, p.vmax) == (2.0, 7.0)
    assert p.doffs == fx.CALIB["doffs"] and p.baseline == fx.CALIB["baseline"]
    # depth = baseline * f / (d + doffs): at a 6 px pixel, 193.001 * 100 / 8.5
    assert p.depth[10, 20] == pytest.approx(193.001 * 100 / 8.5, rel=1e-6) and p.depth[0, 0] == 0
    assert p.left_camera.fx == 100 and p.right_camera.cx == fx.CALIB["cx"] + fx.CALIB["doffs"]
    assert p.right_camera.center[0] == pytest.approx(fx.CALIB["baseline"])


def test_middlebury_half_and_quarter_resolution(tmp_path):
    w = fx.middlebury_pair(tmp_path / "s")
    gt = w["gt"].astype(np.float64)
    gt[4, 7] = 5.0  # one odd value: the half-resolution pixel (2, 3) is the mean of 3, 3, 3, 5 over 2
    fx.write_pfm(tmp_path / "s" / "disp0.pfm", gt.astype(np.float32))
    (h,) = load_middlebury(tmp_path, "half")
    assert h.resolution == "half" and h.disparity.shape == (fx.H // 2, fx.W // 2)
    assert h.disparity[2, 3] == pytest.approx((3 + 3 + 3 + 5) / 4 / 2)
    assert h.disparity[5, 10] == 3.0 and h.disparity[0, 0] == 0 and not h.mask[0, 0]  # 6 px / 2; an inf block
    assert not h.mask[0, 2] and h.mask[0, 3]  # columns 4-5 hold one inf (column 4), 6-7 none
    assert h.noc[5, 10] and not h.noc[4, 15]  # columns 30-31 are occluded (mask 128)
    assert h.left_camera.fx == 50 and h.ndisp == 8 and h.doffs == fx.CALIB["doffs"] / 2
    left = w["left"].astype(np.float64)
    assert h.left_image[1, 2, 0] == np.floor(left[2:4, 4:6, 0].mean() + 0.5)
    (q,) = load_middlebury(tmp_path, "quarter")
    assert q.disparity.shape == (fx.H // 4, fx.W // 4) and q.ndisp == 4 and q.left_camera.fx == 25


def test_middlebury_2021_without_mask_and_a_folder_of_pairs(tmp_path):
    fx.middlebury_pair(tmp_path / "data" / "artroom1", with_mask=False)
    fx.middlebury_pair(tmp_path / "data" / "bandsaw1", seed=1)
    pairs = load_benchmark(tmp_path)  # two levels down, sorted
    assert [p.name for p in pairs] == ["artroom1", "bandsaw1"]
    assert not pairs[0].has_noc_mask and np.array_equal(pairs[0].noc, pairs[0].mask) and pairs[1].has_noc_mask


def test_eth3d_round_trip_and_format_detection(tmp_path):
    w = fx.eth3d_pair(tmp_path / "eth" / "delivery_area_1l")
    fx.middlebury_pair(tmp_path / "mb" / "Motorcycle")
    fx.kitti_folder(tmp_path / "k15", 2015)
    fx.kitti_folder(tmp_path / "k12", 2012)
    assert [detect_format(tmp_path / n) for n in ("eth", "mb", "k15", "k15/training", "k12")] == \
        ["eth3d", "middlebury", "kitti", "kitti", "kitti"]
    assert detect_stereo_format is detect_format and load_stereo_benchmark is load_benchmark  # the package's names
    (tmp_path / "empty" / "sub").mkdir(parents=True)
    assert detect_format(tmp_path / "empty") is None and detect_format(tmp_path / "absent") is None
    (p,) = load_eth3d(tmp_path / "eth")
    assert p.benchmark == "eth3d" and p.left_image.ndim == 2 and np.array_equal(p.left_image, w["left"])
    assert np.array_equal(p.mask, np.isfinite(w["gt"])) and p.doffs == 0.0


def test_eth3d_ground_truth_in_its_separate_tree(tmp_path):
    w = fx.eth3d_pair(tmp_path / "two_view_training" / "playground_1l")
    gt_dir = tmp_path / "two_view_training_gt" / "playground_1l"
    gt_dir.mkdir(parents=True)
    for name in ("disp0GT.pfm", "mask0nocc.png"):
        (tmp_path / "two_view_training" / "playground_1l" / name).rename(gt_dir / name)
    assert detect_format(tmp_path / "two_view_training") == "eth3d"
    (p,) = load_benchmark(tmp_path / "two_view_training")
    assert p.has_noc_mask and np.array_equal(p.noc, w["mask"] == 255) and np.array_equal(p.mask, np.isfinite(w["gt"]))


@pytest.mark.parametrize("version", [2015, 2012])
def test_kitti_round_trip(tmp_path, version):
    written = fx.kitti_folder(tmp_path, version)
    pairs = load_kitti(tmp_path)
    assert [p.name for p in pairs] == ["000000", "000001"]
    for p in pairs:
        raw = written[p.name]
        assert p.benchmark == "kitti" and np.array_equal(p.left_image, raw["left"])
        assert np.array_equal(p.mask, raw["occ"] > 0) and np.array_equal(p.noc, raw["noc"] > 0)
        assert np.array_equal(p.disparity, raw["occ"].astype(np.float32) / 256)
        assert (p.foreground is not None) == (version == 2015)
        assert p.baseline == pytest.approx(fx.KITTI_B, rel=1e-12) and p.left_camera.fx == fx.KITTI_F
        k = np.argwhere(p.mask)[0]
        assert p.depth[tuple(k)] == pytest.approx(fx.KITTI_B * fx.KITTI_F / p.disparity[tuple(k)], rel=1e-6)


def _object_maps(folder: Path, shape: tuple[int, int]) -> list[Path]:
    """Object maps in every PNG form png++'s gray_pixel image takes, written by Pillow: palette (with
    and without a transparent entry), RGB, RGBA, grey, grey + alpha, 16-bit grey and 1-bit."""
    from PIL import Image

    rng = np.random.default_rng(5)
    index = rng.integers(0, 6, shape).astype(np.uint8)
    # black, red, blues just below and at libpng's luminance threshold (2366 b >> 15 > 0 from b = 14), grey
    palette = [0, 0, 0, 255, 0, 0, 0, 0, 13, 0, 0, 14, 1, 1, 1, 3, 0, 0]
    rgb = rng.integers(0, 20, (*shape, 3)).astype(np.uint8)
    rgb[rng.random(shape) < 0.3] = 0
    grey = rng.integers(0, 3, shape).astype(np.uint8)
    grey16 = (rng.integers(0, 3, shape) * rng.choice([1, 256, 300], shape)).astype(np.int32)
    images = {"palette": Image.fromarray(index, "P"), "palette-trns": Image.fromarray(index, "P"),
              "rgb": Image.fromarray(rgb, "RGB"), "rgba": Image.fromarray(np.dstack([rgb, grey * 100]), "RGBA"),
              "grey": Image.fromarray(grey, "L"), "grey-alpha": Image.fromarray(np.dstack([grey, grey]), "LA"),
              "grey16": Image.fromarray(grey16, "I").convert("I;16"), "1-bit": Image.fromarray(grey > 0)}
    paths = []
    for name, image in images.items():
        if image.mode == "P":
            image.putpalette(palette)
        path = folder / f"{name}.png"
        image.save(path, **({"transparency": 2} if name == "palette-trns" else {}))
        paths.append(path)
    return paths


def test_kitti_object_map_in_palette_form(tmp_path):
    """A palette obj_map marks as foreground the pixels whose colour has a non-zero libpng luminance,
    as the devkit's png++ reader sees them; an RGB one the same."""
    from PIL import Image

    fx.kitti_folder(tmp_path, 2015, ids=("000000",))
    (grey,) = load_kitti(tmp_path)
    index = np.zeros((fx.H, fx.W), np.uint8)
    index[6:18, 14:30] = 1   # the fixture's objects, in red
    index[0:3, 0:5] = 2      # blue 13: luminance 2366 * 13 >> 15 = 0, background for the devkit
    index[20:, 40:] = 3      # blue 14: luminance 1, foreground
    image = Image.fromarray(index, "P")
    image.putpalette([0, 0, 0, 255, 0, 0, 0, 0, 13, 0, 0, 14])
    image.save(tmp_path / "training" / "obj_map" / "000000_10.png")
    (p,) = load_kitti(tmp_path)
    expect = grey.foreground.copy()
    expect[20:, 40:] = True
    np.testing.assert_array_equal(p.foreground, expect)
    image.convert("RGB").save(tmp_path / "training" / "obj_map" / "000000_10.png")
    np.testing.assert_array_equal(load_kitti(tmp_path)[0].foreground, expect)


def test_kitti_object_map_read_as_libpng_reads_it(tmp_path):
    """Every PNG form of an object map reads to the grey values that libpng gives with png++'s
    gray_pixel transforms (tests/research/libpng_gray.c, built here with the system's libpng)."""
    import shutil

    from research.datasets.stereo_benchmarks import _devkit_gray

    source = Path(__file__).with_name("libpng_gray.c")
    exe = tmp_path / "libpng_gray"
    if shutil.which("cc") is None or not Path("/usr/include/png.h").is_file():
        pytest.skip("no C compiler or libpng headers to build the libpng reference")
    build = subprocess.run(["cc", str(source), "-o", str(exe), "-lpng16"], capture_output=True, text=True)
    if build.returncode != 0:
        pytest.skip(f"libpng reference did not build: {build.stderr.strip()[:200]}")
    shape = (7, 9)
    for path in _object_maps(tmp_path, shape):
        run = subprocess.run([str(exe), str(path)], capture_output=True, text=True)
        if run.returncode == 3:
            pytest.skip("libpng older than 1.5.5 (other grey weights)")
        assert run.returncode == 0, run.stderr
        out = run.stdout.split()
        assert [int(v) for v in out[:2]] == [shape[1], shape[0]]
        np.testing.assert_array_equal(_devkit_gray(path, shape), np.array(out[2:], int).reshape(shape),
                                      err_msg=path.name)


def test_kitti_without_calibration_and_non_integer_disparities(tmp_path):
    fx.kitti_folder(tmp_path, 2015, ids=("000007",), calib=False)
    raw = np.full((fx.H, fx.W), 3 * 256 + 77, np.uint16)  # 3.30078125 px
    raw[0, 0] = 0
    fx.write_png(tmp_path / "training" / "disp_occ_0" / "000007_10.png", raw)
    disp, valid = read_kitti_disparity(tmp_path / "training" / "disp_occ_0" / "000007_10.png")
    assert disp[1, 1] == np.float32(3.30078125) and not valid[0, 0] and valid.sum() == raw.size - 1
    (p,) = load_kitti(tmp_path / "training")
    assert p.left_camera is None and math.isnan(p.baseline) and not p.depth.any()


# --------------------------------------------------------------------------- protocol metrics


def test_bad_pixel_metrics_hand_computed():
    gt = np.array([[10.0, 10.0, 10.0], [20.0, 20.0, 20.0]])
    pred = gt + np.array([[0.25, -0.75, 1.5], [-3.0, 5.0, 0.0]])
    mask = np.array([[True, True, True], [True, True, False]])
    m = bad_pixel_metrics(pred, gt, mask, (0.5, 1.0, 2.0, 4.0))
    # errors on the mask: 0.25, 0.75, 1.5, 3, 5
    assert m == {"bad0.5": 4 / 5, "bad1": 3 / 5, "bad2": 2 / 5, "bad4": 1 / 5, "avgerr": 10.5 / 5, "pixels": 5}
    empty = bad_pixel_metrics(pred, gt, np.zeros_like(mask), (1.0,))
    assert math.isnan(empty["bad1"]) and empty["pixels"] == 0


def test_kitti_d1_hand_computed():
    # D1 needs both: error > 3 px and > 5 % of the true disparity.
    gt = np.array([[100.0, 100.0, 50.0, 20.0], [40.0, 40.0, 10.0, 10.0]])
    err = np.array([[4.0, 6.0, 4.0, 3.5], [2.0, 3.0, 0.0, 9.0]])
    # outliers: 100/4 no (4 < 5), 100/6 yes, 50/4 yes, 20/3.5 yes; 40/2 no, 40/3 no (not > 3), 10/9 yes
    assert np.array_equal(d1_outliers(gt + err, gt), [[False, True, True, True], [False, False, False, True]])
    occ = np.ones(gt.shape, bool)
    noc = occ.copy()
    noc[:, 3] = False
    fg = np.zeros(gt.shape, bool)
    fg[0, :2] = True
    r = kitti_d1(gt + err, gt, noc, occ, fg)
    assert r["noc"] == {"d1_bg": 1 / 4, "pixels_bg": 4, "d1_fg": 1 / 2, "pixels_fg": 2, "d1_all": 2 / 6,
                        "pixels_all": 6, "pixels": 6}
    assert r["occ"]["d1_all"] == 4 / 8 and r["occ"]["d1_bg"] == 3 / 6 and r["occ"]["d1_fg"] == 1 / 2
    assert set(kitti_d1(gt + err, gt, noc, occ)["noc"]) == {"d1_all", "pixels_all", "pixels"}


def test_protocol_metrics_fill_and_pooling():
    gt = np.full((1, 4), 10.0)
    disp = np.array([[10.0, 0.0, 0.0, 20.0]])
    valid = np.array([[True, False, False, True]])  # filled with min(10, 20) = 10: errors 0, 0, 0, 10
    all_mask = np.ones((1, 4), bool)
    noc = np.array([[True, True, True, False]])
    r = protocol_metrics("eth3d", disp, valid, gt, noc, all_mask)
    assert r["nonocc"]["bad1"] == 0.0 and r["all"]["bad1"] == 0.25 and r["all"]["avgerr"] == 2.5
    assert r["nonocc"]["density"] == 1 / 3 and r["all"]["density"] == 0.5
    # Middlebury / ETH3D pool as the mean over pairs; KITTI over pixels.
    big = {"nonocc": {"bad1": 0.0, "avgerr": 0.0, "density": 1.0, "pixels": 300},
           "all": {"bad1": 0.0, "avgerr": 0.0, "density": 1.0, "pixels": 300}}
    small = {"nonocc": {"bad1": 1.0, "avgerr": 4.0, "density": 0.5, "pixels": 100},
             "all": {"bad1": 1.0, "avgerr": 4.0, "density": 0.5, "pixels": 100}}
    pooled = pool_protocol("eth3d", [big, small])
    assert pooled["all"]["bad1"] == 0.5 and pooled["all"]["avgerr"] == 2.0 and pooled["all"]["pixels"] == 400
    k1 = {m: {"d1_all": 0.0, "pixels_all": 300, "pixels": 300, "density": 1.0} for m in ("noc", "occ")}
    k2 = {m: {"d1_all": 1.0, "pixels_all": 100, "pixels": 100, "density": 1.0} for m in ("noc", "occ")}
    assert pool_protocol("kitti", [k1, k2])["occ"]["d1_all"] == 0.25
    with pytest.raises(ValueError, match="protocol: expected one of"):
        protocol_metrics("sintel", disp, valid, gt, noc, all_mask)


_D = np.zeros((3, 4))
_M = np.ones((3, 4), bool)


@pytest.mark.parametrize("call, message", [
    (lambda: bad_pixel_metrics(_D, np.zeros((3, 5)), _M, (1.0,)), r"^pred, gt, masks: expected \(H, W\) arrays of one shape"),
    (lambda: bad_pixel_metrics(np.full((3, 4), np.nan), _D, _M, (1.0,)), r"^pred, gt: non-finite values inside the mask"),
    (lambda: kitti_d1(_D, _D, _M, _M, foreground=np.ones((2, 4), bool)), r"^foreground: expected shape \(3, 4\)"),
    (lambda: pool_protocol("sintel", []), r"^protocol: expected one of"),
    (lambda: pool_protocol("kitti", []), r"^rows: expected the scores of at least one pair"),
])
def test_protocol_bad_inputs_name_the_argument(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# --------------------------------------------------------------------------- stereo_depth --data


def _write(fmt: str, root: Path) -> Path:
    if fmt == "middlebury":
        fx.middlebury_pair(root / "trainingQ" / "Adirondack")
        fx.middlebury_pair(root / "trainingQ" / "Jadeplant", seed=1, with_mask=False)
    elif fmt == "eth3d":
        fx.eth3d_pair(root / "delivery_area_1l")
    elif fmt == "middlebury2003":  # run with --gt-scale 8, which overrides tsukuba's 16 too
        fx.middlebury2003_scene(root / "tsukuba", scale=8, tsukuba_names=True, pgm=True)
        fx.middlebury2003_scene(root / "other", seed=1, scale=8)
    else:
        fx.kitti_folder(root, int(fmt[-4:]))
    return root


@pytest.mark.timeout(240)
@pytest.mark.parametrize("fmt", ["middlebury", "eth3d", "kitti2015", "kitti2012", "middlebury2003"])
def test_stereo_depth_on_a_benchmark_folder(tmp_path, fmt):
    data = _write(fmt, tmp_path / "data")
    out = tmp_path / "out"
    extra = ["--max-disp", "16"] if fmt.startswith("kitti") else ["--gt-scale", "8"] if fmt == "middlebury2003" else []
    r = subprocess.run([sys.executable, "-m", "experiments.stereo_depth", "--smoke", "--no-progress", "--data",
                        str(data), "--out", str(out), *extra], cwd=REPO_ROOT, capture_output=True, text=True,
                       timeout=200)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    doc = json.loads((out / "metrics.json").read_text())
    bench = fmt[:5] if fmt.startswith("kitti") else fmt
    assert doc["config"]["benchmark"] == bench and doc["metrics"]["benchmark"] == bench
    methods = doc["metrics"]["methods"]
    assert set(methods) == {"drlab default", "BT + SGM-4 soft-argmin", "ZNCC + SGM-4", "SAD + SGM-4 soft-argmin",
                            "census + SGM-8", "OpenCV StereoSGBM bs3", "OpenCV StereoSGBM bs5"}
    table = (out / "table.md").read_text()
    assert (out / "disparity_maps.png").stat().st_size > 1000
    assert f"Dataset: {bench}" in table and "Protocol:" in table and "resolution full" in table
    for m in methods.values():
        pooled = m["pooled"]
        if bench == "kitti":
            assert 0 <= pooled["noc"]["d1_all"] <= 1 and 0 <= pooled["occ"]["d1_all"] <= 1
            assert ("d1_fg" in pooled["noc"]) == (fmt == "kitti2015")
        elif bench == "middlebury2003":
            assert set(pooled) == {"all"} and 0 <= pooled["all"]["d1"] <= 1 and pooled["all"]["avgerr"] >= 0
        else:
            assert 0 <= pooled["nonocc"]["bad2"] <= 1 and pooled["all"]["avgerr"] >= 0
    # The fixtures are textured and exactly shifted: drlab's census + SGM-8 and its default recover them. The
    # default leaves the left D - 1 columns to the fill from the right (border invalidation), which on these
    # 48-px-wide fixtures carries the 6 px square's disparity over up to 15 columns of 3 px background, up to
    # 16 % of the pixels, hence its looser bound.
    for name, bound in (("census + SGM-8", 0.1), ("drlab default", 0.2)):
        best = methods[name]["pooled"]
        got = best["noc"]["d1_all"] if bench == "kitti" else best["all" if bench == "middlebury2003" else "nonocc"]["bad2"]
        assert got < bound, (name, got)
    if fmt == "middlebury2003":
        assert "No occlusion masks" in table and "tsukuba" in table and "other" in table
        # "other" took no part in choosing drlab's default, tsukuba did: a table pools "other" alone.
        assert "Held out from every choice of drlab's default (other; tsukuba chose it)" in table
        held = methods["drlab default"]["pooled_held_out"]["all"]
        assert held["d1"] == methods["drlab default"]["pairs"]["other"]["all"]["d1"]
    if fmt == "middlebury":
        assert "Jadeplant" in table and "without mask0nocc.png" in table


def test_without_data_the_run_stays_the_mitsuba_one(tmp_path, monkeypatch):
    """The default --data (the cache root) is never taken for a benchmark, whatever it holds."""
    import argparse

    from experiments.stereo_depth import benchmark_format
    from research import registry
    from research.experiment import Context

    fx.middlebury_pair(tmp_path / "data" / "Adirondack")
    monkeypatch.setattr(registry, "default_data_dir", lambda: tmp_path / "data")

    def ctx(data: Path) -> Context:
        args = argparse.Namespace(data=data, format=None, resolution="full", max_disp=None, gt_scale=None)
        return Context("stereo_depth", args, "cpu", tmp_path / "tmp", tmp_path / "out")

    assert benchmark_format(ctx(tmp_path / "data")) is None
    assert benchmark_format(ctx(tmp_path / "data" / "Adirondack")) == "middlebury"


def test_kitti_2012_grey_pairs_use_P0_and_P1(tmp_path):
    fx.kitti_folder(tmp_path, 2012, ids=("000003",))
    t = tmp_path / "training"
    for side in ("0", "1"):
        (t / f"colored_{side}").rename(t / f"image_{side}")
        path = t / f"image_{side}" / "000003_10.png"
        fx.write_png(path, np.ascontiguousarray(cv2.imread(str(path))[..., 1]))  # grey, as KITTI 2012's image_0/1
    calib = (t / "calib" / "000003.txt").read_text().splitlines()
    # P0/P1 with a 0.3 m baseline; P2/P3 (the colour cameras) keep theirs, 0.54 m
    calib[1] = "P1: " + " ".join(f"{v:.12e}" for v in [fx.KITTI_F, 0, 23.5, -fx.KITTI_F * 0.3, 0, fx.KITTI_F, 11.5, 0,
                                                          0, 0, 1, 0])
    (t / "calib" / "000003.txt").write_text("\n".join(calib) + "\n")
    assert detect_format(tmp_path) == "kitti"
    (p,) = load_kitti(tmp_path)
    assert p.left_image.ndim == 2 and p.baseline == pytest.approx(0.3, rel=1e-12)


def test_calib_txt_and_pfm_spellings_middlebury_tools_accept(tmp_path):
    """calib.txt with Windows line endings, spaces around '=' and inside the matrices, a tab, and keys
    the reader does not know; disp0.pfm with the header Scharstein's pfmLib writes (one token a line)."""
    w = fx.middlebury_pair(tmp_path / "Motorcycle")
    f, cx, cy, doffs = fx.CALIB["f"], fx.CALIB["cx"], fx.CALIB["cy"], fx.CALIB["doffs"]
    (tmp_path / "Motorcycle" / "calib.txt").write_bytes(
        (f"cam0 = [{f} 0 {cx};0 {f} {cy};0 0 1]\r\ncam1= [ {f}  0  {cx + doffs} ; 0 {f} {cy} ; 0 0 1 ]\r\n"
         f"doffs =\t{doffs}\r\nbaseline={fx.CALIB['baseline']}\r\nwidth={fx.W}\r\nheight={fx.H}\r\n"
         f"ndisp={fx.NDISP}\r\nisint=0\r\nvmin=2\r\nvmax=7\r\ndyavg=0\r\ndymax=0\r\nscene=motorcycle\r\n\r\n").encode())
    gt = w["gt"]
    (tmp_path / "Motorcycle" / "disp0.pfm").write_bytes(f"Pf\n{fx.W}\n{fx.H}\n-1\n".encode()
                                                        + np.ascontiguousarray(gt[::-1], "<f4").tobytes())
    (p,) = load_middlebury(tmp_path / "Motorcycle")
    assert p.left_camera.fx == f and p.right_camera.cx == cx + doffs and p.doffs == doffs
    assert p.ndisp == fx.NDISP and (p.vmin, p.vmax) == (2.0, 7.0)
    known = np.isfinite(gt)
    assert np.array_equal(p.mask, known) and np.array_equal(p.disparity, np.where(known, gt, 0))


@pytest.mark.parametrize("name,stems", [
    ("venus", ("im2", "im6", "disp2")),  # the sets' "ppm" archives: im2.ppm, im6.ppm, disp2.pgm
    ("tsukuba", ("scene1.row3.col3", "scene1.row3.col4", "truedisp.row3.col3")),  # the 2001 release's names
], ids=["venus-ppm", "tsukuba-2001-names"])
def test_middlebury2003_ppm_images_and_the_2001_tsukuba_names(tmp_path, name, stems):
    from research.datasets.middlebury2003 import SCALES, load_middlebury2003

    left, right, disp = fx.scene(3)
    raw = np.rint(disp * SCALES[name]).astype(np.uint8)
    raw[:, :2] = 0
    folder = tmp_path / name
    folder.mkdir()
    for stem, img in zip(stems[:2], (left, right)):  # binary P6 PPM, RGB as stored
        (folder / f"{stem}.ppm").write_bytes(f"P6\n{fx.W} {fx.H}\n255\n".encode() + np.ascontiguousarray(img).tobytes())
    fx.write_pgm(folder / f"{stems[2]}.pgm", raw)
    assert detect_format(tmp_path) == "middlebury2003"
    (p,) = load_middlebury2003(folder)
    np.testing.assert_array_equal(p.left_image, left)
    np.testing.assert_array_equal(p.right_image, right)
    np.testing.assert_array_equal(p.mask, raw > 0)
    np.testing.assert_allclose(p.disparity, np.where(raw > 0, raw / SCALES[name], 0.0), rtol=0, atol=1e-6)
