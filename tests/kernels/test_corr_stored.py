"""kernels.corr.stored: on-the-fly lookups from features stored in float16 (forward-only) or float32."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import corr
from kernels._arrays import Inputs
from kernels.corr import _common, stored
from kernels.reference import corr as ref

# (C, H, W, levels, radius): C a multiple of 8 and not (padded channels), levels through patches
# and (on the CPU) through the full product (2 H_l W_l <= (2r + 2)^2).
CASES = [(16, 12, 16, 3, 2), (12, 9, 11, 2, 1), (24, 20, 22, 4, 1)]


def case(rng: np.random.Generator, c: int, h: int, w: int, levels: int, scale: float = 1.0, relu: bool = False):
    f1 = rng.standard_normal((c, h, w)) * scale
    f2 = rng.standard_normal((c, h, w)) * scale
    if relu:  # feature-network-like: non-negative, with a common offset (dot products far from 0)
        f1, f2 = np.maximum(f1 + 0.5 * scale, 0), np.maximum(f2 + 0.5 * scale, 0)
    f1, f2 = f1.astype(np.float32), f2.astype(np.float32)
    coords = np.stack([rng.uniform(-4, w + 4, (h, w)), rng.uniform(-4, h + 4, (h, w))]).astype(np.float32)
    return f1, corr.pool_features(f2, levels), coords


def rounded(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float16).astype(np.float32)


@pytest.mark.parametrize("shape", CASES, ids=lambda s: "x".join(map(str, s)))
def test_float16_is_float32_lookup_of_rounded_features(shape):
    # The float16 path widens exactly and then runs the float32 arithmetic: equal bit for bit.
    c, h, w, levels, radius = shape
    f1, f2_pyramid, coords = case(np.random.default_rng(3), c, h, w, levels)
    got = corr.lookup_onthefly(f1, f2_pyramid, coords, radius, feature_dtype="float16")
    want = corr.lookup_onthefly(rounded(f1), [rounded(p) for p in f2_pyramid], coords, radius)
    assert got.dtype == np.float32 and got.shape == want.shape
    np.testing.assert_array_equal(got, want)
    # and against the plain NumPy reference (float64) built from the rounded features
    # (1) at level l with the rounded pooled features: V^l[p, q] = f1~[:, p] . P^l(f2)~[:, q] / sqrt(C)
    volumes = [np.einsum("chw,cij->hwij", rounded(f1).astype(np.float64), rounded(p).astype(np.float64)) / np.sqrt(c)
               for p in f2_pyramid]
    np.testing.assert_allclose(got, ref.lookup(volumes, coords.astype(np.float64), radius), rtol=1e-5, atol=2e-5)


@pytest.mark.parametrize("shape", CASES, ids=lambda s: "x".join(map(str, s)))
def test_float32_store_is_bit_identical_to_lookup_onthefly(shape):
    c, h, w, levels, radius = shape
    f1, f2_pyramid, coords = case(np.random.default_rng(4), c, h, w, levels)
    features = corr.onthefly_features(f1, f2_pyramid, feature_dtype="float32")
    want = corr.lookup_onthefly(f1, f2_pyramid, coords, radius)
    np.testing.assert_array_equal(corr.lookup_onthefly_features(features, coords, radius), want)
    np.testing.assert_array_equal(corr.lookup_onthefly(f1, f2_pyramid, coords, radius, feature_dtype="float32"), want)


@pytest.mark.parametrize("kind", ["normal", "relu_features", "large"])
def test_float16_error_within_rounding_bound(kind):
    # Rounding each feature to float16 (relative error <= 2^-11) moves a tap by at most
    # (2^-10 + 2^-22) sum_c |f1_c f2_c| / sqrt(C); a sample is a convex combination of taps. The
    # bound below uses max_p |f1_p| max_q |f2_q| / sqrt(C) (Cauchy-Schwarz) and adds float32's
    # own rounding of both lookups (C products each, 2^-24 relative): a bound, not a tuned tolerance.
    c, h, w, levels, radius = 64, 16, 20, 3, 2
    scale = 300.0 if kind == "large" else 1.0
    f1, f2_pyramid, coords = case(np.random.default_rng(5), c, h, w, levels, scale, relu=kind == "relu_features")
    got = corr.lookup_onthefly(f1, f2_pyramid, coords, radius, feature_dtype="float16")
    want = corr.lookup_onthefly(f1, f2_pyramid, coords, radius)
    n1 = np.linalg.norm(f1.reshape(c, -1), axis=0).max()
    n2 = max(np.linalg.norm(p.reshape(c, -1), axis=0).max() for p in f2_pyramid)
    bound = (2.0 ** -10 + 2.0 ** -22 + 2 * c * 2.0 ** -24) * n1 * n2 / np.sqrt(c)
    err = np.abs(got - want).max()
    assert 0 < err <= bound
    assert err <= 2e-3 * np.abs(want).max()  # relative to the correlation's scale, as documented


def test_float16_to_float32_exact_for_every_finite_half():
    bits = np.arange(2 ** 16, dtype=np.uint32).astype(np.uint16)
    halves = bits.view(np.float16)
    finite = halves[np.isfinite(halves)]
    got = stored.float16_to_float32(finite)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got.view(np.uint32), finite.astype(np.float32).view(np.uint32))


def test_widen_cpu_exact_for_every_finite_half():
    # `widen` on the CPU (patch_cpu.widen_rows_cpu, C++ vector conversions) against NumPy, bit for bit.
    bits = np.arange(2 ** 16, dtype=np.uint32).astype(np.uint16)
    halves = bits.view(np.float16)
    finite = halves[np.isfinite(halves)]  # 63490 values: -0, subnormals, normals up to 65504
    rows = np.zeros(-(-finite.size // 64) * 64, dtype=np.float16)
    rows[:finite.size] = finite
    rows = rows.reshape(-1, 64)
    a = Inputs("cpu")
    a.scalar = wp.float32
    got = stored.widen(wp.array(rows, dtype=wp.float16, device="cpu"), a).numpy().reshape(rows.shape)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got.view(np.uint32), rows.astype(np.float32).view(np.uint32))


def test_widen_kernel_matches_host_conversion():
    # The device path (`_common._pack_rows_v` on float16 rows, used off the CPU) run on the CPU against the
    # host conversion.
    rng = np.random.default_rng(6)
    rows = (rng.standard_normal((7, 16)) * np.exp(rng.uniform(-12, 9, (7, 16)))).clip(-65504, 65504)
    x = wp.array(rows.astype(np.float16), dtype=wp.float16, device="cpu")
    a = Inputs("cpu")
    a.scalar = wp.float32
    out = a.empty((7, 2), corr.vec8f)
    wp.launch(_common._pack_rows_v, dim=out.size, inputs=[x, out, 0], device="cpu")
    want = stored.float16_to_float32(rows.astype(np.float16))
    np.testing.assert_array_equal(out.numpy().reshape(7, 16), want)


@pytest.mark.parametrize("c", [256, 12])
@pytest.mark.cpu_fast_path
def test_held_bytes_exact(c):
    h, w, levels, radius = 46, 62, 4, 4
    c8 = -(-c // 8) * 8
    pixels = h * w + sum(hl * wl for hl, wl in corr.level_shapes(h, w, levels))
    assert corr.stored_bytes(h, w, c, levels) == 2 * c8 * pixels
    assert corr.onthefly_held_bytes(h, w, c, levels, feature_dtype="float16") == 2 * c8 * pixels
    assert corr.stored_bytes(h, w, c, levels, "float32") == 4 * c8 * pixels
    n = h * w
    full3 = c % 8 == 0  # level 3 (5x7) by the full product, else through patches
    patched = 3 if full3 else 4
    shapes = corr.level_shapes(h, w, patched)
    grouping = [4 * n + (wl + 11) * (hl + 11) + 1 + wl + 12 for hl, wl in shapes]
    if full3:  # the float32 call at several threads (C a multiple of 8): every level at once, as below,
        # with every patched level's channels-last copy
        work32 = 4 * (c8 * n + c8 * sum(hl * wl for hl, wl in shapes) + 2 * 100 * n + (n + c) * 35) + 4 * sum(grouping)
    else:  # one level at a time: f1 and level 0 channels-last, the patch buffer, level 0's grouping
        work32 = 4 * (2 * c8 * n + 100 * n) + 4 * grouping[0]
    assert corr.onthefly_bytes(h, w, c, levels, radius) - corr.onthefly_held_bytes(h, w, c, levels) == work32
    # float16 (stored features): with several threads every level at once (`onthefly._forward_phased`):
    # two patch buffers (the patched levels take turns), level 3's rows of V^l beside them, every patched
    # level's grouping
    work16 = 4 * (2 * c8 * n + 2 * 100 * n + (n + c) * 35 * full3) + 4 * sum(grouping)
    assert corr.onthefly_bytes(h, w, c, levels, radius, feature_dtype="float16") == 2 * c8 * pixels + work16
    rng = np.random.default_rng(7)
    f1 = rng.standard_normal((c, h, w)).astype(np.float32)
    pyramid = corr.pool_features(rng.standard_normal((c, h, w)).astype(np.float32), levels)
    features = corr.onthefly_features(f1, pyramid)
    assert features.feature_dtype == "float16" and features.nbytes == 2 * c8 * pixels
    if c == 256:  # RAFT's size: the volume pyramid against the float16 store
        assert corr.dense_bytes(h, w, levels) / features.nbytes > 12.6


@pytest.mark.parametrize("storage", ["float32", "float64", "float16", "float16_wide"])
@pytest.mark.parametrize("radius", [0, 1, 3, 4])  # patch rows of 2, 4, 8 and 10 taps
@pytest.mark.parametrize("spread", ["mixed", "crowded"])
def test_patch_cpu_kernel_is_the_warp_kernel_bit_for_bit(storage, radius, spread):
    """The CPU's patches (patch_cpu: pixels grouped by window column, C++, reading the stored dtype)
    and their windows (window_cpu.sample_patches_cpu, 4 pixels a thread; 598 pixels, so a last block of
    2) equal `onthefly._patch_sample_level` (the Warp kernel, on the widened vectors) bit for bit, patches
    and samples: windows inside level 0 and overhanging or outside the coarser levels, a NaN position,
    padded channels (C = 12), windows far outside. "crowded": every window near one point, so the groups
    hold up to hundreds of pixels and a tap row is shared by 8 pixels at a time (the 16-lane pairs), then the
    4-, 2- and 1-pixel remainders. "float16_wide": features from float16 subnormals to ~2^13, so the
    fused multiply-adds of the float16 kernel meet tiny and large products (exact in float32 all the
    same)."""
    from kernels._arrays import value_checks
    from kernels.corr import onthefly, patch_cpu, window_cpu
    from kernels.corr._common import level_shapes

    rng = np.random.default_rng(60 + radius)
    c, h, w, n_levels = 12, 23, 26, 3
    dtype = np.float64 if storage == "float64" else np.float32
    f1, f2_pyramid, coords = case(rng, c, h, w, n_levels)
    if storage == "float16_wide":
        storage = "float16"
        f1 = f1 * np.exp2(rng.integers(-26, 13, f1.shape)).astype(np.float32)
        f2_pyramid = [x * np.exp2(rng.integers(-26, 13, x.shape)).astype(np.float32) for x in f2_pyramid]
        assert np.abs(f1).max() < 65504 and (np.abs(f1.astype(np.float16)) < 2.0 ** -14).any()
    if spread == "crowded":
        coords = np.stack([rng.uniform(9, 11.5, (h, w)), rng.uniform(8, 14, (h, w))])
    else:
        near = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)) + rng.uniform(-2, 2, (2, h, w))
        coords[:, : h // 2] = near[:, : h // 2]
        # windows far outside every level (the grouping clamps their origins): left, right, above, below
        coords[:, 20, 1:5] = [[-1e4, w + 1e4, 3.0, 5.0], [2.0, 4.0, -1e5, h + 1e5]]
    coords[0, 3, 4] = np.nan
    f1, coords = f1.astype(dtype), coords.astype(dtype)
    f2_pyramid = [x.astype(dtype) for x in f2_pyramid]
    features = corr.onthefly_features(f1, f2_pyramid, feature_dtype="float16" if storage == "float16" else "float32")
    a = Inputs("cpu")
    a.scalar = wp.float64 if storage == "float64" else wp.float32
    xy = wp.array(coords, device="cpu")
    n, side = h * w, 2 * radius + 1
    inv = a.s(1.0 / np.sqrt(c))
    kernel = patch_cpu.patch_groups_cpu(radius, a.scalar, features.f1.dtype)
    assert features.f1.dtype == {"float32": wp.float32, "float64": wp.float64, "float16": wp.float16}[storage]
    f1_v = stored.widen(features.f1, a)
    f1_rows = wp.array(ptr=f1_v.ptr, shape=(n, f1_v.shape[1] * 8), dtype=a.scalar, device="cpu")
    for lvl, (hl, wl) in enumerate(level_shapes(h, w, n_levels)):
        results = []
        for cpp in (True, False):
            patch = wp.full((n, side + 1, side + 1), 7.0, dtype=a.scalar, device="cpu")
            out = wp.full((side * side, h, w), 7.0, dtype=a.scalar, device="cpu")
            with value_checks(False):
                if cpp:
                    n_groups, order, sorted_j0, starts = onthefly._group_pixels(a, xy, a.s(0.5 ** lvl), radius, hl, wl)
                    assert sorted(order.numpy()) == list(range(n))  # every pixel once
                    sizes = np.diff(starts.numpy())
                    assert sizes.max() > (100 if spread == "crowded" else 8)
                    wp.launch(kernel, n_groups, [f1_rows, features.levels[lvl], order, sorted_j0, starts, hl, wl,
                                                 inv, patch, 0], device="cpu")
                    wp.launch(window_cpu.sample_patches_cpu(radius, a.scalar), window_cpu.blocks(n),
                              [patch, xy, out, a.s(0.5 ** lvl), 0, 0], device="cpu")
                else:
                    wp.launch(onthefly._patch_sample_level, n, [f1_v, stored.widen(features.levels[lvl], a), xy,
                                                                patch, out, hl, wl, a.s(0.5 ** lvl), radius, inv, 0,
                                                                0], device="cpu")
            results.append((patch.numpy(), out.numpy()))
        (patch_cpp, out_cpp), (patch_warp, out_warp) = results
        nan = np.isnan(out_warp)
        assert nan.any() and np.array_equal(np.isnan(out_cpp), nan)
        assert out_cpp[~nan].tobytes() == out_warp[~nan].tobytes()
        valid = np.ones(n, dtype=bool)
        valid[3 * w + 4] = False  # the NaN position's window origin is undefined
        assert patch_cpp[valid].tobytes() == patch_warp[valid].tobytes()
        assert (patch_cpp[valid] != 0).any()
        if spread == "mixed":  # (crowded windows lie inside level 0 at small radii)
            assert (patch_cpp[valid] == 0).any()


@pytest.mark.parametrize("feature_dtype", ["float32", "float16"])
def test_lookup_without_patch_cpu_is_bit_identical(monkeypatch, feature_dtype):
    """The forward's other branch (features widened per call, the Warp patch kernel: the path off the
    CPU, here on the CPU) gives the C++ path's lookup bit for bit, stored and direct."""
    from kernels.corr import onthefly

    f1, f2_pyramid, coords = case(np.random.default_rng(8), 16, 12, 16, 3)
    features = corr.onthefly_features(f1, f2_pyramid, feature_dtype=feature_dtype)
    want = [corr.lookup_onthefly_features(features, coords, 2),
            corr.lookup_onthefly(f1, f2_pyramid, coords, 2, feature_dtype=feature_dtype)]
    monkeypatch.setattr(onthefly, "_cpu_patches", lambda a, f1_rows: False)
    got = [corr.lookup_onthefly_features(features, coords, 2),
           corr.lookup_onthefly(f1, f2_pyramid, coords, 2, feature_dtype=feature_dtype)]
    for g, w in zip(got, want):
        assert g.tobytes() == w.tobytes()


