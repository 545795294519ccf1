"""The array contract (kernels._arrays): kinds, devices, dtypes, errors and the value-check switch."""

import numpy as np
import pytest
import warp as wp

from kernels import _arrays as A


def test_inputs_numpy_in_numpy_out():
    a = A.Inputs(None, np.zeros(3))
    x = a.floats("x", np.arange(3.0), (3,))
    assert isinstance(x, wp.array) and x.dtype == wp.float64 and a.as_numpy
    out = a.out(x)
    assert isinstance(out, np.ndarray) and out.tolist() == [0.0, 1.0, 2.0]
    assert a.np_dtype == np.float64 and a.s(1.5) == wp.float64(1.5)


def test_inputs_warp_in_warp_out_and_device_from_array():
    w = wp.array(np.ones(4, np.float32), dtype=wp.float32, device="cpu")
    a = A.Inputs(None, w, np.ones(4, np.float32))
    assert a.device == w.device and not a.as_numpy
    assert a.floats("w", w) is w
    converted = a.floats("n", np.ones(4, np.float32))
    assert converted.dtype == wp.float32 and a.out(converted) is converted


@pytest.mark.parametrize("bad, msg", [
    (np.zeros(3, np.int64), "x: expected dtype float32 or float64"),
    ([1.0, 2.0], "x: expected a NumPy array or a wp.array"),
    (np.zeros((2, 2)), r"x: expected shape \(3,\), got \(2, 2\)"),
    (np.array([0.0, np.nan, 1.0]), "x: expected finite values"),
    (np.array([0.0, np.inf, 1.0]), "x: expected finite values"),
])
def test_floats_errors_name_the_argument(bad, msg):
    with pytest.raises(ValueError, match=msg):
        A.Inputs(None).floats("x", bad, (3,))


def test_dtype_mismatch_names_the_later_argument():
    a = A.Inputs(None)
    a.floats("first", np.zeros(2, np.float32))
    with pytest.raises(ValueError, match="second: expected dtype float32 like the other inputs, got float64"):
        a.floats("second", np.zeros(2))


def test_other_device_and_bad_device():
    with pytest.raises(ValueError, match="device: cannot use 'tpu:7'"):
        A.Inputs("tpu:7")
    w = wp.zeros(2, dtype=wp.float32, device="cpu")
    a = A.Inputs("cpu", w)
    a.device = object()  # stand-in for another device: the array's device no longer matches
    with pytest.raises(ValueError, match="w: expected an array on device"):
        a.floats("w", w)


def test_ndim_nonempty_and_wildcards():
    a = A.Inputs(None)
    assert a.floats("x", np.zeros((5, 3)), (None, 3)).shape == (5, 3)
    with pytest.raises(ValueError, match=r"y: expected shape \(N, 3\)"):
        a.floats("y", np.zeros((5, 2)), (None, 3))
    with pytest.raises(ValueError, match="z: expected 2 dimensions"):
        a.floats("z", np.zeros(3), ndim=2)
    with pytest.raises(ValueError, match="e: expected a non-empty array"):
        a.floats("e", np.zeros((0, 3)), nonempty=True)


def test_value_check_switch_keeps_shape_checks():
    bad = np.array([np.nan, 1.0])
    with A.value_checks(False):
        assert not A.values_checked()
        A.Inputs(None).floats("x", bad, (2,))  # accepted: values are not read
        with pytest.raises(ValueError, match="x: expected shape"):
            A.Inputs(None).floats("x", bad, (3,))
    assert A.values_checked()
    with pytest.raises(ValueError, match="x: expected finite"):
        A.Inputs(None).floats("x", bad, (2,))


def test_all_finite_overflow_and_warp_arrays():
    big = np.full(10, 1e200)
    assert A.all_finite(big)  # x . x overflows; the element test decides
    assert not A.all_finite(np.array([1.0, -np.inf]))
    assert A.all_finite(np.zeros(0))
    w = wp.array(np.array([1.0, np.nan], np.float32), dtype=wp.float32, device="cpu")
    assert not A.all_finite(w)


