"""Stored features of the on-the-fly lookup, kept in float32 or float16 between lookups.

Storage (`onthefly_features`). f1 and every pooled level P^l(f2) (`pool_features`) are kept
channels-last, an (N_l, C8) array per map with N_l = H_l W_l pixels and C8 = C rounded up to a
multiple of 8 (the extra channels zero), in the storage dtype `feature_dtype`:

  * "float32": the values as given (in the inputs' dtype, float32 or float64);
  * "float16": each value rounded to the nearest float16, x~ = x (1 + e) with |e| <= 2^-11
    (values must satisfy |x| <= 65504, float16's largest finite value; checked).

Between lookups the path keeps these arrays alone: s C8 (H W + sum_l H_l W_l) bytes with s = 4
or 2 (`stored_bytes`), in place of the volume pyramid's 4 H W sum_l H_l W_l.

Dequantisation. Every float16 is a float32, so widening is exact. On the CPU the patch kernel
(`patch_cpu`) reads the levels' float16 rows themselves and widens each 8-channel vector in
registers (F16C conversions); f1 is widened once per call (`widen`: on the CPU a C++ kernel of
8-lane conversions, `patch_cpu.widen_rows_cpu`, half the time of the host conversion by integer
operations on the bits, `float16_to_float32`, which float64 work still uses), for the patch
kernel and the full-product levels' BLAS.
Off the CPU, `widen` copies f1 and one level at a time into the channels-last vectors the
float32 path builds in each call.
Everything after the widening, the patch dot products, the BLAS products and their sums, is the
float32 path's arithmetic: the float16 lookup
equals, bit for bit, the float32 lookup of the float16-rounded features. Its difference from the
float32 lookup is the rounding of the features alone; for a tap,

    |T - T~| = |sum_c (f1_c f2_c - f1~_c f2~_c)| / sqrt(C) <= (2^-10 + 2^-22) sum_c |f1_c f2_c| / sqrt(C),

and the window sampling (3) is a convex combination of taps, so a sample's error is at most its
taps' largest.

Reading float16 in the patch kernel: in Warp it was slower than widening per call (a
micro-benchmark of the five-tap dot product, 2852 pixels x 100 taps, one thread, interleaved: 41.5
ns a 256-channel tap read as float16 and converted in the kernel against 17.4 ns as float32; Warp
converts a vector of 8 halves lane by lane; bfloat16 58.2 ns). In C++ with vector conversions
(`patch_cpu`) a float16 patch costs about what a float32 one does (level 0 at the bench's sizes, one thread: 6.16
against 5.90 ms), and the
per-call widened copies of f1 and the patched levels are gone.

Byte counts (`onthefly_held_bytes`, `onthefly_bytes`, `stored_bytes`): what the on-the-fly
path holds between lookups and at the peak of a forward call, for either storage.

The float16 storage is forward-only: the lookup's backward needs gradients with respect to the
float32 features, and the entry points refuse `feature_dtype="float16"` there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs
from kernels.corr import patch_cpu
from kernels.corr._common import VEC, VEC_OF, full_product_level, level_shapes, pack_rows

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

FEATURE_DTYPES = {"float32": (wp.float32, np.float32, 4), "float16": (wp.float16, np.float16, 2)}
FLOAT16_MAX = 65504.0


def check_feature_dtype(feature_dtype: Any) -> str:
    """`feature_dtype` as one of FEATURE_DTYPES' names."""
    if not isinstance(feature_dtype, str) or feature_dtype not in FEATURE_DTYPES:
        raise ValueError(f"feature_dtype: expected one of {', '.join(map(repr, FEATURE_DTYPES))}, "
                         f"got {feature_dtype!r}")
    return feature_dtype


def refuse_backward(feature_dtype: Any) -> None:
    """The on-the-fly backward exists for float32 storage only."""
    if check_feature_dtype(feature_dtype) != "float32":
        raise ValueError(f"feature_dtype: the on-the-fly lookup with {feature_dtype} features is forward-only "
                         "(no gradients through the rounded features); use feature_dtype='float32' for the backward")


