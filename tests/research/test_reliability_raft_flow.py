"""raft_flow --levels/--radius bad values: exit status 2 and one line naming the option, before any results folder."""

from __future__ import annotations

import pytest

from tests.research.test_raft_flow_cells import _run


@pytest.mark.parametrize("args, message", [
    (["--levels", "5"], "--levels: expected one of 1, 2, 3, 4, got 5"),
    (["--radius", "x"], "--radius: expected one of 1, 2, 3, 4, got 'x'"),
], ids=["levels-5", "radius-text"])
def test_bad_cell_exits_2(tmp_path, args, message):
    r = _run(["--smoke", "--no-progress", "--out", str(tmp_path / "out"), *args])
    assert r.returncode == 2 and message in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()
