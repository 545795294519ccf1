"""Middlebury multi-view folders (research.datasets.middlebury_mview) and the real_photos experiment's
skip line: fixtures written in the exact *_par.txt format, with hand-written K, R, t."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from research import io
from research.datasets import DatasetError, detect_format, open_dataset
from research.datasets.middlebury_mview import (PIXEL_CENTRE_OFFSET, box_mask, camera_from_par, load_middlebury_mview,
                                                par_line, read_par, scene_radius)

REPO = Path(__file__).resolve().parents[2]
W, H = 16, 12
# templeRing's first camera, as its file writes it (K with 6 decimals, R with 17-20 digits)
TEMPLE_K = "1520.400000 0.000000 302.320000 0.000000 1525.900000 246.870000 0.000000 0.000000 1.000000"
TEMPLE_R = ("0.02187598221295043000 0.98329680886213122000 -0.18068986436368856000 0.99856708067455469000 "
            "-0.01266114646423925600 0.05199500709979997700 0.04883878372068499500 -0.18156839221560722000 "
            "-0.98216479887691122000")
TEMPLE_T = "-0.0292149526928 -0.0241923869131 0.52269561933"


def rot(axis, angle_deg: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(angle_deg)
    A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * A + (1 - math.cos(t)) * A @ A


def hand_cameras(n: int):
    """(name, K, R, t) written by hand: a ring of cameras about the z axis, looking at the origin."""
    out = []
    for k in range(n):
        # world-to-camera: turn the world so that the camera at angle a looks down +z at the origin
        a = 360.0 * k / n
        R = rot([1, 0, 0], -90.0) @ rot([0, 0, 1], -a - 90.0)  # camera x = tangent, y = -world z, z = inward
        t = np.array([0.0, 0.0, 4.0])
        K = np.array([[20.0 + k, 0.0, 7.5 + 0.1 * k], [0.0, 21.0, 5.25], [0.0, 0.0, 1.0]])
        out.append((f"view{k + 1:04d}.png", K, R, t))
    return out


def fmt(x: float) -> str:
    return f"{x:.17g}"


def write_folder(root: Path, cams, *, header: str | None = None, lines: list[str] | None = None,
                 images: bool = True, size=(W, H), readme: str | None = None, stem: str = "scene") -> Path:
    root.mkdir(parents=True, exist_ok=True)
    if lines is None:
        lines = [" ".join([name, *map(fmt, K.ravel()), *map(fmt, R.ravel()), *map(fmt, t)]) for name, K, R, t in cams]
    (root / f"{stem}_par.txt").write_text((header if header is not None else str(len(lines))) + "\n"
                                          + "\n".join(lines) + "\n")
    if images:
        rng = np.random.default_rng(0)
        for name, *_ in cams:
            io.write_png_u8(root / name, rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8))
    if readme is not None:
        (root / "README.txt").write_text(readme)
    return root


def test_projection_matches_numpy_K_R_t_with_the_half_pixel_shift(tmp_path):
    cams = hand_cameras(5)
    root = write_folder(tmp_path / "scene", cams)
    assert detect_format(root) == "middlebury_mview"
    ds = load_middlebury_mview(root)
    assert ds.format == "middlebury_mview" and ds.scene == "scene" and len(ds.views) == 5
    rng = np.random.default_rng(1)
    X = rng.uniform(-0.5, 0.5, size=(20, 3))
    for v, (name, K, R, t) in zip(ds.views, cams):
        assert v.name == name
        x = (K @ (R @ X.T + t[:, None])).T  # the file's projection K (R X + t)
        uv_file = x[:, :2] / x[:, 2:]
        uv, z = v.camera.project(X)
        assert np.abs(uv - (uv_file + PIXEL_CENTRE_OFFSET)).max() < 1e-9  # drlab centres pixels at +0.5
        assert np.abs(z - x[:, 2]).max() < 1e-9  # z-depth: the third row, K's last row being (0, 0, 1)
        assert np.abs(v.camera.center - (-R.T @ t)).max() < 1e-12
        assert np.abs(v.camera.R - R.T).max() < 1e-12
        assert (v.camera.width, v.camera.height) == (W, H)
    # the camera looks at the origin: it projects to the principal point
    c0 = ds.views[0].camera
    uv, _ = c0.project(np.zeros((1, 3)))
    assert np.abs(uv[0] - [c0.cx, c0.cy]).max() < 1e-9


def test_templering_line_is_read_as_written(tmp_path):
    """The real file's precision (6-decimal K, 20-digit R) passes the rotation check; K and t as written."""
    line = f"templeR0001.png {TEMPLE_K} {TEMPLE_R} {TEMPLE_T}"
    root = write_folder(tmp_path / "templeRing", [("templeR0001.png", None, None, None)], lines=[line, ],
                        size=(64, 48))
    (e,) = read_par(root / "scene_par.txt")
    assert e.name == "templeR0001.png" and e.line == 2
    assert e.K[0, 0] == 1520.4 and e.K[1, 1] == 1525.9 and e.K[0, 2] == 302.32 and e.K[1, 2] == 246.87
    R_file = np.array([float(x) for x in TEMPLE_R.split()]).reshape(3, 3)
    assert np.abs(e.R - R_file).max() < 1e-12 and np.linalg.det(e.R) == pytest.approx(1.0, abs=1e-15)
    assert e.t.tolist() == [float(x) for x in TEMPLE_T.split()]
    cam = camera_from_par(e, 640, 480)
    assert cam.cx == 302.82 and cam.cy == 247.37


