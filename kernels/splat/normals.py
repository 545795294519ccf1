"""Normals for splat geometry: each splat's shortest-axis normal, and normals from a rendered depth map.

Splat normal (PGSR, Chen et al., "PGSR: Planar-based Gaussian Splatting for Efficient and
High-Fidelity Surface Reconstruction", TVCG 2024; gsplat's "normal from the shortest axis"). A 3D
Gaussian flattened along its smallest scale approximates a surface patch, whose normal is that axis:

    k_i = argmin_j l_ij (the first on ties),  n_w = R(q_i / |q_i|) e_k,  n = W n_w (camera frame),
    n_i = -sign(n . p_i) n,  p_i = W mu_i + t the splat's camera-space mean (facing the camera; +n when
    n . p_i = 0),

with [W | t] the world-to-camera matrix. k_i and the sign are piecewise constant, so the only gradient
is the quaternion's: dL/dq = rotation_vjp(q, G) (kernels/splat/ewa.py) with G zero but for its
column k, G e_k = sign W^T dL/dn_i. The means and log-scales get none (one-sided where two scales
tie or n . p = 0).

Normals from depth (gsplat's depth_to_normal; 2DGS's surface normal). With the pinhole intrinsics
fx, fy, cx, cy and pixel centres (x + 1/2, y + 1/2), each pixel's depth z(x, y) is back-projected to
the camera-space point P(x, y) = z(x, y) r(x, y), r(x, y) = ((x + 1/2 - cx) / fx, (y + 1/2 - cy) / fy, 1).
For every pixel not on the image's border (1 <= x <= W - 2, 1 <= y <= H - 2), central differences

    a = P(x, y + 1) - P(x, y - 1)   (down the image),   b = P(x + 1, y) - P(x - 1, y)   (right),
    c = a x b,   n(x, y) = c / max(|c|, EPS),  EPS = 1e-12 (torch's normalize),

which points towards the camera (n_z < 0) for a surface seen from its front. Border pixels get n = 0
and no gradient. VJP for G = dL/dn: dL/dc = (G - n (n . G)) / |c| (G / EPS where |c| <= EPS),
dL/da = b x dL/dc, dL/db = dL/dc x a; dL/dP(x, y +- 1) = +- dL/da, dL/dP(x +- 1, y) = +- dL/db and
dL/dz(q) = r(q) . dL/dP(q), summed over the (at most four) pixels whose differences use q: each
output pixel writes its four terms into its own slots, and a second kernel sums every depth pixel's
slots (race-free on the split CPU launch).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.splat.camera import SplatCamera
from kernels.splat.ewa import quat_to_rotation, rotation_vjp

wp.set_module_options({"enable_backward": False})

EPS = 1e-12
MIN_CHUNK = 4096


@wp.func
def _shortest_axis_normal(means: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
                          log_scales: wp.array2d(dtype=Any), view: wp.array2d(dtype=Any), i: int):
    """(n_i facing the camera, sign, k, W) of splat i (module docstring)."""
    k = int(0)
    if log_scales[i, 1] < log_scales[i, k]:
        k = 1
    if log_scales[i, 2] < log_scales[i, k]:
        k = 2
    q = wp.vector(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3], length=4, dtype=means.dtype)
    qn = wp.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    R = quat_to_rotation(q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn)
    Wr = wp.matrix(view[0, 0], view[0, 1], view[0, 2], view[1, 0], view[1, 1], view[1, 2],
                   view[2, 0], view[2, 1], view[2, 2], shape=(3, 3), dtype=means.dtype)
    mu = wp.vector(means[i, 0], means[i, 1], means[i, 2], length=3, dtype=means.dtype)
    p = Wr * mu + wp.vector(view[0, 3], view[1, 3], view[2, 3], length=3, dtype=means.dtype)
    n = Wr * wp.vector(R[0, k], R[1, k], R[2, k], length=3, dtype=means.dtype)
    sign = means.dtype(1.0)
    if wp.dot(n, p) > means.dtype(0.0):
        sign = -sign
    return sign * n, sign, k, Wr, q


@wp.kernel
def _splat_normals_kernel(means: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
                          log_scales: wp.array2d(dtype=Any), view: wp.array2d(dtype=Any),
                          out: wp.array2d(dtype=Any), offset: int):
    i = wp.tid() + offset
    n, sign, k, Wr, q = _shortest_axis_normal(means, quats, log_scales, view, i)
    for j in range(3):
        out[i, j] = n[j]


@wp.kernel
def _splat_normals_backward_kernel(means: wp.array2d(dtype=Any), quats: wp.array2d(dtype=Any),
                                   log_scales: wp.array2d(dtype=Any), view: wp.array2d(dtype=Any),
                                   g_n: wp.array2d(dtype=Any), g_quats: wp.array2d(dtype=Any), offset: int):
    i = wp.tid() + offset
    n, sign, k, Wr, q = _shortest_axis_normal(means, quats, log_scales, view, i)
    g_w = sign * (wp.transpose(Wr) * wp.vector(g_n[i, 0], g_n[i, 1], g_n[i, 2], length=3, dtype=means.dtype))
    g_R = wp.matrix(shape=(3, 3), dtype=means.dtype)
    for r in range(3):
        g_R[r, k] = g_w[r]
    g_q = rotation_vjp(q, g_R)
    for j in range(4):
        g_quats[i, j] = g_q[j]


@wp.func
def _point(depth: wp.array2d(dtype=Any), x: int, y: int, fx: Any, fy: Any, cx: Any, cy: Any):
    """The back-projected P(x, y) = z r(x, y) and the ray r(x, y)."""
    half = type(fx)(0.5)
    r = wp.vector((type(fx)(float(x)) + half - cx) / fx, (type(fx)(float(y)) + half - cy) / fy, type(fx)(1.0),
                  length=3, dtype=type(fx))
    return depth[y, x] * r, r


@wp.func
def _diffs(depth: wp.array2d(dtype=Any), x: int, y: int, fx: Any, fy: Any, cx: Any, cy: Any):
    pd, rd = _point(depth, x, y + 1, fx, fy, cx, cy)
    pu, ru = _point(depth, x, y - 1, fx, fy, cx, cy)
    pr, rr = _point(depth, x + 1, y, fx, fy, cx, cy)
    pl, rl = _point(depth, x - 1, y, fx, fy, cx, cy)
    return pd - pu, pr - pl, rd, ru, rr, rl


@wp.func
def _depth_pixel(t: int, depth: wp.array2d(dtype=Any)):
    """Pixel (x, y) of thread t (row-major) and whether it is interior (its four neighbours exist:
    elsewhere the normal is 0 and passes no gradient)."""
    w = depth.shape[1]
    h = depth.shape[0]
    y = t / w
    x = t - y * w
    return x, y, x >= 1 and x <= w - 2 and y >= 1 and y <= h - 2


@wp.kernel
def _depth_normals_kernel(depth: wp.array2d(dtype=Any), fx: Any, fy: Any, cx: Any, cy: Any,
                          out: wp.array3d(dtype=Any), offset: int):
    x, y, interior = _depth_pixel(wp.tid() + offset, depth)
    zero = type(fx)(0.0)
    n = wp.vector(zero, zero, zero, length=3, dtype=type(fx))
    if interior:
        a, b, rd, ru, rr, rl = _diffs(depth, x, y, fx, fy, cx, cy)
        c = wp.cross(a, b)
        n = c / wp.max(wp.length(c), type(fx)(EPS))
    for j in range(3):
        out[y, x, j] = n[j]


@wp.kernel
def _depth_normals_backward_kernel(depth: wp.array2d(dtype=Any), fx: Any, fy: Any, cx: Any, cy: Any,
                                   g_n: wp.array3d(dtype=Any), slots: wp.array3d(dtype=Any), offset: int):
    # slots[y, x] = the terms output pixel (x, y) adds to dL/dz of (x, y + 1), (x, y - 1), (x + 1, y), (x - 1, y)
    x, y, interior = _depth_pixel(wp.tid() + offset, depth)
    zero = type(fx)(0.0)
    for j in range(4):
        slots[y, x, j] = zero
    if interior:
        a, b, rd, ru, rr, rl = _diffs(depth, x, y, fx, fy, cx, cy)
        c = wp.cross(a, b)
        ln = wp.length(c)
        g = wp.vector(g_n[y, x, 0], g_n[y, x, 1], g_n[y, x, 2], length=3, dtype=type(fx))
        g_c = g / type(fx)(EPS)
        if ln > type(fx)(EPS):
            n = c / ln
            g_c = (g - n * wp.dot(n, g)) / ln
        g_a = wp.cross(b, g_c)
        g_b = wp.cross(g_c, a)
        slots[y, x, 0] = wp.dot(rd, g_a)
        slots[y, x, 1] = -wp.dot(ru, g_a)
        slots[y, x, 2] = wp.dot(rr, g_b)
        slots[y, x, 3] = -wp.dot(rl, g_b)


@wp.kernel
def _gather_depth_slots_kernel(slots: wp.array3d(dtype=Any), out: wp.array2d(dtype=Any), offset: int):
    t = wp.tid() + offset
    w = slots.shape[1]
    h = slots.shape[0]
    y = t / w
    x = t - y * w
    acc = slots.dtype(0.0)
    if y >= 1:
        acc += slots[y - 1, x, 0]  # pixel (x, y) is (x, y - 1)'s lower neighbour
    if y + 1 < h:
        acc += slots[y + 1, x, 1]
    if x >= 1:
        acc += slots[y, x - 1, 2]
    if x + 1 < w:
        acc += slots[y, x + 1, 3]
    out[y, x] = acc


for _k in (_splat_normals_kernel, _splat_normals_backward_kernel, _depth_normals_kernel,
           _depth_normals_backward_kernel, _gather_depth_slots_kernel):
    A.declare_float_overloads(_k)


# ============================================================================ entry points


def _check_camera(camera: Any, pinhole: bool = False) -> SplatCamera:
    if not isinstance(camera, SplatCamera):
        raise ValueError(f"camera: expected a SplatCamera, got {type(camera).__name__}")
    if pinhole and camera.lens is not None:
        raise ValueError(f"camera: expected a pinhole camera (lens None) to back-project the depth, got lens "
                         f"{camera.lens.model!r}")
    return camera


def _splat_inputs(means: Any, quats: Any, log_scales: Any, camera: Any, device: Any):
    cam = _check_camera(camera)
    a = A.Inputs(device, means, quats, log_scales)
    m = a.floats("means", means, (None, 3))
    n = int(m.shape[0])
    q = a.floats("quats", quats, (n, 4))
    ls = a.floats("log_scales", log_scales, (n, 3))
    if A.values_checked() and n:
        qh = np.asarray(q.numpy() if isinstance(q, wp.array) else quats, dtype=np.float64)
        if not np.all(np.linalg.norm(qh, axis=1) > 0):
            raise ValueError("quats: expected non-zero quaternions")
    view = wp.array(np.asarray(cam.viewmat, dtype=a.np_dtype), dtype=a.scalar, device=a.device)
    return a, n, [m, q, ls, view]


def splat_normals(means: Any, quats: Any, log_scales: Any, camera: SplatCamera, *, device: Any = None) -> Any:
    """(N, 3) camera-frame unit normals of every splat's shortest axis, facing `camera` (module docstring)."""
    a, n, args = _splat_inputs(means, quats, log_scales, camera, device)
    out = a.empty((n, 3))
    if n:
        a.launch(_splat_normals_kernel, n, [*args, out], min_chunk=MIN_CHUNK)
    return a.out(out)


