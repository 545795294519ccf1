"""Depth, normals and the depth-normal consistency loss of a splat render, with their backward.

For one camera (kernels.splat.render: projection, tiles, rasteriser):

  depth map     "expected": e = D / A (kernels/splat/depth.py, gsplat's "ED"), or "median": the z of the
                splat at which the transmittance first crosses 1/2 (2DGS's median depth);
  depth normals n_d = normals_from_depth(depth map) (kernels/splat/normals.py: central differences of
                the back-projected depth, cross product, normalised; zero on the image border);
  splat normals N(p) = sum_i w_i(p) n_i, each splat's shortest-axis normal n_i facing the camera
                (PGSR, Chen et al. 2024; kernels/splat/normals.py) alpha-blended by the same weights
                w_i = alpha_i T_i as the colours (the rasteriser run with n_i as the colours, black
                background), so |N(p)| <= A(p).

Depth-normal consistency loss (2DGS, Huang et al. SIGGRAPH 2024, Eq. 14, "L_n = sum_i w_i (1 - n_i^T N)",
with the blended normal in place of the per-splat sum, as its code does), over the interior pixels I
(those off the border, where n_d is defined):

    L_n = (1/|I|) sum_{p in I} (1 - N(p) . n_d(p)).

Pixels the splats barely cover weigh little (|N| small); the splats' orientations (through n_i, the
quaternions) and their positions, opacities and depths (through the weights and the depth map) all
get gradients. Since 3DGS's splats have no normal of their own, the shortest axis stands in for it
(PGSR's choice); 2DGS's own surfels carry one. Backward (`consistency_backward`), for a cotangent g of
L_n:

    dL/dN(p) = -g n_d(p) / |I|,  dL/dn_d(p) = -g N(p) / |I|,

then the normal raster's backward (its "colors" gradient is dL/dn_i, taken to the quaternions by
splat_normals_backward; its other screen-space gradients join the image's), normals_from_depth's
backward to the depth map, and expected_depth's (to the rasteriser's depth and alpha cotangents) or
median_depth's (to the splats' z) backward; one projection backward carries the sum to the parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import splat as ks
from kernels.splat import depth as kd
from kernels.splat import normals as kn

DEPTHS = ("expected", "median")
_SCREEN = ("means2d", "conics", "colors", "opacities", "depths")


@dataclass
class Geometry:
    """A render with its depth map, depth normals and blended splat normals (module docstring)."""

    render: ks.Render
    depth_kind: str
    depth: np.ndarray  # (H, W) the depth map
    median: kd.MedianDepth | None
    depth_normals: np.ndarray  # (H, W, 3) camera frame
    splat_normals: np.ndarray  # (N, 3) camera frame
    normal_map: np.ndarray  # (H, W, 3) blended splat normals N
    normal_splats: ks.Splats2D
    normal_tiles: ks.Tiles
    normal_raster: ks.Raster


def _splats(g: ks.GaussianInputs, proj: ks.Projection, colors: Any = None) -> ks.Splats2D:
    """The render's screen-space splats (its projection's wp.arrays; `colors` a wp.array in place of its
    colours), with NumPy results."""
    colors = proj.colors if colors is None else colors
    return ks.Splats2D(proj.means2d, proj.conics, colors, proj.opacities, proj.depths, proj.radii, g.scalar, g.device,
                       True)


def render_geometry(g: ks.GaussianInputs, camera: ks.SplatCamera, background: Any = None, *,
                    depth: str = "expected", sh_degree: int | None = None, mode: str = ks.DEFAULT_MODE,
                    render: ks.Render | None = None) -> Geometry:
    """Render (or take `render`, made from `g` and `camera`), then its depth map of kind `depth`,
    the depth normals and the blended splat normals (module docstring). Arrays are NumPy."""
    if depth not in DEPTHS:
        raise ValueError(f"depth: expected one of {', '.join(DEPTHS)}, got {depth!r}")
    r = render if render is not None else ks.render(g, camera, background, sh_degree=sh_degree, mode=mode)
    proj = r.projection
    median = None
    if depth == "expected":
        dmap = kd.expected_depth(r.depth, r.alpha, device=g.device)
    else:
        median = kd.median_depth(_splats(g, proj), r.tiles, r.raster, mode=r.mode)
        dmap = _np(median.depth)
    dn = kn.normals_from_depth(dmap, camera, device=g.device)
    sn = kn.splat_normals(g.means, g.quats, g.log_scales, camera)
    ns = _splats(g, proj, sn)
    nr, nt = ks.rasterize(ns, camera.width, camera.height, None, mode=r.mode)
    return Geometry(r, depth, _np(dmap), median, _np(dn), _np(sn), _np(nr.rgb), ns, nt, nr)


def _np(x: Any) -> np.ndarray:
    return x if isinstance(x, np.ndarray) else x.numpy()


def consistency_loss(geo: Geometry) -> float:
    """L_n of the module docstring."""
    inner = geo.normal_map[1:-1, 1:-1]
    if inner.size == 0:
        raise ValueError("geo: expected an image of at least 3 x 3 pixels for the depth normals")
    return float(np.mean(1.0 - np.sum(inner * geo.depth_normals[1:-1, 1:-1], axis=-1)))


def consistency_backward(g: ks.GaussianInputs, geo: Geometry, grad: float = 1.0) -> dict[str, Any]:
    """The cotangents L_n's gradient `grad` * dL_n adds, returned as the pieces the image's backward
    combines with (`render_backward_with`): "screen" (the screen-space gradients), "grad_depth" and
    "grad_alpha" (the rasteriser's depth and alpha outputs), and "quats" (N, 4)."""
    cam, r = geo.render.camera, geo.render
    h, w = cam.height, cam.width
    count = (h - 2) * (w - 2)
    dtype = g.dtype
    g_nmap = np.zeros((h, w, 3), dtype)
    g_nmap[1:-1, 1:-1] = -grad * geo.depth_normals[1:-1, 1:-1] / count
    g_dn = np.zeros((h, w, 3), dtype)
    g_dn[1:-1, 1:-1] = -grad * geo.normal_map[1:-1, 1:-1] / count
    screen = ks.rasterize_backward(geo.normal_splats, w, h, None, geo.normal_tiles, geo.normal_raster, g_nmap,
                                   mode=r.mode)
    g_quats = _np(kn.splat_normals_backward(g.means, g.quats, g.log_scales, cam,
                                            wp.array(screen.pop("colors"), dtype=g.scalar, device=g.device)))
    screen.pop("background")
    g_dmap = kn.normals_from_depth_backward(geo.depth, cam, g_dn, device=g.device)
    zeros = np.zeros((h, w), dtype)
    out = {"screen": screen, "quats": g_quats, "grad_depth": zeros, "grad_alpha": zeros}
    if geo.depth_kind == "expected":
        out["grad_depth"], out["grad_alpha"] = (_np(x) for x in kd.expected_depth_backward(
            r.depth, r.alpha, g_dmap, device=g.device))
    else:
        screen["depths"] = screen["depths"] + kd.median_depth_backward(_splats(g, r.projection), r.tiles, geo.median,
                                                                       g_dmap)
    return out


def render_backward_with(g: ks.GaussianInputs, result: ks.Render, grad_rgb: Any, extra: dict[str, Any],
                         grad_alpha: Any = None, grad_depth: Any = None, *, absgrad: bool = False) -> dict[str, Any]:
    """kernels.splat.render_backward for the image cotangents plus `extra` (consistency_backward's): the
    rasteriser's backward, the extra screen-space gradients added, one projection backward, the extra
    quaternion gradient added. Returns the parameters' gradients, "background" and "means2d" (the image's
    screen-space mean gradient plus the extra one) (and "means2d_abs" with `absgrad`, of the image alone)."""
    cam, proj = result.camera, result.projection
    h, w = cam.height, cam.width
    ga = extra["grad_alpha"] if grad_alpha is None else grad_alpha + extra["grad_alpha"]
    gd = extra["grad_depth"] if grad_depth is None else grad_depth + extra["grad_depth"]
    g2 = ks.rasterize_backward(_splats(g, proj), w, h, result.background.numpy(), result.tiles, result.raster, grad_rgb,
                               ga, gd,
                               mode=result.mode, absgrad=absgrad)
    for k in _SCREEN:
        if k in extra["screen"]:
            g2[k] = g2[k] + extra["screen"][k]
    g3 = ks.project_backward(g, cam, proj.radii, g2["means2d"], g2["conics"], g2["depths"], g2["colors"],
                             g2["opacities"], sh_degree=result.sh_degree, antialiased=result.antialiased,
                             mode=result.mode, dilation=result.dilation)
    g3 = {k: _np(v) for k, v in g3.items()}
    g3["quats"] = g3["quats"] + extra["quats"]
    g3["background"] = _np(g2["background"])
    g3["means2d"] = _np(g2["means2d"])
    if absgrad:
        g3["means2d_abs"] = _np(g2["means2d_abs"])
    return g3