def test_six_digit_rotation_text_is_accepted(tmp_path):
    cams = hand_cameras(3)
    lines = [" ".join([name, *(f"{x:.6f}" for x in K.ravel()), *(f"{x:.6f}" for x in R.ravel()),
                       *(f"{x:.6f}" for x in t)]) for name, K, R, t in cams]
    ds = load_middlebury_mview(write_folder(tmp_path / "s", cams, lines=lines))
    for v, (_, _, R, _) in zip(ds.views, cams):
        assert np.abs(v.camera.R - R.T).max() < 5e-6


def test_every_8th_view_by_name_is_a_test_view_and_the_protocol_says_so(tmp_path):
    cams = hand_cameras(17)
    root = write_folder(tmp_path / "s", list(reversed(cams)))  # listed out of order: sorted by name
    ds = open_dataset(root, "middlebury_mview")
    assert [v.name for v in ds.split_views("test")] == ["view0001.png", "view0009.png", "view0017.png"]
    assert len(ds.split_views("train")) == 14
    p = ds.protocol
    assert p.name == "middlebury-mview-hold8" and p.background is None and "black" in p.description
    split = ds.load_split("test")
    raw = io.read_png_u8(root / "view0009.png").astype(np.float64) / 255.0
    assert np.abs(split.srgb[1, ..., :3] - raw).max() < 1e-7 and np.all(split.srgb[..., 3] == 1.0)


