"""The whole splatting chain for one camera: project, bin and sort, rasterise; and its VJP.

    rgb, alpha, depth = rasterize(bin_tiles(project(gaussians, camera)))

(kernels/splat/projection.py, tiles.py, raster.py), every stage following `mode`: "3dgs" (the
default, the original 3DGS code) or "gsplat" (kernels/splat/modes.py has the table). The
backward runs the stages' backwards in reverse: the rasteriser's gives the gradients of the
screen-space splats, which the projection's carries to the parameters. Intermediate arrays stay
wp.arrays on the device; only the results the caller sees follow the kind of its inputs
(kernels/_arrays.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.splat.camera import SplatCamera
from kernels.splat.modes import DEFAULT_MODE, dilation_of, mode_id
from kernels.splat.projection import GaussianInputs, Projection, project_backward, project_wp, sh_degree_of
from kernels.splat.raster import Raster, background_array, rasterize_backward_wp, rasterize_wp
from kernels.splat.tiles import Splats2D, Tiles


@dataclass
class Render:
    """Everything `render` computed; `render_backward` needs it.

    rgb, alpha and depth are in the kind of the Gaussians' inputs (NumPy or wp.array); the
    projection, tiles, raster and background are the chain's state, wp.arrays on the device.
    """

    rgb: Any  # (H, W, 3)
    alpha: Any  # (H, W)
    depth: Any  # (H, W)
    projection: Projection
    tiles: Tiles
    raster: Raster
    camera: SplatCamera
    background: wp.array
    sh_degree: int
    antialiased: bool
    mode: str = DEFAULT_MODE
    dilation: float | None = None  # the low-pass dilation (px^2); None: the mode's (kernels/splat/modes.py)


def _splats_2d(g: GaussianInputs, proj: Projection) -> Splats2D:
    return Splats2D(proj.means2d, proj.conics, proj.colors, proj.opacities, proj.depths, proj.radii, g.scalar,
                    g.device, g.as_numpy)


def render(g: GaussianInputs, camera: SplatCamera, background: Any = None, *, sh_degree: int | None = None,
           antialiased: bool = False, mode: str = DEFAULT_MODE, dilation: float | None = None) -> Render:
    """Project, bin, sort and rasterise: rgb (H, W, 3), alpha (H, W), depth (H, W), following `mode`
    ("3dgs" or "gsplat", kernels/splat/modes.py); `antialiased` multiplies the opacities by that
    mode's Mip-Splatting compensation; `dilation` replaces the mode's low-pass dilation 0.3 px^2 of every
    projected covariance (None keeps it)."""
    mode_id(mode)
    dilation_of(mode, dilation, antialiased)
    if not isinstance(g, GaussianInputs):
        raise ValueError(f"g: expected GaussianInputs (kernels.splat.gaussian_inputs), got {type(g).__name__}")
    if not isinstance(camera, SplatCamera):
        raise ValueError(f"camera: expected a SplatCamera, got {type(camera).__name__}")
    deg = sh_degree_of(tuple(g.sh.shape), sh_degree)
    a = g.inputs()
    bg = background_array(a, background)
    proj = project_wp(g, camera, deg, antialiased, mode, dilation)
    raster, tiles = rasterize_wp(_splats_2d(g, proj), camera.width, camera.height, bg, None, mode)
    return Render(a.out(raster.rgb), a.out(raster.alpha), a.out(raster.depth), proj, tiles, raster, camera, bg, deg,
                  bool(antialiased), mode, dilation)


def render_backward(g: GaussianInputs, result: Render, grad_rgb: Any, grad_alpha: Any = None,
                    grad_depth: Any = None, *, want_camera: bool = False, absgrad: bool = False) -> dict[str, Any]:
    """VJP of `render` for the cotangents of rgb (and optionally alpha and depth).

    Returns a dict of arrays in the kind of g's inputs: the gradients of "means", "log_scales",
    "quats", "opacity_logits", "sh" (shaped like the parameters) and "background" (3,), and
    "means2d" (N, 2), the screen-space (pixel) gradient of every splat's 2D mean, which
    densification uses. With `want_camera`, also the camera's: "pose" (6,), dL/dxi for the
    left perturbation viewmat <- exp(xi^) viewmat at xi = 0, xi = (rho, phi) translation first
    (SplatCamera.perturbed), and "intrinsics" (4,), dL/d(fx, fy, cx, cy). With `absgrad`, also
    "means2d_abs" (N, 2), AbsGS's sum over pixels of |each pixel's term of dL/dmean2d| per component
    (kernels/splat/raster.py), which densification reads with DensifyConfig(absgrad=True).
    """
    if not isinstance(result, Render):
        raise ValueError(f"result: expected the Render of kernels.splat.render, got {type(result).__name__}")
    cam, proj = result.camera, result.projection
    a = g.inputs()
    g2 = rasterize_backward_wp(a, _splats_2d(g, proj), cam.width, cam.height, result.background, result.tiles,
                               result.raster, grad_rgb, grad_alpha, grad_depth, result.mode, absgrad)
    with A.value_checks(False):  # the screen-space gradients were computed here from checked inputs
        g3 = project_backward(g, cam, proj.radii, g2["means2d"], g2["conics"], g2["depths"], g2["colors"],
                              g2["opacities"], sh_degree=result.sh_degree, antialiased=result.antialiased,
                              mode=result.mode, dilation=result.dilation, want_camera=want_camera)
    g3["background"] = a.out(g2["background"])
    g3["means2d"] = a.out(g2["means2d"])
    if absgrad:
        g3["means2d_abs"] = a.out(g2["means2d_abs"])
    return g3