def splat_normals_backward(means: Any, quats: Any, log_scales: Any, camera: SplatCamera, grad: Any, *,
                           device: Any = None) -> Any:
    """dL/dquats (N, 4) for the cotangent `grad` (N, 3) of `splat_normals` (its only input with a gradient)."""
    a, n, args = _splat_inputs(means, quats, log_scales, camera, device)
    g = a.floats("grad", grad, (n, 3))
    out = a.empty((n, 4))
    if n:
        a.launch(_splat_normals_backward_kernel, n, [*args, g, out], min_chunk=MIN_CHUNK)
    return a.out(out)


def _depth_inputs(depth: Any, camera: Any, device: Any):
    cam = _check_camera(camera, pinhole=True)
    a = A.Inputs(device, depth)
    d = a.floats("depth", depth, (cam.height, cam.width))
    K = cam.K
    return a, d, [a.s(K[0, 0]), a.s(K[1, 1]), a.s(K[0, 2]), a.s(K[1, 2])]


def normals_from_depth(depth: Any, camera: SplatCamera, *, device: Any = None) -> Any:
    """(H, W, 3) camera-frame unit normals of the depth map `depth` (H, W) seen by `camera` (its pinhole
    intrinsics), zero on the border (module docstring)."""
    a, d, k = _depth_inputs(depth, camera, device)
    h, w = (int(x) for x in d.shape)
    out = a.empty((h, w, 3))
    a.launch(_depth_normals_kernel, h * w, [d, *k, out], min_chunk=MIN_CHUNK)
    return a.out(out)


def normals_from_depth_backward(depth: Any, camera: SplatCamera, grad: Any, *, device: Any = None) -> Any:
    """dL/ddepth (H, W) for the cotangent `grad` (H, W, 3) of `normals_from_depth`."""
    a, d, k = _depth_inputs(depth, camera, device)
    h, w = (int(x) for x in d.shape)
    g = a.floats("grad", grad, (h, w, 3))
    slots, out = a.empty((h, w, 4)), a.empty((h, w))
    a.launch(_depth_normals_backward_kernel, h * w, [d, *k, g, slots], min_chunk=MIN_CHUNK)
    a.launch(_gather_depth_slots_kernel, h * w, [slots, out], min_chunk=MIN_CHUNK)
    return a.out(out)