def test_downscale_factor_scales_K(tmp_path):
    cams = hand_cameras(3)
    root = write_folder(tmp_path / "s", cams)
    full, half = load_middlebury_mview(root), load_middlebury_mview(root, factor=2)
    a, b = full.views[0].camera, half.views[0].camera
    assert (b.width, b.height) == (W // 2, H // 2) and b.fx == a.fx / 2 and b.cx == a.cx / 2
    assert half.load_split("train").srgb.shape[1:3] == (H // 2, W // 2)


def test_par_line_is_the_inverse_of_the_reader(tmp_path):
    cams = hand_cameras(4)
    first = load_middlebury_mview(write_folder(tmp_path / "a", cams))
    lines = [par_line(v.name, v.camera) for v in first.views]
    again = load_middlebury_mview(write_folder(tmp_path / "b", cams, lines=lines))
    for u, v in zip(first.views, again.views):
        assert np.abs(u.camera.K - v.camera.K).max() < 1e-12 and np.abs(u.camera.c2w - v.camera.c2w).max() < 1e-12


def test_readme_box_is_the_bound_and_its_mask_covers_the_object(tmp_path):
    readme = ("The (tight) bounding box for the model is\n(-0.25 -0.25 -0.25)\n(0.25 0.25 0.25)\n\nmore text\n")
    ds = load_middlebury_mview(write_folder(tmp_path / "s", hand_cameras(3), readme=readme))
    assert ds.bbox.tolist() == [[-0.25] * 3, [0.25] * 3] and ds.manifest["object_box"] == ds.bbox.tolist()
    cam = ds.views[0].camera
    m = box_mask(cam, ds.bbox)
    assert m.shape == (H, W) and m[int(cam.cy), int(cam.cx)] and not m[0, 0] and 0 < m.mean() < 1
    # without a README: the cameras' bound
    assert load_middlebury_mview(write_folder(tmp_path / "t", hand_cameras(3))).manifest["object_box"] is None
    assert scene_radius([v.camera for v in ds.views]) == pytest.approx(4.0)


def _line(name, K, R, t):
    return " ".join([name, *map(fmt, np.ravel(K)), *map(fmt, np.ravel(R)), *map(fmt, np.ravel(t))])


def last(line: str, value: str) -> str:
    """`line` with its last field (t3) replaced by `value`."""
    return " ".join(line.split()[:-1] + [value])


def _bad_cases():
    cams = hand_cameras(3)
    good = [_line(*c) for c in cams]
    n, K, R, t = cams[1]
    k = lambda **kw: np.array([[kw.get("fx", 20.0), kw.get("s", 0.0), 7.5], [kw.get("k21", 0.0), 21.0, 5.25],  # noqa: E731
                               [0.0, 0.0, kw.get("k33", 1.0)]])
    return {
        "count mismatch": ({"header": "4", "lines": good}, "count mismatch: the first line says 4 cameras, the file lists 3"),
        "bad count": ({"header": "three", "lines": good}, "expected the number of cameras"),
        "wrong fields": ({"lines": [good[0], good[1] + " 0.5", good[2]]}, "line 3 (view0002.png): expected 22 fields"),
        "not a number": ({"lines": [good[0], last(good[1], "four"), good[2]]}, "'four' is not a number"),
        "non-finite": ({"lines": [good[0], last(good[1], "inf"), good[2]]}, "non-finite"),
        "non-rotation": ({"lines": [good[0], _line(n, K, R * 1.001, t), good[2]]}, "line 3 (view0002.png): R"),
        "reflection": ({"lines": [good[0], _line(n, K, -R, t), good[2]]}, "line 3 (view0002.png): R"),
        "K lower": ({"lines": [good[0], _line(n, k(k21=0.5), R, t), good[2]]}, "K is not upper triangular"),
        "k33": ({"lines": [good[0], _line(n, k(k33=2.0), R, t), good[2]]}, "K is not upper triangular with k33 = 1"),
        "negative focal": ({"lines": [good[0], _line(n, k(fx=-20.0), R, t), good[2]]}, "focal lengths k11, k22 must be > 0"),
        "skew": ({"lines": [good[0], _line(n, k(s=0.5), R, t), good[2]]}, "skew k12 = 0.5 is not supported"),
        "duplicate": ({"lines": [good[0], good[0], good[2]]}, "listed twice (also on line 2)"),
        "missing image": ({"lines": good + [_line("gone.png", *cams[0][1:])], "header": "4"},
                          "image 'gone.png' is listed but"),
    }


@pytest.mark.parametrize("case", list(_bad_cases()))
def test_bad_input_is_refused_in_one_line_by_name(tmp_path, case):
    kwargs, message = _bad_cases()[case]
    root = write_folder(tmp_path / "s", hand_cameras(3), **kwargs)
    with pytest.raises(DatasetError) as e:
        load_middlebury_mview(root)
    text = str(e.value)
    assert message in text and "\n" not in text and str(root / "scene_par.txt") in text


def test_folder_level_refusals(tmp_path):
    root = write_folder(tmp_path / "s", hand_cameras(3))
    io.write_png_u8(root / "view0002.png", np.zeros((H + 2, W, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"view0002.png: image is 16x14, but view0001.png is 16x12"):
        load_middlebury_mview(root)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DatasetError, match="no \\*_par.txt"):
        load_middlebury_mview(empty)
    two = write_folder(tmp_path / "two", hand_cameras(3))
    write_folder(two, hand_cameras(3), images=False, stem="other")
    with pytest.raises(DatasetError, match="several \\*_par.txt files"):
        load_middlebury_mview(two)
    lines = [_line(n, np.array([[20.0, 0, 70.0], [0, 21.0, 5.0], [0, 0, 1]]), R, t) for n, _, R, t in hand_cameras(2)]
    with pytest.raises(DatasetError, match="principal point .* is outside the 16x12 image"):
        load_middlebury_mview(write_folder(tmp_path / "pp", hand_cameras(2), lines=lines))


def test_drlab_reproduce_skips_real_photos_in_one_line_without_its_data(tmp_path, monkeypatch, capsys):
    from research import cli, registry

    names = ["lucas_kanade", "real_photos"]
    monkeypatch.setattr(cli, "EXPERIMENTS", {n: cli.EXPERIMENTS[n] for n in names})
    monkeypatch.setattr(registry, "EXPERIMENTS", cli.EXPERIMENTS)
    monkeypatch.setattr(registry, "results_dir", lambda quick=False, smoke=False: tmp_path / "results")
    monkeypatch.setattr(registry, "default_data_dir", lambda: tmp_path / "data")
    ran = []

    def fake_run(name, quick, device, out, seed, extra):
        ran.append(name)
        out.mkdir(parents=True, exist_ok=True)
        (out / "table.md").write_text(f"table of {name}\n")
        return 0

    monkeypatch.setattr(cli, "_run_one", fake_run)
    assert cli.main(["reproduce"]) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if "real_photos" in ln]
    assert ran == ["lucas_kanade"] and len(said) == 1
    assert said[0].startswith("drlab reproduce: real_photos skipped: its data folder ") and \
        str(tmp_path / "data" / "middlebury_mview" / "templeRing") in said[0]
    # with the folder in place it runs
    (tmp_path / "data" / "middlebury_mview" / "templeRing").mkdir(parents=True)
    assert cli.main(["reproduce", "real_photos"]) == 0 and ran[-1] == "real_photos"


def test_real_photos_without_a_middlebury_folder_is_a_usage_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "experiments.real_photos", "--data", str(tmp_path), "--out",
                        str(tmp_path / "out"), "--no-progress"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and not (tmp_path / "out").exists()
    (line,) = r.stderr.strip().splitlines()
    assert "is not a Middlebury multi-view folder (no *_par.txt)" in line
