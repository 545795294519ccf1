"""kernels.launch.launch_split: identical to one launch, every index once, errors propagate.

No timing is asserted here (tests must pass on a slow, busy machine); the
speedup is measured by `drlab bench launch`.
"""

from __future__ import annotations

import threading
import typing

import numpy as np
import pytest
import warp as wp

import kernels.launch as kl
from kernels.launch import chunk_bounds, default_threads, launch_split

DEVICE = "cpu"


@wp.kernel
def affine_offset(x: wp.array(dtype=typing.Any), y: wp.array(dtype=typing.Any), hits: wp.array(dtype=wp.int32),
                  offset: int):
    i = wp.tid() + offset
    v = x[i]
    for _k in range(8):
        v = wp.sin(v) * x.dtype(0.75) + x.dtype(float(i)) * x.dtype(1e-3)
    y[i] = v
    # Slot i is touched by index i alone. An atomic on a slot shared between chunks
    # would race: Warp's CPU atomics are plain read-modify-writes (kernels/launch.py).
    wp.atomic_add(hits, i, 1)


@wp.kernel
def float64_only(x: wp.array(dtype=wp.float64), offset: int):
    i = wp.tid() + offset
    x[i] = x[i] + wp.float64(1.0)


@wp.kernel
def no_offset(x: wp.array(dtype=wp.float64)):
    i = wp.tid()
    x[i] = wp.float64(0.0)


def _run(dtype, dim: int, split: bool, **kwargs):
    rng = np.random.default_rng(dim)
    x = wp.array(rng.uniform(-2.0, 2.0, dim), dtype=dtype, device=DEVICE)
    y = wp.full(dim, 7.0, dtype=dtype, device=DEVICE)
    hits = wp.zeros(dim, dtype=wp.int32, device=DEVICE)
    if split:
        launch_split(affine_offset, dim, [x, y, hits], device=DEVICE, **kwargs)
    else:
        wp.launch(affine_offset, dim=dim, inputs=[x, y, hits, 0], device=DEVICE)
    return y.numpy(), hits.numpy()


@pytest.mark.parametrize("dtype", [wp.float32, wp.float64])
@pytest.mark.parametrize("threads", [1, 2, 3, 4])
@pytest.mark.parametrize("dim", [0, 1, 3, 7, 1000, 4097])
@pytest.mark.parametrize("min_chunk", [1, kl.DEFAULT_MIN_CHUNK])
def test_split_equals_single(dtype, threads, dim, min_chunk):
    ref, _ = _run(dtype, dim, split=False)
    got, hits = _run(dtype, dim, split=True, threads=threads, min_chunk=min_chunk)
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(hits, np.ones(dim, dtype=np.int32))  # every index exactly once


def test_default_threads_and_env(monkeypatch):
    monkeypatch.delenv(kl.ENV_THREADS, raising=False)
    assert default_threads() >= 1
    monkeypatch.setenv(kl.ENV_THREADS, "3")
    assert default_threads() == 3
    got, hits = _run(wp.float64, 5000, split=True)  # threads from the environment
    np.testing.assert_array_equal(got, _run(wp.float64, 5000, split=False)[0])
    np.testing.assert_array_equal(hits, np.ones(5000, dtype=np.int32))
    for bad in ("0", "two"):
        monkeypatch.setenv(kl.ENV_THREADS, bad)
        with pytest.raises(ValueError, match=kl.ENV_THREADS):
            default_threads()


@pytest.mark.parametrize("dim, n", [(0, 1), (1, 1), (10, 3), (10, 10), (4097, 8)])
def test_chunk_bounds_cover_range(dim, n):
    bounds = chunk_bounds(dim, n)
    assert len(bounds) == n
    assert [o for o, _ in bounds] == list(np.cumsum([0] + [s for _, s in bounds[:-1]]))
    assert sum(s for _, s in bounds) == dim
    assert max(s for _, s in bounds) - min(s for _, s in bounds) <= 1


@pytest.mark.parametrize("dim, threads, min_chunk", [(2048, 2, 1024), (98_304, 2, 1024), (1_000_003, 2, 1024),
                                                    (4097, 3, 7), (100, 4, 1)],
                         ids=["two_min_chunks", "launch_bench", "million_odd", "three_threads", "min_chunk_one"])
