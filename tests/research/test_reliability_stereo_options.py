"""stereo_depth's one-configuration options: each bad combination exits 2 with one line naming the option."""

from __future__ import annotations

import pytest

from experiments import stereo_depth


@pytest.mark.parametrize("argv, match", [
    (["--p1", "8"], "--p1: applies with --cost only"),
    (["--radius", "2"], "--radius: applies with --cost only"),
    (["--cost", "sad", "--zncc-eps", "0.001"], "--zncc-eps: applies to --cost zncc only"),
    (["--cost", "sad", "--aggregation", "none", "--p1", "0.1"], "--p1, --p2: apply to an SGM aggregation"),
    (["--cost", "census", "--p1", "8", "--p2", "4"], "--p2: expected P2 >= P1"),
    (["--cost", "census", "--radius", "4"], "--radius: --cost census --radius 4"),
], ids=["p1-without-cost", "radius-without-cost", "eps-for-sad", "penalties-without-sgm", "p2-below-p1",
        "census-over-64-bits"])
def test_bad_single_configuration(argv, match, tmp_path, capsys):
    rc = stereo_depth.main(["--smoke", "--no-progress", "--out", str(tmp_path / "out"), "--data",
                            str(tmp_path / "data"), *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and match in err and "\n" not in err
    assert not (tmp_path / "out").exists() and not (tmp_path / "data").exists()  # nothing rendered or written


@pytest.mark.parametrize("argv", [["--cost", "ssd"], ["--radius", "-1"], ["--p1", "nan"], ["--p2", "-3"]],
                         ids=["unknown-cost", "negative-radius", "nan-p1", "negative-p2"])
def test_bad_option_values_exit_2(argv, tmp_path, capsys):
    rc = stereo_depth.main(["--smoke", "--out", str(tmp_path / "out"), *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and argv[0] in err and "\n" not in err
