"""Frequency positional encoding (NeRF, Mildenhall et al. 2020, eq. 4).

A point p in the box [lo, hi] is normalised to x = 2 (p - lo) / (hi - lo) - 1 in [-1, 1]^3, then

    gamma(x) = (x, sin(2^0 pi x), cos(2^0 pi x), ..., sin(2^{K-1} pi x), cos(2^{K-1} pi x))

per coordinate, laid out as [x_0, x_1, x_2, then for k = 0..K-1: sin(2^k pi x_a) for a = 0..2,
cos(2^k pi x_a) for a = 0..2], 3 + 6K values. The encoding has no parameters; the fields built
on it need no gradient with respect to the points, so it has no backward. `encode` takes and
returns wp.arrays (the neural fields' intermediate values).
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.launch import launch_split
from kernels.volume._checks import check_bbox
from kernels.volume.mlp import empty_array

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _pe_kernel(
    points: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any), n_freqs: int,
    out: wp.array2d(dtype=typing.Any), offset: int,
):
    n = wp.tid() + offset
    for a in range(3):
        x = points.dtype(2.0) * (points[n, a] - bbox[0, a]) / (bbox[1, a] - bbox[0, a]) - points.dtype(1.0)
        out[n, a] = x
        scale = points.dtype(3.141592653589793)
        for k in range(n_freqs):
            out[n, 3 + 6 * k + a] = wp.sin(scale * x)
            out[n, 6 + 6 * k + a] = wp.cos(scale * x)
            scale = scale * points.dtype(2.0)


class PositionalEncoding:
    def __init__(self, bbox: Any, n_freqs: int = 8) -> None:
        self.bbox = check_bbox("bbox", bbox)
        self.n_freqs = A.check_int("n_freqs", n_freqs, minimum=0)

    @property
    def n_outputs(self) -> int:
        return 3 + 6 * self.n_freqs

    def encode(self, points: wp.array, pool: A.HostPool | None = None) -> wp.array:
        """gamma (N, 3 + 6K) for points (N, 3), a wp.array on the points' device."""
        if not isinstance(points, wp.array):
            raise ValueError(f"points: expected a wp.array, got {type(points).__name__}")
        A.check_shape("points", points, (None, 3))
        A.float_dtype("points", points)
        n = points.shape[0]
        out = empty_array((n, self.n_outputs), points.dtype, points.device, pool)  # a block of `pool` if given
        if n:
            launch_split(_pe_kernel, n, [points, wp.array(self.bbox, dtype=points.dtype, device=points.device),
                                         self.n_freqs, out], device=points.device)
        return out


A.declare_float_overloads(_pe_kernel)
