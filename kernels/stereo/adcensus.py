"""A matching cost for real camera pairs: census + Birchfield-Tomasi on a clipped x-gradient (+ intensity).

Real pairs differ in gain, offset and vignetting between the cameras, which an intensity cost
(SAD, BT) reads as mismatch. This cost combines terms that are robust to those differences, each
squashed to [0, 1) by rho(c, lambda) = 1 - exp(-c / lambda) before they are summed, as AD-Census does
(Mei et al., ICCV Workshops 2011), so that no term dominates by its units and one outlying term
cannot exceed its weight:

    C(x, y, d) = rho(C_census, l_census) + rho(C_grad, l_grad) + w_bt rho(C_bt, l_bt).

* C_census: the Hamming distance of census bit strings (kernels.stereo.costs.census_cost) over a
  (2 ry + 1) x (2 rx + 1) window of the grey images; invariant to any monotonic intensity change
  (gain, offset, gamma); l_census in bits. With a tolerance census_eps > 0 (in [0, 1] intensity units)
  the bit is [I(q) < I(p) - eps]: on a flat, noisy surface (a textureless wall) every bit is then 0
  in both views instead of a coin toss, so the term is flat there; still invariant to an offset, not
  to gain (it did not improve drlab's tuning pairs, research.stereo; off by default).
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

Launches: the census bit strings of each grey image (one uint64 per pixel, computed once;
kernels.stereo.costs.census_transform), the gradient images, each term image's half-pixel ranges
(I_min, I_max) of the BT dissimilarity, a table rho(h, l_census) for every Hamming distance h, then ONE
fused launch that writes the final cost: a thread owns a band of rows and keeps, per BT term, a ring
of the 2 r + 1 rows of per-pixel bt values its window needs (each row computed once per band) and
their row sums; for every cell it adds rho(popcount(c_L xor c_R)) from the table and the two terms'
rho(window mean). The sums and rho run in the images' float type in the order of the separate passes
(kernels.stereo.bt's, then the terms added in order), so the volume is bit-identical to the former
composition of census_cost, bt_cost and one rho-accumulation pass per term. No (H, W, D) volume besides the
result exists; the band buffers hold 2 (2 r + 2) W D' values per band (D' = D rounded up to whole vectors).

The kernels: the per-image passes (the gradient, the census with a tolerance, the half-pixel ranges,
the rho table, the mirrored rows) are in kernels.stereo.adcensus_images, the fused kernel and its
vector form (the hypotheses of a pixel in vectors of 16 float32 or 8 float64 lanes, bit for bit the
scalar loop) in kernels.stereo.adcensus_kernels, the vector rho of compact mode in
kernels.stereo.adcensus_vrho; this module checks the arguments and launches them.

Compact mode (`levels` = q > 0, float32 images): the cost is stored as the uint8 round(C q), with
q <= 255 / (2 + w_bt) so that every cost (< 2 + w_bt) fits; the quantisation step is 1 / q
(compact_levels(0.3) = 110: a step of 0.0091, at most 0.0045 off), a quarter of float32's memory,
and the volume kernels.stereo.sgm's compact mode takes with integer penalties P q.

Vector rho (compact mode with `vector_rho`, float32 on the CPU; research.stereo.matching's DEFAULT_CONFIG runs it): the
two BT terms' rho on 16 lanes by a degree-8 polynomial and 5 squarings (kernels.stereo.adcensus_vrho), within
about 2e-5 of 1 - exp(-z): a cell's uint8 value can differ from the scalar-exp volume's by one level near a half
level (2.8e-6 of the cells at 741x500x64 on the bench pair; tests bound it).
"""

from __future__ import annotations

import math
from typing import Any

import warp as wp

from kernels._arrays import Inputs, check_float, check_int
from kernels.launch import default_threads
from kernels.stereo._common import check_range, grey_or_colour_pair, image_pair
from kernels.stereo.adcensus_images import (_census_eps, _half_ranges, _reverse_planar, _rho_table,
                                            _robust_term, sobel_x_clipped)
