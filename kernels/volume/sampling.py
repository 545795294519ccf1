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
filling pass of one kernel (one thread per ray in both; disjoint writes, so launch_split is safe).

Inputs follow the array contract (kernels._arrays): `ray_aabb` and `sample_rays` return NumPy
arrays for NumPy rays and wp.arrays on the device for wp.array rays.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.volume._checks import check_bbox, check_directions
from kernels.volume.occupancy import OccupancyGrid, occupied_at

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _ray_aabb_kernel(
    origins: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any),
    near: typing.Any, far: typing.Any,
    out_t0: wp.array(dtype=typing.Any), out_t1: wp.array(dtype=typing.Any), out_hit: wp.array(dtype=wp.int32),
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
def _strata(t0: typing.Any, t1: typing.Any, step: typing.Any, n_fixed: int):
    """(number of strata, stratum length) of [t0, t1]: n_fixed equal ones, or length `step`."""
    if n_fixed > 0:
        return n_fixed, (t1 - t0) / type(t0)(n_fixed)
    return wp.max(int(wp.ceil((t1 - t0) / step - type(t0)(1e-6))), 1), step


@wp.func
def _stratum(origins: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), r: int, k: int,
             t0: typing.Any, t1: typing.Any, h: typing.Any, occ: wp.array(dtype=wp.int32),
             occ_bbox: wp.array2d(dtype=typing.Any), occ_res: wp.vec3i):
    """Stratum k = [a, b] of ray r, and whether its midpoint lies in an occupied cell."""
    a = t0 + type(t0)(k) * h
    b = wp.min(a + h, t1)
    tm = type(t0)(0.5) * (a + b)
    occupied = occupied_at(origins[r, 0] + tm * dirs[r, 0], origins[r, 1] + tm * dirs[r, 1],
                           origins[r, 2] + tm * dirs[r, 2], occ, occ_bbox, occ_res)
    return a, b, occupied


@wp.kernel
def _march_kernel(
    origins: wp.array2d(dtype=typing.Any), dirs: wp.array2d(dtype=typing.Any), z_scale: wp.array(dtype=typing.Any),
    t_enter: wp.array(dtype=typing.Any), t_exit: wp.array(dtype=typing.Any), hit: wp.array(dtype=wp.int32),
    step: typing.Any, n_fixed: int, occ: wp.array(dtype=wp.int32), occ_bbox: wp.array2d(dtype=typing.Any),
    occ_res: wp.vec3i, jitter: int, seed: int, fill: int,
    counts: wp.array(dtype=wp.int32), ray_offsets: wp.array(dtype=wp.int32),
    out_points: wp.array2d(dtype=typing.Any), out_dirs: wp.array2d(dtype=typing.Any), out_t: wp.array(dtype=typing.Any),
    out_delta: wp.array(dtype=typing.Any), out_z: wp.array(dtype=typing.Any), out_ray: wp.array(dtype=wp.int32),
    offset: int,
):
    # Both passes over ray r's strata: fill = 0 counts the occupied ones into counts[r]; fill = 1
    # writes their samples from ray_offsets[r] on (the outputs are placeholders in the counting pass).
    r = wp.tid() + offset
    j = int(0)
    if fill != 0:
        j = ray_offsets[r]
    if hit[r] != 0:
        state = wp.rand_init(seed, r)
        t0 = t_enter[r]
        t1 = t_exit[r]
        n, h = _strata(t0, t1, step, n_fixed)
        for k in range(n):
            a, b, occupied = _stratum(origins, dirs, r, k, t0, t1, h, occ, occ_bbox, occ_res)
            if occupied != 0:
                if fill != 0:
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
    if fill == 0:
        counts[r] = j


