"""Lucas-Kanade optical flow: window least squares, minimum-eigenvalue validity, pyramidal coarse to fine.

Follows Lucas and Kanade, "An Iterative Image Registration Technique with an
Application to Stereo Vision" (IJCAI 1981), with the validity test of Shi and
Tomasi, "Good Features to Track" (CVPR 1994), and the pyramidal, iterative
scheme of Bouguet, "Pyramidal Implementation of the Lucas Kanade Feature
Tracker" (Intel, 2000), applied densely (every pixel is a feature).

Conventions. Frames are (H, W) grey images; x runs along columns (right), y
along rows (down), the centre of pixel (row i, column j) at (j + 0.5, i + 0.5).
Flow is (H, W, 2) with [..., 0] = u (x, right) and [..., 1] = v (y, down), in
pixels, mapping frame 1 to frame 2, as the datasets store it.

Gradients of frame 1 by central differences, with replicated borders:

    Ix[i, j] = (I[i, j+1] - I[i, j-1]) / 2,     Iy[i, j] = (I[i+1, j] - I[i-1, j]) / 2.      (1)

(The Lucas-Kanade snippet of the Video and 3D Vision textbook chapter
differentiates along rows and calls it Ix: its "u" is the vertical flow.)

One LK step at pixel p with current flow d_p and window W(p) of
(2 half_window + 1)^2 pixels (those inside the image):

    G = sum_{q in W(p)} [Ix^2, Ix Iy; Ix Iy, Iy^2](q)                 (structure tensor)
    b = sum_{q in W(p)} e(q) [Ix(q), Iy(q)],   e(q) = I2(q + d_p) - I1(q)
    d_p <- d_p + delta,   G delta = -b.                                                   (2)

I2(q + d_p) is bilinear with clamped borders; the whole window moves with its
centre's flow, so with d_p = 0 and one step this is the classical LK solve
G [u, v] = -[sum Ix It, sum Iy It], It = I2 - I1. Validity (Shi-Tomasi): the
smaller eigenvalue of the mean tensor G / |W(p)|,

    lambda_min = (a + c)/2 - sqrt(((a - c)/2)^2 + b^2),   [a, b; b, c] = G / |W(p)|,       (3)

must reach `min_eigenvalue`; elsewhere the step is skipped (d_p unchanged) and
the pixel is reported invalid. A flat region or a straight edge (the aperture
problem) has lambda_min ~ 0.

Pyramid. Level l + 1 is level l blurred by the separable [1, 3, 3, 1] / 8 filter
centred between pixels 2k and 2k + 1 and decimated, so that its pixel k covers
level-l pixels 2k, 2k + 1 (sizes floor(H / 2), floor(W / 2); the pixel-centre
convention makes coordinates scale by exactly 2). Coarse to fine: the flow of
level l + 1 is sampled bilinearly at ((j + 0.5) / 2, (i + 0.5) / 2), doubled, and
refined at level l by `iterations` steps (2), each re-warping frame 2 with the
current flow.

Lucas-Kanade is an estimator here, not a layer of a trained model: these
kernels are forward only (no adjoints). Entry points take NumPy arrays or
wp.arrays (float32 or float64, one dtype for all) and return the kind of their
first array argument on its device (kernels._arrays): validity masks are bool
NumPy arrays or uint8 wp.arrays. Bad input raises ValueError naming the
argument before any launch.
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels._arrays import Inputs, check_float, check_int, declare_float_overloads

wp.set_module_options({"enable_backward": False})

Array = Any  # np.ndarray or wp.array


# --------------------------------------------------------------------------- kernels


@wp.func
def _clamped(img: wp.array2d(dtype=typing.Any), i: int, j: int):
    return img[wp.clamp(i, 0, img.shape[0] - 1), wp.clamp(j, 0, img.shape[1] - 1)]


@wp.func
def _cell(x: typing.Any):
    """The pixel index left of (or above) continuous coordinate x, and x's fraction past its centre."""
    u = x - type(x)(0.5)
    fu = wp.floor(u)
    return int(fu), u - fu


@wp.func
def _lerp2(v00: typing.Any, v01: typing.Any, v10: typing.Any, v11: typing.Any, ax: typing.Any, ay: typing.Any):
    """Bilinear blend of the taps [v00, v01; v10, v11] (rows i, i + 1; columns j, j + 1)."""
    one = type(ax)(1.0)
    top = (one - ax) * v00 + ax * v01
    bottom = (one - ax) * v10 + ax * v11
    return (one - ay) * top + ay * bottom