def stored_bytes(height: int, width: int, channels: int, levels: int, feature_dtype: str = "float16") -> int:
    """Bytes of `OnTheFlyFeatures` of float32 features: s C8 (H W + sum_l H_l W_l), s = 4 or 2."""
    itemsize = FEATURE_DTYPES[check_feature_dtype(feature_dtype)][2]
    pixels = height * width + sum(hl * wl for hl, wl in level_shapes(height, width, levels))
    return itemsize * (-(-channels // VEC) * VEC) * pixels


@dataclass(frozen=True)
class OnTheFlyFeatures:
    """f1 and the pooled f2 levels, channels-last (N_l, C8) in `feature_dtype` (`onthefly_features`)."""

    f1: wp.array
    levels: tuple[wp.array, ...]
    channels: int
    height: int
    width: int
    feature_dtype: str
    scalar: Any  # the working dtype of the lookups (that of the features given)

    @property
    def nbytes(self) -> int:
        """Bytes held: the stored arrays' own."""
        return self.f1.capacity + sum(x.capacity for x in self.levels)

    @property
    def device(self) -> wp.Device:
        return self.f1.device


def store(maps: list[wp.array], feature_dtype: str, a: Inputs) -> list[wp.array]:
    """Each (C, N_l) map channels-last as (N_l, C8) in the storage dtype (rounded to nearest).

    Packed on the host by NumPy (transposed copy, then one conversion), once per stored feature set.
    """
    wdt, ndt, _ = FEATURE_DTYPES[feature_dtype]
    if feature_dtype == "float32":
        wdt, ndt = a.scalar, a.np_dtype
    hosts = [x.numpy() for x in maps]
    if feature_dtype == "float16":  # every map checked before any is stored
        big = max(float(np.abs(h).max(initial=0.0)) for h in hosts)
        if big > FLOAT16_MAX:
            raise ValueError(f"feature_dtype: float16 storage holds |values| <= {FLOAT16_MAX:g}, "
                             f"the features reach {big:g}; use feature_dtype='float32'")
    out = []
    for host in hosts:
        channels, n = host.shape
        rows = np.zeros((n, -(-channels // VEC) * VEC), dtype=ndt)
        rows[:, :channels] = host.T  # rounds to nearest in the storage dtype
        out.append(wp.array(rows, dtype=wdt, device=a.device))
    return out


def float16_to_float32(h: np.ndarray) -> np.ndarray:
    """Finite float16 values as float32, exactly, by integer operations on their bits.

    A float16 with sign s, exponent field e (5 bits) and mantissa m (10 bits) is
    (-1)^s 2^(e - 15) (1 + m / 2^10) (e > 0) or (-1)^s 2^-14 m / 2^10 (e = 0). Placing s at bit 31
    and e, m at bits 27..13 (above 0 in float32's 8-bit exponent field) gives the float32
    (-1)^s 2^(e - 127) (1 + m / 2^10), or the float32 subnormal (-1)^s 2^-126 m / 2^10: either
    times 2^112 is the float16's value, exactly (a power-of-two scale). The bits move by one
    shift left by 16 (s to bit 31), an arithmetic shift right by 3 (e, m to 27..13; s copied into
    30..28) and a mask clearing 30..28. Infinities and NaN would come out finite: the stores
    hold finite values only. Five in-place passes (0.19 ms for 2852 x 256 values against 1.2 ms
    for NumPy's astype, which converts value by value here).
    """
    w = h.view(np.uint16).astype(np.uint32)
    w <<= 16
    v = w.view(np.int32)
    v >>= 3
    v &= np.int32(-0x70000001)  # 0x8fffffff
    f = w.view(np.float32)
    f *= np.float32(2.0 ** 112)
    return f


def widen(x: wp.array, a: Inputs) -> wp.array:
    """Stored rows (N, C8) as (N, C8 / 8) vectors of the working dtype (exact; float32 storage: no copy
    where the working dtype is float32)."""
    n, c8 = x.shape
    vec = VEC_OF[a.scalar]
    if x.dtype == a.scalar:
        return wp.array(ptr=x.ptr, shape=(n, c8 // VEC), dtype=vec, device=x.device)  # x outlives the call
    if fast_paths.on(a.device):
        if a.scalar == wp.float32 and x.strides[1] == 2:
            # the rows converted in C++ (`patch_cpu.widen_rows_cpu`, 8-lane conversions), into the vectors' memory
            out_v = a.empty((n, c8 // VEC), vec)
            out = wp.array(ptr=out_v.ptr, shape=(n, c8), dtype=wp.float32, device=a.device)  # out_v outlives it
            a.launch(patch_cpu.widen_rows_cpu(), n, [x, out], min_chunk=256)
            return out_v
        if a.scalar == wp.float32:
            rows = float16_to_float32(x.numpy()).reshape(n, c8 // VEC, VEC)
        else:
            rows = x.numpy().astype(a.np_dtype).reshape(n, c8 // VEC, VEC)
        return wp.array(rows, dtype=vec, device=a.device, copy=False)  # keeps `rows` alive
    return pack_rows(x, c8 // VEC, a)


def onthefly_held_bytes(height: int, width: int, channels: int, levels: int, itemsize: int = 4, *,
                        feature_dtype: str = "float32") -> int:
    """Bytes the on-the-fly path keeps between lookups: f1 and the pooled f2 pyramid, (C, H_l, W_l) each
    ("float32": the inputs themselves, `itemsize` bytes a value), or their float16 store (`stored_bytes`:
    channels-last, padded to a multiple of 8 channels, 2 bytes a value).

    The counterpart of `volume.dense_bytes` (the volume pyramid the dense path keeps instead).
    """
    if check_feature_dtype(feature_dtype) != "float32":
        return stored_bytes(height, width, channels, levels, feature_dtype)
    pixels = height * width + sum(hl * wl for hl, wl in level_shapes(height, width, levels))
    return itemsize * channels * pixels


def onthefly_bytes(height: int, width: int, channels: int, levels: int, radius: int, itemsize: int = 4, *,
                   feature_dtype: str = "float32") -> int:
    """Peak bytes of an on-the-fly forward on the CPU, its output excluded (the dense lookup's is the same).

    `onthefly_held_bytes` plus the working buffers of one call: f1 channels-last (channels padded
    to 8), one level's channels-last copy at a time (the largest level sampled through patches),
    the patch buffer (whose memory a full-product level reuses for its blocks of V^l), at a
    full-product level the scaled P^l(f2), and on the CPU the pixels' grouping for the patch kernel
    (`onthefly_layout._group_pixels`: four int32 of N and the counting sort's (W_l + 2r + 3)(H_l + 2r + 3)
    + 1 + W_l + 2r + 4 at the largest patched level). With float16 features
    (`lookup_onthefly_features`) the working copies are the widened f1 and level, of the same sizes,
    in the working dtype; on the CPU the patch kernel reads the stored level rows in place, so there
    the count is an upper bound (no level copy is made). On the CPU with several threads the lookups
    form all levels at once (`onthefly_phased._forward_phased`; the float32 `lookup_onthefly` where C is a
    multiple of 8): the count holds two patch buffers (the patched levels take turns), every
    full-product level's rows of V^l (N H_l W_l) and scaled P^l(f2), every patched level's grouping
    (kept between calls, per thread and size) and, for the float32 lookup, every patched level's
    channels-last copy at once. These are the counts of the several-thread path (one thread holds
    less); stored float32 features take the float16 count's buffers, beside float32 held bytes.
    """
    c_pad = -(-channels // VEC) * VEC
    n = height * width
    patch = n * (2 * radius + 2) ** 2
    shapes = level_shapes(height, width, levels)
    # the full product needs whole 8-channel vectors (`onthefly._forward`)
    is_full = [full_product_level(hl, wl, radius, wp.get_device("cpu")) and channels % VEC == 0 for hl, wl in shapes]
    full = [hl * wl for (hl, wl), f in zip(shapes, is_full) if f]
    patched = [hl * wl for (hl, wl), f in zip(shapes, is_full) if not f]
    work = c_pad * n + c_pad * max(patched, default=0) + patch + channels * max(full, default=0)
    held = onthefly_held_bytes(height, width, channels, levels, itemsize, feature_dtype=feature_dtype)
    side = 2 * radius + 2
    groupings = [4 * n + (wl + side + 1) * (hl + side + 1) + 1 + wl + side + 2
                 for (hl, wl), f in zip(shapes, is_full) if not f]
    if feature_dtype == "float16" or channels % VEC == 0:  # all levels at once (`_forward_phased`)
        copies = max(patched, default=0) if feature_dtype == "float16" else sum(patched)
        work = c_pad * n + c_pad * copies + patch * min(2, len(patched)) + (n + channels) * sum(full)
        return held + itemsize * work + 4 * sum(groupings)
    return held + itemsize * work + 4 * max(groupings, default=0)
