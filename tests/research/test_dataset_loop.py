"""`drlab dataset --flow --flow-path loop`: a camera-path sequence that orbits once and returns to its
start, with per-frame depth, for SLAM; the default arc path's files and records are unchanged."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from research.poses import se3 as P
from research.datasets import DatasetConfig, ensure, generate, load_flow
from research.datasets.config import config_record


@pytest.fixture(scope="module")
def loop_ds(tmp_path_factory):
    out = tmp_path_factory.mktemp("loop") / "objects"
    cfg = DatasetConfig("objects", views=3, res=24, spp=2, seed=2, flow=True, flow_frames=8, flow_path="loop")
    generate(cfg, out, show_progress=False)
    return out


def test_loop_returns_to_its_start_with_depth(loop_ds):
    seq = load_flow(loop_ds)
    c2w = np.array([c.c2w for c in seq.cameras])
    assert len(c2w) == 8 and seq.depth.shape == (8, 24, 24) and seq.flow.shape == (7, 24, 24, 2)
    assert np.all(seq.depth[seq.depth > 0] > 0) and (seq.depth > 0).mean() > 0.2  # a surface in every frame
    steps = np.linalg.norm(np.diff(np.concatenate([c2w, c2w[:1]])[:, :3, 3], axis=0), axis=1)
    # The closing step (last frame -> first) is like every other step: the path is one closed orbit.
    assert steps.max() / steps.min() < 1.5
    angles = [P.rotation_angle_deg(a[:3, :3].T @ b[:3, :3]) for a, b in zip(c2w, np.roll(c2w, -1, axis=0))]
    assert max(angles) < 60 and abs(angles[-1] - np.mean(angles)) < 0.5 * np.mean(angles)
    doc = json.loads((loop_ds / "flow" / "flow.json").read_text())
    assert doc["path"] == "loop"
    m = json.loads((loop_ds / "manifest.json").read_text())
    assert m["config"]["flow_path"] == "loop" and "flow/f_007_depth.exr" in m["files"]


def test_loop_path_is_periodic_and_looks_at_the_centre():
    poses = P.loop_path(12, 2.0, center=(0.1, 0.2, 0.3), up=(0.0, 0.0, 1.0), start_azimuth_deg=40.0)
    more = P.loop_path(24, 2.0, center=(0.1, 0.2, 0.3), up=(0.0, 0.0, 1.0), start_azimuth_deg=40.0)
    np.testing.assert_allclose(more[::2], poses, atol=1e-12)  # frame k of 12 = frame 2k of 24: same curve
    for T in poses:
        to_centre = np.array([0.1, 0.2, 0.3]) - T[:3, 3]
        np.testing.assert_allclose(T[:3, 2], to_centre / np.linalg.norm(to_centre), atol=1e-12)  # +z looks at it
    total = P.path_length(poses + poses[:1])
    assert total == pytest.approx(2 * math.pi * 2.0 * math.cos(math.radians(25.0)), rel=0.1)


def test_arc_config_record_and_reuse_unchanged(tmp_path):
    """The default arc path records the configuration as before the option existed (no flow_path key),
    so datasets rendered then still match and are reused without rendering."""
    cfg = DatasetConfig("spheres", views=3, res=8, spp=1, flow=True, flow_frames=2)
    assert "flow_path" not in config_record(cfg)
    out = generate(cfg, tmp_path / "arc", show_progress=False)
    assert "path" not in json.loads((out / "flow" / "flow.json").read_text())
    m = json.loads((out / "manifest.json").read_text())
    assert "flow_path" not in m["config"]
    stamp = (out / "manifest.json").stat().st_mtime_ns
    assert ensure(cfg, out, show_progress=False) == out
    assert (out / "manifest.json").stat().st_mtime_ns == stamp  # reused, not rendered again
    # A loop of the same settings is another dataset.
    loop = DatasetConfig("spheres", views=3, res=8, spp=1, flow=True, flow_frames=4, flow_path="loop")
    assert config_record(loop)["flow_path"] == "loop"