@wp.func
def _sample_clamped(img: wp.array2d(dtype=typing.Any), x: typing.Any, y: typing.Any):
    """Bilinear sample at continuous (x, y) (pixel centres at +0.5), borders replicated."""
    j, ax = _cell(x)
    i, ay = _cell(y)
    return _lerp2(_clamped(img, i, j), _clamped(img, i, j + 1), _clamped(img, i + 1, j), _clamped(img, i + 1, j + 1),
                  ax, ay)


@wp.kernel
def _gradients(img: wp.array2d(dtype=typing.Any), ix: wp.array2d(dtype=typing.Any),
               iy: wp.array2d(dtype=typing.Any), offset: int):
    """Equation (1)."""
    t = wp.tid() + offset
    i = t // img.shape[1]
    j = t % img.shape[1]
    half = img.dtype(0.5)
    ix[i, j] = (_clamped(img, i, j + 1) - _clamped(img, i, j - 1)) * half
    iy[i, j] = (_clamped(img, i + 1, j) - _clamped(img, i - 1, j)) * half


@wp.kernel
def _lk_step(img1: wp.array2d(dtype=typing.Any), ix: wp.array2d(dtype=typing.Any), iy: wp.array2d(dtype=typing.Any),
             img2: wp.array2d(dtype=typing.Any), flow_in: wp.array3d(dtype=typing.Any),
             flow_out: wp.array3d(dtype=typing.Any), min_eig: wp.array2d(dtype=typing.Any),
             valid: wp.array2d(dtype=wp.uint8),
             half_window: int, min_eigenvalue: typing.Any, offset: int):
    """Equations (2) and (3) at one pixel."""
    t = wp.tid() + offset
    height = img1.shape[0]
    width = img1.shape[1]
    i = t // width
    j = t % width
    zero = img1.dtype(0.0)
    du = flow_in[i, j, 0]
    dv = flow_in[i, j, 1]
    gxx = zero
    gxy = zero
    gyy = zero
    bx = zero
    by = zero
    count = int(0)
    for a in range(-half_window, half_window + 1):
        qi = i + a
        if qi >= 0 and qi < height:
            for b in range(-half_window, half_window + 1):
                qj = j + b
                if qj >= 0 and qj < width:
                    gx = ix[qi, qj]
                    gy = iy[qi, qj]
                    x2 = img1.dtype(qj) + img1.dtype(0.5) + du
                    y2 = img1.dtype(qi) + img1.dtype(0.5) + dv
                    e = _sample_clamped(img2, x2, y2) - img1[qi, qj]
                    gxx += gx * gx
                    gxy += gx * gy
                    gyy += gy * gy
                    bx += e * gx
                    by += e * gy
                    count += 1
    n = img1.dtype(count)
    a_ = gxx / n
    b_ = gxy / n
    c_ = gyy / n
    half_diff = (a_ - c_) * img1.dtype(0.5)
    lam = (a_ + c_) * img1.dtype(0.5) - wp.sqrt(half_diff * half_diff + b_ * b_)
    min_eig[i, j] = lam
    if lam >= min_eigenvalue:
        det = gxx * gyy - gxy * gxy
        flow_out[i, j, 0] = du - (gyy * bx - gxy * by) / det
        flow_out[i, j, 1] = dv - (gxx * by - gxy * bx) / det
        valid[i, j] = wp.uint8(1)
    else:
        flow_out[i, j, 0] = du
        flow_out[i, j, 1] = dv
        valid[i, j] = wp.uint8(0)


@wp.func
def _blur_row(img: wp.array2d(dtype=typing.Any), i: int, j: int):
    """[1, 3, 3, 1] / 8 along a row, centred between columns 2j and 2j + 1."""
    c = 2 * j
    return (_clamped(img, i, c - 1) + img.dtype(3.0) * (_clamped(img, i, c) + _clamped(img, i, c + 1))
            + _clamped(img, i, c + 2)) * img.dtype(0.125)


