"""Race-free split launches of CPU kernels over several Python threads.

Warp runs a CPU launch on one thread, but its binding releases the GIL during
the launch (docs/warp.md). So a 1-D grid of `dim` threads can be cut into
contiguous chunks [o_j, o_j + n_j), each launched from its own Python thread
with `dim = n_j`; inside the kernel the global index is `wp.tid() + offset`.

Convention: the kernel's LAST parameter is `offset: int`. `launch_split`
appends it to `inputs`; a kernel written for it looks like

    @wp.kernel
    def scale(x: wp.array(dtype=typing.Any), y: wp.array(dtype=typing.Any), offset: int):
        i = wp.tid() + offset
        y[i] = x.dtype(2.0) * x[i]

Which kernels may use it. The chunks run concurrently, so the result equals a
single launch only if no two thread indices interfere:
  * allowed: each thread index writes only its own output slots (disjoint
    writes) and reads only what no thread writes;
  * NOT allowed: ANY atomic (`wp.atomic_add`, `atomic_min/max/sub`, or `+=`
    on an array element, which compiles to one) whose target two chunks can
    hit, integer or float. Warp 1.19 compiles every CPU atomic to a plain
    read-modify-write (native/builtin.h: `old = buf[0]; buf[0] += value`), so
    concurrent CPU launches lose updates: measured here, two threads adding 1
    into 64 int32 slots kept 7.47M-7.97M of 8M (floats lose the same way,
    docs/warp.md). An atomic on a slot only index i touches is just a write
    and is fine. Scatter-style (backward) kernels must run as one launch,
    accumulate into a buffer per chunk and reduce afterwards, or be rewritten
    as gathers;
  * nothing that depends on the order of indices (reading a value another
    index writes in the same launch).
An active `wp.Tape` records each chunk as its own launch (each chunk is a
self-contained launch, so replaying them is equivalent).

A generic kernel (`typing.Any` parameters) is launched as its overload for the arguments' types,
resolved once per (kernel, device, argument types) by Warp's own inference: wp.launch would
otherwise infer it again at every launch, ~50 us of Python, paid by every chunk.

On a CUDA device the grid is launched once with offset 0 (asynchronously, as
`wp.launch` is; pass `synchronize=True` to wait for it). On the CPU every chunk
has finished when `launch_split` returns, and an exception raised by any chunk
(a failed argument check, a compile error) is re-raised in the caller after
all chunks have stopped.

Threads: `threads` if given, else the environment variable DRLAB_THREADS, else
`os.cpu_count()`. The grid is cut into chunks of decreasing size (guided
self-scheduling, `guided_bounds`): each chunk takes 1 / (GUIDED_FACTOR *
threads) of the indices not yet assigned, and none is smaller than `min_chunk`;
the threads (the caller plus pool workers) pull them in order, one at a time.
A static split into `threads` equal parts waits for the slowest part; pulling
chunks balances indices of unequal cost (early ray termination, tiles holding
different numbers of splats) and a core that is briefly busy with another
process. With equal chunks the last one to finish leaves the other threads idle
for up to a chunk's time (8 chunks on 2 threads: up to 1/8 of the work); the
guided chunks start large (few launches) and end with chunks of `min_chunk`, so
that idle tail is a small chunk's time. The cut depends only on `dim`, the
thread count and `min_chunk`. A grid too small for two chunks runs as one plain
launch.

Two host-side helpers share the same thread pool: `parallel_ranges(fn, n)`
calls fn(lo, hi) on contiguous ranges, one per thread (NumPy passes over large
arrays; NumPy's ufuncs release the GIL), and `parallel_items(fn, n)` calls
fn(i) for each of a few items of unequal cost, each thread pulling the next
(e.g. one launch per hash-grid level, whose writes are disjoint). The same
rule holds for both: what one range or item writes, no other touches.
"""

from __future__ import annotations

import operator
import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, Iterator, Sequence

import warp as wp

# A launch costs tens of microseconds of Python; smaller chunks rarely repay the hand-off to a thread.
DEFAULT_MIN_CHUNK = 1024
# Guided chunks: each takes 1 / (GUIDED_FACTOR * threads) of the indices left (module docstring).
GUIDED_FACTOR = 2
ENV_THREADS = "DRLAB_THREADS"

