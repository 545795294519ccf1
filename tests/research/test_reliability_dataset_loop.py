"""Reliability of the loop path option: bad --flow-path values and too-short loops raise one line naming the
option before any folder exists; the CLI exits 2."""

from __future__ import annotations

import pytest

from research import cli
from research.poses import se3 as poses
from research.datasets import DatasetConfig, generate

CASES = [
    ("path-unknown", dict(flow=True, flow_path="circle"), r"--flow-path: expected one of arc, loop, got 'circle'"),
    ("path-not-text", dict(flow=True, flow_path=3), r"--flow-path: expected one of arc, loop"),
    ("loop-3-frames", dict(flow=True, flow_frames=3, flow_path="loop"), r"--flow-frames: a loop path needs at least 4"),
]


@pytest.mark.parametrize("kwargs,message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_loop_config(kwargs, message, tmp_path):
    with pytest.raises(ValueError, match=message) as info:
        generate(DatasetConfig("spheres", views=3, res=8, spp=1, **kwargs), tmp_path / "x", show_progress=False)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "x").exists() and not (tmp_path / "x.partial").exists()


def test_cli_bad_flow_path_exits_2(tmp_path, capsys):
    rc = cli.main(["dataset", "--scene", "spheres", "--flow", "--flow-path", "spiral", "--out", str(tmp_path / "x")])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--flow-path: expected one of arc, loop" in err[0]
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("args,message", [((2, 1.0), r"n_frames: expected an integer >= 3"),
                                          ((5, 0.0), r"radius: expected a positive value")],
                         ids=["two-frames", "zero-radius"])
def test_loop_path_bad_input(args, message):
    with pytest.raises(ValueError, match=message):
        poses.loop_path(*args)