@pytest.mark.parametrize("feature_dtype", ["float16", "float32"])
@pytest.mark.parametrize("shape", [*CASES, (16, 24, 24, 3, 4)], ids=lambda s: "x".join(map(str, s)))
@pytest.mark.cpu_fast_path
def test_phased_lookup_is_the_level_by_level_lookup_bit_for_bit(monkeypatch, feature_dtype, shape):
    """With several threads, stored features and the float32 lookup (C a multiple of 8) go through
    `_forward_phased` (all levels at once, groups cut by pixel counts, BLAS row chunks and channels-last
    copies as items): the one-thread, level-by-level lookup's bytes. The last
    case has three BLAS row chunks at its 6x6 level (576 pixels, radius 4); C = 12 takes no full product."""
    from kernels.corr import onthefly

    c, h, w, levels, radius = shape
    f1, f2_pyramid, coords = case(np.random.default_rng(9), c, h, w, levels)
    features = corr.onthefly_features(f1, f2_pyramid, feature_dtype=feature_dtype)
    monkeypatch.setenv("DRLAB_THREADS", "1")
    want = corr.lookup_onthefly_features(features, coords, radius)
    want_direct = corr.lookup_onthefly(f1, f2_pyramid, coords, radius)  # float32 features given as arrays
    calls = []
    phased = onthefly._forward_phased
    monkeypatch.setattr(onthefly, "_forward_phased", lambda *args: calls.append(1) or phased(*args))
    for threads in ("2", "3"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        for _ in range(2):  # a key's first call at several threads loads the kernels level by level
            assert corr.lookup_onthefly_features(features, coords, radius).tobytes() == want.tobytes()
            if feature_dtype == "float32":  # the channels-last copies made by the items (C % 8 == 0)
                assert corr.lookup_onthefly(f1, f2_pyramid, coords, radius).tobytes() == want_direct.tobytes()
    assert len(calls) >= (2 if feature_dtype == "float16" or c % 8 else 4)


def test_weighted_pieces_cover_the_groups_by_pixel_counts():
    """Group ranges for the phased patches: contiguous, covering every group holding pixels, balanced by pixels."""
    from kernels.corr import onthefly

    starts = np.array([0, 0, 5, 5, 30, 31, 60, 100, 100], dtype=np.int32)  # 8 groups, 100 pixels
    for k in (1, 2, 3, 4, 8, 20):
        pieces = onthefly._weighted_pieces(starts, k)
        assert 1 <= len(pieces) <= k
        assert all(g0 < g1 for g0, g1 in pieces) and all(a[1] <= b[0] for a, b in zip(pieces, pieces[1:]))
        covered = {g for g0, g1 in pieces for g in range(g0, g1)}
        assert {g for g in range(8) if starts[g + 1] > starts[g]} <= covered
    # each cut at the first group starting at or past j / k of the pixels: 60 | 40, 31 | 29 | 40
    assert onthefly._weighted_pieces(starts, 2) == [(0, 6), (6, 8)]
    assert onthefly._weighted_pieces(starts, 4) == [(0, 4), (4, 6), (6, 7)]


@pytest.mark.parametrize("threads", ["1", "2", "3"])
def test_ordered_items_wait_for_their_predecessors_and_raise(monkeypatch, threads):
    """`_run_ordered`: an item starts only after the items it comes after have finished, on any number
    of threads; a failing item's exception reaches the caller and releases an item waiting for it."""
    import threading
    import time

    from kernels.corr import onthefly

    monkeypatch.setenv("DRLAB_THREADS", threads)
    log: list[tuple[str, int]] = []
    lock = threading.Lock()

    def item(i: int, sleep: float = 0.0):
        def run() -> None:
            with lock:
                log.append(("start", i))
            time.sleep(sleep)
            with lock:
                log.append(("end", i))
        return run

    after = [(), (), (0, 1), (), (2,), (3, 4)]
    onthefly._run_ordered([item(0, 0.02), item(1, 0.01), item(2), item(3, 0.02), item(4), item(5)], after)
    for i, deps in enumerate(after):
        assert all(log.index(("end", j)) < log.index(("start", i)) for j in deps)
    assert sorted(log) == sorted([(e, i) for i in range(6) for e in ("start", "end")])

    def fail() -> None:
        time.sleep(0.01)
        raise RuntimeError("item failed")

    ran = []
    with pytest.raises(RuntimeError, match="item failed"):
        onthefly._run_ordered([fail, lambda: ran.append(1), lambda: ran.append(2)], [(), (0,), (1,)])
    assert ran == []  # the items after the failure never ran


@pytest.mark.cpu_fast_path
def test_phased_float64_lookup_is_the_one_thread_lookup_bit_for_bit(monkeypatch):
    """float64 features (working dtype float64, C = 16): the phased path at 2 threads gives the one-thread bytes."""
    from kernels.corr import onthefly

    rng = np.random.default_rng(12)
    c, h, w, levels, radius = 16, 24, 24, 3, 4
    f1, f2 = rng.standard_normal((2, c, h, w))
    coords = np.stack([rng.uniform(-4, w + 4, (h, w)), rng.uniform(-4, h + 4, (h, w))])
    pyramid = corr.pool_features(f2, levels)
    monkeypatch.setenv("DRLAB_THREADS", "1")
    want = corr.lookup_onthefly(f1, pyramid, coords, radius)
    calls = []
    phased = onthefly._forward_phased
    monkeypatch.setattr(onthefly, "_forward_phased", lambda *args: calls.append(1) or phased(*args))
    monkeypatch.setenv("DRLAB_THREADS", "2")
    for _ in range(2):
        got = corr.lookup_onthefly(f1, pyramid, coords, radius)
        assert got.dtype == np.float64 and got.tobytes() == want.tobytes()
    assert calls


@pytest.mark.cpu_fast_path
def test_phased_lookup_raises_when_the_early_widening_fails(monkeypatch):
    """`_forward_phased` hands f1's widening to a launch thread first (`submit`); a failure there reaches the
    caller, and no patch item runs."""
    from kernels import launch
    from kernels.corr import onthefly_phased

    f1, f2_pyramid, coords = case(np.random.default_rng(5), 16, 24, 24, 3)
    features = corr.onthefly_features(f1, f2_pyramid, feature_dtype="float16")
    monkeypatch.setenv("DRLAB_THREADS", "2")
    want = corr.lookup_onthefly_features(features, coords, 4)  # loads the kernels (the key's first call)
    corr.lookup_onthefly_features(features, coords, 4)

    def fail() -> None:
        raise RuntimeError("early widening failed")

    launched = []
    real_launch, real_replay = onthefly_phased.wp.launch, onthefly_phased._replay
    monkeypatch.setattr(onthefly_phased, "submit", lambda fn: launch.submit(fail))
    monkeypatch.setattr(onthefly_phased.wp, "launch",
                        lambda k, *a, **kw: launched.append(k) or real_launch(k, *a, **kw))
    monkeypatch.setattr(onthefly_phased, "_replay", lambda r, s, k, *a: launched.append(k) or real_replay(r, s, k, *a))
    with pytest.raises(RuntimeError, match="early widening failed"):
        corr.lookup_onthefly_features(features, coords, 4)
    assert any("group_pixels" in k.key for k in launched)  # the spies see the call's launches
    assert not any("patch_groups" in k.key for k in launched)
    monkeypatch.undo()
    monkeypatch.setenv("DRLAB_THREADS", "2")
    assert corr.lookup_onthefly_features(features, coords, 4).tobytes() == want.tobytes()


def test_replayed_launch_equals_wp_launch_with_new_arguments_each_call():
    """`_replay` (the phased path's launches): a launch recorded once per slot, then every argument set again
    and replayed: the same writes as `wp.launch` with each call's own arrays, dims and offsets; it keeps no
    array between calls."""
    import warp as wp

    from kernels.corr import onthefly, patch_cpu

    rng = np.random.default_rng(3)
    kernel = patch_cpu.widen_rows_cpu()
    replays: dict = {}
    for rows, lo, hi in ((7, 0, 7), (9, 2, 6), (5, 1, 5)):
        x = rng.standard_normal((rows, 16)).astype(np.float16)
        src = wp.array(x, dtype=wp.float16, device="cpu")
        got = wp.zeros((rows, 16), dtype=wp.float32, device="cpu")
        onthefly._replay(replays, "slot", kernel, hi - lo, [src, got, lo], wp.get_device("cpu"))
        want = np.zeros((rows, 16), np.float32)
        want[lo:hi] = x[lo:hi].astype(np.float32)
        assert got.numpy().tobytes() == want.tobytes()
        assert len(replays) == 1 and replays["slot"].fwd_args is None
