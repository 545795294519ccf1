"""Checks that only the volume family needs, on top of the array contract (kernels._arrays).

    check_bbox         a box [lo, hi] as (2, 3) float64 with finite corners and lo < hi
    check_dtype        a field's Warp float type (float32 or float64)
    check_ray_offsets  packed-sample offsets: (R+1,) integers from 0 to N, non-decreasing
    check_directions   ray directions without a zero row

Like every check of kernels._arrays they raise ValueError naming the argument before any launch,
and the value checks (the offsets' order, zero directions) read the data where it lives (a
zero-copy view on the CPU, a counting kernel on CUDA) and are skipped inside
`value_checks(False)`.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _count_bad_offsets(offsets: wp.array(dtype=wp.int32), n_samples: int, count: wp.array(dtype=wp.int32)):
    # One launch on a CUDA device (where atomics are atomic): offsets[0] = 0, offsets[-1] = N, non-decreasing.
    i = wp.tid()
    last = offsets.shape[0] - 1
    bad = int(0)
    if i == 0 and offsets[0] != 0:
        bad = 1
    if i == last and offsets[last] != n_samples:
        bad = 1
    if i < last and offsets[i + 1] < offsets[i]:
        bad = 1
    if bad != 0:
        wp.atomic_add(count, 0, 1)


@wp.kernel
def _count_zero_rows(x: wp.array2d(dtype=typing.Any), count: wp.array(dtype=wp.int32)):
    i = wp.tid()
    zero = x.dtype(0.0)
    if x[i, 0] == zero and x[i, 1] == zero and x[i, 2] == zero:
        wp.atomic_add(count, 0, 1)


A.declare_float_overloads(_count_zero_rows)


def check_bbox(name: str, bbox: Any) -> np.ndarray:
    """`bbox` as a (2, 3) float64 array [min corner, max corner] with finite corners and min < max."""
    b = np.asarray(bbox.numpy() if isinstance(bbox, wp.array) else bbox, dtype=np.float64)
    if b.shape != (2, 3):
        raise ValueError(f"{name}: expected shape (2, 3) (min and max corners), got {b.shape}")
    if not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
        raise ValueError(f"{name}: expected finite corners with min < max, got {b.tolist()}")
    return b


def check_dtype(name: str, dtype: Any) -> Any:
    """A Warp float type, wp.float32 or wp.float64."""
    if dtype not in A.FLOATS:
        raise ValueError(f"{name}: expected wp.float32 or wp.float64, got {dtype}")
    return dtype


def check_ray_offsets(a: A.Inputs, name: str, offsets: Any, n_samples: int) -> wp.array:
    """Packed-sample offsets as an int32 wp.array: shape (R+1,), offsets[0] = 0, non-decreasing,
    offsets[-1] = n_samples (the order is a value check)."""
    if not A.is_array(offsets) or len(offsets.shape) != 1 or offsets.shape[0] < 1:
        shape = tuple(offsets.shape) if A.is_array(offsets) else type(offsets).__name__
        raise ValueError(f"{name}: expected shape (R+1,), got {shape}")
    arr = a.ints(name, offsets)
    if A.values_checked():
        h = A.host_view(arr)
        if h is None:
            bad = A.device_count(_count_bad_offsets, arr.shape[0], [arr, int(n_samples)], arr.device) > 0
        else:
            bad = h[0] != 0 or h[-1] != n_samples or bool(np.any(h[1:] < h[:-1]))
        if bad:
            raise ValueError(f"{name}: expected non-decreasing offsets from 0 to the sample count {n_samples}")
    return arr


def check_directions(name: str, dirs: wp.array) -> None:
    """ValueError if a row of the (R, 3) float array `dirs` is the zero vector (a value check)."""
    if not A.values_checked() or dirs.shape[0] == 0:
        return
    h = A.host_view(dirs)
    zero = (np.any(np.all(h == 0, axis=1)) if h is not None
            else A.device_count(_count_zero_rows, dirs.shape[0], [dirs], dirs.device) > 0)
    if zero:
        raise ValueError(f"{name}: expected non-zero directions, found a zero row")