@wp.kernel
def _downsample(img: wp.array2d(dtype=typing.Any), out: wp.array2d(dtype=typing.Any), offset: int):
    """One pyramid level: separable [1, 3, 3, 1] / 8 blur, decimated by 2."""
    t = wp.tid() + offset
    i = t // out.shape[1]
    j = t % out.shape[1]
    r = 2 * i
    out[i, j] = (_blur_row(img, r - 1, j) + img.dtype(3.0) * (_blur_row(img, r, j) + _blur_row(img, r + 1, j))
                 + _blur_row(img, r + 2, j)) * img.dtype(0.125)


@wp.kernel
def _upsample_flow(coarse: wp.array3d(dtype=typing.Any), fine: wp.array3d(dtype=typing.Any), offset: int):
    """fine[i, j] = 2 * coarse sampled at ((j + 0.5) / 2, (i + 0.5) / 2), borders replicated."""
    t = wp.tid() + offset
    i = t // fine.shape[1]
    j = t % fine.shape[1]
    half = coarse.dtype(0.5)
    cj, ax = _cell((coarse.dtype(j) + half) * half)
    ci, ay = _cell((coarse.dtype(i) + half) * half)
    hi = coarse.shape[0] - 1
    wi = coarse.shape[1] - 1
    i0 = wp.clamp(ci, 0, hi)
    i1 = wp.clamp(ci + 1, 0, hi)
    j0 = wp.clamp(cj, 0, wi)
    j1 = wp.clamp(cj + 1, 0, wi)
    for k in range(2):
        fine[i, j, k] = coarse.dtype(2.0) * _lerp2(coarse[i0, j0, k], coarse[i0, j1, k], coarse[i1, j0, k],
                                                   coarse[i1, j1, k], ax, ay)


for _k in (_gradients, _lk_step, _downsample, _upsample_flow):
    declare_float_overloads(_k)


# --------------------------------------------------------------------------- input handling


def _frame(a: Inputs, name: str, x: Array) -> wp.array:
    """A grey image (H, W) as a wp.array."""
    return a.floats(name, x, ndim=2, nonempty=True)


def _check_settings(half_window: Any, iterations: Any, min_eigenvalue: Any) -> tuple[int, int, float]:
    return (check_int("half_window", half_window, minimum=1), check_int("iterations", iterations, minimum=1),
            check_float("min_eigenvalue", min_eigenvalue, nonnegative=True))


# --------------------------------------------------------------------------- pieces


def _gradients_wp(img: wp.array, a: Inputs) -> tuple[wp.array, wp.array]:
    ix = a.empty(img.shape)
    iy = a.empty(img.shape)
    a.launch(_gradients, img.size, [img, ix, iy])
    return ix, iy


