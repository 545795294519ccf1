"""The on-the-fly lookup on several CPU threads: every level at once, as one ordered list of items.

The maths is `onthefly`'s (equation (4) from patches T[p, ty, tx] = f1[:, p] . P^l(f2)[:, (j0 + ty,
i0 + tx)] / sqrt(C), or from the full product V^l = f1^T P^l(f2) / sqrt(C) on the coarse levels,
then each window sampled bilinearly); this module only schedules it. `_forward_phased` runs the
same kernels on the same values as `onthefly._forward` level by level (bit for bit), as items that
`_run_ordered` hands to the launch threads in list order, each waiting only for the items it reads:
f1's widening first (on a launch thread from the start, `submit`), each level's channels-last copy
by row ranges, each patched level's patches by ranges of equal pixel counts (`_weighted_pieces`),
the full-product levels' rows by BLAS, and each level's windows. Launches go through `_replay`
(one recorded launch per slot, its arguments set again before each replay: about half of
`wp.launch`'s Python), and a thread keeps its grouping arrays and launches between lookups of one
size (`_thread_kept`).
"""

from __future__ import annotations

import math
import threading
from typing import Any, Callable, Sequence

import numpy as np
import warp as wp

from kernels._arrays import Inputs
from kernels.corr import patch_cpu, window_cpu
from kernels.corr._common import VEC, VEC_OF, full_product_level, level_shapes
from kernels.corr.onthefly_layout import _BLAS_ROWS, _grouping_arrays, _one_blas_thread, _rows
from kernels.corr.stored import widen
from kernels.launch import chunk_bounds, default_threads, parallel_items, submit

# (radius, working dtype, storage dtype, kinds of levels) whose kernels a call has loaded (level by level,
# on one launch thread at a time), so that `_forward_phased`'s threads never load a module at once
_phased_ready: set[tuple] = set()


def _pieces(lo: int, hi: int, k: int) -> list[tuple[int, int]]:
    """[lo, hi) cut into at most k contiguous non-empty ranges of near-equal size."""
    return [(lo + o, lo + o + s) for o, s in chunk_bounds(hi - lo, max(1, min(k, hi - lo)))]


