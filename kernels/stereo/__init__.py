"""Stereo matching on rectified pairs: cost volumes, semi-global aggregation, disparity and depth.

Conventions
-----------
Images are single-channel (H, W) float32 or float64 arrays (convert colour first; `bt_cost`
alone also takes colour (H, W, C)); row 0 is the top. The pair is rectified: the left pixel (x, y)
with disparity d matches the right pixel (x - d, y). A disparity range [dmin, dmax) gives
D = dmax - dmin hypotheses d_k = dmin + k, and every cost volume is (H, W, D) with the hypotheses
contiguous:

    C(x, y, k) = cost of matching I_L(x, y) with I_R(x - d_k, y),   lower = better,

except for the feature correlation (a similarity). A cell is *in range* when its right pixel
exists, 0 <= x - d_k < W; out-of-range cells hold a fixed cost no real match can beat.

Stages, one module each
-----------------------
* `costs`: SAD and ZNCC over a window (O(1) per cell from running sums), census + Hamming
  distance, and the feature correlation <F_L(x, y), F_R(x - d_k, y)> / sqrt(C) with its backward.
* `bt`: the Birchfield-Tomasi sampling-insensitive dissimilarity (grey or colour, channel mean),
  window-averaged like SAD.
* `adcensus`: census + BT on the clipped x-Sobel gradient (+ optionally BT on intensity), each term
  squashed by 1 - exp(-c / lambda) and summed: robust to gain, offset and vignetting between cameras
  (its per-image passes in `adcensus_images`, the fused kernel in `adcensus_kernels`, compact mode's
  vector rho in `adcensus_vrho`).
* `sgm`: semi-global matching (Hirschmueller, PAMI 2008), S(p, k) = sum_r L_r(p, k) over 4 or 8
  path directions r, L_r penalising disparity steps by P1 (one step) and P2 (more).
* compact mode: census costs (and adcensus costs quantised, step 1 / compact_levels) as uint8 and
  the SGM aggregate as uint16 (3 bytes per cell instead of float32's 8; on the CPU also the faster
  path, kernels.stereo.sweep).
* `fused`: `sgm_disparity`, SGM + both views' winners + the left-right check in one call.
* `post`: the row fill of invalid pixels and a 3x3 median of the filled map (`fill_median3`).
* `disparity`: winner-take-all with a sub-pixel parabola and a uniqueness test, the right view's
  winner from the same volume, soft-argmin d = sum_k d_k softmax_k(-C / T) with its backward, the
  left-right consistency check, and depth Z = f b / d.

Every module opens with the math it implements.

Arrays
------
Entry points follow the array contract of kernels._arrays: NumPy arrays or wp.arrays in (they may
be mixed; NumPy ones are copied to the device), results in the kind of the first array argument
(masks as bool NumPy, or uint8 wp.arrays), on the `device` argument, else the first wp.array's
device, else the CPU. Every bad argument (mismatched shapes, mixed float dtypes, a disparity
range that is empty or wider than the image, non-finite pixels or costs, a wrong device) raises a
ValueError naming it before any kernel runs. The backward entry points return a dict from the
forward's argument name to its gradient.
"""

from kernels.stereo.adcensus import adcensus_cost, compact_levels, sobel_x_clipped
from kernels.stereo.bt import bt_cost
from kernels.stereo.costs import (CENSUS_MAX_BITS, census_cost, census_transform, feature_correlation,
                                  feature_correlation_backward, sad_cost, zncc_cost)
from kernels.stereo.disparity import (depth_from_disparity, left_right_check, soft_argmin, soft_argmin_backward,
                                      wta, wta_left_right, wta_right)
from kernels.stereo.fused import sgm_disparity
from kernels.stereo.post import fill_median3
from kernels.stereo.sgm import SGM_AXES, SGM_DIRECTIONS, SGM_LANES, sgm

__all__ = [
    "CENSUS_MAX_BITS", "SGM_AXES", "SGM_DIRECTIONS", "SGM_LANES",
    "sad_cost", "zncc_cost", "bt_cost", "adcensus_cost", "compact_levels", "sobel_x_clipped", "census_transform", "census_cost", "feature_correlation",
    "feature_correlation_backward",
    "sgm", "sgm_disparity",
    "wta", "wta_right", "wta_left_right", "soft_argmin", "soft_argmin_backward", "left_right_check",
    "depth_from_disparity", "fill_median3",
]
