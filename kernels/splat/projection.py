"""Projection of 3D Gaussians into a camera, and its hand-written backward.

Per splat i with mean mu, log-scales l, quaternion q (normalised here), opacity logit a and SH
coefficients f (K = (L+1)^2, 3), for the world-to-camera [W | t] and intrinsics fx, fy, cx, cy:

    Sigma = R(q/|q|) S S^T R^T,  S = diag(exp l)                      (ewa.quat_scale_to_covar)
    p = W mu + t = (x, y, z);  culled if z < near or z > far
    mean2d, Sigma2d = EWA projection of (p, W Sigma W^T)               (ewa.persp_proj)
    (a1, b, c1) = Sigma2d + s I  (the low-pass dilation s, 0.3 px^2 by default); culled if det <= 0
    conic Q = (a1, b, c1)^-1 stored as (Q00, Q01, Q11)                 (ewa.conic_inverse)
    radius = ceil(3 sqrt(lambda_max)),  lambda_max = h + sqrt(max(f, h^2 - det)), h = (a1 + c1)/2,
        f = 0.1 ("3dgs") or 0.01 ("gsplat"); culled when the mode's tile rectangle of the square
        mean2d +- radius is empty ("3dgs") or the square misses the image ("gsplat") (radius 0
        marks a culled splat, whose other outputs are 0)
    stored radius = min(radius, reach),  reach = 2 max(|u|, |u - W|, |v|, |v - H|) + 16 for
        mean2d = (u, v) and a W x H image                                (clamp_radius)

`mode` ("3dgs", the default, or "gsplat") selects the reference code followed: the Jacobian's
frustum clamp, the radius floor f, the culling rule and the antialiasing floor
(kernels/splat/modes.py has the table, kernels/splat/ewa.py the clamp's formulas).

The radius clamp. The radius is only a culling flag (> 0) and the half-size of the square a splat
is binned with (kernels/splat/tiles.py clamps that square to the image's tiles); the rasteriser
reads the conic, never the radius. Any square mean2d +- r with r >= reach contains the whole
image, so clamping to reach changes neither the culling nor the tiles nor any pixel or gradient:
a splat larger than the image still covers it all, and its gradients stay finite and non-zero
(about 1e-24 through the conic of a log-scale-30 splat seen from 4 units). Splats whose radius is
below reach are untouched, bit for bit. Without the clamp the float-to-int32 conversion overflowed
from about log-scale 20 (radius > 2^31) to -2^31, and the splat vanished with a zero gradient.

The wide path. In float32, det = a1 c1 - b^2 overflows once the 2D standard deviations pass about
4e9 px ((4e9)^4 > 3.4e38: log-scale 20 where fx / z = 10 px per unit). For such a splat (det not
finite) both kernels redo its geometry in float64: the forward its conic, radius and compensation,
the backward the VJP of its opacity factor, conic, dilation, projection and covariance, and round
the results to float32. No other splat takes this path, so float32 results are otherwise unchanged.

Largest scale that renders exactly: in float64, no limit within the |log-scale| <= 80 that
gaussian_inputs accepts (the backward's det^2 stays finite while fx / z < about 5e3 px per
unit), with one exception: a splat whose clamped radius would still exceed RADIUS_CAP = 2^30 (its
mean2d over 2^29 px off the image, its radius larger still) is culled, so the tile arithmetic stays
in int32. In float32 the limit is the conic's magnitude, about (fx / z)^-2 exp(-2 log-scale): it
leaves float32's normal range (1.2e-38) near log-scale 41 where fx / z = 10; beyond, it rounds to
a subnormal and then to 0. The splat still covers the image with alpha = its opacity, as the math
gives to float32 precision (its tile box is then the clamped radius, kernels/splat/tiles.py), and
its opacity and colour gradients stay exact, but the gradients that flow through the conic
(log-scales, quaternion, mean) fall below float32's range and read 0.

The backward kernel recomputes the forward through the same functions of kernels/splat/ewa.py and
chains their VJPs in reverse: colour and SH (sh.sh_basis_grad, view_direction_vjp), opacity
and compensation, conic inverse and dilation, EWA projection, covariance. One thread per splat
writes only that splat's gradients, so both kernels run split over CPU threads.

The kernels are in kernels.splat.projection_kernels; this module holds the entry points, their
checks and the value-check kernel of CUDA inputs. A camera with a lens model (SplatCamera.lens:
opencv, fisheye, orthographic) takes the kernels of kernels.splat.lens_projection instead, whose
docstring states how the mean and the covariance go through the lens; the pinhole's kernels and
results are unchanged by that route.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.splat.camera import SplatCamera
from kernels.splat.lens_projection import _lens_project_backward_kernel, _lens_project_kernel
from kernels.splat.modes import DEFAULT_MODE, dilation_of, mode_id
from kernels.splat.projection_kernels import _project_backward_kernel, _project_kernel

wp.set_module_options({"enable_backward": False})

MIN_CHUNK = 1024


@wp.kernel
def _count_bad_kernel(quats: wp.array2d(dtype=Any), log_scales: wp.array2d(dtype=Any), bound: float,
                      count: wp.array(dtype=wp.int32)):
    # Value checks on a CUDA device (one launch; the CPU reads a zero-copy view instead).
    i = wp.tid()
    qn = wp.float64(0.0)
    for j in range(4):
        qn += wp.float64(quats[i, j]) * wp.float64(quats[i, j])
    if wp.sqrt(qn) < wp.float64(1e-12):
        wp.atomic_add(count, 0, 1)
    for j in range(3):
        if wp.abs(wp.float64(log_scales[i, j])) > wp.float64(bound):
            wp.atomic_add(count, 1, 1)


A.declare_float_overloads(_count_bad_kernel)

LOG_SCALE_BOUND = 80.0


# ============================================================================ entry points


@dataclass
class GaussianInputs:
    """Validated splat parameters: wp.arrays on one device, in one float dtype.

    `as_numpy` is the kind of the arrays the caller passed: every result computed from these
    inputs (projections, renders, gradients) comes back as NumPy arrays when it is True, and as
    wp.arrays on `device` otherwise.
    """

    means: wp.array
    log_scales: wp.array
    quats: wp.array
    opacity_logits: wp.array
    sh: wp.array
    scalar: Any  # wp.float32 or wp.float64
    device: wp.Device
    as_numpy: bool

    @property
    def n(self) -> int:
        return self.means.shape[0]

    @property
    def dtype(self) -> np.dtype:
        return A.NP_OF_WP[self.scalar]

    def inputs(self) -> A.Inputs:
        """An `Inputs` for a call on these parameters: their device, dtype and output kind."""
        return A.Inputs.like(self.device, self.scalar, self.as_numpy)


def sh_degree_of(sh_shape: tuple, sh_degree: int | None) -> int:
    """The SH degree to evaluate: `sh_degree`, or the full degree of the (N, K, 3) coefficients."""
    k = sh_shape[1]
    full = int(round(math.sqrt(k))) - 1
    if (full + 1) ** 2 != k or not 0 <= full <= 3:
        raise ValueError(f"sh: expected (N, K, 3) with K in (1, 4, 9, 16), got {tuple(sh_shape)}")
    if sh_degree is None:
        return full
    return A.check_int("sh_degree", sh_degree, 0, full)


def _check_values(quats: wp.array, log_scales: wp.array) -> None:
    if not A.values_checked() or quats.shape[0] == 0:
        return
    if quats.device.is_cpu:
        qn = np.linalg.norm(quats.numpy().astype(np.float64), axis=1)
        if np.any(qn < 1e-12):
            raise ValueError(f"quats: quaternion {int(np.argmin(qn))} has zero norm; expected non-zero quaternions")
        big = np.abs(log_scales.numpy()).max()
        if big > LOG_SCALE_BOUND:
            raise ValueError(f"log_scales: |log-scale| up to {big:.3g}; expected values in [-80, 80] "
                             "(scales are exp(log_scales), and must stay finite and non-zero)")
        return
    bad_q, bad_l = A.device_counts(_count_bad_kernel, quats.shape[0], [quats, log_scales, LOG_SCALE_BOUND],
                                   quats.device, slots=2)
    if bad_q:
        raise ValueError(f"quats: {bad_q} quaternions have zero norm; expected non-zero quaternions")
    if bad_l:
        raise ValueError("log_scales: expected values in [-80, 80] (scales are exp(log_scales), and must stay "
                         "finite and non-zero)")


def gaussian_inputs(means: Any, log_scales: Any, quats: Any, opacity_logits: Any, sh: Any,
                    device: Any = None) -> GaussianInputs:
    """Check the parameter arrays (shapes, one float dtype, device, finite, non-zero quaternions,
    |log_scales| <= 80) and hold them as wp.arrays; NumPy or wp.array inputs (kernels/_arrays.py)."""
    a = A.Inputs(device, means, log_scales, quats, opacity_logits, sh)
    m = a.floats("means", means, (None, 3))
    n = m.shape[0]
    ls = a.floats("log_scales", log_scales, (n, 3))
    q = a.floats("quats", quats, (n, 4))
    o = a.floats("opacity_logits", opacity_logits, (n,))
    s = a.floats("sh", sh, (n, None, 3))
    sh_degree_of(tuple(s.shape), None)
    _check_values(q, ls)
    return GaussianInputs(m, ls, q, o, s, a.scalar, a.device, a.as_numpy)


@dataclass
class Projection:
    """Per-splat screen-space quantities (radius 0 = culled; its other outputs are 0)."""

    means2d: Any  # (N, 2) pixels
    conics: Any  # (N, 3) (Q00, Q01, Q11)
    depths: Any  # (N,)
    radii: Any  # (N,) int32
    colors: Any  # (N, 3)
    opacities: Any  # (N,)

    def out(self, a: A.Inputs) -> "Projection":
        """This projection in the output kind of `a`."""
        return Projection(a.out(self.means2d), a.out(self.conics), a.out(self.depths), a.out(self.radii),
                          a.out(self.colors), a.out(self.opacities))


def _camera_arrays(a: A.Inputs, camera: SplatCamera) -> tuple[wp.array, wp.array]:
    if not isinstance(camera, SplatCamera):
        raise ValueError(f"camera: expected a SplatCamera, got {type(camera).__name__}")
    view = wp.array(camera.viewmat.astype(a.np_dtype), dtype=a.scalar, device=a.device)
    cam = wp.array(camera.params().astype(a.np_dtype), dtype=a.scalar, device=a.device)
    return view, cam


def _lens_arrays(a: A.Inputs, camera: SplatCamera) -> list:
    """[model id, lens parameter array] of a camera with a lens (kernels.lens)."""
    return [camera.lens.model_id, wp.array(camera.lens.params().astype(a.np_dtype), dtype=a.scalar, device=a.device)]


def project_wp(g: GaussianInputs, camera: SplatCamera, sh_degree: int, antialiased: bool,
               mode: str = DEFAULT_MODE, dilation: float | None = None) -> Projection:
    """`project` with wp.array results on g's device (the render chain's first stage)."""
    mid = mode_id(mode)
    s = dilation_of(mode, dilation, antialiased)
    a = g.inputs()
    view, cam = _camera_arrays(a, camera)
    n = g.n
    # Every row is written by its thread (zeros first, for a culled splat): no zero fill; on the CPU the
    # large arrays recycle freed blocks (kernels/_arrays.py, HostPool).
    out = Projection(a.empty((n, 2)), a.empty((n, 3)), a.empty(n), a.empty(n, wp.int32), a.empty((n, 3)),
                     a.empty(n))
    if camera.lens is not None:  # a lens model: kernels.splat.lens_projection
        a.launch(_lens_project_kernel, n,
                 [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh, view, cam, *_lens_arrays(a, camera),
                  camera.width, camera.height, sh_degree, mid, wp.float64(s), int(bool(antialiased)), out.means2d,
                  out.conics, out.depths, out.radii, out.colors, out.opacities], min_chunk=MIN_CHUNK)
        return out
    a.launch(_project_kernel, n,
             [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh, view, cam, camera.width, camera.height,
              sh_degree, mid, wp.float64(s), int(bool(antialiased)), out.means2d, out.conics, out.depths, out.radii,
              out.colors, out.opacities], min_chunk=MIN_CHUNK)
    return out


def project(g: GaussianInputs, camera: SplatCamera, *, sh_degree: int | None = None,
            antialiased: bool = False, mode: str = DEFAULT_MODE, dilation: float | None = None) -> Projection:
    """Project every splat into `camera` (module docstring) following `mode` ("3dgs" or "gsplat",
    kernels/splat/modes.py), with the low-pass `dilation` (px^2; None: the mode's, 0.3); arrays in the
    kind of g's inputs."""
    mode_id(mode)
    dilation_of(mode, dilation, antialiased)
    deg = sh_degree_of(tuple(g.sh.shape), sh_degree)
    return project_wp(g, camera, deg, antialiased, mode, dilation).out(g.inputs())


def project_backward(g: GaussianInputs, camera: SplatCamera, radii: Any, grad_means2d: Any, grad_conics: Any,
                     grad_depths: Any, grad_colors: Any, grad_opacities: Any, *, sh_degree: int | None = None,
                     antialiased: bool = False, mode: str = DEFAULT_MODE, dilation: float | None = None,
                     want_camera: bool = False) -> dict[str, Any]:
    """Vector-Jacobian product of `project` (with the same `mode`, `antialiased` and `dilation`).

    Returns a dict with the gradients of "means", "log_scales", "quats", "opacity_logits" and
    "sh", each shaped like the parameter, in the kind of g's inputs (NumPy or wp.array). With
    `want_camera`, also "pose" (6,): dL/dxi for the left perturbation viewmat <- exp(xi^) viewmat,
    xi = (rho, phi) translation first, and "intrinsics" (4,): dL/d(fx, fy, cx, cy)
    (kernels/splat/ewa.py, `pose_vjp` and `persp_intrinsics_vjp`). Each splat's thread writes its
    own row of these, and the rows are summed afterwards, so the split launch stays race-free
    (docs/warp.md, section 2).
    """
    mid = mode_id(mode)
    s = dilation_of(mode, dilation, antialiased)
    deg = sh_degree_of(tuple(g.sh.shape), sh_degree)
    n = g.n
    a = g.inputs()
    r = a.ints("radii", radii, (n,), minimum=0)
    gm = a.floats("grad_means2d", grad_means2d, (n, 2))
    gc = a.floats("grad_conics", grad_conics, (n, 3))
    gd = a.floats("grad_depths", grad_depths, (n,))
    gcol = a.floats("grad_colors", grad_colors, (n, 3))
    go = a.floats("grad_opacities", grad_opacities, (n,))
    view, cam = _camera_arrays(a, camera)
    out = {"means": a.zeros((n, 3)), "log_scales": a.zeros((n, 3)), "quats": a.zeros((n, 4)),
           "opacity_logits": a.zeros(n), "sh": a.zeros(tuple(g.sh.shape))}
    rows = a.zeros((max(n, 1) if want_camera else 1, 10))
    kernel, lens_args = _project_backward_kernel, []
    if camera.lens is not None:  # a lens model: kernels.splat.lens_projection
        kernel, lens_args = _lens_project_backward_kernel, _lens_arrays(a, camera)
    a.launch(kernel, n,
             [g.means, g.log_scales, g.quats, g.opacity_logits, g.sh, view, cam, *lens_args, camera.width,
              camera.height, deg, mid, wp.float64(s), int(bool(antialiased)), r, gm, gc, gd, gcol, go, out["means"],
              out["log_scales"], out["quats"], out["opacity_logits"], out["sh"], int(bool(want_camera)), rows],
             min_chunk=MIN_CHUNK)
    result = {k: a.out(v) for k, v in out.items()}
    if want_camera:
        total = rows.numpy()[:n].sum(axis=0, dtype=np.float64).astype(a.np_dtype)
        result["pose"] = a.out(wp.array(total[:6], dtype=a.scalar, device=a.device))
        result["intrinsics"] = a.out(wp.array(total[6:], dtype=a.scalar, device=a.device))
    return result
