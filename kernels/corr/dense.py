"""Dense lookups: the windowed bilinear lookup (4) in a stored volume pyramid, and its adjoint.

For each pixel p of frame 1, level l and window offsets a, b in {0, ..., 2r},

    out[l (2r+1)^2 + a (2r+1) + b, p] = V^l[p](x_p / 2^l + a - r, y_p / 2^l + b - r),   (4)

with V^l[p] the level's (H_l, W_l) slice for p sampled by (3), taps outside the
slice counting as 0. All samples of a level share the fractions (fx, fy), so
they read the (2r + 2) x (2r + 2) tap patch of V^l[p] from (j0, i0). The forward
and the adjoint each run one thread per pixel, the forward over up to four levels
per launch, the adjoint one level per launch, adding into row p of the level's
gradient and pixel p of the coordinates' only. The kernels are
`_common.sample_levels` and `_common.sample_windows_adjoint` (the window
sampling is shared with the on-the-fly lookup), where the adjoint's formulas are
written out; on the CPU the forward runs `window_cpu.sample_levels_cpu`, the same
sampling in C++ with the window's side fixed at compile time (same outputs, bit
for bit).
"""

from __future__ import annotations

from typing import Sequence

import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs
from kernels.corr._common import (LEVELS_PER_LAUNCH, Array, check_levels, check_list, check_radius, coords_in,
                                  levels_in, sample_levels, sample_windows_adjoint, volume_in)
from kernels.corr import window_cpu


# --------------------------------------------------------------------------- entry points


def _volume_pyramid(a: Inputs, pyramid: Sequence[Array]) -> tuple[list[wp.array], int, int]:
    """The pyramid's levels as (H W, H_l, W_l) wp.arrays, and (H, W)."""
    v0 = volume_in(a, "pyramid[0]", pyramid[0], finite=False)  # see volume_in
    height, width = v0.shape[:2]
    check_levels(len(pyramid), height, width)
    return levels_in(a, "pyramid", pyramid, v0, (height, width), height, width, finite=False), height, width


def lookup(pyramid: Sequence[Array], coords: Array, radius: int, *, device: str | None = None) -> Array:
    """Windowed lookup (4) in a volume pyramid: (L (2r+1)^2, H, W) in RAFT's channel order."""
    radius = check_radius(radius)
    check_list("pyramid", pyramid, "(H, W, H_l, W_l)")
    a = Inputs(device, *pyramid, coords)
    levels, height, width = _volume_pyramid(a, pyramid)
    xy = coords_in(a, coords, height, width)
    side = 2 * radius + 1
    n = height * width
    out = a.empty((len(levels) * side * side, height, width))  # every element is written
    cpu_kernel = window_cpu.sample_levels_cpu(radius, a.scalar) if fast_paths.on(a.device) else None
    for lvl0 in range(0, len(levels), LEVELS_PER_LAUNCH):
        group = levels[lvl0:lvl0 + LEVELS_PER_LAUNCH]
        padded = group + [group[0]] * (LEVELS_PER_LAUNCH - len(group))  # unused slots: never read
        head = [*padded, len(group), xy, out, a.s(0.5 ** lvl0)]
        if cpu_kernel is not None:
            a.launch(cpu_kernel, window_cpu.blocks(n), [*head, lvl0 * side * side],
                     min_chunk=256 // window_cpu.LANES)
        else:
            a.launch(sample_levels, n, [*head, radius, lvl0 * side * side], min_chunk=256)
    return a.out(out)


def lookup_backward(pyramid: Sequence[Array], coords: Array, radius: int, grad_out: Array, *,
                    device: str | None = None) -> dict[str, Array | list[Array]]:
    """Adjoint of (4). Returns a dict {"pyramid": [gradient (H, W, H_l, W_l) of every level],
    "coords": gradient (2, H, W)}, in pyramid[0]'s kind."""
    radius = check_radius(radius)
    check_list("pyramid", pyramid, "(H, W, H_l, W_l)")
    a = Inputs(device, *pyramid, coords, grad_out)
    levels, height, width = _volume_pyramid(a, pyramid)
    xy = coords_in(a, coords, height, width)
    side = 2 * radius + 1
    n = height * width
    g = a.floats("grad_out", grad_out, (len(levels) * side * side, height, width))
    grad_coords = a.zeros((2, height, width))
    grads = []
    for lvl, v in enumerate(levels):
        gv = a.zeros(v.shape)
        a.launch(sample_windows_adjoint, n, [v, xy, g, gv, grad_coords, a.s(0.5 ** lvl), radius, lvl * side * side, 0])
        grads.append(a.out(gv.reshape((height, width, v.shape[1], v.shape[2]))))
    return {"pyramid": grads, "coords": a.out(grad_coords)}