@wp.kernel
def _dense_kernel(
    origins: wp.array(dtype=typing.Any), dirs: wp.array(dtype=typing.Any), t: wp.array2d(dtype=typing.Any),
    delta: wp.array2d(dtype=typing.Any), z_scale: wp.array(dtype=typing.Any),
    out_points: wp.array(dtype=typing.Any), out_dirs: wp.array(dtype=typing.Any), out_t: wp.array(dtype=typing.Any),
    out_delta: wp.array(dtype=typing.Any), out_z: wp.array(dtype=typing.Any), out_ray: wp.array(dtype=wp.int32),
    offset: int,
):
    # One thread per ray: its S samples x = o + t d (the product, then the sum: NumPy's two roundings).
    # origins, dirs, out_points and out_dirs are (N, 3) arrays viewed as N vec3s: one load or store
    # per point instead of three indexed ones.
    r = wp.tid() + offset
    n_s = t.shape[1]
    zs = z_scale[r]
    o = origins[r]
    dr = dirs[r]
    k = r * n_s
    for j in range(n_s):
        tk = t[r, j]
        out_points[k] = type(o)(o[0] + tk * dr[0], o[1] + tk * dr[1], o[2] + tk * dr[2])
        out_dirs[k] = dr
        out_t[k] = tk
        out_delta[k] = delta[r, j]
        out_z[k] = tk * zs
        out_ray[k] = r
        k += 1


@wp.kernel
def _dense4_kernel(
    origins: wp.array(dtype=typing.Any), dirs: wp.array(dtype=typing.Any), t4: wp.array2d(dtype=typing.Any),
    delta4: wp.array2d(dtype=typing.Any), z_scale: wp.array(dtype=typing.Any),
    out_points4: wp.array(dtype=typing.Any), out_dirs4: wp.array(dtype=typing.Any), out_t4: wp.array(dtype=typing.Any),
    out_delta4: wp.array(dtype=typing.Any), out_z4: wp.array(dtype=typing.Any), out_ray4: wp.array(dtype=wp.vec4i),
    offset: int,
):
    # _dense_kernel with S % 4 == 0, four samples at a time: every array is seen as vec4s (t4 and
    # delta4 as (R, S/4); the points' and directions' 12 coordinates of four samples as 3 vec4s),
    # so four samples take 10 stores instead of 24. The same roundings, lane by lane.
    r = wp.tid() + offset
    n_q = t4.shape[1]
    zs = z_scale[r]
    o = origins[r]
    dr = dirs[r]
    d4a = type(t4[r, 0])(dr[0], dr[1], dr[2], dr[0])
    d4b = type(t4[r, 0])(dr[1], dr[2], dr[0], dr[1])
    d4c = type(t4[r, 0])(dr[2], dr[0], dr[1], dr[2])
    ray4 = wp.vec4i(r, r, r, r)
    q = r * n_q
    for jq in range(n_q):
        tq = t4[r, jq]
        x0 = o[0] + tq[0] * dr[0]
        y0 = o[1] + tq[0] * dr[1]
        z0 = o[2] + tq[0] * dr[2]
        x1 = o[0] + tq[1] * dr[0]
        y1 = o[1] + tq[1] * dr[1]
        z1 = o[2] + tq[1] * dr[2]
        x2 = o[0] + tq[2] * dr[0]
        y2 = o[1] + tq[2] * dr[1]
        z2 = o[2] + tq[2] * dr[2]
        x3 = o[0] + tq[3] * dr[0]
        y3 = o[1] + tq[3] * dr[1]
        z3 = o[2] + tq[3] * dr[2]
        b = 3 * q
        out_points4[b] = type(tq)(x0, y0, z0, x1)
        out_points4[b + 1] = type(tq)(y1, z1, x2, y2)
        out_points4[b + 2] = type(tq)(z2, x3, y3, z3)
        out_dirs4[b] = d4a
        out_dirs4[b + 1] = d4b
        out_dirs4[b + 2] = d4c
        out_t4[q] = tq
        out_delta4[q] = delta4[r, jq]
        out_z4[q] = tq * zs
        out_ray4[q] = ray4
        q += 1


@dataclass
class Samples:
    """Packed samples along rays (NumPy or wp.arrays): ray r owns ray_offsets[r] .. ray_offsets[r+1]-1."""

    points: A.ArrayLike  # (N, 3) x_k = o + t_k d
    dirs: A.ArrayLike  # (N, 3) the ray direction of each sample
    t: A.ArrayLike  # (N,)
    delta: A.ArrayLike  # (N,) stratum length
    z: A.ArrayLike  # (N,) t_k * z_scale
    ray_index: A.ArrayLike  # (N,) int32
    ray_offsets: A.ArrayLike  # (R+1,) int32

    @property
    def n_samples(self) -> int:
        return self.t.shape[0]

    @property
    def n_rays(self) -> int:
        return self.ray_offsets.shape[0] - 1


