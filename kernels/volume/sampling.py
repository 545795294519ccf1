"""Ray-box intersection and sample placement along rays (stratified, occupancy-skipped).

Ray-AABB (slab method, Kay & Kajiya 1986). For ray o + t d and box [lo, hi],
    t_enter = max(near, max_a min(t_a^lo, t_a^hi)),  t_exit = min(far, min_a max(t_a^lo, t_a^hi)),
    t_a^{lo,hi} = ({lo,hi}_a - o_a) / d_a,
with an axis where d_a = 0 excluding the ray unless lo_a <= o_a <= hi_a. The ray hits when
t_exit > t_enter; a miss gets t_enter = t_exit = 0 and hit = 0.

Stratified sampling (NeRF, Mildenhall et al. 2020, eq. 2). [t_enter, t_exit] is cut into strata
[a_k, b_k] -- either S equal strata per ray (``n_samples``) or strata of a fixed length
``step`` with the last one shortened to end at t_exit (ray marching as in instant-ngp).
Each stratum holds one sample

    t_k = a_k + u_k (b_k - a_k),   u_k ~ U[0, 1) drawn from (seed, ray) when jittered, else 1/2,
    delta_k = b_k - a_k,   z_k = t_k * z_scale_r,   x_k = o + t_k d,

so that sum_k sigma(x_k) delta_k is a Riemann sum of the optical depth. ``delta`` is a ray
length only when |d| = 1; z_scale_r converts t to the depth the caller wants (the cosine to
the optical axis for z-depth with unit directions).

Empty-space skipping (instant-ngp; nerfacc, Li et al. 2023): with an occupancy grid, a stratum
whose midpoint lies in an unoccupied cell gets no sample. Samples are packed: ray r owns
samples ray_offsets[r] .. ray_offsets[r+1]-1, found by a counting pass, a prefix sum and a
filling pass (one thread per ray in both; disjoint writes, so launch_split is safe).
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels.launch import launch_split
from kernels.volume import _util as U
from kernels.volume.occupancy import OccupancyGrid, occupied_at

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _ray_aabb_kernel(
    origins: wp.array2d(dtype=typing.Any),
    dirs: wp.array2d(dtype=typing.Any),
    bbox: wp.array2d(dtype=typing.Any),
    near: typing.Any,
    far: typing.Any,
    out_t0: wp.array(dtype=typing.Any),
    out_t1: wp.array(dtype=typing.Any),
    out_hit: wp.array(dtype=wp.int32),
    offset: int,
):
    r = wp.tid() + offset
    zero = origins.dtype(0.0)
    t0 = near
    t1 = far
    hit = int(1)
    for a in range(3):
        o = origins[r, a]
        d = dirs[r, a]
        lo = bbox[0, a]
        hi = bbox[1, a]
        if d == zero:
            if o < lo or o > hi:
                hit = 0
        else:
            ta = (lo - o) / d
            tb = (hi - o) / d
            t0 = wp.max(t0, wp.min(ta, tb))
            t1 = wp.min(t1, wp.max(ta, tb))
    if hit == 0 or not (t1 > t0):
        hit = 0
        t0 = zero
        t1 = zero
    out_t0[r] = t0
    out_t1[r] = t1
    out_hit[r] = hit


@wp.func
def _n_strata(t0: typing.Any, t1: typing.Any, step: typing.Any, n_fixed: int) -> int:
    if n_fixed > 0:
        return n_fixed
    return wp.max(int(wp.ceil((t1 - t0) / step - type(t0)(1e-6))), 1)


@wp.kernel
def _count_kernel(
    origins: wp.array2d(dtype=typing.Any),
    dirs: wp.array2d(dtype=typing.Any),
    t_enter: wp.array(dtype=typing.Any),
    t_exit: wp.array(dtype=typing.Any),
    hit: wp.array(dtype=wp.int32),
    step: typing.Any,
    n_fixed: int,
    occ: wp.array(dtype=wp.int32),
    occ_bbox: wp.array2d(dtype=typing.Any),
    occ_res: wp.vec3i,
    counts: wp.array(dtype=wp.int32),
    offset: int,
):
    r = wp.tid() + offset
    count = int(0)
    if hit[r] != 0:
        t0 = t_enter[r]
        t1 = t_exit[r]
        n = _n_strata(t0, t1, step, n_fixed)
        h = step
        if n_fixed > 0:
            h = (t1 - t0) / origins.dtype(n_fixed)
        for k in range(n):
            a = t0 + origins.dtype(k) * h
            b = wp.min(a + h, t1)
            tm = origins.dtype(0.5) * (a + b)
            if occupied_at(origins[r, 0] + tm * dirs[r, 0], origins[r, 1] + tm * dirs[r, 1],
                           origins[r, 2] + tm * dirs[r, 2], occ, occ_bbox, occ_res) != 0:
                count += 1
    counts[r] = count


@wp.kernel
def _fill_kernel(
    origins: wp.array2d(dtype=typing.Any),
    dirs: wp.array2d(dtype=typing.Any),
    z_scale: wp.array(dtype=typing.Any),
    t_enter: wp.array(dtype=typing.Any),
    t_exit: wp.array(dtype=typing.Any),
    hit: wp.array(dtype=wp.int32),
    step: typing.Any,
    n_fixed: int,
    occ: wp.array(dtype=wp.int32),
    occ_bbox: wp.array2d(dtype=typing.Any),
    occ_res: wp.vec3i,
    jitter: int,
    seed: int,
    ray_offsets: wp.array(dtype=wp.int32),
    out_points: wp.array2d(dtype=typing.Any),
    out_dirs: wp.array2d(dtype=typing.Any),
    out_t: wp.array(dtype=typing.Any),
    out_delta: wp.array(dtype=typing.Any),
    out_z: wp.array(dtype=typing.Any),
    out_ray: wp.array(dtype=wp.int32),
    offset: int,
):
    r = wp.tid() + offset
    if hit[r] != 0:
        state = wp.rand_init(seed, r)
        t0 = t_enter[r]
        t1 = t_exit[r]
        n = _n_strata(t0, t1, step, n_fixed)
        h = step
        if n_fixed > 0:
            h = (t1 - t0) / origins.dtype(n_fixed)
        j = ray_offsets[r]
        for k in range(n):
            a = t0 + origins.dtype(k) * h
            b = wp.min(a + h, t1)
            tm = origins.dtype(0.5) * (a + b)
            if occupied_at(origins[r, 0] + tm * dirs[r, 0], origins[r, 1] + tm * dirs[r, 1],
                           origins[r, 2] + tm * dirs[r, 2], occ, occ_bbox, occ_res) != 0:
                u = origins.dtype(0.5)
                if jitter != 0:
                    u = origins.dtype(wp.randf(state))
                t = a + u * (b - a)
                for c in range(3):
                    out_points[j, c] = origins[r, c] + t * dirs[r, c]
                    out_dirs[j, c] = dirs[r, c]
                out_t[j] = t
                out_delta[j] = b - a
                out_z[j] = t * z_scale[r]
                out_ray[j] = r
                j += 1


@dataclass
class Samples:
    """Packed samples along rays (wp.arrays): ray r owns ray_offsets[r] .. ray_offsets[r+1]-1."""

    points: wp.array  # (N, 3) x_k = o + t_k d
    dirs: wp.array  # (N, 3) the ray direction of each sample
    t: wp.array  # (N,)
    delta: wp.array  # (N,) stratum length
    z: wp.array  # (N,) t_k * z_scale
    ray_index: wp.array  # (N,) int32
    ray_offsets: wp.array  # (R+1,) int32

    @property
    def n_samples(self) -> int:
        return self.t.shape[0]

    @property
    def n_rays(self) -> int:
        return self.ray_offsets.shape[0] - 1


def _rays(origins: U.ArrayLike, dirs: U.ArrayLike, device: wp.Device) -> tuple[Any, wp.array, wp.array]:
    dtype = U.common_dtype([("origins", origins), ("dirs", dirs)])
    if len(origins.shape) != 2 or origins.shape[1] != 3:
        raise ValueError(f"origins: expected shape (R, 3), got {tuple(origins.shape)}")
    U.check_shape("dirs", dirs, (origins.shape[0], 3))
    U.check_finite("origins", origins)
    d = U.check_finite("dirs", dirs)
    if d.size and np.any(np.all(d == 0, axis=1)):
        raise ValueError("dirs: contains a zero direction")
    return dtype, U.to_warp("origins", origins, dtype, device), U.to_warp("dirs", dirs, dtype, device)


def _near_far(near: float, far: float) -> None:
    if not (np.isfinite(near) and np.isfinite(far)):
        raise ValueError(f"near, far: expected finite values, got near={near}, far={far}")
    if near < 0:
        raise ValueError(f"near: expected near >= 0, got {near}")
    if not near < far:
        raise ValueError(f"near, far: expected near < far, got near={near}, far={far}")


def ray_aabb(
    origins: U.ArrayLike,
    dirs: U.ArrayLike,
    bbox: Any,
    near: float = 0.0,
    far: float = 1e10,
    device: str | wp.Device | None = None,
) -> tuple[wp.array, wp.array, wp.array]:
    """(t_enter (R,), t_exit (R,), hit (R,) int32) of rays o + t d, t in [near, far], with the box."""
    device = U.default_device(device)
    dtype, o, d = _rays(origins, dirs, device)
    box = U.check_bbox("bbox", bbox)
    _near_far(near, far)
    n = o.shape[0]
    t0 = wp.empty(n, dtype=dtype, device=device)
    t1 = wp.empty(n, dtype=dtype, device=device)
    hit = wp.empty(n, dtype=wp.int32, device=device)
    if n:
        launch_split(_ray_aabb_kernel, n, [o, d, wp.array(box, dtype=dtype, device=device), dtype(near),
                                            dtype(far), t0, t1, hit], device=device)
    return t0, t1, hit


def sample_rays(
    origins: U.ArrayLike,
    dirs: U.ArrayLike,
    bbox: Any,
    *,
    near: float = 0.0,
    far: float = 1e10,
    n_samples: int | None = None,
    step: float | None = None,
    z_scale: U.ArrayLike | None = None,
    occupancy: OccupancyGrid | None = None,
    jitter: bool = False,
    seed: int = 0,
    device: str | wp.Device | None = None,
) -> Samples:
    """Packed stratified samples of rays (R, 3) inside `bbox` and [near, far] (module docstring).

    Give exactly one of `n_samples` (S equal strata per ray) and `step` (fixed stratum length).
    `z_scale` (R,) defaults to 1 (z_k = t_k). With `occupancy`, strata whose midpoint is in an
    unoccupied cell are skipped. `jitter` draws u_k from `seed`; otherwise u_k = 1/2.
    """
    device = U.default_device(device)
    dtype, o, d = _rays(origins, dirs, device)
    box = U.check_bbox("bbox", bbox)
    _near_far(near, far)
    if (n_samples is None) == (step is None):
        raise ValueError("n_samples, step: give exactly one of them")
    n_fixed = 0 if n_samples is None else U.check_positive_int("n_samples", n_samples)
    if step is not None and not (math.isfinite(step) and step > 0):
        raise ValueError(f"step: expected a positive finite length, got {step}")
    n_rays = o.shape[0]
    if z_scale is None:
        zs = wp.array(np.ones(n_rays), dtype=dtype, device=device)
    else:
        U.check_shape("z_scale", z_scale, (n_rays,))
        U.check_finite("z_scale", z_scale)
        zs = U.to_warp("z_scale", z_scale, U.float_dtype("z_scale", z_scale), device)
        if zs.dtype != dtype:
            raise ValueError(f"z_scale: expected dtype {U.NP_TYPES[dtype].__name__}")
    if occupancy is None:
        occ = wp.ones(1, dtype=wp.int32, device=device)
        occ_box, occ_res = box, wp.vec3i(1, 1, 1)
    else:
        if occupancy.device != device:
            raise ValueError(f"occupancy: grid is on {occupancy.device}, expected {device}")
        occ, occ_box, occ_res = occupancy.occupied, occupancy.bbox, wp.vec3i(*occupancy.resolution)
    occ_box = wp.array(occ_box, dtype=dtype, device=device)

    t0, t1, hit = ray_aabb(o, d, box, near, far, device)
    step_f = dtype(0.0 if step is None else step)
    counts = wp.empty(n_rays, dtype=wp.int32, device=device)
    if n_rays:
        launch_split(_count_kernel, n_rays, [o, d, t0, t1, hit, step_f, n_fixed, occ, occ_box, occ_res, counts],
                     device=device, min_chunk=256)
    offsets_np = np.zeros(n_rays + 1, dtype=np.int64)
    np.cumsum(counts.numpy(), out=offsets_np[1:])
    if offsets_np[-1] > np.iinfo(np.int32).max:
        raise ValueError(f"too many samples ({offsets_np[-1]}) for int32 offsets; use fewer rays or a longer step")
    offsets = wp.array(offsets_np.astype(np.int32), dtype=wp.int32, device=device)
    n = int(offsets_np[-1])
    s = Samples(points=wp.empty((n, 3), dtype=dtype, device=device), dirs=wp.empty((n, 3), dtype=dtype, device=device),
                t=wp.empty(n, dtype=dtype, device=device), delta=wp.empty(n, dtype=dtype, device=device),
                z=wp.empty(n, dtype=dtype, device=device), ray_index=wp.empty(n, dtype=wp.int32, device=device),
                ray_offsets=offsets)
    if n_rays and n:
        launch_split(_fill_kernel, n_rays,
                     [o, d, zs, t0, t1, hit, step_f, n_fixed, occ, occ_box, occ_res, int(jitter), int(seed), offsets,
                      s.points, s.dirs, s.t, s.delta, s.z, s.ray_index], device=device, min_chunk=256)
    return s


def dense_samples(
    origins: np.ndarray,
    dirs: np.ndarray,
    t: np.ndarray,
    delta: np.ndarray,
    z_scale: np.ndarray | None = None,
    device: str | wp.Device | None = None,
) -> Samples:
    """Packed Samples from explicit per-ray sample positions t (R, S) and lengths delta (R, S).

    For sample layouts other than sample_rays' strata (e.g. the textbook's linspace with a final
    delta of 1e-3). Points are o + t d; z = t * z_scale (default 1).
    """
    device = U.default_device(device)
    dtype = U.common_dtype([("origins", origins), ("dirs", dirs), ("t", t), ("delta", delta)])
    o, d, t, delta = (np.asarray(a) for a in (origins, dirs, t, delta))
    U.check_shape("origins", o, (None, 3))
    n_rays = o.shape[0]
    U.check_shape("dirs", d, (n_rays, 3))
    if t.ndim != 2 or t.shape[0] != n_rays:
        raise ValueError(f"t: expected shape ({n_rays}, S), got {t.shape}")
    U.check_shape("delta", delta, t.shape)
    for name, a in (("origins", o), ("dirs", d), ("t", t)):
        U.check_finite(name, a)
    U.check_nonnegative("delta", delta)
    zs = np.ones(n_rays, dtype=t.dtype) if z_scale is None else np.asarray(z_scale, dtype=t.dtype)
    U.check_shape("z_scale", zs, (n_rays,))
    s = t.shape[1]
    np_t = U.NP_TYPES[dtype]
    points = (o[:, None, :] + t[:, :, None] * d[:, None, :]).reshape(-1, 3)
    arr = lambda a, dt=dtype: wp.array(np.ascontiguousarray(a), dtype=dt, device=device)  # noqa: E731
    return Samples(points=arr(points.astype(np_t)), dirs=arr(np.repeat(d, s, axis=0).astype(np_t)),
                   t=arr(t.reshape(-1).astype(np_t)), delta=arr(delta.reshape(-1).astype(np_t)),
                   z=arr((t * zs[:, None]).reshape(-1).astype(np_t)),
                   ray_index=arr(np.repeat(np.arange(n_rays), s).astype(np.int32), wp.int32),
                   ray_offsets=arr((np.arange(n_rays + 1) * s).astype(np.int32), wp.int32))
