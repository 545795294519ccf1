"""A matching cost for real camera pairs: census + Birchfield-Tomasi on a clipped x-gradient (+ intensity).

Real pairs differ in gain, offset and vignetting between the cameras, which an intensity cost
(SAD, BT) reads as mismatch. This cost combines terms that are robust to those differences, each
squashed to [0, 1) by rho(c, lambda) = 1 - exp(-c / lambda) before they are summed, as AD-Census does
(Mei et al., ICCV Workshops 2011), so that no term dominates by its units and one outlying term
cannot exceed its weight:

    C(x, y, d) = rho(C_census, l_census) + rho(C_grad, l_grad) + w_bt rho(C_bt, l_bt).

* C_census: the Hamming distance of census bit strings (kernels.stereo.costs.census_cost) over a
  (2 ry + 1) x (2 rx + 1) window of the grey images; invariant to any monotonic intensity change
  (gain, offset, gamma); l_census in bits.
* C_grad: the Birchfield-Tomasi window mean (kernels.stereo.bt) on the images' clipped x-gradient,
  StereoSGBM's prefilter. Per channel c of an image I in [0, 1] (rows clamped at the border),

      g(x, y) = sum_{dy in -1..1} w_dy (I(x + 1, y + dy) - I(x - 1, y + dy)),  w = (1, 2, 1),
      G(x, y) = (clip(g, -cap, cap) + cap) / (2 cap)  in [0, 1],

  (columns clamped too), the x-Sobel filter; it does not see an intensity offset, and the clip
  bounds what a gain change can do to strong edges. l_grad in units of G, i.e. fractions of the
  clipped gradient range 2 cap.
* C_bt: the Birchfield-Tomasi window mean on the intensities (grey or the channel mean of colour),
  with weight w_bt (0 drops it); l_bt in [0, 1] intensity units.

Every term is independent of the stored image range once the images are in [0, 1] (research.images'
normalisation). Each term's out-of-range cells (x - d outside [0, W)) hold its own maximum (census:
the bit count; BT: the value range), so the sum's out-of-range cost is at least every in-range one.

Launches: the gradient image (one thread per pixel), then for each term its cost volume and one
accumulation C += w rho(c, lambda) (one thread per pixel, over its D hypotheses).
"""

from __future__ import annotations

import typing
from typing import Any

import warp as wp

from kernels._arrays import Inputs, check_float, declare_float_overloads
from kernels.stereo._common import check_range, image_pair, pixel
from kernels.stereo.bt import bt_cost
from kernels.stereo.costs import _census_radii, census_cost

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _sobel_x(img: wp.array3d(dtype=typing.Any), out: wp.array3d(dtype=typing.Any), cap: wp.float64,
             offset: int):
    H = img.shape[0]
    W = img.shape[1]
    y, x = pixel(wp.tid() + offset, W)
    xm = wp.max(x - 1, 0)
    xp = wp.min(x + 1, W - 1)
    ym = wp.max(y - 1, 0)
    yp = wp.min(y + 1, H - 1)
    c_ = img.dtype(cap)
    two = img.dtype(2.0)
    for c in range(img.shape[2]):
        g = (img[ym, xp, c] - img[ym, xm, c]) + two * (img[y, xp, c] - img[y, xm, c]) + (img[yp, xp, c] - img[yp, xm, c])
        g = wp.min(wp.max(g, -c_), c_)
        out[y, x, c] = (g + c_) / (two * c_)


@wp.kernel
def _robust_add(src: wp.array3d(dtype=typing.Any), acc: wp.array3d(dtype=typing.Any), lam: wp.float64,
                weight: wp.float64, first: int, offset: int):
    y, x = pixel(wp.tid() + offset, src.shape[1])
    inv = acc.dtype(wp.float64(1.0) / lam)
    w = acc.dtype(weight)
    for k in range(src.shape[2]):
        term = w * (acc.dtype(1.0) - wp.exp(-acc.dtype(src[y, x, k]) * inv))
        if first != 0:
            acc[y, x, k] = term
        else:
            acc[y, x, k] = acc[y, x, k] + term


for _kernel in (_sobel_x, _robust_add):
    declare_float_overloads(_kernel)


