"""Bad sample values to composite_forward on arrays large enough for several threads and blocks of
the CPU factor pass (where sigma and delta are checked) and rays that terminate early (whose later
colours and depths the kernel adds up only for the check): one ValueError naming the argument,
wherever the bad value sits, in float32 and float64; -0.0 is a valid density."""

from __future__ import annotations

import numpy as np
import pytest

from kernels._arrays import value_checks
from kernels.volume import composite_forward, dense_offsets
from kernels.volume.composite import _FILL_BLOCK

R, S = 1100, 256  # 281600 samples: more than 4 blocks of the factor pass
N = R * S


def _good(dtype):
    rng = np.random.default_rng(0)
    return {"sigma": rng.uniform(0, 1, N).astype(dtype), "rgb": rng.uniform(0, 1, (N, 3)).astype(dtype),
            "delta": np.full(N, 0.01, dtype), "z": np.tile(np.linspace(1, 2, S), R).astype(dtype),
            "ray_offsets": dense_offsets(R, S)}


def _put(name, index, value):
    def change(args):
        args[name][index] = value
    return change


CASES = [
    ("sigma_negative_last", _put("sigma", N - 1, -0.5), "sigma: expected values >= 0"),
    ("sigma_inf_first", _put("sigma", 0, np.inf), "sigma: expected finite values >= 0, found inf"),
    ("sigma_nan_second_block", _put("sigma", _FILL_BLOCK + 3, np.nan), "sigma: expected finite values >= 0, found NaN"),
    ("delta_negative_middle", _put("delta", N // 2, -1e-3), "delta: expected values >= 0"),
    ("delta_nan_last", _put("delta", N - 1, np.nan), "delta: expected finite values >= 0, found NaN"),
    ("rgb_nan_last", _put("rgb", (N - 1, 2), np.nan), "rgb: expected finite values, found NaN or infinite"),
    ("rgb_inf_middle", _put("rgb", (N // 2, 0), -np.inf), "rgb: expected finite values"),
    ("z_inf_first", _put("z", 0, np.inf), "z: expected finite values"),
    ("z_nan_after_termination", _put("z", S - 1, np.nan), "z: expected finite values"),
]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("change, match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_sample_values_raise(dtype, change, match):
    args = _good(dtype)
    args["sigma"][:S] = 1e3  # ray 0 terminates after its first samples: its tail is still checked
    change(args)
    with pytest.raises(ValueError, match=match):
        composite_forward(**args)
    with value_checks(False):  # shapes only: no value check, no error
        composite_forward(**args)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_negative_zero_density_and_huge_finite_colours_are_valid(dtype):
    args = _good(dtype)
    args["sigma"][::7] = -0.0  # fails the one-pass bit test, passes the exact check (-0.0 >= 0)
    args["rgb"][5] = np.finfo(dtype).max  # the largest finite value is valid
    res = composite_forward(**args)
    plus = composite_forward(**{**args, "sigma": np.abs(args["sigma"])})
    np.testing.assert_array_equal(res.rgb, plus.rgb)


def test_background_seen_with_checks_off_is_still_checked_later():
    args = {k: v[:2 * S] if k != "ray_offsets" else dense_offsets(2, S) for k, v in _good(np.float64).items()}
    bg = (0.0, np.nan, 0.0)
    with value_checks(False):
        composite_forward(**args, background=bg)
    with pytest.raises(ValueError, match="background: expected finite values"):
        composite_forward(**args, background=bg)
