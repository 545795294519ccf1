"""`drlab sfm` (research.poses.sfm) on a small feature-rich Mitsuba render: registered images, pose error
against the ground truth after a Sim(3) alignment, the output layout and research.datasets.colmap
reading it. About 30 s on 2 cores (render 6 s, three SfM runs)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from research import cli
from research.poses.align import pose_errors
from research.datasets import detect_format, load_colmap

sys.path.insert(0, str(Path(__file__).parent))
from sfm_fixtures import TEXTURED, render_textured  # noqa: E402

VIEWS, RES = 24, 128


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("sfm")
    cams = render_textured(root / "photos", n=VIEWS, res=RES)
    rc = cli.main(["sfm", str(root / "photos"), "--out", str(root / "model"), "--shared-camera",
                   "--camera-model", "SIMPLE_PINHOLE", "--threads", "1", "--no-progress"])
    assert rc == 0
    return root, cams


def _errors(ds, cams):
    index = [int(Path(v.name).stem[2:]) for v in ds.views]
    return index, pose_errors(np.array([v.camera.c2w for v in ds.views]), np.array([cams[i].c2w for i in index]))


def test_registers_every_view_with_small_pose_error(capture):
    root, cams = capture
    assert detect_format(root / "model") == "colmap"
    ds = load_colmap(root / "model", factor=1)
    index, pe = _errors(ds, cams)
    assert len(index) >= VIEWS - 2  # measured: 24 of 24
    s = pe.summary()
    # measured: median 0.43 deg, max 1.2 deg; translation median 0.026 (0.7% of the 3.5 camera distance)
    assert s["rotation_deg_median"] < 1.5 and s["rotation_deg_max"] < 4.0, s
    assert s["translation_median"] < 0.03 * TEXTURED.radius and s["translation_max"] < 0.1 * TEXTURED.radius, s
    focal = ds.views[0].camera.fx
    assert abs(focal / cams[0].fx - 1.0) < 0.05  # estimated focal length (measured: 0.9% off)
    assert ds.points is not None and len(ds.points) > 100 and ds.point_colors.shape == ds.points.shape
    # the SfM points lie on the scene: aligned into the ground-truth frame, inside its box (with a margin)
    pts = pe.sim3.apply(ds.points)
    inside = np.all((pts > np.array(TEXTURED.bbox_min) - 0.2) & (pts < np.array(TEXTURED.bbox_max) + 0.2), axis=1)
    assert inside.mean() > 0.9


def test_output_layout_and_summary(capture):
    root, _ = capture
    out = root / "model"
    assert sorted(p.name for p in out.iterdir()) == ["images", "sfm.json", "sparse"]
    model = {p.name for p in (out / "sparse" / "0").iterdir()}
    assert {"cameras.bin", "images.bin", "points3D.bin"} <= model <= {"cameras.bin", "images.bin", "points3D.bin",
                                                                     "frames.bin", "rigs.bin"}  # pycolmap 4 adds these
    summary = json.loads((out / "sfm.json").read_text())
    assert summary["total"] == VIEWS and len(summary["registered"]) + len(summary["unregistered"]) == VIEWS
    assert sorted(p.name for p in (out / "images").iterdir()) == summary["registered"]
    assert summary["options"]["shared_camera"] and len(summary["cameras"]) == 1
    assert summary["cameras"][0]["model"] == "SIMPLE_PINHOLE"
    assert set(summary["seconds"]) == {"features", "matching", "mapping", "undistortion"}
    # a pinhole model is undistorted as a copy: the images are the inputs, bit for bit
    name = summary["registered"][0]
    assert (out / "images" / name).read_bytes() == (root / "photos" / name).read_bytes()


def test_known_intrinsics_stay_fixed_and_force_replaces(capture, capsys):
    root, cams = capture
    K = cams[0].K
    args = ["sfm", str(root / "photos"), "--out", str(root / "model-k"), "--intrinsics",
            ",".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2])), "--threads", "1", "--no-progress"]
    assert cli.main(args) == 0
    assert "registered" in capsys.readouterr().out
    ds = load_colmap(root / "model-k", factor=1)
    for v in ds.views:
        assert np.abs(v.camera.K - K).max() < 1e-9  # PINHOLE, not refined in bundle adjustment
    index, pe = _errors(ds, cams)
    assert len(index) >= VIEWS - 2 and pe.summary()["rotation_deg_median"] < 1.5  # measured 0.39-0.56 deg
    assert cli.main(args) == 2  # exists
    assert "exists" in capsys.readouterr().err
    assert cli.main(args + ["--force"]) == 0
    assert not list(root.glob("model-k.*"))  # no temporary or old folder left beside it


def test_sequential_matching_registers_the_ring(capture):
    """Sequential matching pairs each view with the next --overlap by name only: on this closed ring the
    loop is never closed, and in seven multi-threaded runs with known intrinsics (overlap 3, 6 and 10) four
    put one camera 60-70 degrees off, so only registration is asserted here. The runs use one thread, the
    only setting in which COLMAP's matching and mapping repeat (research.poses.sfm.SfmOptions.threads): with
    two, one CI run registered 20 of 24; with one, 24 of 24 and the same 487 points every run."""
    root, _ = capture
    assert cli.main(["sfm", str(root / "photos"), "--out", str(root / "model-seq"), "--shared-camera",
                     "--matcher", "sequential", "--overlap", "6", "--threads", "1", "--no-progress",
                     "--no-undistort"]) == 0
    summary = json.loads((root / "model-seq" / "sfm.json").read_text())
    assert summary["options"]["matcher"] == "sequential" and len(summary["registered"]) >= VIEWS - 2
    # --no-undistort: the model as estimated (COLMAP's SIMPLE_RADIAL) and the photographs bit for bit,
    # read back with the camera's lens (research/datasets/colmap.py)
    assert not summary["options"]["undistort"] and "undistortion" not in summary["seconds"]
    (cam,) = summary["cameras"]
    assert cam["model"] == "SIMPLE_RADIAL" and cam["params"][3] != 0.0
    out = root / "model-seq"
    assert sorted(p.name for p in (out / "images").iterdir()) == summary["registered"]
    for name in summary["registered"]:
        assert (out / "images" / name).read_bytes() == (root / "photos" / name).read_bytes()
    ds = load_colmap(out, factor=1)
    lens = ds.views[0].camera.lens
    assert lens is not None and lens.coeffs[0] == pytest.approx(cam["params"][3])