def _rays(a: A.Inputs, origins: A.ArrayLike, dirs: A.ArrayLike) -> tuple[wp.array, wp.array]:
    o = a.floats("origins", origins, (None, 3))
    d = a.floats("dirs", dirs, (o.shape[0], 3))
    check_directions("dirs", d)
    return o, d


def _near_far(near: float, far: float) -> tuple[float, float]:
    near = A.check_float("near", near)
    far = A.check_float("far", far)
    if near < 0:
        raise ValueError(f"near: expected near >= 0, got {near}")
    if not near < far:
        raise ValueError(f"near, far: expected near < far, got near={near}, far={far}")
    return near, far


def _ray_aabb(a: A.Inputs, o: wp.array, d: wp.array, box: np.ndarray, near: float, far: float
              ) -> tuple[wp.array, wp.array, wp.array]:
    n = o.shape[0]
    t0, t1, hit = a.empty(n), a.empty(n), a.empty(n, wp.int32)
    a.launch(_ray_aabb_kernel, n, [o, d, wp.array(box, dtype=a.scalar, device=a.device), a.s(near), a.s(far),
                                   t0, t1, hit])
    return t0, t1, hit


def ray_aabb(origins: A.ArrayLike, dirs: A.ArrayLike, bbox: Any, near: float = 0.0, far: float = 1e10,
             device: str | wp.Device | None = None) -> tuple[A.ArrayLike, A.ArrayLike, A.ArrayLike]:
    """(t_enter (R,), t_exit (R,), hit (R,) int32) of rays o + t d, t in [near, far], with the box,
    in the kind of `origins`."""
    a = A.Inputs(device, origins, dirs)
    o, d = _rays(a, origins, dirs)
    box = check_bbox("bbox", bbox)
    near, far = _near_far(near, far)
    return tuple(a.out(x) for x in _ray_aabb(a, o, d, box, near, far))


def sample_rays(
    origins: A.ArrayLike,
    dirs: A.ArrayLike,
    bbox: Any,
    *,
    near: float = 0.0,
    far: float = 1e10,
    n_samples: int | None = None,
    step: float | None = None,
    z_scale: A.ArrayLike | None = None,
    occupancy: OccupancyGrid | None = None,
    jitter: bool = False,
    seed: int = 0,
    device: str | wp.Device | None = None,
) -> Samples:
    """Packed stratified samples of rays (R, 3) inside `bbox` and [near, far] (module docstring).

    Give exactly one of `n_samples` (S equal strata per ray) and `step` (fixed stratum length).
    `z_scale` (R,) defaults to 1 (z_k = t_k). With `occupancy`, strata whose midpoint is in an
    unoccupied cell are skipped. `jitter` draws u_k from `seed`; otherwise u_k = 1/2. The Samples
    hold arrays of the kind of `origins`.
    """
    a = A.Inputs(device, origins, dirs, z_scale)
    s = pack_samples(a, origins, dirs, bbox, near=near, far=far, n_samples=n_samples, step=step, z_scale=z_scale,
                     occupancy=occupancy, jitter=jitter, seed=seed)
    return s if not a.as_numpy else Samples(**{k: a.out(v) for k, v in vars(s).items()})


