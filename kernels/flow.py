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

(The textbook snippet differentiates along rows and calls it Ix: its "u" is the
vertical flow.)

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
wp.arrays (float32 or float64) and return the same kind; bad input raises
ValueError naming the argument before any launch.
"""

from __future__ import annotations

import typing
from typing import Any

import numpy as np
import warp as wp

from kernels.launch import launch_split

wp.set_module_options({"enable_backward": False})

Array = Any  # np.ndarray or wp.array
_SCALAR_OF_NP = {np.dtype(np.float32): wp.float32, np.dtype(np.float64): wp.float64}


# --------------------------------------------------------------------------- kernels


@wp.func
def _clamped(img: wp.array2d(dtype=typing.Any), i: int, j: int):
    return img[wp.clamp(i, 0, img.shape[0] - 1), wp.clamp(j, 0, img.shape[1] - 1)]


@wp.func
def _sample_clamped(img: wp.array2d(dtype=typing.Any), x: typing.Any, y: typing.Any):
    """Bilinear sample at continuous (x, y) (pixel centres at +0.5), borders replicated."""
    u = x - img.dtype(0.5)
    v = y - img.dtype(0.5)
    fu = wp.floor(u)
    fv = wp.floor(v)
    j = int(fu)
    i = int(fv)
    ax = u - fu
    ay = v - fv
    one = img.dtype(1.0)
    top = (one - ax) * _clamped(img, i, j) + ax * _clamped(img, i, j + 1)
    bottom = (one - ax) * _clamped(img, i + 1, j) + ax * _clamped(img, i + 1, j + 1)
    return (one - ay) * top + ay * bottom


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
def _lk_step(
    img1: wp.array2d(dtype=typing.Any),
    ix: wp.array2d(dtype=typing.Any),
    iy: wp.array2d(dtype=typing.Any),
    img2: wp.array2d(dtype=typing.Any),
    flow_in: wp.array3d(dtype=typing.Any),
    flow_out: wp.array3d(dtype=typing.Any),
    min_eig: wp.array2d(dtype=typing.Any),
    valid: wp.array2d(dtype=wp.int32),
    half_window: int,
    min_eigenvalue: typing.Any,
    offset: int,
):
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
        valid[i, j] = 1
    else:
        flow_out[i, j, 0] = du
        flow_out[i, j, 1] = dv
        valid[i, j] = 0


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
    u = (coarse.dtype(j) + half) * half - half
    v = (coarse.dtype(i) + half) * half - half
    fu = wp.floor(u)
    fv = wp.floor(v)
    cj = int(fu)
    ci = int(fv)
    ax = u - fu
    ay = v - fv
    one = coarse.dtype(1.0)
    hi = coarse.shape[0] - 1
    wi = coarse.shape[1] - 1
    i0 = wp.clamp(ci, 0, hi)
    i1 = wp.clamp(ci + 1, 0, hi)
    j0 = wp.clamp(cj, 0, wi)
    j1 = wp.clamp(cj + 1, 0, wi)
    for k in range(2):
        top = (one - ax) * coarse[i0, j0, k] + ax * coarse[i0, j1, k]
        bottom = (one - ax) * coarse[i1, j0, k] + ax * coarse[i1, j1, k]
        fine[i, j, k] = coarse.dtype(2.0) * ((one - ay) * top + ay * bottom)


def _instantiate(kernel: Any) -> None:
    """float32 and float64 overloads declared up front, so the module compiles once."""
    for scalar in (wp.float32, wp.float64):
        types: dict[str, Any] = {}
        for arg in kernel.adj.args:
            if wp.types.is_array(arg.type) and arg.type.dtype is typing.Any:
                types[arg.label] = wp.array(dtype=scalar, ndim=arg.type.ndim)
            elif arg.type is typing.Any:
                types[arg.label] = scalar
        wp.overload(kernel, types)


for _k in (_gradients, _lk_step, _downsample, _upsample_flow):
    _instantiate(_k)


# --------------------------------------------------------------------------- input handling


def _scalar_of(x: Array, name: str) -> Any:
    if isinstance(x, np.ndarray):
        scalar = _SCALAR_OF_NP.get(x.dtype)
    elif isinstance(x, wp.array):
        scalar = x.dtype if x.dtype in (wp.float32, wp.float64) else None
    else:
        raise ValueError(f"{name}: expected a numpy array or a wp.array, got {type(x).__name__}")
    if scalar is None:
        raise ValueError(f"{name}: expected dtype float32 or float64, got {x.dtype}")
    return scalar


def _host(x: Array) -> np.ndarray:
    return x if isinstance(x, np.ndarray) else x.numpy()


class _Frames:
    """Validated frames on one device, plus how to hand results back."""

    def __init__(self, frame1: Array, frame2: Array, device: str | None):
        s1 = _scalar_of(frame1, "frame1")
        s2 = _scalar_of(frame2, "frame2")
        if s2 is not s1:
            raise ValueError(f"frame2: expected dtype {s1.__name__} like frame1, got {s2.__name__}")
        shape1, shape2 = tuple(frame1.shape), tuple(frame2.shape)
        if len(shape1) != 2 or min(shape1) < 1:
            raise ValueError(f"frame1: expected a grey image (H, W) with H, W >= 1, got shape {shape1}")
        if shape2 != shape1:
            raise ValueError(f"frame2: expected the shape of frame1 {shape1}, got {shape2}")
        want = wp.get_device(device) if device is not None else None
        for name, x in (("frame1", frame1), ("frame2", frame2)):
            if isinstance(x, wp.array):
                want = want or x.device
                if x.device != want:
                    raise ValueError(f"{name}: expected an array on device {want}, got one on {x.device}")
            bad = int(np.count_nonzero(~np.isfinite(_host(x))))
            if bad:
                raise ValueError(f"{name}: expected finite intensities, found {bad} NaN or infinite values")
        self.device = want or wp.get_device("cpu")
        self.scalar = s1
        self.as_numpy = isinstance(frame1, np.ndarray)
        self.shape = shape1
        self.img1 = self.to_wp(frame1)
        self.img2 = self.to_wp(frame2)

    def to_wp(self, x: Array) -> wp.array:
        return x if isinstance(x, wp.array) else wp.array(np.ascontiguousarray(x), dtype=self.scalar,
                                                          device=self.device)

    def zeros(self, shape: tuple[int, ...], dtype: Any = None) -> wp.array:
        return wp.zeros(shape, dtype=dtype or self.scalar, device=self.device)

    def launch(self, kernel: Any, dim: int, inputs: list[Any]) -> None:
        launch_split(kernel, dim, inputs, device=self.device)

    def out(self, x: wp.array) -> Array:
        return x.numpy() if self.as_numpy else x


def _check_window(half_window: Any) -> int:
    if not isinstance(half_window, (int, np.integer)) or isinstance(half_window, bool) or half_window < 1:
        raise ValueError(f"half_window: expected an integer >= 1 (window 2 * half_window + 1), got {half_window!r}")
    return int(half_window)


def _check_positive_int(value: Any, name: str) -> int:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
        raise ValueError(f"{name}: expected an integer >= 1, got {value!r}")
    return int(value)


def _check_threshold(min_eigenvalue: Any) -> float:
    try:
        value = float(min_eigenvalue)
    except (TypeError, ValueError):
        raise ValueError(f"min_eigenvalue: expected a finite number >= 0, got {min_eigenvalue!r}") from None
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"min_eigenvalue: expected a finite number >= 0, got {min_eigenvalue!r}")
    return value


def _check_flow(flow: Array, shape: tuple[int, int], frames: _Frames) -> wp.array:
    if _scalar_of(flow, "flow_init") is not frames.scalar:
        raise ValueError(f"flow_init: expected dtype {frames.scalar.__name__} like the frames")
    if tuple(flow.shape) != (*shape, 2):
        raise ValueError(f"flow_init: expected shape {(*shape, 2)} (u, v per pixel), got {tuple(flow.shape)}")
    if not np.all(np.isfinite(_host(flow))):
        raise ValueError("flow_init: expected finite values")
    return frames.to_wp(flow)


# --------------------------------------------------------------------------- pieces


def _gradients_wp(img: wp.array, frames: _Frames) -> tuple[wp.array, wp.array]:
    ix = frames.zeros(img.shape)
    iy = frames.zeros(img.shape)
    frames.launch(_gradients, img.size, [img, ix, iy])
    return ix, iy


def _refine(img1: wp.array, img2: wp.array, flow: wp.array, half_window: int, iterations: int,
            min_eigenvalue: float, frames: _Frames) -> tuple[wp.array, wp.array, wp.array]:
    """`iterations` steps (2) at one level, each warping frame 2 with the current flow."""
    ix, iy = _gradients_wp(img1, frames)
    min_eig = frames.zeros(img1.shape)
    valid = frames.zeros(img1.shape, wp.int32)
    for _ in range(iterations):
        nxt = frames.zeros(flow.shape)
        frames.launch(_lk_step, img1.size, [img1, ix, iy, img2, flow, nxt, min_eig, valid, half_window,
                                            frames.scalar(min_eigenvalue)])
        flow = nxt
    return flow, min_eig, valid


def image_gradients(frame: Array, *, device: str | None = None) -> tuple[Array, Array]:
    """(Ix, Iy) of equation (1): derivatives along x (columns) and y (rows)."""
    frames = _Frames(frame, frame, device)
    ix, iy = _gradients_wp(frames.img1, frames)
    return frames.out(ix), frames.out(iy)


def downsample(frame: Array, *, device: str | None = None) -> Array:
    """One pyramid level down: [1, 3, 3, 1] / 8 blur and decimation, (H // 2, W // 2)."""
    frames = _Frames(frame, frame, device)
    h, w = frames.shape
    if h < 2 or w < 2:
        raise ValueError(f"frame: expected at least 2x2 pixels to downsample, got {h}x{w}")
    out = frames.zeros((h // 2, w // 2))
    frames.launch(_downsample, out.size, [frames.img1, out])
    return frames.out(out)


def upsample_flow(flow: Array, height: int, width: int, *, device: str | None = None) -> Array:
    """Coarse flow (h, w, 2) to (height, width, 2): bilinear at the matching positions, doubled."""
    scalar = _scalar_of(flow, "flow")
    if flow.ndim != 3 or flow.shape[2] != 2 or min(flow.shape) < 1:
        raise ValueError(f"flow: expected shape (h, w, 2), got {tuple(flow.shape)}")
    if not (height // 2 == flow.shape[0] and width // 2 == flow.shape[1]):
        raise ValueError(f"height, width: expected a level whose halves are the flow's {tuple(flow.shape[:2])}, "
                         f"got {height}x{width}")
    dev = wp.get_device(device) if device is not None else (flow.device if isinstance(flow, wp.array)
                                                           else wp.get_device("cpu"))
    coarse = flow if isinstance(flow, wp.array) else wp.array(np.ascontiguousarray(flow), dtype=scalar, device=dev)
    fine = wp.zeros((height, width, 2), dtype=scalar, device=dev)
    launch_split(_upsample_flow, height * width, [coarse, fine], device=dev)
    return fine.numpy() if isinstance(flow, np.ndarray) else fine


def lucas_kanade(frame1: Array, frame2: Array, *, half_window: int = 3, iterations: int = 1,
                 min_eigenvalue: float = 1e-4, flow_init: Array | None = None,
                 device: str | None = None) -> tuple[Array, Array, Array]:
    """Single-scale LK: `iterations` steps (2) from `flow_init` (zero by default).

    Returns (flow (H, W, 2), valid (H, W) bool, lambda_min (H, W)). With the defaults
    this is the textbook's one-shot solve with a 7x7 window.
    """
    frames = _Frames(frame1, frame2, device)
    half_window = _check_window(half_window)
    iterations = _check_positive_int(iterations, "iterations")
    min_eigenvalue = _check_threshold(min_eigenvalue)
    flow = frames.zeros((*frames.shape, 2)) if flow_init is None else _check_flow(flow_init, frames.shape, frames)
    flow, min_eig, valid = _refine(frames.img1, frames.img2, flow, half_window, iterations, min_eigenvalue, frames)
    return frames.out(flow), valid.numpy().astype(bool), frames.out(min_eig)


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
    """Coarse-to-fine LK (Bouguet): returns (flow (H, W, 2), valid (H, W) bool, lambda_min (H, W)) at full size.

    `valid` and lambda_min are the finest level's; invalid pixels keep the flow
    carried up from the coarser levels.
    """
    frames = _Frames(frame1, frame2, device)
    half_window = _check_window(half_window)
    levels = _check_positive_int(levels, "levels")
    iterations = _check_positive_int(iterations, "iterations")
    min_eigenvalue = _check_threshold(min_eigenvalue)
    h, w = frames.shape
    deepest = max_levels(h, w, half_window)
    if levels > deepest:
        raise ValueError(f"levels: a {h}x{w} frame with a {2 * half_window + 1}-pixel window allows at most "
                         f"{deepest} levels (the coarsest level must hold one window), got {levels}")
    pyr1, pyr2 = [frames.img1], [frames.img2]
    for _ in range(1, levels):
        for pyr in (pyr1, pyr2):
            out = frames.zeros((pyr[-1].shape[0] // 2, pyr[-1].shape[1] // 2))
            frames.launch(_downsample, out.size, [pyr[-1], out])
            pyr.append(out)
    flow = frames.zeros((*pyr1[-1].shape, 2))
    for lvl in range(levels - 1, -1, -1):
        if lvl < levels - 1:
            fine = frames.zeros((*pyr1[lvl].shape, 2))
            frames.launch(_upsample_flow, pyr1[lvl].size, [flow, fine])
            flow = fine
        flow, min_eig, valid = _refine(pyr1[lvl], pyr2[lvl], flow, half_window, iterations, min_eigenvalue, frames)
    return frames.out(flow), valid.numpy().astype(bool), frames.out(min_eig)
