"""The array contract every kernel family's entry points follow (host code only, no math).

An entry point takes NumPy arrays or `wp.array`s and hands back the same kind. This module is
the one place that converts, checks and sets up dtypes, so every family behaves the same way:

* **Kinds and devices.** An entry point opens an `Inputs` with its `device` argument and its
  array arguments. The device is the `device` argument when given, else the device of the first
  `wp.array` among the arguments, else the CPU. A `wp.array` on another device is an error (no
  silent transfers); a NumPy array is copied to the device. Outputs are NumPy arrays when the
  first array argument (the *primary* input) is a NumPy array, else `wp.array`s on the device.
* **Dtypes.** Float inputs are float32 or float64, all in one dtype: the first float argument
  sets it (`Inputs.scalar`, a Warp type; `Inputs.np_dtype`, its NumPy dtype). A generic kernel
  (arrays typed `dtype=typing.Any`) gets both overloads declared up front with
  `declare_float_overloads`, so its module compiles once.
* **Errors.** Every check raises `ValueError` whose message starts with the argument's name and
  says what was expected, before any kernel is launched.
* **Host memory.** `Inputs.empty` on the CPU takes blocks of 64 KB and more from `HOST_POOL`,
  which keeps the blocks of freed arrays (up to 256 MB) for the next array of their size class:
  their pages are mapped already, where a fresh block faults every page on first touch.
* **Value checks** (NaN, inf, sign, ranges) read the data where it lives: on the CPU through a
  zero-copy NumPy view, on CUDA with a reduction kernel that returns one integer (no copy of the
  array to the host). `value_checks(False)` turns them off for a hot loop whose inputs are known
  good (training), while shape, dtype and device checks stay on. It is a context manager and
  applies to the calling thread (a `contextvars.ContextVar`).
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import threading
import typing
from typing import Any, Iterator, Sequence

import numpy as np
import warp as wp

from kernels.launch import launch_split

ArrayLike = Any  # np.ndarray | wp.array
FLOATS = (wp.float32, wp.float64)
WP_OF_NP = {np.dtype(np.float32): wp.float32, np.dtype(np.float64): wp.float64}
NP_OF_WP = {wp.float32: np.dtype(np.float32), wp.float64: np.dtype(np.float64)}

_VALUE_CHECKS: contextvars.ContextVar[bool] = contextvars.ContextVar("drlab_value_checks", default=True)


# =========================================================================== the value-check switch


@contextlib.contextmanager
def value_checks(enabled: bool) -> Iterator[None]:
    """Turn value checks (finiteness, signs, ranges) on or off inside a `with` block.

    Shape, dtype and device checks are never turned off. Use `value_checks(False)` only around
    loops whose inputs were checked once before (a training loop feeding its own outputs back).
    """
    token = _VALUE_CHECKS.set(bool(enabled))
    try:
        yield
    finally:
        _VALUE_CHECKS.reset(token)


def values_checked() -> bool:
    """Whether value checks are on in this context."""
    return _VALUE_CHECKS.get()


# =========================================================================== devices, dtypes, kernels


def get_device(device: Any) -> wp.Device:
    """`device` as a wp.Device (None means `default_device()`); ValueError naming `device` otherwise."""
    if isinstance(device, wp.Device):
        return device
    if device is None:
        return default_device()
    try:
        return wp.get_device(device)
    except (RuntimeError, ValueError, TypeError) as exc:
        raise ValueError(f"device: cannot use {device!r} ({exc})") from None


# The device of NumPy inputs and of objects made without a `device` argument: the CPU, unless a
# `default_device_scope` is active (the device-parametrised tests, `drlab gradcheck --device`).
_DEFAULT_DEVICES: list[wp.Device] = []


def default_device() -> wp.Device:
    """The CPU, or the device of the innermost active `default_device_scope`."""
    return _DEFAULT_DEVICES[-1] if _DEFAULT_DEVICES else wp.get_device("cpu")


@contextlib.contextmanager
def default_device_scope(device: Any) -> Iterator[wp.Device]:
    """Inside the block, NumPy inputs are copied to `device` and objects made without a device live
    there (results still come back as NumPy arrays). Not thread-local: enter it from the thread that
    makes the calls, around whole calls."""
    dev = get_device(device)
    _DEFAULT_DEVICES.append(dev)
    try:
        with wp.ScopedDevice(dev):  # and Warp's own default: wp.array(x) without a device lands there too
            yield dev
    finally:
        _DEFAULT_DEVICES.pop()


def is_array(x: Any) -> bool:
    return isinstance(x, (np.ndarray, wp.array))


def float_dtype(name: str, x: ArrayLike) -> Any:
    """The Warp float type (float32 or float64) of the array `x`; ValueError for anything else."""
    if isinstance(x, wp.array):
        if x.dtype in FLOATS:
            return x.dtype
        raise ValueError(f"{name}: expected dtype float32 or float64, got {wp.types.type_repr(x.dtype)}")
    dt = np.asarray(x).dtype
    if dt in WP_OF_NP:
        return WP_OF_NP[dt]
    raise ValueError(f"{name}: expected dtype float32 or float64, got {dt}")


def type_name(dtype: Any) -> str:
    """A readable name of a Warp or NumPy dtype, for messages."""
    if dtype in NP_OF_WP:
        return NP_OF_WP[dtype].name
    try:
        return np.dtype(dtype).name
    except TypeError:
        return wp.types.type_repr(dtype)


def declare_float_overloads(kernel: Any, vector_types: dict[Any, Any] | None = None,
                            vector_suffix: str = "_v") -> None:
    """Declare a generic kernel's float32 and float64 overloads up front.

    Every `typing.Any` array argument becomes an array of the scalar type and every `typing.Any`
    scalar argument the scalar type. With `vector_types` ({scalar: vector type}), array arguments
    whose name ends in `vector_suffix` hold that vector type instead. Warp rebuilds a module each
    time a launch meets a new overload, so declaring both here makes the module compile once.
    """
    for scalar in FLOATS:
        types: dict[str, Any] = {}
        for arg in kernel.adj.args:
            if wp.types.is_array(arg.type) and arg.type.dtype is typing.Any:
                dtype = scalar
                if vector_types is not None and arg.label.endswith(vector_suffix):
                    dtype = vector_types[scalar]
                types[arg.label] = wp.array(dtype=dtype, ndim=arg.type.ndim)
            elif arg.type is typing.Any:
                types[arg.label] = scalar
        wp.overload(kernel, types)


# =========================================================================== value checks on the device


@wp.kernel(enable_backward=False)
def _count_nonfinite(x: wp.array(dtype=typing.Any), count: wp.array(dtype=wp.int32)):
    # One launch on a CUDA device, where atomics are atomic (never split across CPU threads).
    if not wp.isfinite(x[wp.tid()]):
        wp.atomic_add(count, 0, 1)


@wp.kernel(enable_backward=False)
def _count_below(x: wp.array(dtype=typing.Any), bound: float, count: wp.array(dtype=wp.int32)):
    v = x[wp.tid()]
    if not (v >= x.dtype(bound)):  # NaN counts too
        wp.atomic_add(count, 0, 1)


@wp.kernel(enable_backward=False)
def _count_below_int(x: wp.array(dtype=wp.int32), bound: int, count: wp.array(dtype=wp.int32)):
    if x[wp.tid()] < bound:
        wp.atomic_add(count, 0, 1)


declare_float_overloads(_count_nonfinite)
declare_float_overloads(_count_below)


def host_view(x: ArrayLike) -> np.ndarray | None:
    """A zero-copy NumPy view of a host array, or None for an array on a CUDA device.

    Value checks read host arrays through it; for None they count on the device instead
    (`device_count`).
    """
    if isinstance(x, wp.array):
        return x.numpy() if x.device.is_cpu else None
    return np.asarray(x)


def device_counts(kernel: Any, dim: int, inputs: list[Any], device: wp.Device, slots: int = 1) -> tuple[int, ...]:
    """Run a counting kernel as ONE launch and return its `slots` counts.

    The kernel's last parameter is `count: wp.array(dtype=wp.int32)` of `slots` elements, into
    which offending threads `wp.atomic_add(count, j, 1)` for the check j they fail. One launch
    keeps the atomics exact on every device (on the CPU one launch is one thread; docs/warp.md).
    Reading the counts back is the only transfer: the data stays where it is.
    """
    count = wp.zeros(slots, dtype=wp.int32, device=device)
    wp.launch(kernel, dim=dim, inputs=[*inputs, count], device=device)
    return tuple(int(c) for c in count.numpy())


def device_count(kernel: Any, dim: int, inputs: list[Any], device: wp.Device) -> int:
    """`device_counts` of a kernel with one count."""
    return device_counts(kernel, dim, inputs, device)[0]


def _device_count(kernel: Any, x: wp.array, *extra: Any) -> int:
    flat = x.flatten() if x.is_contiguous else wp.clone(x).flatten()
    return device_count(kernel, flat.size, [flat, *extra], x.device)


def all_finite(x: ArrayLike) -> bool:
    """Whether every element of the float array `x` is finite, computed where `x` lives.

    On the host the dot product x . x is NaN or infinite if any element is; it can also overflow
    for huge finite values, and only then is every element tested (one pass, no temporary: half
    the time of np.isfinite(x).all() on large arrays).
    """
    h = host_view(x)
    if h is None:
        return x.size == 0 or _device_count(_count_nonfinite, x) == 0
    flat = h.reshape(-1)
    if flat.dtype.kind != "f":
        return True
    with np.errstate(over="ignore", invalid="ignore"):  # overflow or NaN is the answer, not a problem
        if flat.size == 0 or np.isfinite(np.dot(flat, flat)):
            return True
    return bool(np.isfinite(flat).all())


def check_finite(name: str, x: ArrayLike) -> None:
    """ValueError naming `name` if `x` holds NaN or inf (skipped while value checks are off)."""
    if values_checked() and not all_finite(x):
        raise ValueError(f"{name}: expected finite values, found NaN or infinite entries")


def check_at_least(name: str, x: ArrayLike, bound: float = 0.0) -> None:
    """ValueError naming `name` unless every value is finite and >= `bound` (skipped while off)."""
    if not values_checked() or x.size == 0:
        return
    h = host_view(x)
    if h is None:
        if _device_count(_count_below, x, float(bound)) or not all_finite(x):
            raise ValueError(f"{name}: expected finite values >= {bound:g}")
        return
    lo = h.min()  # NaN anywhere makes the minimum NaN
    if np.isnan(lo):
        raise ValueError(f"{name}: expected finite values >= {bound:g}, found NaN")
    if lo < bound:
        raise ValueError(f"{name}: expected values >= {bound:g}, got a minimum of {lo:.6g}")
    if not all_finite(h):
        raise ValueError(f"{name}: expected finite values >= {bound:g}, found inf")


# =========================================================================== shapes and scalars


def shape_text(shape: Sequence[Any]) -> str:
    """(N, 3) for (None, 3): None (or a string) stands for a size the caller does not fix."""
    parts = ["N" if s is None else str(s) for s in shape]
    return "(" + ", ".join(parts) + ("," if len(parts) == 1 else "") + ")"


def check_shape(name: str, x: ArrayLike, shape: Sequence[Any]) -> tuple[int, ...]:
    """ValueError naming `name` unless x.shape matches `shape` (None entries match any size)."""
    got = tuple(int(s) for s in x.shape)
    if len(got) != len(shape) or any(s is not None and s != g for s, g in zip(shape, got)):
        raise ValueError(f"{name}: expected shape {shape_text(shape)}, got {got}")
    return got


def check_int(name: str, v: Any, minimum: int | None = None, maximum: int | None = None) -> int:
    """An integer (not a bool) within [minimum, maximum]; ValueError naming `name` otherwise."""
    ok = not isinstance(v, bool) and isinstance(v, (int, np.integer))
    if ok and minimum is not None and v < minimum:
        ok = False
    if ok and maximum is not None and v > maximum:
        ok = False
    if not ok:
        if minimum is not None and maximum is not None:
            want = f"an integer in [{minimum}, {maximum}]"
        elif minimum is not None:
            want = f"an integer >= {minimum}"
        elif maximum is not None:
            want = f"an integer <= {maximum}"
        else:
            want = "an integer"
        raise ValueError(f"{name}: expected {want}, got {v!r}")
    return int(v)


def check_float(name: str, v: Any, *, positive: bool = False, nonnegative: bool = False) -> float:
    """A finite real number (positive or non-negative when asked); ValueError naming `name`."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {v!r}") from None
    if isinstance(v, bool) or not math.isfinite(f) or (positive and not f > 0) or (nonnegative and not f >= 0):
        need = "a positive finite" if positive else ("a finite non-negative" if nonnegative else "a finite")
        raise ValueError(f"{name}: expected {need} number, got {v!r}")
    return f