_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_pool_lock = threading.Lock()
# (kernel, device, argument types) already launched here: their module is compiled and loaded.
_loaded: set[tuple] = set()
# (kernel, device, argument types) -> (the kernel, its overload for those types). Holding the kernel keeps
# its id, part of the key, from being reused by another kernel while the entry exists.
_resolved: dict[tuple, tuple[Any, Any]] = {}


def default_threads() -> int:
    """DRLAB_THREADS if set (a positive integer), else os.cpu_count()."""
    env = os.environ.get(ENV_THREADS, "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"{ENV_THREADS}={env!r} is not an integer") from None
        if n < 1:
            raise ValueError(f"{ENV_THREADS}={env!r} must be >= 1")
        return n
    return os.cpu_count() or 1


def chunk_bounds(dim: int, n_chunks: int) -> list[tuple[int, int]]:
    """(offset, size) of `n_chunks` contiguous chunks covering [0, dim), sizes differing by at most 1."""
    base, extra = divmod(dim, n_chunks)
    bounds, offset = [], 0
    for j in range(n_chunks):
        size = base + (1 if j < extra else 0)
        bounds.append((offset, size))
        offset += size
    return bounds


def guided_bounds(dim: int, threads: int, min_chunk: int) -> list[tuple[int, int]]:
    """(offset, size) of contiguous chunks covering [0, dim) in order: each takes
    ceil(left / (GUIDED_FACTOR * threads)) of the `left` indices not yet cut, at least `min_chunk`
    (the last one may be smaller only when fewer are left)."""
    bounds, offset = [], 0
    while offset < dim:
        left = dim - offset
        size = min(left, max(min_chunk, -(-left // (GUIDED_FACTOR * threads))))
        bounds.append((offset, size))
        offset += size
    return bounds


def _submit(fn: Callable[[], None], count: int) -> list[Future]:
    """Run `fn` `count` times on a shared pool (reused, so a launch pays no thread start-up)."""
    global _pool, _pool_size
    with _pool_lock:  # submitting under the lock: another caller may replace the pool
        if _pool is None or _pool_size < count:
            if _pool is not None:
                _pool.shutdown(wait=False)  # its submitted work still runs to completion
            _pool, _pool_size = ThreadPoolExecutor(max_workers=count, thread_name_prefix="drlab-launch"), count
        return [_pool.submit(fn) for _ in range(count)]


def submit(fn: Callable[[], Any]) -> Future:
    """Start `fn()` on one of the launch threads (the shared pool) and return at once; the Future gives
    its result or re-raises its exception. For work a caller overlaps with its own (e.g. a native launch,
    which releases the GIL, while the caller prepares the next ones); the caller must wait for it."""
    return _submit(fn, 1)[0]


def parallel_ranges(fn: Callable[[int, int], None], n: int, *, threads: int | None = None,
                    min_chunk: int = 1 << 16) -> None:
    """Call `fn(lo, hi)` over contiguous ranges covering [0, n), one per thread, concurrently.

    For host-side NumPy passes over large arrays (NumPy's ufuncs release the GIL): `fn` must write
    only inside its own range. The caller's thread is one of the workers; after a failure no new
    range starts, and the first exception is re-raised here once every worker has stopped.
    """
    n_threads = default_threads() if threads is None else threads
    n_parts = max(1, min(n_threads, n // max(1, min_chunk)))
    if n_parts <= 1:
        if n > 0:
            fn(0, n)
        return
    _pull_all(iter(chunk_bounds(n, n_parts)), lambda b: fn(b[0], b[0] + b[1]), n_parts)


def parallel_items(fn: Callable[[int], None], n: int, *, threads: int | None = None) -> None:
    """Call `fn(i)` for i in [0, n) on the launch threads, each pulling the next item when free.

    For a few items of unequal cost (one launch per item, e.g. per hash-grid level, whose writes
    are disjoint). `fn` must write nothing another item touches. The caller's thread is one of the
    workers; an exception raised by any item is re-raised here after all workers have stopped.
    """
    n_threads = default_threads() if threads is None else threads
    _pull_all(iter(range(n)), fn, max(1, min(n_threads, n)))


def _pull_all(items: Iterator[Any], fn: Callable[[Any], None], n_workers: int) -> None:
    """Call `fn(item)` for every item on n_workers threads, the caller's one of them: each pulls the
    next item when free (so the items finish even while the pool's workers are busy with another
    caller's work). After a failure no new item starts; the first exception is re-raised once every
    worker has stopped (they use the caller's arrays)."""
    lock = threading.Lock()
    errors: list[BaseException] = []

    def work() -> None:
        while True:
            with lock:
                item = None if errors else next(items, None)
            if item is None:
                return
            try:
                fn(item)
            except BaseException as exc:
                with lock:
                    errors.append(exc)
                return

    futures = _submit(work, n_workers - 1) if n_workers > 1 else []
    work()
    for fut in futures:
        fut.result()
    if errors:
        raise errors[0]


def _overload_key(kernel: Any, device: Any, inputs: list[Any]) -> tuple:
    types = tuple((type(a), getattr(a, "dtype", None), getattr(a, "ndim", None)) for a in inputs)
    return (id(kernel), device.alias, types)


def _resolve(kernel: Any, key: tuple, args: list[Any]) -> Any:
    """The kernel `wp.launch` would run for `args`: a generic kernel's overload for their types.

    wp.launch infers a generic kernel's overload from its arguments at every launch (~50 us of
    Python for a dozen arguments); launching the overload itself skips that. Resolved once per
    (kernel, device, argument types) with Warp's own inference; a later argument of another type
    under the same key would fail wp.launch's argument check, not run the wrong overload.
    """
    if not kernel.is_generic:
        return kernel
    entry = _resolved.get(key)
    if entry is None or entry[0] is not kernel:
        entry = (kernel, kernel.add_overload(kernel.infer_argument_types(args)))
        _resolved[key] = entry
    return entry[1]


def launch_split(
    kernel: Any,
    dim: int,
    inputs: Sequence[Any],
    *,
    device: wp.Device | str,
    threads: int | None = None,
    min_chunk: int = DEFAULT_MIN_CHUNK,
    synchronize: bool = False,
) -> None:
    """Launch `kernel` over indices [0, dim) as chunks on several CPU threads.

    The kernel receives `[*inputs, offset]` and must handle index
    `wp.tid() + offset`; see the module docstring for which kernels qualify.
    """
    try:
        dim = operator.index(dim)
    except TypeError:
        raise ValueError(f"launch_split: dim must be a non-negative int, got {dim!r}") from None
    if dim < 0:
        raise ValueError(f"launch_split: dim must be a non-negative int, got {dim!r}")
    args = getattr(getattr(kernel, "adj", None), "args", None)
    if not args or args[-1].label != "offset":
        raise ValueError("launch_split: the kernel's last parameter must be `offset: int`")
    n_threads = default_threads() if threads is None else threads
    if n_threads < 1:
        raise ValueError(f"launch_split: threads must be >= 1, got {threads}")
    if min_chunk < 1:
        raise ValueError(f"launch_split: min_chunk must be >= 1, got {min_chunk}")
    device = wp.get_device(device)
    inputs = list(inputs)
    key = _overload_key(kernel, device, inputs)
    kernel = _resolve(kernel, key, [*inputs, 0])

    if device.is_cuda or n_threads == 1 or dim < 2 * min_chunk:
        wp.launch(kernel, dim=dim, inputs=[*inputs, 0], device=device)
        if synchronize:
            wp.synchronize_device(device)
        return

    bounds = guided_bounds(dim, n_threads, min_chunk)
    n_workers = min(n_threads, len(bounds))
    chunks = iter(bounds)
    if key not in _loaded:
        # First use: one chunk alone compiles and loads the module (or overload), so that
        # the threads do not each compile it at once (correct, but n times the work).
        offset, size = next(chunks)
        wp.launch(kernel, dim=size, inputs=[*inputs, offset], device=device)
        _loaded.add(key)
    # Each worker pulls chunks until none are left, so a faster core takes more of them.
    _pull_all(chunks, lambda b: wp.launch(kernel, dim=b[1], inputs=[*inputs, b[0]], device=device), n_workers)