def _downsample_wp(img: wp.array, a: Inputs) -> wp.array:
    out = a.empty((img.shape[0] // 2, img.shape[1] // 2))
    a.launch(_downsample, out.size, [img, out])
    return out


def _upsample_wp(flow: wp.array, height: int, width: int, a: Inputs) -> wp.array:
    fine = a.empty((height, width, 2))
    a.launch(_upsample_flow, height * width, [flow, fine])
    return fine


def _refine(img1: wp.array, img2: wp.array, flow: wp.array, half_window: int, iterations: int,
            min_eigenvalue: float, a: Inputs) -> tuple[wp.array, wp.array, wp.array]:
    """`iterations` steps (2) at one level, each warping frame 2 with the current flow.

    Every kernel here writes all of its outputs, so the buffers start empty; the steps alternate
    between two flow buffers (never writing the caller's `flow`).
    """
    ix, iy = _gradients_wp(img1, a)
    min_eig = a.empty(img1.shape)
    valid = a.empty(img1.shape, wp.uint8)
    buffers = [a.empty(flow.shape) for _ in range(min(iterations, 2))]
    for k in range(iterations):
        nxt = buffers[k % 2]
        a.launch(_lk_step, img1.size, [img1, ix, iy, img2, flow, nxt, min_eig, valid, half_window,
                                       a.s(min_eigenvalue)])
        flow = nxt
    return flow, min_eig, valid


# --------------------------------------------------------------------------- entry points


def image_gradients(frame: Array, *, device: str | None = None) -> tuple[Array, Array]:
    """(Ix, Iy) of equation (1): derivatives along x (columns) and y (rows)."""
    a = Inputs(device, frame)
    ix, iy = _gradients_wp(_frame(a, "frame", frame), a)
    return a.out(ix), a.out(iy)


def downsample(frame: Array, *, device: str | None = None) -> Array:
    """One pyramid level down: [1, 3, 3, 1] / 8 blur and decimation, (H // 2, W // 2)."""
    a = Inputs(device, frame)
    img = _frame(a, "frame", frame)
    h, w = img.shape
    if h < 2 or w < 2:
        raise ValueError(f"frame: expected at least 2x2 pixels to downsample, got {h}x{w}")
    return a.out(_downsample_wp(img, a))


def upsample_flow(flow: Array, height: int, width: int, *, device: str | None = None) -> Array:
    """Coarse flow (h, w, 2) to (height, width, 2): bilinear at the matching positions, doubled."""
    a = Inputs(device, flow)
    coarse = a.floats("flow", flow, (None, None, 2), nonempty=True)
    height = check_int("height", height, minimum=1)
    width = check_int("width", width, minimum=1)
    if not (height // 2 == coarse.shape[0] and width // 2 == coarse.shape[1]):
        raise ValueError(f"height, width: expected a level whose halves are the flow's {tuple(coarse.shape[:2])}, "
                         f"got {height}x{width}")
    return a.out(_upsample_wp(coarse, height, width, a))


def lucas_kanade(frame1: Array, frame2: Array, *, half_window: int = 3, iterations: int = 1,
                 min_eigenvalue: float = 1e-4, flow_init: Array | None = None,
                 device: str | None = None) -> tuple[Array, Array, Array]:
    """Single-scale LK: `iterations` steps (2) from `flow_init` (zero by default).

    Returns (flow (H, W, 2), valid (H, W) mask, lambda_min (H, W)) in frame1's kind. With the
    defaults this is the one-shot solve of the Video and 3D Vision textbook chapter, 7x7 window.
    """
    half_window, iterations, min_eigenvalue = _check_settings(half_window, iterations, min_eigenvalue)
    a = Inputs(device, frame1, frame2, flow_init)
    img1 = _frame(a, "frame1", frame1)
    img2 = a.floats("frame2", frame2, tuple(img1.shape))
    shape = (*img1.shape, 2)
    flow = a.floats_or_zeros("flow_init", flow_init, shape)
    flow, min_eig, valid = _refine(img1, img2, flow, half_window, iterations, min_eigenvalue, a)
    return a.out(flow), a.out_mask(valid), a.out(min_eig)


def max_levels(height: int, width: int, half_window: int) -> int:
    """The deepest pyramid whose coarsest level still holds one whole window."""
    side = 2 * half_window + 1
    levels = 1
    while (height >> levels) >= side and (width >> levels) >= side:
        levels += 1
    return levels


def pyramidal_lucas_kanade(frame1: Array, frame2: Array, *, levels: int = 3, half_window: int = 3,
                           iterations: int = 5, min_eigenvalue: float = 1e-4,
                           device: str | None = None) -> tuple[Array, Array, Array]:
    """Coarse-to-fine LK (Bouguet): returns (flow (H, W, 2), valid (H, W) mask, lambda_min (H, W)) at full
    size, in frame1's kind.

    `valid` and lambda_min are the finest level's; invalid pixels keep the flow
    carried up from the coarser levels.
    """
    half_window, iterations, min_eigenvalue = _check_settings(half_window, iterations, min_eigenvalue)
    levels = check_int("levels", levels, minimum=1)
    a = Inputs(device, frame1, frame2)
    img1 = _frame(a, "frame1", frame1)
    img2 = a.floats("frame2", frame2, tuple(img1.shape))
    h, w = img1.shape
    deepest = max_levels(h, w, half_window)
    if levels > deepest:
        raise ValueError(f"levels: a {h}x{w} frame with a {2 * half_window + 1}-pixel window allows at most "
                         f"{deepest} levels (the coarsest level must hold one window), got {levels}")
    pyr1, pyr2 = [img1], [img2]
    for _ in range(1, levels):
        for pyr in (pyr1, pyr2):
            pyr.append(_downsample_wp(pyr[-1], a))
    flow = a.zeros((*pyr1[-1].shape, 2))
    for lvl in range(levels - 1, -1, -1):
        if lvl < levels - 1:
            flow = _upsample_wp(flow, *pyr1[lvl].shape, a)
        flow, min_eig, valid = _refine(pyr1[lvl], pyr2[lvl], flow, half_window, iterations, min_eigenvalue, a)
    return a.out(flow), a.out_mask(valid), a.out(min_eig)