def check_out(name: str, x: Any, shape: Sequence[int], dtype: Any, device: wp.Device) -> wp.array:
    """A caller-supplied output buffer: a contiguous wp.array of exactly `shape` and `dtype` on `device`."""
    if not isinstance(x, wp.array):
        raise ValueError(f"{name}: expected a wp.array output buffer, got {type(x).__name__}")
    if tuple(x.shape) != tuple(shape) or x.dtype != dtype:
        raise ValueError(f"{name}: expected an output buffer of shape {tuple(shape)} and dtype "
                         f"{type_name(dtype)}, got shape {tuple(x.shape)} and dtype {type_name(x.dtype)}")
    if x.device != device:
        raise ValueError(f"{name}: expected an array on device {device}, got one on {x.device}")
    if not x.is_contiguous:
        raise ValueError(f"{name}: expected a contiguous array")
    return x


# =========================================================================== recycled host memory


class HostPool:
    """Host blocks of freed CPU arrays kept for the next array of the same size class.

    A fresh host array of megabytes comes from the OS: every 4 KB page faults (and is zeroed) on
    first touch, and glibc returns a large freed block at the top of its heap to the OS again, so a
    call that allocates its outputs afresh pays the faults on every call. For the textbook spheres'
    packed render (dense_samples + render_samples, ~20 MB of samples, field outputs and factors a
    call) the faults were about as much CPU time as the kernels (5088 faults a call; 27 with the pool). `Inputs.empty`
    takes host blocks of at least MIN_BYTES from here: a block whose array is freed goes back into
    the pool (the array's deleter) and the next request of the same size class gets it, its pages
    already mapped. Sizes are rounded up to 8 classes per octave (at most 12.5% more memory), so
    that arrays whose sizes vary a little from call to call (occupancy-skipped samples in
    training) still find a block. At most `limit` bytes are kept; beyond that the oldest blocks are
    freed. The contents of a block are undefined, as wp.empty's are. Thread-safe (arrays are freed
    on any thread, by the garbage collector too).
    """

    MIN_BYTES = 1 << 16

    def __init__(self, limit: int = 256 << 20):
        self.limit = int(limit)
        self._free: dict[int, list[int]] = {}  # size class -> pointers of the kept blocks
        self._order: dict[int, int] = {}  # ptr -> size class of every kept block, oldest first
        # ptr -> the NumPy byte buffer that owns the block, for every block in use or kept: the memory
        # is NumPy's (public API only), and a block is freed when its buffer is dropped from here.
        self._owners: dict[int, np.ndarray] = {}
        self._bytes = 0
        self._lock = threading.Lock()

    @staticmethod
    def size_class(nbytes: int) -> int:
        """nbytes rounded up to a multiple of 2^(e-3), where 2^e <= nbytes < 2^(e+1)."""
        step = 1 << max(nbytes.bit_length() - 4, 0)
        return -(-nbytes // step) * step

    def empty(self, shape: tuple[int, ...], dtype: Any, device: wp.Device) -> wp.array:
        """A contiguous host wp.array of `shape` and `dtype` whose block returns here when it is freed."""
        nbytes = wp.types.type_size_in_bytes(dtype) * math.prod(shape)
        size = self.size_class(nbytes)
        with self._lock:
            kept = self._free.get(size)
            ptr = kept.pop() if kept else None
            if ptr is not None:
                del self._order[ptr]
                self._bytes -= size
        if ptr is None:
            # 64 bytes of slack so that the block can start on a cache line (NumPy aligns to 16)
            owner = np.empty(size + 64, dtype=np.uint8)
            ptr = owner.ctypes.data + (-owner.ctypes.data) % 64
            with self._lock:
                self._owners[ptr] = owner
        # capacity: the array's own bytes, as wp.empty's (the deleter maps it to the block's class)
        return wp.array(ptr=ptr, dtype=dtype, shape=shape, device=device, capacity=nbytes, deleter=self._release)

    def _release(self, ptr: int, nbytes: int) -> None:
        size = self.size_class(nbytes)
        evicted = []
        with self._lock:
            self._free.setdefault(size, []).append(ptr)
            self._order[ptr] = size
            self._bytes += size
            while self._bytes > self.limit:
                old = next(iter(self._order))
                old_size = self._order.pop(old)
                self._free[old_size].remove(old)
                self._bytes -= old_size
                evicted.append(self._owners.pop(old))
        del evicted  # the owners' buffers, freed here, outside the lock

    def nbytes(self) -> int:
        """Bytes kept for reuse now."""
        return self._bytes

    def clear(self) -> None:
        """Free every kept block."""
        with self._lock:
            owners = [self._owners.pop(p) for p in self._order]
            self._free, self._order, self._bytes = {}, {}, 0
        del owners


HOST_POOL = HostPool()


# =========================================================================== one entry point's inputs


class Inputs:
    """The inputs of one entry-point call: their device, float dtype and array kind.

    `Inputs(device, *arrays)` resolves the device (the `device` argument, else the first
    wp.array's, else `default_device()`: the CPU unless a `default_device_scope` is active) and the output kind (that of the first array); then `floats`,
    `ints` and `mask` check and convert each argument, and `out` hands results back.
    """

    def __init__(self, device: Any = None, *arrays: Any):
        candidates = [a for a in arrays if is_array(a)]
        if device is None:
            on_device = [a for a in candidates if isinstance(a, wp.array)]
            self.device = on_device[0].device if on_device else default_device()
        else:
            self.device = get_device(device)
        self.as_numpy = not candidates or isinstance(candidates[0], np.ndarray)
        self.scalar: Any = None  # set by the first float argument

    @classmethod
    def like(cls, device: wp.Device, scalar: Any, as_numpy: bool) -> "Inputs":
        """An `Inputs` whose device, scalar type and output kind are already known.

        For the later stages of a chain whose first stage resolved them (a checked parameter set
        handed to project, bin, rasterise and their backwards).
        """
        a = cls(device)
        a.scalar = scalar
        a.as_numpy = bool(as_numpy)
        return a

    # ------------------------------------------------------------------- properties

    @property
    def np_dtype(self) -> np.dtype:
        return NP_OF_WP[self.scalar]

    def s(self, value: float) -> Any:
        """`value` as the scalar type (a Python float passed to a kernel would be float32)."""
        return self.scalar(value)

    # ------------------------------------------------------------------- arguments

    def _array(self, name: str, x: Any) -> None:
        if not is_array(x):
            raise ValueError(f"{name}: expected a NumPy array or a wp.array, got {type(x).__name__}")
        if isinstance(x, wp.array):
            if x.device != self.device:
                raise ValueError(f"{name}: expected an array on device {self.device}, got one on {x.device}")
            if not x.is_contiguous:
                raise ValueError(f"{name}: expected a contiguous wp.array")

    def float_dtype(self, name: str, x: Any) -> Any:
        """The float dtype of argument x: the first float argument sets the call's scalar type, later ones
        must match it (ValueError naming the argument)."""
        dtype = float_dtype(name, x)
        if self.scalar is None:
            self.scalar = dtype
        elif dtype != self.scalar:
            raise ValueError(f"{name}: expected dtype {type_name(self.scalar)} like the other inputs, "
                             f"got {type_name(dtype)}")
        return dtype

    def floats(self, name: str, x: Any, shape: Sequence[Any] | None = None, *, ndim: int | None = None,
               finite: bool = True, nonempty: bool = False) -> wp.array:
        """A float argument as a wp.array of the call's scalar type on the call's device.

        The first float argument sets the scalar type; later ones must match it. `shape` entries
        of None match any size; `ndim` checks only the number of dimensions. `finite` checks for
        NaN and inf (while value checks are on); `nonempty` rejects a zero-sized array.
        """
        self._array(name, x)
        dtype = self.float_dtype(name, x)
        if shape is not None:
            check_shape(name, x, shape)
        if ndim is not None and len(x.shape) != ndim:
            raise ValueError(f"{name}: expected {ndim} dimensions, got shape {tuple(x.shape)}")
        if nonempty and (len(x.shape) == 0 or min(x.shape) == 0):
            raise ValueError(f"{name}: expected a non-empty array, got shape {tuple(x.shape)}")
        if finite:
            check_finite(name, x)
        if isinstance(x, wp.array):
            return x
        return wp.array(np.ascontiguousarray(x), dtype=dtype, device=self.device)

    def floats_or_zeros(self, name: str, x: Any, shape: Sequence[Any]) -> wp.array:
        """`floats(name, x, shape)`, or zeros of `shape` where `x` is None (a missing cotangent or a
        missing initial value counts as zero)."""
        return self.zeros(shape) if x is None else self.floats(name, x, shape)

    def ints(self, name: str, x: Any, shape: Sequence[Any] | None = None, *, minimum: int | None = None) -> wp.array:
        """An integer argument as an int32 wp.array (NumPy integers must fit in int32)."""
        self._array(name, x)
        if isinstance(x, wp.array):
            if x.dtype != wp.int32:
                raise ValueError(f"{name}: expected dtype int32, got {type_name(x.dtype)}")
            arr = x
        else:
            h = np.asarray(x)
            if not np.issubdtype(h.dtype, np.integer):
                raise ValueError(f"{name}: expected an integer array, got dtype {h.dtype}")
            if h.size and (h.min() < np.iinfo(np.int32).min or h.max() > np.iinfo(np.int32).max):
                raise ValueError(f"{name}: expected values that fit in int32")
            arr = None
        if shape is not None:
            check_shape(name, x, shape)
        if minimum is not None and values_checked() and x.size:
            h = host_view(x)
            if h is None:  # an int32 wp.array on a CUDA device: count on the device
                if _device_count(_count_below_int, x, int(minimum)):
                    raise ValueError(f"{name}: expected values >= {minimum}")
            elif int(h.min()) < minimum:
                raise ValueError(f"{name}: expected values >= {minimum}, got a minimum of {int(h.min())}")
        if arr is None:
            arr = wp.array(np.ascontiguousarray(x, dtype=np.int32), dtype=wp.int32, device=self.device)
        return arr

    def mask(self, name: str, m: Any, shape: Sequence[Any]) -> wp.array:
        """A validity mask (bool or uint8 NumPy, uint8 wp.array) of `shape`, as a uint8 wp.array."""
        self._array(name, m)
        check_shape(name, m, shape)
        if isinstance(m, wp.array):
            if m.dtype != wp.uint8:
                raise ValueError(f"{name}: expected dtype uint8, got {type_name(m.dtype)}")
            return m
        if m.dtype not in (np.bool_, np.uint8):
            raise ValueError(f"{name}: expected dtype bool or uint8, got {m.dtype}")
        return wp.array(np.ascontiguousarray(m, dtype=np.uint8), dtype=wp.uint8, device=self.device)

    # ------------------------------------------------------------------- allocation and results

    def zeros(self, shape: Any, dtype: Any = None) -> wp.array:
        return wp.zeros(shape, dtype=dtype or self.scalar, device=self.device)

    def empty(self, shape: Any, dtype: Any = None) -> wp.array:
        """An array the caller overwrites entirely (on the CPU, large ones recycle freed blocks: HostPool)."""
        dtype = dtype or self.scalar
        if self.device.is_cpu:
            shape = (int(shape),) if isinstance(shape, (int, np.integer)) else tuple(int(s) for s in shape)
            if shape and wp.types.type_size_in_bytes(dtype) * math.prod(shape) >= HostPool.MIN_BYTES:
                return HOST_POOL.empty(shape, dtype, self.device)
        return wp.empty(shape, dtype=dtype, device=self.device)

    def out(self, x: wp.array) -> ArrayLike:
        """A result in the primary input's kind: NumPy (a host copy) or the wp.array itself."""
        return x.numpy() if self.as_numpy else x

    def out_mask(self, m: wp.array) -> ArrayLike:
        """A uint8 mask result: bool NumPy, or the uint8 wp.array itself."""
        return m.numpy().astype(bool) if self.as_numpy else m

    def launch(self, kernel: Any, dim: int, inputs: list[Any], min_chunk: int | None = None,
               threads: int | None = None) -> None:
        """Launch a split-launch kernel (last parameter `offset`) over `dim` threads; no-op when dim = 0."""
        if dim <= 0:
            return
        kwargs: dict[str, Any] = {"device": self.device, "threads": threads}
        if min_chunk is not None:
            kwargs["min_chunk"] = min_chunk
        launch_split(kernel, dim, inputs, **kwargs)