def test_guided_bounds_cover_range_in_shrinking_chunks(dim, threads, min_chunk):
    bounds = kl.guided_bounds(dim, threads, min_chunk)
    assert bounds[0][0] == 0 and sum(s for _, s in bounds) == dim
    assert all(o + s == bounds[j + 1][0] for j, (o, s) in enumerate(bounds[:-1]))  # contiguous, in order
    sizes = [s for _, s in bounds]
    assert all(a >= b for a, b in zip(sizes, sizes[1:]))  # never growing
    assert all(s >= min_chunk for s in sizes[:-1]) and sizes[-1] >= 1
    assert sizes[0] == -(-dim // (kl.GUIDED_FACTOR * threads)) or sizes[0] == min(dim, min_chunk)
    if dim >= 16 * min_chunk * threads:  # large grids: the tail is small chunks, the head few large ones
        assert sizes[-2] == min_chunk and len(bounds) < dim // min_chunk / 4
    assert kl.guided_bounds(dim, threads, min_chunk) == bounds  # depends only on the arguments


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_argument_check_error_propagates(threads):
    x32 = wp.zeros(4096, dtype=wp.float32, device=DEVICE)
    with pytest.raises(Exception, match="float"):
        launch_split(float64_only, 4096, [x32], device=DEVICE, threads=threads, min_chunk=16)
    x = wp.zeros(4096, dtype=wp.float64, device=DEVICE)
    with pytest.raises(RuntimeError, match="arguments"):
        launch_split(float64_only, 4096, [x, x], device=DEVICE, threads=threads, min_chunk=16)


def test_worker_thread_error_propagates_after_all_chunks(monkeypatch):
    """A failure inside a pool worker (not the caller's thread) reaches the caller."""
    real_launch = wp.launch
    main = threading.get_ident()
    worker_started = threading.Event()

    def flaky_launch(kernel, dim, inputs, device):
        if threading.get_ident() != main:
            worker_started.set()
            raise RuntimeError("boom in worker")
        worker_started.wait(timeout=30)  # keep chunks left over for the worker to take
        return real_launch(kernel, dim=dim, inputs=inputs, device=device)

    x = wp.zeros(4096, dtype=wp.float64, device=DEVICE)
    # loaded first: a first use launches one chunk alone before any worker starts (kernels.launch),
    # which here would wait out the timeout instead of letting a worker take a chunk
    launch_split(float64_only, 4096, [x], device=DEVICE, threads=2, min_chunk=64)
    monkeypatch.setattr(kl.wp, "launch", flaky_launch)
    with pytest.raises(RuntimeError, match="boom in worker"):
        launch_split(float64_only, 4096, [x], device=DEVICE, threads=2, min_chunk=64)
    monkeypatch.undo()
    # The pool is still usable after a failure.
    launch_split(float64_only, 4096, [x], device=DEVICE, threads=2, min_chunk=64)
    assert np.all(x.numpy() >= 1.0)


def test_bad_arguments_rejected():
    x = wp.zeros(8, dtype=wp.float64, device=DEVICE)
    with pytest.raises(ValueError, match="offset"):
        launch_split(no_offset, 8, [x], device=DEVICE)
    with pytest.raises(ValueError, match="threads"):
        launch_split(float64_only, 8, [x], device=DEVICE, threads=0)
    with pytest.raises(ValueError, match="dim"):
        launch_split(float64_only, -1, [x], device=DEVICE)
    with pytest.raises(ValueError, match="min_chunk"):
        launch_split(float64_only, 8, [x], device=DEVICE, min_chunk=0)


def test_concurrent_callers_share_the_pool():
    """Two Python threads calling launch_split at once (pool growth under the lock)."""
    xs = [wp.zeros(6000, dtype=wp.float64, device=DEVICE) for _ in range(4)]
    errors = []

    def call(x, threads):
        try:
            for _ in range(3):
                launch_split(float64_only, 6000, [x], device=DEVICE, threads=threads, min_chunk=100)
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    workers = [threading.Thread(target=call, args=(x, t)) for x, t in zip(xs, (2, 3, 4, 5))]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert not errors
    for x in xs:
        np.testing.assert_array_equal(x.numpy(), np.full(6000, 3.0))


@wp.kernel
def first_use(x: wp.array(dtype=typing.Any), offset: int):
    i = wp.tid() + offset
    x[i] = x.dtype(i) * x.dtype(0.5)


@pytest.mark.parametrize("dtype", [wp.float32, wp.float64])
def test_first_launch_of_an_overload_is_split_safely(dtype):
    """The very first launch of an overload (compile + load) happens inside launch_split."""
    x = wp.zeros(10_000, dtype=dtype, device=DEVICE)
    launch_split(first_use, 10_000, [x], device=DEVICE, threads=4, min_chunk=10)
    np.testing.assert_array_equal(x.numpy(), (np.arange(10_000) * 0.5).astype(x.numpy().dtype))


def test_generic_kernel_launches_the_overload_of_its_argument_types():
    """launch_split resolves a generic kernel's overload once per argument types (wp.launch's own
    inference) and launches that: alternating dtypes each get theirs."""
    for dtype in (wp.float32, wp.float64, wp.float32):
        for threads in (1, 2):
            ref, _ = _run(dtype, 3000, split=False)
            got, hits = _run(dtype, 3000, split=True, threads=threads, min_chunk=64)
            np.testing.assert_array_equal(got, ref)
            np.testing.assert_array_equal(hits, np.ones(3000, dtype=np.int32))
    resolved = {k: v for k, v in kl._resolved.items() if k[0] == id(affine_offset)}
    assert len(resolved) >= 2
    for key, (generic, kernel) in resolved.items():
        assert generic is affine_offset and not kernel.is_generic
        assert kernel.adj.args[0].type.dtype == key[2][0][1]  # x's dtype


@pytest.mark.parametrize("n, threads, min_chunk", [(0, 2, 4), (5, 2, 4), (1000, 2, 16), (1001, 3, 7), (10, 1, 1)],
                         ids=["empty", "one_range", "two_threads", "three_threads_uneven", "one_thread"])
def test_parallel_ranges_covers_every_index_once(n, threads, min_chunk):
    hits = np.zeros(n, dtype=np.int64)
    calls = []

    def fn(lo, hi):
        calls.append((lo, hi))
        hits[lo:hi] += 1

    kl.parallel_ranges(fn, n, threads=threads, min_chunk=min_chunk)
    assert np.all(hits == 1)
    assert len(calls) == (0 if n == 0 else max(1, min(threads, n // min_chunk)))


def test_parallel_ranges_reraises_and_starts_no_range_after_a_failure():
    done = []

    def fn(lo, hi):
        if lo == 0:
            raise RuntimeError("range 0 failed")
        done.append(lo)

    with pytest.raises(RuntimeError, match="range 0 failed"):
        kl.parallel_ranges(fn, 100, threads=2, min_chunk=10)
    assert done in ([], [50])  # the other range ran only if a worker took it before the failure
    hits = np.zeros(100, dtype=int)
    kl.parallel_ranges(lambda lo, hi: hits.__setitem__(slice(lo, hi), hits[lo:hi] + 1), 100, threads=2,
                       min_chunk=10)
    assert np.all(hits == 1)  # the pool still works after a failure


@pytest.mark.parametrize("n, threads", [(0, 2), (1, 2), (16, 2), (5, 3), (7, 1)],
                         ids=["empty", "one_item", "levels", "more_threads_than_needed", "one_thread"])
def test_parallel_items_calls_every_item_once(n, threads):
    seen = []
    lock = threading.Lock()

    def fn(i):
        with lock:
            seen.append(i)

    kl.parallel_items(fn, n, threads=threads)
    assert sorted(seen) == list(range(n))


def test_parallel_items_reraises():
    def fn(i):
        if i == 3:
            raise KeyError("item 3")

    with pytest.raises(KeyError, match="item 3"):
        kl.parallel_items(fn, 8, threads=2)


def test_submit_runs_on_a_launch_thread_and_reraises():
    """`submit`: fn runs on a pool thread while the caller goes on; its Future gives the result or the exception."""
    caller = threading.get_ident()
    started = threading.Event()

    def fn():
        started.set()
        return threading.get_ident()

    fut = kl.submit(fn)
    assert started.wait(10)
    assert fut.result(10) != caller

    def fail():
        raise KeyError("early")

    with pytest.raises(KeyError, match="early"):
        kl.submit(fail).result(10)
