"""Bad inputs to SphereField.render_dense: one ValueError naming the argument, before any launch."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.volume import SphereField

R, S = 4, 5


def _good():
    o = np.zeros((R, 3), np.float32)
    d = np.tile(np.array([0, 0, 1], np.float32), (R, 1))
    t = np.tile(np.linspace(1, 6, S, dtype=np.float32), (R, 1))
    return {"origins": o, "dirs": d, "t": t, "delta": np.full((R, S), 0.1, np.float32)}


def _with(**changes):
    args = _good()
    args.update(changes)
    return args


CASES = [
    ("origins_wrong_shape", _with(origins=np.zeros((R, 2), np.float32)), {}, "origins: expected shape"),
    ("origins_float64_for_float32_field", _with(origins=np.zeros((R, 3))), {}, "origins: expected dtype float32"),
    ("origins_nan", _with(origins=np.full((R, 3), np.nan, np.float32)), {}, "origins: expected finite"),
    ("dirs_other_ray_count", _with(dirs=np.zeros((R + 1, 3), np.float32)), {}, "dirs: expected shape"),
    ("dirs_other_dtype", _with(dirs=np.zeros((R, 3))), {}, "dirs: expected dtype float32"),
    ("t_1d", _with(t=np.ones(R, np.float32)), {}, "t: expected shape"),
    ("t_inf", _with(t=np.full((R, S), np.inf, np.float32)), {}, "t: expected finite"),
    ("delta_other_shape", _with(delta=np.ones((R, S + 1), np.float32)), {}, "delta: expected shape"),
    ("delta_negative", _with(delta=np.full((R, S), -0.1, np.float32)), {}, "delta: expected values >= 0"),
    ("delta_list", _with(delta=[[0.1] * S] * R), {}, "delta: expected a NumPy array or a wp.array"),
    ("background_wrong_shape", _good(), {"background": (0.0, 0.0)}, "background: expected shape"),
    ("background_nan", _good(), {"background": (0.0, np.nan, 0.0)}, "background: expected finite"),
    ("t_threshold_one", _good(), {"t_threshold": 1.0}, "t_threshold: expected a value in"),
    ("t_threshold_negative", _good(), {"t_threshold": -0.1}, "t_threshold: expected a finite non-negative"),
]


@pytest.mark.parametrize("args, kwargs, match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_render_dense_rejects_bad_input(args, kwargs, match):
    field = SphereField.textbook(wp.float32)
    with pytest.raises(ValueError, match=match) as info:
        field.render_dense(args["origins"], args["dirs"], args["t"], args["delta"], **kwargs)
    assert "\n" not in str(info.value)