def test_device_reductions_match_host(monkeypatch):
    # The CUDA path (a counting kernel) runs here on the CPU by hiding the host view.
    monkeypatch.setattr(A, "host_view", lambda x: None if isinstance(x, wp.array) else np.asarray(x))
    for dt in (np.float32, np.float64):
        good = wp.array(np.linspace(0, 1, 7).astype(dt), device="cpu")
        bad = wp.array(np.array([0.0, np.nan, -1.0], dt), device="cpu")
        assert A.all_finite(good) and not A.all_finite(bad)
        A.check_at_least("g", good, 0.0)
        with pytest.raises(ValueError, match="b: expected finite values >= 0"):
            A.check_at_least("b", bad, 0.0)
    ints = wp.array(np.array([3, -1, 2], np.int32), device="cpu")
    A.Inputs(None).ints("i", ints, minimum=-1)
    with pytest.raises(ValueError, match="i: expected values >= 0"):
        A.Inputs(None).ints("i", ints, minimum=0)


def test_check_at_least_host():
    A.check_at_least("x", np.array([0.0, 2.0]))
    with pytest.raises(ValueError, match="x: expected values >= 0, got a minimum of -1"):
        A.check_at_least("x", np.array([0.0, -1.0]))
    with pytest.raises(ValueError, match="x: expected finite values >= 0, found NaN"):
        A.check_at_least("x", np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="found inf"):
        A.check_at_least("x", np.array([0.0, np.inf]))


def test_ints_and_masks():
    a = A.Inputs(None)
    assert a.ints("i", np.array([0, 3])).dtype == wp.int32
    with pytest.raises(ValueError, match="i: expected an integer array"):
        a.ints("i", np.zeros(2))
    with pytest.raises(ValueError, match="i: expected values that fit in int32"):
        a.ints("i", np.array([2**40]))
    with pytest.raises(ValueError, match="i: expected values >= 0, got a minimum of -2"):
        a.ints("i", np.array([1, -2]), minimum=0)
    m = a.mask("m", np.array([[True, False]]), (1, 2))
    assert m.dtype == wp.uint8 and a.out_mask(m).dtype == np.bool_
    with pytest.raises(ValueError, match="m: expected dtype bool or uint8"):
        a.mask("m", np.zeros((1, 2), np.int64), (1, 2))


def test_scalar_checks():
    assert A.check_int("k", 3, minimum=1) == 3
    for bad in (True, 2.0, 0):
        with pytest.raises(ValueError, match="k: expected an integer >= 1"):
            A.check_int("k", bad, minimum=1)
    with pytest.raises(ValueError, match=r"k: expected an integer in \[0, 3\]"):
        A.check_int("k", 4, minimum=0, maximum=3)
    assert A.check_float("t", "0.5", positive=True) == 0.5
    for bad in (0.0, float("nan"), float("inf"), "x", True):
        with pytest.raises(ValueError, match="t: expected"):
            A.check_float("t", bad, positive=True)


def test_check_out():
    buf = wp.zeros((2, 3), dtype=wp.float32, device="cpu")
    assert A.check_out("out", buf, (2, 3), wp.float32, buf.device) is buf
    with pytest.raises(ValueError, match=r"out: expected an output buffer of shape \(3, 2\) and dtype float32"):
        A.check_out("out", buf, (3, 2), wp.float32, buf.device)
    with pytest.raises(ValueError, match="out: expected a wp.array output buffer"):
        A.check_out("out", np.zeros((2, 3)), (2, 3), wp.float32, buf.device)


def test_launch_and_overloads():
    a = A.Inputs(None)
    x = a.floats("x", np.arange(3000, dtype=np.float32))
    y = a.zeros(3000)
    a.launch(_double, 3000, [x, y])
    assert np.array_equal(a.out(y), 2 * np.arange(3000, dtype=np.float32))
    a.launch(_double, 0, [x, y])  # nothing to do


