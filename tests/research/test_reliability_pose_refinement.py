"""Reliability of `python -m experiments.pose_refinement`: bad perturbation sizes, depth weights and dilations exit 2 with
one line naming the option, before any dataset is rendered or results folder created."""

from __future__ import annotations

import pytest

from experiments import pose_refinement

CASES = [
    ("rot-negative", ["--rot-deg", "-1"], r"--rot-deg: expected a value in \[0, 30\] degrees, got -1.0"),
    ("rot-huge", ["--rot-deg", "90"], r"--rot-deg: expected a value in \[0, 30\] degrees"),
    ("rot-nan", ["--rot-deg", "nan"], r"--rot-deg: expected a value in \[0, 30\] degrees"),
    ("trans-negative", ["--trans-frac", "-0.1"], r"--trans-frac: expected a value in \[0, 0.5\]"),
    ("depth-negative", ["--depth-weight", "-1"], r"--depth-weight: expected a finite value >= 0"),
    ("depth-inf", ["--depth-weight", "inf"], r"--depth-weight: expected a finite value >= 0"),
    ("model-unknown", ["--model", "nerf"], r"--model: invalid choice: 'nerf'"),
    ("dilation-zero", ["--dilation", "0"], r"--dilation: expected a finite value > 0 px\^2, got 0.0"),
    ("dilation-nan", ["--dilation", "nan"], r"--dilation: expected a finite value > 0 px\^2"),
]


@pytest.mark.parametrize("argv,message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_option_exits_2(argv, message, tmp_path, capsys):
    import re

    rc = pose_refinement.main(["--smoke", "--no-progress", "--out", str(tmp_path / "out"), "--data",
                               str(tmp_path / "data"), *argv])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(message, err[0]), err
    assert not (tmp_path / "out").exists() and not (tmp_path / "data").exists()
