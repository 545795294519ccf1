"""Bad input to `drlab sfm` (research.poses.sfm): one line naming the argument, exit status 2, no output folder.

Each case is a command line against a folder the test writes; every case but the last fails before
pycolmap runs. The last one runs real SfM on images of pure noise, where nothing can register.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from research import cli, io


def _noise(folder: Path, n: int, size=(48, 40), seed: int = 0, start: int = 0) -> None:
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(start, start + n):
        io.write_png_u8(folder / f"img_{k:02d}.png", rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8))


def _setup(case: str, tmp: Path) -> None:
    imgs = tmp / "imgs"
    if case == "empty":
        imgs.mkdir()
        (imgs / "notes.txt").write_text("not an image")
    elif case == "a-file":
        imgs.write_text("x")
    elif case == "mixed-sizes":
        _noise(imgs, 3)
        _noise(imgs, 1, size=(40, 40), start=3)
    elif case == "out-exists":
        _noise(imgs, 3)
        (tmp / "out").mkdir()
        (tmp / "out" / "keep.txt").write_text("mine")
    elif case != "missing":
        _noise(imgs, 3)


CASES = [
    ("missing", [], r"IMAGES_DIR: .*imgs does not exist$"),
    ("a-file", [], r"IMAGES_DIR: .*imgs is not a folder$"),
    ("empty", [], r"IMAGES_DIR: .*imgs holds no images \(expected \.png, \.jpg, \.jpeg files directly in it\)$"),
    ("mixed-sizes", ["--shared-camera"], r"img_03\.png: image is 40x40, but img_00\.png is 48x40 \(one shared camera"),
    ("intrinsics-text", ["--intrinsics", "50,50,24"], r"--intrinsics: expected four numbers fx,fy,cx,cy"),
    ("intrinsics-outside", ["--intrinsics", "50,50,90,20"], r"--intrinsics: the principal point \(90, 20\) is outside"),
    ("intrinsics-focal", ["--intrinsics", "0,50,24,20"],
     r"--intrinsics: expected fx,fy,cx,cy \(finite, fx and fy > 0\)"),
    ("overlap", ["--matcher", "sequential", "--overlap", "0"], r"--overlap: expected an integer >= 1, got 0"),
    ("min-registered", ["--min-registered", "7"], r"--min-registered: 7 exceeds the 3 images"),
    ("threads", ["--threads", "0"], r"--threads: expected -1 \(every core\) or an integer >= 1"),
    ("matcher", ["--matcher", "vocab"], r"--matcher: invalid choice: 'vocab'"),
    ("out-exists", [], r"--out: .*out exists \(choose another folder, or --force"),
    ("out-not-sfm", ["--force"], r"--out: .*out is not a `drlab sfm` output \(no sfm\.json\)"),
    ("too-few-registered", ["--no-progress"], r"IMAGES_DIR: only 0 of 3 images registered in .*imgs \(at least 3 "
                                              r"needed; --min-registered\)"),
]


@pytest.mark.parametrize("case, extra, message", CASES, ids=[c[0] for c in CASES])
def test_bad_input_one_line_exit_2(tmp_path, capsys, case, extra, message):
    _setup("out-exists" if case == "out-not-sfm" else case, tmp_path)
    rc = cli.main(["sfm", str(tmp_path / "imgs"), "--out", str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert "\n" not in err and err.startswith("drlab sfm: "), err
    import re

    assert re.search(message, err), err
    out = tmp_path / "out"
    if case in ("out-exists", "out-not-sfm"):
        assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]  # left as it was
    else:
        assert not out.exists()
    assert not list(tmp_path.glob("out.partial-*"))  # no temporary folder left behind


EXPERIMENT_CASES = [
    (["--views", "4"], "--views: expected an integer >= 8, got 4"),
    (["--res", "100"], "--res: expected a multiple of 8, at least 128, got 100"),
    (["--iterations", "0"], "--iterations: expected an integer >= 1, got 0"),
    (["--threads", "0"], "--threads: expected -1 (every core) or an integer >= 1, got 0"),
]


@pytest.mark.parametrize("extra, message", EXPERIMENT_CASES, ids=["views", "res", "iterations", "threads"])
def test_sfm_poses_bad_options_before_any_render(tmp_path, capsys, monkeypatch, extra, message):
    from experiments import sfm_poses

    monkeypatch.delenv("DRLAB_PROG", raising=False)
    rc = sfm_poses.main(["--smoke", "--no-progress", "--out", str(tmp_path / "res"), "--data", str(tmp_path / "data"),
                         *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err == f"python -m experiments.sfm_poses: {message}", err
    assert not (tmp_path / "data").exists() and not (tmp_path / "res").exists()
