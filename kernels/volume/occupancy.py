"""Occupancy grid for empty-space skipping (instant-ngp, Mueller et al. 2022; nerfacc, Li et al. 2023).

A grid of G = gx * gy * gz cells over a box [lo, hi] keeps a density estimate rho_c per cell
and a bit occ_c. Cell c = ix + gx (iy + gy iz) (x fastest; NumPy shape (gz, gy, gx)) covers
lo + ([ix, iy, iz] + [0, 1]) (hi - lo) / [gx, gy, gz]. An update draws one point x_c uniformly
in every cell (seeded), evaluates the field's density there and sets

    rho_c <- max(decay * rho_c, sigma(x_c))                  (exponential decay, then max)
    occ_c <- [rho_c > min(mean_c rho_c, threshold)]

Before the first update every cell is occupied, so early training samples everywhere. The
samplers (kernels.volume.sampling) skip a stratum whose midpoint lies in a cell with occ_c = 0;
points outside the box are looked up in the nearest cell.
"""

from __future__ import annotations

import typing
from typing import Any, Callable, Sequence

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.launch import launch_split
from kernels.volume._checks import check_bbox, check_dtype
from kernels.volume.grid import flat_coords

wp.set_module_options({"enable_backward": False})


@wp.func
def cell_index(x: typing.Any, y: typing.Any, z: typing.Any, bbox: wp.array2d(dtype=typing.Any), res: wp.vec3i) -> int:
    """Flat index of the cell holding (x, y, z), clamped to the grid."""
    ix = wp.clamp(int(wp.floor((x - bbox[0, 0]) / (bbox[1, 0] - bbox[0, 0]) * type(x)(res[0]))), 0, res[0] - 1)
    iy = wp.clamp(int(wp.floor((y - bbox[0, 1]) / (bbox[1, 1] - bbox[0, 1]) * type(x)(res[1]))), 0, res[1] - 1)
    iz = wp.clamp(int(wp.floor((z - bbox[0, 2]) / (bbox[1, 2] - bbox[0, 2]) * type(x)(res[2]))), 0, res[2] - 1)
    return ix + res[0] * (iy + res[1] * iz)


@wp.func
def occupied_at(x: typing.Any, y: typing.Any, z: typing.Any, occ: wp.array(dtype=wp.int32),
                bbox: wp.array2d(dtype=typing.Any), res: wp.vec3i) -> int:
    return occ[cell_index(x, y, z, bbox, res)]


@wp.kernel
def _cell_points_kernel(
    bbox: wp.array2d(dtype=typing.Any), res: wp.vec3i, seed: int, out_points: wp.array2d(dtype=typing.Any), offset: int,
):
    c = wp.tid() + offset
    state = wp.rand_init(seed, c)
    ijk = flat_coords(c, res)
    for a in range(3):
        u = (bbox.dtype(ijk[a]) + bbox.dtype(wp.randf(state))) / bbox.dtype(res[a])
        out_points[c, a] = bbox[0, a] + u * (bbox[1, a] - bbox[0, a])


@wp.kernel
def _ema_kernel(
    density: wp.array(dtype=wp.float32), sigma: wp.array(dtype=typing.Any), decay: float, offset: int,
):
    c = wp.tid() + offset
    density[c] = wp.max(decay * density[c], wp.float32(sigma[c]))


@wp.kernel
def _threshold_kernel(
    density: wp.array(dtype=wp.float32), threshold: float, occupied: wp.array(dtype=wp.int32), offset: int,
):
    c = wp.tid() + offset
    occupied[c] = wp.where(density[c] > threshold, 1, 0)


class OccupancyGrid:
    """Per-cell density estimates and occupancy bits over `bbox` (module docstring)."""

    def __init__(
        self,
        bbox: Any,
        resolution: Sequence[int],
        decay: float = 0.95,
        threshold: float = 0.01,
        device: str | wp.Device | None = None,
    ) -> None:
        self.bbox = check_bbox("bbox", bbox)
        if len(resolution) != 3:
            raise ValueError(f"resolution: expected three cell counts (gx, gy, gz), got {resolution!r}")
        self.resolution = tuple(A.check_int("resolution", r, minimum=1) for r in resolution)
        self.decay = A.check_float("decay", decay, nonnegative=True)
        if not self.decay < 1.0:
            raise ValueError(f"decay: expected a value in [0, 1), got {decay}")
        self.threshold = A.check_float("threshold", threshold, nonnegative=True)
        self.device = A.get_device(device)
        n = self.n_cells
        self.density = wp.zeros(n, dtype=wp.float32, device=self.device)
        self.occupied = wp.ones(n, dtype=wp.int32, device=self.device)
        self.n_updates = 0

    @property
    def n_cells(self) -> int:
        gx, gy, gz = self.resolution
        return gx * gy * gz

    @property
    def cell_size(self) -> np.ndarray:
        return (self.bbox[1] - self.bbox[0]) / np.array(self.resolution)

    def occupied_fraction(self) -> float:
        return float(self.occupied.numpy().mean())

    def cell_points(self, seed: int, dtype: Any = wp.float32) -> wp.array:
        """One uniformly random point in every cell, (G, 3) wp.array on the grid's device, drawn from `seed`."""
        check_dtype("dtype", dtype)
        pts = wp.empty((self.n_cells, 3), dtype=dtype, device=self.device)
        launch_split(_cell_points_kernel, self.n_cells,
                     [wp.array(self.bbox, dtype=dtype, device=self.device), wp.vec3i(*self.resolution), int(seed), pts],
                     device=self.device)
        return pts

    def update(self, sigma: A.ArrayLike) -> None:
        """EMA-max update with densities (G,) >= 0 (NumPy or a wp.array on the grid's device, float32 or
        float64) measured at this update's `cell_points`, then threshold."""
        s = A.Inputs(self.device, sigma).floats("sigma", sigma, (self.n_cells,), finite=False)
        A.check_at_least("sigma", s, 0.0)
        launch_split(_ema_kernel, self.n_cells, [self.density, s, self.decay], device=self.device)
        thr = min(float(self.density.numpy().mean()), self.threshold)
        launch_split(_threshold_kernel, self.n_cells, [self.density, thr, self.occupied], device=self.device)
        self.n_updates += 1

    def update_from(self, density_fn: Callable[[wp.array], A.ArrayLike], seed: int, dtype: Any = wp.float32) -> None:
        """`update(density_fn(cell_points(seed)))`."""
        self.update(density_fn(self.cell_points(seed, dtype)))


A.declare_float_overloads(_cell_points_kernel)
A.declare_float_overloads(_ema_kernel)