def sobel_x_clipped(image: Any, cap: float = 0.25, *, device: Any = None) -> Any:
    """G = (clip(Sobel_x I, -cap, cap) + cap) / (2 cap) per channel (module docstring), same shape as `image`."""
    a = Inputs(device, image)
    ndim = len(getattr(image, "shape", ()))
    if ndim not in (2, 3):
        raise ValueError(f"image: expected a grey (H, W) or colour (H, W, C) image, got shape "
                         f"{tuple(getattr(image, 'shape', ()))}")
    img = a.floats("image", image, ndim=ndim, nonempty=True)
    cap = check_float("cap", cap, positive=True)
    H, W = img.shape[:2]
    src = img.contiguous().reshape((H, W, 1)) if ndim == 2 else img
    out = a.empty(src.shape)
    a.launch(_sobel_x, H * W, [src, out, wp.float64(cap)], min_chunk=1024)
    return a.out(out.reshape((H, W)) if ndim == 2 else out)


def adcensus_cost(left: Any, right: Any, dmin: int, dmax: int, *, grey: tuple[Any, Any] | None = None,
                  census_radii: tuple[int, int] = (3, 4), radius: int = 2, grad_cap: float = 0.25,
                  lambda_census: float = 30.0, lambda_grad: float = 0.04, bt_weight: float = 0.0,
                  lambda_bt: float = 0.04, device: Any = None) -> Any:
    """The combined cost volume (H, W, dmax - dmin) of the module docstring.

    `left`, `right`: grey (H, W) or colour (H, W, C) float images in [0, 1] (the gradient and BT terms);
    `grey`: the (left, right) grey images the census term reads, required for colour input (grey input
    is its own grey image). `radius`: the window radius of the BT terms.
    """
    a = Inputs(device, left, right)
    ndim = len(getattr(left, "shape", ()))
    if ndim not in (2, 3):
        raise ValueError(f"left: expected a grey (H, W) or colour (H, W, C) image, got shape "
                         f"{tuple(getattr(left, 'shape', ()))}")
    l_img, r_img = image_pair(a, left, right, ndim)
    H, W = l_img.shape[:2]
    check_range(dmin, dmax, W)
    _census_radii(*census_radii)
    if grey is None:
        if ndim == 3:
            raise ValueError("grey: expected the (left, right) grey images for the census term of colour input")
        g_l, g_r = l_img, r_img
    else:
        if not (isinstance(grey, (tuple, list)) and len(grey) == 2):
            raise ValueError(f"grey: expected a (left, right) pair of grey images, got {type(grey).__name__}")
        g_l, g_r = image_pair(a, grey[0], grey[1], 2, names=("grey[0]", "grey[1]"))
        if tuple(g_l.shape) != (H, W):
            raise ValueError(f"grey[0]: expected shape ({H}, {W}) like left, got {tuple(g_l.shape)}")
    for name, value in (("grad_cap", grad_cap), ("lambda_census", lambda_census), ("lambda_grad", lambda_grad),
                        ("lambda_bt", lambda_bt)):
        check_float(name, value, positive=True)
    bt_weight = check_float("bt_weight", bt_weight, nonnegative=True)

    total = a.empty((H, W, dmax - dmin))
    census = census_cost(g_l, g_r, dmin, dmax, *census_radii, device=a.device)
    a.launch(_robust_add, H * W, [census, total, wp.float64(lambda_census), wp.float64(1.0), 1], min_chunk=256)
    del census
    gl, gr = sobel_x_clipped(l_img, grad_cap, device=a.device), sobel_x_clipped(r_img, grad_cap, device=a.device)
    grad = bt_cost(gl, gr, dmin, dmax, radius, device=a.device)
    a.launch(_robust_add, H * W, [grad, total, wp.float64(lambda_grad), wp.float64(1.0), 0], min_chunk=256)
    del grad
    if bt_weight > 0:
        bt = bt_cost(l_img, r_img, dmin, dmax, radius, device=a.device)
        a.launch(_robust_add, H * W, [bt, total, wp.float64(lambda_bt), wp.float64(bt_weight), 0], min_chunk=256)
    return a.out(total)
