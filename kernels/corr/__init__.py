"""RAFT's correlation machinery: all-pairs volume, pyramid, windowed lookups, and an on-the-fly path.

Follows Teed and Deng, "RAFT: Recurrent All-Pairs Field Transforms for Optical
Flow" (ECCV 2020), section 3.2 and its CorrBlock / AlternateCorrBlock.

Features. f1 and f2 are (C, H, W) feature maps of the two frames; p = (h, w) is
a pixel of frame 1 and q = (h', w') a pixel of frame 2.

All-pairs volume (H, W, H, W):

    V[p, q] = sum_c f1[c, p] f2[c, q] / sqrt(C).                          (1)

Pyramid. V^0 = V and, pooling 2x2 over frame 2's dimensions only,

    V^l[p, h', w'] = 1/4 sum_{a, b in {0, 1}} V^{l-1}[p, 2h' + a, 2w' + b],   (2)

of shape (H, W, H >> l, W >> l) (odd trailing rows and columns are dropped, as
avg_pool2d does). Pooling is linear in f2, so V^l equals (1) computed with
f2 pooled l times, P^l(f2): the on-the-fly path rests on that identity.

Coordinates. coords (2, H, W) holds, for each pixel of frame 1, a continuous
position (x, y) in frame 2 in the project's convention: x right, y down, the
centre of pixel (h', w') at (w' + 0.5, h' + 0.5). At level l the position is
(x, y) / 2^l, which is exact for 2x2 pooling with this convention (RAFT indexes
pixel centres at integers, so its coarser levels sit (1 - 2^-l)/2 level-l pixels
off; at level 0 our lookup at coords equals RAFT's at coords - 0.5).

Bilinear sampling with zeros outside. A level-l map S (H_l, W_l) sampled at
(x, y): with u = x - 1/2, v = y - 1/2, i = floor(u), j = floor(v),
fx = u - i, fy = v - j,

    S(x, y) = (1-fx)(1-fy) S[j, i] + fx (1-fy) S[j, i+1]
            + (1-fx) fy S[j+1, i] + fx fy S[j+1, i+1],                     (3)

where every tap outside [0, H_l) x [0, W_l) counts as 0 (grid_sample's zero
padding, tap by tap).

Lookup with radius r. For each level l and offsets a, b in {0, ..., 2r},

    out[l (2r+1)^2 + a (2r+1) + b, p] = V^l[p](x_p / 2^l + a - r, y_p / 2^l + b - r).   (4)

This is RAFT's channel order: levels outermost, and within a level the x offset
varies slowest (RAFT stacks meshgrid(dy, dx) and adds its first component to x).

Stages, one module each (each opens with its own math, adjoints and layout):
  * `volume`: the all-pairs product (1) and the pyramid (2), with adjoints; the
    product is a GEMM, by BLAS on the CPU (`backend="numpy"`, the default there)
    or by a blocked Warp kernel (`backend="warp"`, the default on CUDA);
  * `dense`: the lookup (4) in a stored pyramid, with its adjoint;
  * `window_cpu`: the dense lookup's window sampling on the CPU, in C++ (one kernel per
    radius and float type, 4 pixels a thread), bit-identical to `_common`'s;
  * `onthefly`: the same lookup from f1 and the pooled features P^l(f2) without
    storing V, with its adjoint (its Warp kernels in `onthefly_kernels`, the channels-last
    layout and BLAS full products in `onthefly_layout`, the every-level-at-once schedule on
    several threads in `onthefly_phased`);
  * `patch_cpu`: the on-the-fly forward's patches on the CPU, in C++ (pixels grouped by
    window column so that up to 8 share each tap row's vectors; one kernel per radius,
    float type and storage dtype), bit-identical to `onthefly`'s Warp kernel;
  * `stored`: f1 and P^l(f2) stored for repeated on-the-fly lookups, in float32 or,
    halving what is held, float16 (forward-only; the arithmetic stays float32);
  * `_common`: what they share: the window sampling (3)-(4) and its adjoint, the
    pooling (2) and its adjoint, vector packing and the argument checks.

Entry points take NumPy arrays or wp.arrays (float32 or float64, one dtype for
all inputs) and return the same kind as their first array argument, on its
device (kernels._arrays). Every argument is checked before any launch; bad
input raises ValueError naming the argument. Volumes and pyramids given to the
forward entry points are checked for shape, not for NaN or inf (that would read
as much as the lookup itself; they come from `correlation_volume`, whose
features are checked). Every backward entry point returns
a dict from the name of each differentiated input to its gradient (a list of
arrays for a list input). Warp's own autodiff is off for these modules: every
backward here is written by hand.
"""

from kernels.corr._common import VEC, level_shapes, vec8d, vec8f
from kernels.corr.dense import lookup, lookup_backward
from kernels.corr._common import full_product_level
from kernels.corr.onthefly import (lookup_onthefly, lookup_onthefly_backward, lookup_onthefly_features,
                                   onthefly_features, pool_features, pool_features_backward)
from kernels.corr.stored import FEATURE_DTYPES, OnTheFlyFeatures, onthefly_bytes, onthefly_held_bytes, stored_bytes
from kernels.corr.volume import (correlation_pyramid, correlation_pyramid_backward, correlation_volume,
                                 correlation_volume_backward, dense_bytes)

__all__ = [
    "VEC", "vec8f", "vec8d", "level_shapes",
    "correlation_volume", "correlation_volume_backward", "correlation_pyramid", "correlation_pyramid_backward",
    "dense_bytes", "lookup", "lookup_backward",
    "pool_features", "pool_features_backward", "lookup_onthefly", "lookup_onthefly_backward", "onthefly_bytes",
    "onthefly_held_bytes", "full_product_level", "onthefly_features", "lookup_onthefly_features",
    "OnTheFlyFeatures", "FEATURE_DTYPES", "stored_bytes",
]
