"""3D Gaussian splatting: projection, tile binning, rasterisation and their adjoints.

Follows Kerbl et al., "3D Gaussian Splatting for Real-Time Radiance Field Rendering" (SIGGRAPH
2023), with the EWA splatting of Zwicker et al. (2002) and, optionally, the antialiasing
compensation of Yu et al., "Mip-Splatting" (CVPR 2024) as gsplat's rasterize_mode="antialiased"
has it.

Parameters of Gaussian i: mean mu (3), log-scales l (3), quaternion q = (w, x, y, z)
(normalised here), opacity logit a, SH coefficients f (K = (L+1)^2, 3), L <= 3. Camera:
world-to-camera [W | t] (OpenCV axes), intrinsics fx, fy, cx, cy, image W_img x H_img.

The chain, one module per stage:

    projection.py  Sigma = R S S^T R^T, p = W mu + t, EWA: mean2d, Sigma2d = J W Sigma W^T J^T
                   + 0.3 I, conic Q = Sigma2d^-1, radius, colour = max(0, sum_k f_k Y_k(d) + 1/2),
                   opacity sigmoid(a) (times Mip-Splatting's compensation); the per-splat math and
                   its VJPs live in ewa.py, the SH basis in kernels/sh.py, the Warp kernels in
                   projection_kernels.py
    tiles.py       16 x 16 pixel tiles: each splat listed in the tiles its alpha >= 1/255 region
                   meets, sorted by tile then depth (a radix sort by depth, then a counting sort
                   by tile on the CPU, a radix sort on CUDA); each splat's pixel spans (spans.py)
    raster.py      per pixel, front to back: alpha_i = min(0.99, o_i G_i), T_{i+1} = T_i (1 - alpha_i),
                   rgb = sum_i c_i alpha_i T_i + T_final background, stopping at T < 1e-4
                   (in the default mode; "gsplat": 0.999 and <= 1e-4); the Warp kernels in
                   raster_kernels.py
    render.py      the whole chain for one camera and its VJP
    depth.py       median depth (2DGS: the z where the transmittance first crosses 1/2) and
                   expected depth D / A, with their backward
    normals.py     each splat's shortest-axis normal (PGSR) and normals from a depth map (central
                   differences of the back-projected depth), with their backward

Two conventions (`mode=`, every projecting or rasterising entry point; kernels/splat/modes.py has
the full table): "3dgs", the default, follows the original 3DGS code (graphdeco-inria's
diff-gaussian-rasterization): Jacobian clamp |x/z| <= 1.3 W / (2 fx), radius floor 0.1, its
getRect tile rule, alpha clamp 0.99, stop when T (1 - alpha) < 1e-4, and its `antialiasing`
option as `antialiased=True`. "gsplat" follows gsplat: clamp x/z to [-cx/fx - 0.15 W/fx,
(W - cx)/fx + 0.15 W/fx], radius floor 0.01, its tile rule, alpha clamp 0.999, stop when
T (1 - alpha) <= 1e-4, and its rasterize_mode="antialiased" as `antialiased=True`. Both dilate
Sigma2d by 0.3 I (the entry points' `dilation` replaces 0.3) and skip alpha < 1/255.

The rasteriser's backward can also return AbsGS's densification statistic (`absgrad=True`: per
splat, the sum over pixels of |each pixel's term of dL/dmean2d|, per component; raster.py).

Every backward is written by hand; each module's docstring gives its math. Non-smooth points,
where gradients are one-sided: the 1/255 skip, the alpha clamp, the T stop, the colour
clamp at 0, the Jacobian's frustum clamp, the ceil of the radius and a change of tile set or depth
order. The gradient here is the one of the smooth piece the inputs lie on.

Camera gradients (the API pose refinement and SLAM call). `render_backward(g, result, grad_rgb,
grad_alpha, grad_depth, want_camera=True)` adds to the splats' gradients

    "pose"        (6,) dL/dxi at xi = 0 for the LEFT perturbation of world-to-camera,
                  viewmat <- exp(xi^) viewmat, xi = (rho, phi): translation first, both in the
                  camera frame (kernels/splat/camera.py: se3_exp, SplatCamera.perturbed);
    "intrinsics"  (4,) dL/d(fx, fy, cx, cy),

for any cotangents of the image, the alpha (silhouette) and the depth output (depth / alpha is
the expected z-depth; research.splats.loss.depth_loss is a masked depth loss on it). A gradient
step on the pose is `camera.perturbed(-lr * grads["pose"])`. The math: the projection's backward
already has dL/dp and dL/dSigma_c of every splat's camera-frame mean and covariance; with
p <- p + phi x p + rho and Sigma_c <- Sigma_c + [phi]x Sigma_c + Sigma_c [phi]x^T to first order,

    dL/drho = sum_i (dL/dp_i + W dL/dmu_i|view),   dL/dphi = sum_i (p_i x dL/dp_i + (M21 - M12,
    M02 - M20, M10 - M01)_i),   M_i = (G_i + G_i^T) Sigma_c,i,  G_i = dL/dSigma_c,i,

where dL/dmu|view is the SH colour's view-direction term (the camera centre -W^T t moves by
-W^T rho and not with phi); the intrinsics' terms are kernels/splat/ewa.py's
`persp_intrinsics_vjp` (mean2d, the Jacobian, and the clamp's limits, which move with cx in
"gsplat" mode). Each splat's thread writes its own row of these ten numbers and the rows are summed
afterwards, so the split CPU launch is race-free (docs/warp.md, section 2). Every term is checked
against float64 finite differences (research/checks/splat.py, `drlab gradcheck splat`).

Arrays follow kernels/_arrays.py: entry points take NumPy arrays or wp.arrays (float32 or
float64, all one dtype), run on the device of the wp.arrays (or the `device` argument, else the
CPU), and return results of the kind of the first array argument. `gaussian_inputs` and
`splats_2d` check the inputs once and remember that kind; bad input raises ValueError naming the
argument before any launch. All kernels are generic over float32 and float64.
"""

from kernels.sh import SH_C0
from kernels.splat.camera import DEFAULT_FAR, DEFAULT_NEAR, SplatCamera, se3_exp
from kernels.splat.ewa import DILATION
from kernels.splat.modes import ALPHA_MAX_OF, DEFAULT_MODE, DILATION_OF, MODES, RADIUS_FLOOR_OF, dilation_of
from kernels.splat.projection import GaussianInputs, Projection, gaussian_inputs, project, project_backward
from kernels.splat.raster import ALPHA_MAX, ALPHA_MIN, T_MIN, Raster, rasterize, rasterize_backward
from kernels.splat.render import Render, render, render_backward
from kernels.splat.tiles import TILE, TILE_PIXELS, Splats2D, Tiles, bin_tiles, splats_2d

__all__ = [
    "ALPHA_MAX", "ALPHA_MAX_OF", "ALPHA_MIN", "DEFAULT_MODE", "MODES", "RADIUS_FLOOR_OF", "DEFAULT_FAR",
    "DEFAULT_NEAR", "DILATION", "DILATION_OF", "SH_C0", "TILE", "TILE_PIXELS", "T_MIN",
    "GaussianInputs", "Projection", "Raster", "Render", "SplatCamera", "Splats2D", "Tiles",
    "bin_tiles", "dilation_of", "gaussian_inputs", "project", "project_backward", "rasterize", "rasterize_backward",
    "render", "render_backward", "se3_exp", "splats_2d",
]