def _weighted_pieces(starts: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Groups [0, G) cut into at most k contiguous ranges holding near-equal numbers of pixels
    (starts (G + 1,): each group's first pixel position, the pixel count at the end)."""
    n_groups, total = len(starts) - 1, int(starts[-1])
    cuts = np.searchsorted(starts, [total * j / k for j in range(1, k)], side="left")
    bounds = sorted({0, n_groups, *(int(min(max(c, 0), n_groups)) for c in cuts)})
    return [(g0, g1) for g0, g1 in zip(bounds[:-1], bounds[1:]) if starts[g1] > starts[g0]]


_kept = threading.local()  # per thread: {name: {key: value}}, what a thread keeps between lookups of one size


def _thread_kept(name: str, key: tuple, limit: int, make: Callable[[], Any]) -> Any:
    """The calling thread's kept value `name` for `key`, made on first use; a few keys at a time (all are
    dropped when `limit` are held and a new one comes)."""
    kept = getattr(_kept, name, None)
    if kept is None:
        kept = {}
        setattr(_kept, name, kept)
    if key not in kept:
        if len(kept) >= limit:
            kept.clear()
        kept[key] = make()
    return kept[key]


def _kept_grouping_arrays(a: Inputs, lvl: int, n: int, radius: int, height_l: int,
                          width_l: int) -> tuple[int, list[wp.array], wp.array, wp.array]:
    """`_grouping_arrays`, kept between the calling thread's lookups of the same size (a call fills them
    entirely before reading them): 18 small allocations a call were ~0.2 ms of its Python."""
    key = (a.device.alias, lvl, n, radius, height_l, width_l)  # a level's own: the levels group at once
    return _thread_kept("arrays", key, 16, lambda: _grouping_arrays(a, n, radius, height_l, width_l))


def _kept_launches(key: tuple) -> dict[Any, Any]:
    """The calling thread's recorded launches (`_replay`) for the phased lookups of one size (`key`)."""
    return _thread_kept("launches", key, 8, dict)


def _replay(replays: dict[Any, Any], slot: Any, kernel: Any, dim: int, inputs: list[Any], device: wp.Device) -> None:
    """`wp.launch(kernel, dim, inputs)` through a launch recorded once per slot (`replays`, one call's items
    each own a slot): its arguments set from their ctypes values and replayed, ~half of `wp.launch`'s Python
    (which packs and checks every argument). The recorded launch keeps no array between calls (fwd_args
    dropped); every argument is set again before each replay. Concrete (non-generic) CPU kernels only."""
    cmd = replays.get(slot)
    if cmd is None or cmd.kernel is not kernel or len(cmd.params) != len(inputs) + 1:
        cmd = wp.launch(kernel, dim=dim, inputs=inputs, device=device, record_cmd=True)
        cmd.fwd_args = None
        replays[slot] = cmd
    else:
        cmd.set_dim(dim)
        for i, v in enumerate(inputs):
            if isinstance(v, wp.array):
                cmd.set_param_at_index_from_ctype(i, v.__ctype__())
            else:
                cmd.set_param_at_index_from_ctype(i, v if isinstance(v, int) else float(v))
    cmd.launch()


def _run_ordered(items: list[Callable[[], None]], after: list[tuple[int, ...]]) -> None:
    """Run the items on the launch threads: each thread pulls the next item in list order and, before
    running it, waits for the items it comes `after` (all earlier in the list). One hand-off to the pool
    a call, and no thread waits at a barrier for a whole stage, only for what its item reads.

    No deadlock: an item's predecessors were pulled before it, so each is done or running on another
    thread (a thread alone runs them all in order). After a failure no item starts, the waiting threads
    are released, and the first exception is re-raised here once every thread has stopped.
    """
    done = [threading.Event() for _ in items]
    order = iter(range(len(items)))
    lock = threading.Lock()
    errors: list[BaseException] = []

    def work(_: int) -> None:
        while True:
            with lock:
                i = None if errors else next(order, None)
            if i is None:
                return
            for j in after[i]:
                done[j].wait()
            if errors:
                return
            try:
                items[i]()
            except BaseException as exc:
                with lock:
                    errors.append(exc)
                for event in done:  # release every waiting thread
                    event.set()
                return
            done[i].set()

    parallel_items(work, min(default_threads(), len(items)))
    if errors:
        raise errors[0]


def _forward_phased(a: Inputs, f1_rows: wp.array, channels: int, xy: wp.array, radius: int, n_levels: int,
                    level_rows: Callable[[int], wp.array], level_scaled: Callable[[int], np.ndarray],
                    out: wp.array, fills: dict[Any, Callable[[int, int], None]]) -> None:
    """`_forward`'s CPU path on several threads: every level at once, two hand-offs to the launch threads.

    The same kernels on the same values as `_forward` (bit for bit), as items run in this order by
    `_run_ordered` (each waiting only for the items it reads):
      0. f1 widened or copied channels-last (`fills`), whole, on a launch thread from the start
         (`submit`), while this thread builds the list;
      1. each patched level's pixels grouped and its groups cut into ranges of equal pixel counts, here
         while the list is built (no item); each patched level's channels-last copy (`fills`), by row
         ranges; each full-product level's P^l(f2) / sqrt(C); then an item that waits for 0;
      2. each patched level's patches, by those ranges (after f1), and each full-product level's rows
         of V^l by BLAS (the same 256-row products; after f1 and its scaled level);
      3. each level's windows sampled, ranges of pixel blocks (after that level's patches or rows),
         interleaved with 2 (order below).
    The patched levels take turns in two patch buffers (`onthefly_bytes` counts both), each
    full-product level has its rows of its own; items running at once write disjoint memory. Against
    level by level (at two threads ~10 parallel sections, ~70 guided-chunk launches, three groupings on
    one thread): ~25 launches and two hand-offs a call (0, then the list).
    """
    n = f1_rows.shape[0]
    threads = default_threads()
    side = 2 * radius + 1
    inv = a.s(1.0 / math.sqrt(channels))
    vec = VEC_OF[a.scalar]
    shapes = level_shapes(xy.shape[1], xy.shape[2], n_levels)
    full = [full_product_level(hl, wl, radius, a.device) and channels % VEC == 0 for hl, wl in shapes]
    device = a.device
    items: list[Callable[[], None]] = []
    after: list[tuple[int, ...]] = []

    def add(fn: Callable[[], None], deps: Sequence[int] = ()) -> int:
        items.append(fn)
        after.append(tuple(deps))
        return len(items) - 1

    replays = _kept_launches((device.alias, n, tuple(shapes), radius, a.scalar, f1_rows.dtype, threads, channels))

    def launch_range(kernel: Any, lo: int, hi: int, inputs: list[Any], slot: Any) -> Callable[[], None]:
        return lambda: _replay(replays, slot, kernel, hi - lo, [*inputs, lo], device)

    # 0. f1 widened (exact; float32 storage: a view) or copied channels-last, handed whole to a launch
    # thread first: it runs (one native launch or NumPy copy, without the GIL) while this thread builds the
    # list and groups the pixels; the item `widened`, before the first patches, waits for it
    def fill_items(key: Any, rows: int) -> list[int]:
        return [add(lambda lo=lo, hi=hi: fills[key](lo, hi)) for lo, hi in _pieces(0, rows, threads)]

    early_fn = None
    if f1_rows.dtype == a.scalar:
        f1_v = widen(f1_rows, a)
        if "f1" in fills:
            early_fn = lambda: fills["f1"](0, n)  # noqa: E731
    else:  # float16 rows, float32 work (`_cpu_patches`): `widen`'s C++ conversion
        f1_v = a.empty((n, f1_rows.shape[1] // VEC), vec)
        f1_w = wp.array(ptr=f1_v.ptr, shape=f1_rows.shape, dtype=a.scalar, device=device)  # f1_v outlives it
        early_fn = lambda: wp.launch(patch_cpu.widen_rows_cpu(), dim=n, inputs=[f1_rows, f1_w, 0],  # noqa: E731
                                     device=device)
    early = None
    if early_fn is not None:
        # This thread waits (GIL released) until the launch thread has started 0: else this thread's Python
        # keeps the GIL and the woken launch thread could not start 0 before the list is built. Bounded, in
        # case every launch thread is busy.
        started = threading.Event()
        early = submit(lambda: started.set() or early_fn())
        started.wait(0.002)
    # 1. level copies, scaled levels (items); groupings (here)
    level_arrays: dict[int, wp.array] = {}
    copied: dict[int, list[int]] = {}  # level -> its copy's items
    for lvl in range(n_levels):
        if not full[lvl]:
            level_arrays[lvl] = level_rows(lvl)
            copied[lvl] = fill_items(lvl, level_arrays[lvl].shape[0]) if lvl in fills else []
    scaled: dict[int, np.ndarray] = {}
    grouping: dict[int, tuple] = {}
    pieces = 2 * threads
    cuts: dict[int, list[tuple[int, int]]] = {}  # patched level -> its groups' ranges for the patch items
    ready: dict[int, list[int]] = {}  # level -> the items its products or patches wait for (besides f1)
    for lvl, (hl, wl) in enumerate(shapes):
        if full[lvl]:
            ready[lvl] = [add(lambda lvl=lvl: scaled.__setitem__(lvl, level_scaled(lvl)))]
        else:
            grouping[lvl] = _kept_grouping_arrays(a, lvl, n, radius, hl, wl)
            n_groups, ints, starts, counts = grouping[lvl]
            inputs = [xy, a.s(0.5 ** lvl), *ints, starts, counts, hl, wl]
            # grouped here, on this thread (native launches, which release the GIL: meanwhile the launch
            # thread takes it to start 0), and cut into `pieces` ranges of equal pixel counts for the patches
            wp.launch(patch_cpu.group_pixels_cpu(radius, a.scalar), dim=1, inputs=[*inputs, 0], device=device)
            cuts[lvl] = _weighted_pieces(starts.numpy(), pieces)
            ready[lvl] = copied[lvl]
    widened = [add(early.result)] if early is not None else []  # f1 ready (re-raises a failure of it)

    # 2-3. patches and full products, then windows, in the order
    #   P0 (B) P1 S0 P2 S1 P3 S2 ... S(full) S(last): Pk = patched level k's patches (into buffer k % 2,
    #   after f1, its grouping and, from k = 2, S(k - 2), the windows that read that buffer), B = the
    #   full-product levels' rows by BLAS, Sk = level k's windows (after Pk); so a thread that pulls Sk
    #   finds Pk done (P(k+1) was pulled in between), and the full-product windows fill the last wait.
    patch_kernel = patch_cpu.patch_groups_cpu(radius, a.scalar, f1_rows.dtype)
    f1_r = _rows(f1_v)
    x1_rows = f1_v.numpy().reshape(n, -1)[:, :channels]  # f1 channels-last: the vectors' own memory
    patched = [lvl for lvl in range(n_levels) if not full[lvl]]
    patch_buffers = [a.empty((n, side + 1, side + 1)) for _ in patched[:2]]  # every tap is written
    formed: dict[int, list[int]] = {}
    sampled: dict[int, list[Any]] = {}  # a level's window kernel and first inputs, then its items
    n_blocks = window_cpu.blocks(n)

    def add_products() -> None:
        for lvl in (lvl for lvl in range(n_levels) if full[lvl]):
            hl, wl = shapes[lvl]
            buf = a.empty((n, hl, wl))
            rows = buf.numpy().reshape(n, hl * wl)
            chunks = range(0, n, _BLAS_ROWS)

            def products(c0: int, c1: int, rows: np.ndarray = rows, lvl: int = lvl, chunks: range = chunks) -> None:
                for r0 in chunks[c0:c1]:  # the same 256-row products as `_sample_full_product`
                    r1 = min(r0 + _BLAS_ROWS, n)
                    np.matmul(x1_rows[r0:r1], scaled[lvl], out=rows[r0:r1])

            formed[lvl] = [add(lambda c0=c0, c1=c1, f=products: f(c0, c1), [*widened, *ready[lvl]])
                           for c0, c1 in _pieces(0, len(chunks), pieces)]
            # the dense lookup's kernel on this one level
            sampled[lvl] = [window_cpu.sample_levels_cpu(radius, a.scalar), [buf, buf, buf, buf, 1]]

    def add_windows(lvl: int) -> None:
        kernel, head = sampled[lvl]
        inputs = [*head, xy, out, a.s(0.5 ** lvl), lvl * side * side]
        sampled[lvl] = [add(launch_range(kernel, lo, hi, inputs, ("windows", lvl, lo)), formed[lvl])
                        for lo, hi in _pieces(0, n_blocks, threads)]

    if not patched:
        add_products()
    for k, lvl in enumerate(patched):
        hl, wl = shapes[lvl]
        n_groups, ints, starts, _ = grouping[lvl]
        buf = patch_buffers[k % 2]
        inputs = [f1_r, level_arrays[lvl], ints[2], ints[3], starts, hl, wl, inv, buf]

        def patches(j: int, inputs: list[Any] = inputs, lvl: int = lvl) -> None:
            # piece j of the groups cut by pixel counts (`cuts`, made with the grouping)
            cut = cuts[lvl]
            if j < len(cut):
                _replay(replays, ("patches", lvl, j), patch_kernel, cut[j][1] - cut[j][0], [*inputs, cut[j][0]],
                        device)

        deps = [*widened, *ready[lvl], *(sampled[patched[k - 2]] if k >= 2 else [])]
        formed[lvl] = [add(lambda j=j, f=patches: f(j), deps) for j in range(pieces)]
        sampled[lvl] = [window_cpu.sample_patches_cpu(radius, a.scalar), [buf]]
        if k == 0:
            add_products()
        else:
            add_windows(patched[k - 1])
    for lvl in range(n_levels):
        if full[lvl]:
            add_windows(lvl)
    if patched:
        add_windows(patched[-1])
    with _one_blas_thread():
        _run_ordered(items, after)
