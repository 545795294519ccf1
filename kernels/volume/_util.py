"""Input validation and array conversion shared by the volume kernels (no kernels here).

Every entry point validates its inputs here, before any launch, and raises
ValueError naming the argument and what was expected.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import warp as wp

FLOAT_TYPES = {np.dtype(np.float32): wp.float32, np.dtype(np.float64): wp.float64}
NP_TYPES = {wp.float32: np.float32, wp.float64: np.float64}

ArrayLike = Any  # np.ndarray | wp.array


def default_device(device: str | wp.Device | None) -> wp.Device:
    return wp.get_device("cpu" if device is None else device)


def float_dtype(name: str, x: ArrayLike) -> Any:
    """The Warp float type of `x` (float32 or float64); ValueError for anything else."""
    if isinstance(x, wp.array):
        if x.dtype in NP_TYPES:
            return x.dtype
        raise ValueError(f"{name}: expected a float32 or float64 array, got Warp dtype {x.dtype}")
    arr = np.asarray(x)
    if arr.dtype in FLOAT_TYPES:
        return FLOAT_TYPES[arr.dtype]
    raise ValueError(f"{name}: expected a float32 or float64 array, got dtype {arr.dtype}")


def common_dtype(named: Sequence[tuple[str, ArrayLike]]) -> Any:
    """The float type shared by every array in `named`; ValueError naming the first that differs."""
    first_name, first = named[0]
    dtype = float_dtype(first_name, first)
    for name, x in named[1:]:
        d = float_dtype(name, x)
        if d != dtype:
            raise ValueError(f"{name}: dtype {NP_TYPES[d].__name__} differs from {first_name}'s "
                             f"{NP_TYPES[dtype].__name__}; pass every float input in one dtype")
    return dtype


def host_view(x: ArrayLike) -> np.ndarray:
    """A NumPy view (CPU arrays) or copy (CUDA arrays) of `x`, for validation."""
    return x.numpy() if isinstance(x, wp.array) else np.asarray(x)


def check_shape(name: str, x: ArrayLike, shape: tuple[int | None, ...]) -> None:
    """`shape` entries of None match any size."""
    got = tuple(x.shape)
    if len(got) != len(shape) or any(s is not None and s != g for s, g in zip(shape, got)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {got}")


def all_finite(h: np.ndarray) -> bool:
    """Whether every element of the float array `h` is finite, in one pass without a temporary.

    The dot product x . x is NaN or infinite if any element is; it can also overflow for huge
    finite values, and only then is every element tested (half the time of np.isfinite(h).all()
    on 25M float32, which the per-call validation of the compositing kernel pays).
    """
    flat = h.reshape(-1)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow or NaN is the answer, not a problem
        if flat.size and np.isfinite(np.dot(flat, flat)):
            return True
    return bool(np.isfinite(flat).all())


def check_finite(name: str, x: ArrayLike) -> np.ndarray:
    h = host_view(x)
    if not all_finite(h):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return h


def check_nonnegative(name: str, x: ArrayLike) -> None:
    h = host_view(x)
    if not h.size:
        return
    lo = h.min()  # a NaN anywhere makes it NaN
    if np.isnan(lo):
        raise ValueError(f"{name}: contains NaN values")
    if lo < 0:
        raise ValueError(f"{name}: expected values >= 0, got a minimum of {lo:.6g}")
    if not all_finite(h):
        raise ValueError(f"{name}: contains infinite values")


def to_warp(name: str, x: ArrayLike, dtype: Any, device: wp.Device) -> wp.array:
    """`x` as a contiguous wp.array of `dtype` on `device` (no copy when it already is one).

    A wp.array on another device is an error (no silent transfers); NumPy input is copied over.
    """
    if isinstance(x, wp.array):
        if x.device != device:
            raise ValueError(f"{name}: array is on {x.device}, expected {device}")
        if x.dtype != dtype:
            raise ValueError(f"{name}: Warp dtype {x.dtype}, expected {dtype}")
        if not x.is_contiguous:
            raise ValueError(f"{name}: expected a contiguous array")
        return x
    arr = np.ascontiguousarray(x, dtype=NP_TYPES.get(dtype, None) or np.asarray(x).dtype)
    return wp.array(arr, dtype=dtype, device=device)


def check_out(name: str, x: Any, shape: tuple[int, ...], dtype: Any, device: wp.Device) -> wp.array:
    """A caller-supplied output buffer: a contiguous wp.array of exactly `shape` and `dtype` on `device`."""
    if not isinstance(x, wp.array):
        raise ValueError(f"{name}: expected a wp.array output buffer, got {type(x).__name__}")
    if tuple(x.shape) != tuple(shape) or x.dtype != dtype:
        raise ValueError(f"{name}: expected an output buffer of shape {tuple(shape)} and dtype "
                         f"{getattr(dtype, '__name__', dtype)}, got shape {tuple(x.shape)} and dtype "
                         f"{getattr(x.dtype, '__name__', x.dtype)}")
    if x.device != device:
        raise ValueError(f"{name}: array is on {x.device}, expected {device}")
    if not x.is_contiguous:
        raise ValueError(f"{name}: expected a contiguous array")
    return x


def to_int32(name: str, x: ArrayLike, device: wp.Device) -> wp.array:
    if isinstance(x, wp.array):
        if x.dtype != wp.int32:
            raise ValueError(f"{name}: expected int32, got Warp dtype {x.dtype}")
        if x.device != device:
            raise ValueError(f"{name}: array is on {x.device}, expected {device}")
        return x
    arr = np.asarray(x)
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name}: expected an integer array, got dtype {arr.dtype}")
    if arr.size and (arr.min() < np.iinfo(np.int32).min or arr.max() > np.iinfo(np.int32).max):
        raise ValueError(f"{name}: values do not fit in int32")
    return wp.array(np.ascontiguousarray(arr, dtype=np.int32), dtype=wp.int32, device=device)


def check_bbox(name: str, bbox: Any) -> np.ndarray:
    b = np.asarray(bbox, dtype=np.float64)
    if b.shape != (2, 3):
        raise ValueError(f"{name}: expected shape (2, 3) (min and max corners), got {b.shape}")
    if not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
        raise ValueError(f"{name}: expected finite corners with min < max, got {b.tolist()}")
    return b


def check_positive_int(name: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
        raise ValueError(f"{name}: expected a positive integer, got {v!r}")
    return int(v)


def check_ray_offsets(name: str, offsets: ArrayLike, n_rays: int | None, n_samples: int) -> np.ndarray:
    """Packed-sample offsets: int, shape (R+1,), offsets[0] = 0, non-decreasing, offsets[-1] = N."""
    h = host_view(offsets)
    if h.ndim != 1 or h.size < 1 or (n_rays is not None and h.size != n_rays + 1):
        want = "(R+1,)" if n_rays is None else f"({n_rays + 1},)"
        raise ValueError(f"{name}: expected shape {want}, got {tuple(h.shape)}")
    if not np.issubdtype(h.dtype, np.integer):
        raise ValueError(f"{name}: expected an integer array, got dtype {h.dtype}")
    if h[0] != 0 or h[-1] != n_samples or np.any(np.diff(h) < 0):
        raise ValueError(f"{name}: expected non-decreasing offsets from 0 to the sample count {n_samples}, "
                         f"got first {h[0]}, last {h[-1]}")
    return h