@wp.kernel
def _double(x: wp.array(dtype=wp.float32), y: wp.array(dtype=wp.float32), offset: int):
    i = wp.tid() + offset
    y[i] = x[i] * wp.float32(2.0)


def test_like_carries_device_scalar_and_kind():
    a = A.Inputs.like(wp.get_device("cpu"), wp.float64, False)
    assert a.scalar == wp.float64 and not a.as_numpy and a.device == wp.get_device("cpu")
    with pytest.raises(ValueError, match="y: expected dtype float64 like the other inputs"):
        a.floats("y", np.zeros(2, np.float32))


def test_host_pool_recycles_freed_blocks_of_the_same_size():
    x0 = np.zeros(3, np.float32)
    a = A.Inputs("cpu", x0)
    a.floats("x0", x0)  # sets the call's scalar type
    n = A.HostPool.MIN_BYTES // 4 + 17  # float32 elements: above the pooling threshold
    x = a.empty((n,))
    ptr = x.ptr
    x.numpy()[:] = 1.5
    del x  # back into the pool
    y = a.empty(n)
    assert y.ptr == ptr and y.shape == (n,) and y.dtype == wp.float32
    assert np.all(y.numpy() == 1.5)  # the same block (contents undefined in general)
    z = a.empty((n // 3, 3))  # another byte size: a new block
    assert z.ptr != ptr
    # Small arrays stay with Warp's allocator.
    assert a.empty(4).deleter is not None and a.empty(4).deleter != A.HOST_POOL._release


def test_host_pool_keeps_blocks_alive_while_a_numpy_view_exists():
    x0 = np.zeros(3, np.float64)
    a = A.Inputs("cpu", x0)
    a.floats("x0", x0)
    n = A.HostPool.MIN_BYTES // 8 + 5
    x = a.empty(n)
    view = a.out(x)  # what an entry point hands back for NumPy inputs
    view[:] = 2.0
    ptr = x.ptr
    del x
    y = a.empty(n)  # must not reuse the block the view still reads
    assert y.ptr != ptr
    y.numpy()[:] = -1.0
    assert np.all(view == 2.0)


def test_host_pool_limit_frees_the_oldest_blocks():
    pool = A.HostPool(limit=3 * A.HostPool.MIN_BYTES)
    dev = wp.get_device("cpu")
    n = A.HostPool.MIN_BYTES // 4
    arrays = [pool.empty((n,), wp.float32, dev) for _ in range(5)]
    ptrs = [x.ptr for x in arrays]
    while arrays:  # five blocks freed in allocation order, three kept: the last three freed
        arrays.pop(0)
    assert pool.nbytes() == 3 * A.HostPool.MIN_BYTES
    again = [pool.empty((n,), wp.float32, dev) for _ in range(3)]
    assert sorted(x.ptr for x in again) == sorted(ptrs[2:])
    del again
    pool.clear()
    assert pool.nbytes() == 0


def test_host_pool_size_classes():
    # 8 classes per octave: at most 12.5% more than asked, and sizes a little apart share a block.
    for n in (1 << 16, (1 << 16) + 1, 70000, 3 << 20, 12345678, (1 << 30) - 1):
        c = A.HostPool.size_class(n)
        assert n <= c <= n * 1.125 and c % (1 << max(n.bit_length() - 4, 0)) == 0
    pool = A.HostPool()
    dev = wp.get_device("cpu")
    x = pool.empty((100000,), wp.float32, dev)
    ptr = x.ptr
    del x
    y = pool.empty((100500,), wp.float32, dev)  # 400 000 and 402 000 bytes: one class
    assert y.ptr == ptr and y.shape == (100500,) and y.capacity == 402000  # capacity: the array's bytes
    del y
    pool.clear()