def pack_samples(a: A.Inputs, origins: A.ArrayLike, dirs: A.ArrayLike, bbox: Any, *, near: float, far: float,
                 n_samples: int | None, step: float | None, z_scale: A.ArrayLike | None,
                 occupancy: OccupancyGrid | None, jitter: bool, seed: int) -> Samples:
    """`sample_rays` for the call `a` (kernels._arrays.Inputs), as wp.arrays on its device."""
    o, d = _rays(a, origins, dirs)
    box = check_bbox("bbox", bbox)
    near, far = _near_far(near, far)
    if (n_samples is None) == (step is None):
        raise ValueError("n_samples, step: give exactly one of them")
    n_fixed = 0 if n_samples is None else A.check_int("n_samples", n_samples, minimum=1)
    if step is not None:
        step = A.check_float("step", step, positive=True)
    n_rays = o.shape[0]
    zs = a.floats("z_scale", z_scale, (n_rays,)) if z_scale is not None else \
        wp.array(np.ones(n_rays), dtype=a.scalar, device=a.device)
    if occupancy is None:
        occ = wp.ones(1, dtype=wp.int32, device=a.device)
        occ_box, occ_res = box, wp.vec3i(1, 1, 1)
    else:
        if not isinstance(occupancy, OccupancyGrid) or occupancy.device != a.device:
            raise ValueError(f"occupancy: expected a kernels.volume.OccupancyGrid on {a.device}")
        occ, occ_box, occ_res = occupancy.occupied, occupancy.bbox, wp.vec3i(*occupancy.resolution)
    occ_box = wp.array(occ_box, dtype=a.scalar, device=a.device)

    t0, t1, hit = _ray_aabb(a, o, d, box, near, far)
    march = [o, d, zs, t0, t1, hit, a.s(0.0 if step is None else step), n_fixed, occ, occ_box, occ_res, int(jitter),
             int(seed)]
    counts = a.empty(n_rays, wp.int32)
    placeholders = [a.empty((0, 3)), a.empty((0, 3)), a.empty(0), a.empty(0), a.empty(0), a.empty(0, wp.int32)]
    a.launch(_march_kernel, n_rays, march + [0, counts, counts, *placeholders], min_chunk=256)
    offsets_np = np.zeros(n_rays + 1, dtype=np.int64)
    np.cumsum(counts.numpy(), out=offsets_np[1:])
    if offsets_np[-1] > np.iinfo(np.int32).max:
        raise ValueError(f"n_samples, step: too many samples ({offsets_np[-1]}) for int32 offsets; "
                         "use fewer rays or a longer step")
    offsets = wp.array(offsets_np.astype(np.int32), dtype=wp.int32, device=a.device)
    n = int(offsets_np[-1])
    s = Samples(points=a.empty((n, 3)), dirs=a.empty((n, 3)), t=a.empty(n), delta=a.empty(n), z=a.empty(n),
                ray_index=a.empty(n, wp.int32), ray_offsets=offsets)
    if n:
        a.launch(_march_kernel, n_rays, march + [1, counts, offsets, s.points, s.dirs, s.t, s.delta, s.z,
                                                 s.ray_index], min_chunk=256)
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

    For sample layouts other than sample_rays' strata (e.g. the Video and 3D Vision chapter's linspace with a final
    delta of 1e-3). Points are o + t d; z = t * z_scale (default 1). The inputs are NumPy arrays;
    the Samples are packed as wp.arrays on `device` (default the CPU), ready for
    kernels.volume.render_samples.
    """
    o, d, t, delta = (np.asarray(x) for x in (origins, dirs, t, delta))
    a = A.Inputs(device, o, d, t, delta)
    A.check_shape("origins", o, (None, 3))
    named = (("origins", o, (None, 3)), ("dirs", d, (o.shape[0], 3)), ("t", t, (o.shape[0], None)),
             ("delta", delta, t.shape))
    for name, x, shape in named:
        a.float_dtype(name, x)
        A.check_shape(name, x, shape)
        A.check_finite(name, x)
    A.check_at_least("delta", delta, 0.0)
    n_rays = o.shape[0]
    zs = np.ones(n_rays, dtype=t.dtype) if z_scale is None else np.asarray(z_scale, dtype=t.dtype)
    A.check_shape("z_scale", zs, (n_rays,))
    n_s = t.shape[1]
    n = n_rays * n_s
    # Packed by one kernel (one thread per ray, split over the launch threads) rather than NumPy
    # broadcasting, repeats and copies: 22-23 -> 16 ms on the textbook's 4096 x 64 float32 samples
    # on a busy host, with the same roundings (bit for bit, tested); four
    # samples at a time with vec4 stores when S % 4 == 0.
    out = Samples(points=a.empty((n, 3)), dirs=a.empty((n, 3)), t=a.empty(n), delta=a.empty(n), z=a.empty(n),
                  ray_index=a.empty(n, wp.int32),
                  ray_offsets=wp.array((np.arange(n_rays + 1) * n_s).astype(np.int32), dtype=wp.int32,
                                       device=a.device))
    if not n:
        return out
    v3, v4 = _VEC3[a.scalar], _VEC4[a.scalar]
    quads = n_s % 4 == 0  # four samples at a time (bit for bit the same arrays)
    shapes = [(n_rays,), (n_rays,)] + ([(n_rays, n_s // 4)] * 2 if quads else [t.shape] * 2) + [(n_rays,)]
    dtypes = [v3, v3] + ([v4, v4] if quads else [a.scalar, a.scalar]) + [a.scalar]
    if a.device.is_cpu:
        # The kernel reads the NumPy inputs in place: views of contiguous arrays (`host` keeps them
        # alive until the launch returns), seen directly as the vectors the kernel takes.
        host = [np.ascontiguousarray(x) for x in (o, d, t, delta, zs)]
        args = [wp.array(ptr=x.ctypes.data, dtype=dt, shape=sh, device=a.device)
                for x, dt, sh in zip(host, dtypes, shapes)]
    else:
        inputs = [a.floats(name, x, finite=False) for name, x in
                  (("origins", o), ("dirs", d), ("t", t), ("delta", delta), ("z_scale", zs))]
        args = [wp.array(ptr=x.ptr, dtype=dt, shape=sh, device=a.device) for x, dt, sh in zip(inputs, dtypes, shapes)]
    view = lambda x, dtype, shape: wp.array(ptr=x.ptr, dtype=dtype, shape=shape, device=a.device)  # noqa: E731
    if quads:
        outs = [view(x, v4, (3 * n // 4,)) for x in (out.points, out.dirs)]
        outs += [view(x, v4, (n // 4,)) for x in (out.t, out.delta, out.z)] + [view(out.ray_index, wp.vec4i, (n // 4,))]
        a.launch(_DENSE4[a.scalar], n_rays, args + outs, min_chunk=64)
    else:
        outs = [view(x, v3, (n,)) for x in (out.points, out.dirs)] + [out.t, out.delta, out.z, out.ray_index]
        a.launch(_DENSE[a.scalar], n_rays, args + outs, min_chunk=64)
    return out


A.declare_float_overloads(_ray_aabb_kernel)
A.declare_float_overloads(_march_kernel)
_VEC3 = {wp.float32: wp.vec3f, wp.float64: wp.vec3d}
_DENSE = {s: wp.overload(_dense_kernel, {
    "origins": wp.array(dtype=_VEC3[s]), "dirs": wp.array(dtype=_VEC3[s]), "t": wp.array2d(dtype=s),
    "delta": wp.array2d(dtype=s), "z_scale": wp.array(dtype=s), "out_points": wp.array(dtype=_VEC3[s]),
    "out_dirs": wp.array(dtype=_VEC3[s]), "out_t": wp.array(dtype=s), "out_delta": wp.array(dtype=s),
    "out_z": wp.array(dtype=s)}) for s in A.FLOATS}
_VEC4 = {wp.float32: wp.vec4f, wp.float64: wp.vec4d}
_DENSE4 = {s: wp.overload(_dense4_kernel, {
    "origins": wp.array(dtype=_VEC3[s]), "dirs": wp.array(dtype=_VEC3[s]), "t4": wp.array2d(dtype=_VEC4[s]),
    "delta4": wp.array2d(dtype=_VEC4[s]), "z_scale": wp.array(dtype=s), "out_points4": wp.array(dtype=_VEC4[s]),
    "out_dirs4": wp.array(dtype=_VEC4[s]), "out_t4": wp.array(dtype=_VEC4[s]), "out_delta4": wp.array(dtype=_VEC4[s]),
    "out_z4": wp.array(dtype=_VEC4[s])}) for s in A.FLOATS}