from kernels.stereo.adcensus_kernels import LANES, VEC, _V32, _fused_cost, _rho_lanes
from kernels.stereo.adcensus_vrho import U8_VEC, _fused_cost_vrho
from kernels.stereo.costs import _census_radii, census_transform

# _V32, _rho_lanes and _robust_term are imported from here by tests/kernels/test_vexp.py and test_fast_paths.py.
__all__ = ["adcensus_cost", "compact_levels", "sobel_x_clipped", "_V32", "_rho_lanes", "_robust_term"]


def _vector_view(flat: wp.array, lanes: int) -> wp.array:
    """Vectors of `lanes` consecutive scalars of `flat` starting at any scalar (unaligned, strides of one scalar)."""
    item = wp.types.type_size_in_bytes(flat.dtype)
    return wp.array(ptr=flat.ptr, dtype=VEC[flat.dtype], shape=(flat.shape[0] - lanes + 1,), strides=(item,),
                    device=flat.device)


def compact_levels(bt_weight: float) -> int:
    """Quantisation levels per unit cost of compact mode: the largest q with q (2 + bt_weight) <= 255, so every
    cost (< 2 + bt_weight) fits a uint8 as round(C q)."""
    return int(255 // (2.0 + float(bt_weight)))



def adcensus_cost(left: Any, right: Any, dmin: int, dmax: int, *, grey: tuple[Any, Any] | None = None,
                  census_radii: tuple[int, int] = (3, 4), radius: int = 2, grad_cap: float = 0.25,
                  lambda_census: float = 30.0, lambda_grad: float = 0.04, bt_weight: float = 0.0,
                  lambda_bt: float = 0.04, census_eps: float = 0.0, levels: int = 0, vector_rho: bool = False,
                  device: Any = None) -> Any:
    """The combined cost volume (H, W, dmax - dmin) of the module docstring.

    `left`, `right`: grey (H, W) or colour (H, W, C) float images in [0, 1] (the gradient and BT terms);
    `grey`: the (left, right) grey images the census term reads, required for colour input (grey input
    is its own grey image). `radius`: the window radius of the BT terms. `census_eps` >= 0: the census
    tolerance (module docstring; 0 is the plain census transform). `levels` > 0 (compact mode): the
    cost as uint8 round(C levels), at most compact_levels(bt_weight) levels per unit (float32 images).
    `vector_rho` (compact mode on the CPU only): the BT terms' rho on 16 lanes by a polynomial (module docstring:
    Vector rho), not bit-identical to the scalar exp's volume: a cell may differ by one level.
    """
    a = Inputs(device, left, right)
    l_img, r_img, ndim = grey_or_colour_pair(a, left, right)
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
    r = check_int("radius", radius, minimum=0)
    census_eps = check_float("census_eps", census_eps, nonnegative=True)
    levels = check_int("levels", levels, minimum=0)
    if levels and levels * (2.0 + bt_weight) > 255:
        raise ValueError(f"levels: expected at most {compact_levels(bt_weight)} levels per unit so that every cost "
                         f"(< 2 + bt_weight = {2 + bt_weight:g}) fits a uint8, got {levels}")
    if levels and a.scalar != wp.float32:
        raise ValueError("levels: compact mode (levels > 0) takes float32 images")
    if not isinstance(vector_rho, bool):
        raise ValueError(f"vector_rho: expected True or False, got {vector_rho!r}")
    if vector_rho and not (levels and a.device.is_cpu):
        raise ValueError("vector_rho: only compact mode (levels > 0) on the CPU takes the vector rho")
    ry, rx, bits = _census_radii(*census_radii)
    dmin, D = check_range(dmin, dmax, W)
    if census_eps > 0:
        cl, cr = a.empty((H, W), wp.uint64), a.empty((H, W), wp.uint64)
        a.launch(_census_eps, H * W, [g_l, cl, ry, rx, wp.float64(census_eps)], min_chunk=1024)
        a.launch(_census_eps, H * W, [g_r, cr, ry, rx, wp.float64(census_eps)], min_chunk=1024)
    else:
        cl = census_transform(g_l, ry, rx, device=a.device)
        cr = census_transform(g_r, ry, rx, device=a.device)
    rho_census = a.empty((bits + 1,))
    a.launch(_rho_table, bits + 1, [rho_census, wp.float64(lambda_census)])
    src = l_img if ndim == 3 else l_img.contiguous().reshape((H, W, 1))
    dst = r_img if ndim == 3 else r_img.contiguous().reshape((H, W, 1))
    terms = [sobel_x_clipped(src, grad_cap, device=a.device), sobel_x_clipped(dst, grad_cap, device=a.device)]
    if bt_weight > 0:
        terms += [src, dst]
    scalar = a.scalar
    lanes = LANES[scalar]
    nb = -(-D // lanes)
    pad = lanes  # the mirrored rows' margins: a vector holding one in-range cell reads at most lanes - 1 beyond
    row = W + 2 * pad
    images, invalid, keep = [], [], []  # keep: the mirrored arrays the vector views (no owners) point into
    for j, img in enumerate(terms):
        lo, hi = a.empty(img.shape), a.empty(img.shape)
        a.launch(_half_ranges, H, [img, lo, hi], min_chunk=8)
        if j % 2:  # right images: mirrored planar rows, read as vectors over d (kernels' _fill_row)
            views = []
            for arr in (img, lo, hi):
                flat = a.zeros((img.shape[2] * H * row,))
                a.launch(_reverse_planar, H, [arr, flat, row, pad], min_chunk=8)
                keep.append(flat)
                views.append(_vector_view(flat, lanes))
            images += views
            # the term's out-of-range cost: the range of both images' values (kernels.stereo.bt)
            lh, rh = terms[j - 1].numpy(), img.numpy()
            invalid.append(float(max(lh.max(), rh.max())) - float(min(lh.min(), rh.min())))
        else:
            images += [img, lo, hi]
    if bt_weight == 0:  # unused stand-ins for the intensity term's arrays
        images += images[:6]
        invalid.append(0.0)
    # Bands of rows: at least 4 (r + 1) rows, so the 2 r rows each band's ring starts with add under half its
    # work and all buffers together never exceed one float volume; on the CPU, fewer and longer bands where
    # 4 per thread balance the threads.
    band = 4 * (r + 1) if a.device.is_cuda else max(4 * (r + 1), math.ceil(H / (4 * default_threads())))
    n_bands = math.ceil(H / band)
    vec = VEC[scalar]
    # zeros: the lanes past the in-range cells stay finite (never read, but summed alongside)
    ring_v = wp.zeros((2 * n_bands * (2 * r + 1) * W * nb,), dtype=vec, device=a.device)
    rowsum = a.zeros((2 * n_bands * W * nb * lanes,))
    rowsum_v = wp.array(ptr=rowsum.ptr, dtype=vec, shape=(2 * n_bands * W * nb,), device=a.device)
    out = a.empty((H, W, D), wp.uint8 if levels else None)
    if vector_rho:
        out_v = wp.array(ptr=out.ptr, dtype=U8_VEC, shape=(H * W * D - lanes + 1,), strides=(1,), device=a.device)
        f32 = wp.float32
        a.launch(_fused_cost_vrho, n_bands,
                 [cl, cr, rho_census, *images, ring_v, rowsum, rowsum_v, out, out_v, dmin, r, band, bits, row, pad,
                  f32(1.0 / lambda_grad), f32(invalid[0]), f32(bt_weight), f32(1.0 / lambda_bt), f32(invalid[1]),
                  f32(levels)], min_chunk=1)
        return a.out(out)
    a.launch(_fused_cost, n_bands, [cl, cr, rho_census, *images, ring_v, rowsum, rowsum_v, out, dmin, r, band, bits,
                                    lanes, row, pad, wp.float64(lambda_grad), wp.float64(invalid[0]),
                                    wp.float64(bt_weight), wp.float64(lambda_bt), wp.float64(invalid[1]),
                                    wp.float64(levels)], min_chunk=1)
    return a.out(out)
