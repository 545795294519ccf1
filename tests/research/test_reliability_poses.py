"""Reliability of research.poses.se3: a pose that is not a rotation, bad TUM lines, mismatched trajectories.

Each case names the input and the one-line ValueError it must raise.
"""

from __future__ import annotations

import numpy as np
import pytest

from research.poses import se3 as P

GOOD = np.array([P.se3_exp([0.1 * k, 0.0, 0.2, 0.0, 0.05 * k, 0.0]) for k in range(6)])
SCALED = GOOD.copy()
SCALED[2, :3, :3] *= 1.1
REFLECT = GOOD.copy()
REFLECT[4, :3, :3] = REFLECT[4, :3, :3] @ np.diag([1.0, 1.0, -1.0])
BAD_ROW = GOOD.copy()
BAD_ROW[1, 3, 0] = 0.5
NAN = GOOD.copy()
NAN[0, 0, 3] = np.nan

CASES = [
    ("scaled-rotation", P.ate, (SCALED, GOOD), {}, r"c2w_est\[2\]: rotation part is not orthonormal"),
    ("reflection", P.rpe, (GOOD, REFLECT), {}, r"c2w_ref\[4\]: rotation part has determinant -1"),
    ("bad-last-row", P.ate, (BAD_ROW, GOOD), {}, r"c2w_est\[1\]: last row must be \[0, 0, 0, 1\]"),
    ("nan-pose", P.ate, (NAN, GOOD), {}, r"c2w_est\[0\]: contains non-finite values"),
    ("not-4x4", P.ate, (GOOD[:, :3], GOOD), {}, r"c2w_est: expected a non-empty array of 4x4 poses"),
    ("lengths-differ", P.ate, (GOOD[:5], GOOD), {}, r"est, ref: expected trajectories of the same length"),
    ("align-unknown", P.ate, (GOOD, GOOD), {"align": "affine"}, r"align: expected one of \['none', 'se3', 'sim3'\]"),
    ("rpe-delta-0", P.rpe, (GOOD, GOOD), {"delta": 0}, r"delta: expected an integer in \[1, 5\]"),
    ("rpe-delta-too-long", P.rpe, (GOOD, GOOD), {"delta": 6}, r"delta: expected an integer in \[1, 5\]"),
    ("umeyama-2-points", P.umeyama, (GOOD[:2, :3, 3], GOOD[:2, :3, 3]), {}, r"src: expected at least 3 points"),
    ("umeyama-coincident", P.umeyama, (np.zeros((4, 3)), GOOD[:4, :3, 3]), {}, r"src: all points coincide"),
    ("se3-log-not-rotation", P.se3_log, (SCALED[2],), {}, r"T: rotation part is not orthonormal"),
    ("so3-log-shape", P.so3_log, (np.eye(4),), {}, r"R: expected shape \(3, 3\)"),
    ("se3-exp-shape", P.se3_exp, (np.zeros(3),), {}, r"xi: expected shape \(6,\)"),
    ("perturb-not-rotation", P.perturb_c2w, (SCALED[2], np.zeros(6)), {}, r"c2w: rotation part is not orthonormal"),
    ("write-timestamps-shape", P.write_tum, ("unused.txt", np.arange(5.0), GOOD), {},
     r"timestamps: expected shape \(6,\)"),
    ("write-timestamps-decrease", P.write_tum, ("unused.txt", -np.arange(6.0), GOOD), {},
     r"timestamps: expected finite, strictly increasing"),
    ("perturbations-negative", P.random_perturbations, (3, -1.0, 0.1, 0), {}, r"rot_deg: expected a finite value >= 0"),
]


@pytest.mark.parametrize("fn,args,kwargs,message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_raises_one_line(fn, args, kwargs, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=message) as info:
        fn(*args, **kwargs)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "unused.txt").exists()


TUM_CASES = [
    ("seven-numbers", "0 1 2 3 0 0 0\n", r"t\.txt:1: expected 8 numbers"),
    ("text-field", "# header\n0 1 2 3 0 0 0 x\n", r"t\.txt:2: expected 8 numbers"),
    ("zero-quaternion", "0 1 2 3 0 0 0 0\n", r"t\.txt:1: quaternion \(qx qy qz qw\) has norm 0, expected a non-zero"),
    ("nan", "0 nan 2 3 0 0 0 1\n", r"t\.txt:1: expected finite numbers"),
    ("empty", "# nothing\n\n", r"t\.txt: no poses"),
]


@pytest.mark.parametrize("text,message", [c[1:] for c in TUM_CASES], ids=[c[0] for c in TUM_CASES])
def test_bad_tum_file_names_file_and_line(text, message, tmp_path):
    path = tmp_path / "t.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        P.read_tum(path)
    assert "\n" not in str(info.value)
