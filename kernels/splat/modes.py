"""The two reference conventions the splatting kernels follow: `mode="3dgs"` (the default) and `"gsplat"`.

Every entry point of kernels/splat that projects or rasterises takes `mode`. Each mode reproduces
one reference implementation's forward exactly (its equations, thresholds and tile rule), and the
backward is the gradient of that forward (kernels/reference/splat.py writes both modes in NumPy):

                        "3dgs" (graphdeco-inria's             "gsplat" (nerfstudio's gsplat:
                        diff-gaussian-rasterization:          persp_proj, fully_fused_projection,
                        computeCov2D, preprocessCUDA,          isect_tiles, rasterize_to_pixels)
                        renderCUDA)
    Jacobian clamp      |x/z| <= 1.3 tan_fovx,                 -cx/fx - 0.3 tan_fovx <= x/z
                        tan_fovx = W / (2 fx)                    <= (W - cx)/fx + 0.3 tan_fovx
                        (symmetric about the principal point)   (y/z likewise with fy, cy, H)
    dilation s          Sigma2d + 0.3 I                        Sigma2d + 0.3 I
                        (the entry points' `dilation` replaces s; default None keeps 0.3)
    radius              ceil(3 sqrt(h + sqrt(max(0.1,          ceil(3 sqrt(h + sqrt(max(0.01,
                        h^2 - det))))                          h^2 - det))))
    tiles of a splat    3DGS's getRect on pixel centres at     floor((u - r)/16) <= tx <
                        integers: floor((u - 1/2 - r)/16)      ceil((u + r)/16) (rows likewise)
                        <= tx < floor((u - 1/2 + r + 15)/16)
    culled when         that rectangle is empty                the square u +- r, v +- r misses the image
    alpha               min(0.99, o G)                         min(0.999, o G)
    skipped when        alpha < 1/255 (or G's exponent > 0)    alpha < 1/255 (or G's exponent > 0)
    stop                before a splat with T (1 - alpha)      before a splat with T (1 - alpha)
                        < 1e-4 (it is not blended)             <= 1e-4 (it is not blended)
    antialiased=True    o sqrt(max(2.5e-5, det0 / det))        o sqrt(max(0, det0 / det))
                        (3DGS's `antialiasing` option)         (rasterize_mode="antialiased")

with u, v the splat's 2D mean in drlab's pixel coordinates (pixel (i, j) has its centre at
(i + 1/2, j + 1/2), as in gsplat; 3DGS puts centres at integers, so its getRect, written here in
drlab's coordinates, carries the 1/2 shift), h = (a1 + c1) / 2 and det of the dilated Sigma2d.
The two clamps agree when cx = W/2. Both codes cull z-depths outside [near, far] as SplatCamera
sets them; 3DGS itself hard-codes near = 0.2 (`in_frustum`, z <= 0.2 culled) and gsplat defaults to
0.01, SplatCamera's default. 3DGS divides by w + 1e-7 in its projection matrix; drlab divides by z
exactly (a relative difference of 1e-7 / z in mean2d).

The radius floor changes which tiles list a splat, and so, in both codes, which pixels blend it:
a nearly isotropic splat whose 3 sqrt(lambda) lies just below an integer gets a radius 1 px larger
with the floor 0.1 than with 0.01, and pixels at 3-3.2 sigma (alpha up to 0.011 o > 1/255) in the
tiles only the larger square meets then blend it (tests/kernels/test_splat_modes.py shows one).
"""

from __future__ import annotations

import math
import numbers

MODES = ("3dgs", "gsplat")
DEFAULT_MODE = "3dgs"
# Per mode: the alpha clamp and the floor of the eigenvalue term of the radius (module docstring).
ALPHA_MAX_OF = {"3dgs": 0.99, "gsplat": 0.999}
RADIUS_FLOOR_OF = {"3dgs": 0.1, "gsplat": 0.01}
# Per mode: the low-pass dilation s (px^2) added to every projected covariance (kernels/splat/ewa.py).
DILATION_OF = {"3dgs": 0.3, "gsplat": 0.3}


def mode_id(mode: str) -> int:
    """The kernels' integer for `mode` (0 = "3dgs", 1 = "gsplat"); ValueError naming the argument otherwise."""
    if not isinstance(mode, str) or mode not in MODES:
        raise ValueError(f"mode: expected one of {', '.join(repr(m) for m in MODES)}, got {mode!r}")
    return MODES.index(mode)


def dilation_of(mode: str, dilation: float | None, antialiased: bool = False) -> float:
    """The low-pass dilation (px^2) to use: `dilation`, or the mode's (DILATION_OF) when it is None.

    ValueError naming the argument unless it is a finite number >= 0, and > 0 with `antialiased`: the
    compensation sqrt(det0 / det) compares the covariance before and after the dilation, so with s = 0 it
    is 1 and `antialiased` would silently do nothing."""
    mode_id(mode)
    if dilation is None:
        return DILATION_OF[mode]
    if isinstance(dilation, bool) or not isinstance(dilation, numbers.Real) or not math.isfinite(dilation) \
            or dilation < 0:
        raise ValueError(f"dilation: expected a finite number >= 0 (px^2) or None, got {dilation!r}")
    if antialiased and dilation == 0:
        raise ValueError("dilation: expected > 0 with antialiased=True (the compensation sqrt(det0 / det) is 1 "
                         "without a dilation), got 0")
    return float(dilation)
