"""NumPy reference of kernels/splat: projection, SH colour, tile lists and rasterisation.

Float64 loops written from the module docstrings of kernels/splat (the 3DGS forward of Kerbl et
al. 2023, with EWA splatting and the optional Mip-Splatting compensation), in both modes of
kernels/splat/modes.py: "3dgs" writes the equations of the original 3DGS code (computeCov2D,
preprocessCUDA with getRect, renderCUDA), "gsplat" those of gsplat (persp_proj,
fully_fused_projection, isect_tiles, rasterize_to_pixels). `rasterize` blends the splats of the
mode's square tile sets; the kernels bin by a smaller box that only leaves out pixels with
alpha < 1/255, so both give the same image. `render` is the whole chain. `mean2d_pixel_terms`
sums each pixel's term of the rasteriser's mean2d gradient per splat, plain and in absolute value
(AbsGS's densification statistic, the backward's `absgrad` output).
"""

from __future__ import annotations

import math

import numpy as np

from kernels.reference.sh import sh_basis
from kernels.reference import lens as lens_reference


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of the quaternion q / |q|, q = (w, x, y, z)."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


MODES = ("3dgs", "gsplat")
ALPHA_MAX = {"3dgs": 0.99, "gsplat": 0.999}
RADIUS_FLOOR = {"3dgs": 0.1, "gsplat": 0.01}
AA_FLOOR = {"3dgs": 2.5e-5, "gsplat": 0.0}
DILATION = 0.3  # the low-pass dilation (px^2) of both modes


def frustum_limits(cam, mode: str) -> tuple[float, float, float, float]:
    """(lim_x-, lim_x+, lim_y-, lim_y+): the Jacobian clamps x/z to [-lim_x-, lim_x+] (y/z likewise)."""
    fx, fy, cx, cy = cam.params()[:4]
    tan_fovx, tan_fovy = 0.5 * cam.width / fx, 0.5 * cam.height / fy
    if mode == "3dgs":  # computeCov2D: limx = 1.3 tan_fovx, symmetric about the optical axis
        return 1.3 * tan_fovx, 1.3 * tan_fovx, 1.3 * tan_fovy, 1.3 * tan_fovy
    # gsplat's persp_proj
    return (cx / fx + 0.3 * tan_fovx, (cam.width - cx) / fx + 0.3 * tan_fovx,
            cy / fy + 0.3 * tan_fovy, (cam.height - cy) / fy + 0.3 * tan_fovy)


def square_tiles(u: float, r: float, n_tiles: int, mode: str) -> tuple[int, int]:
    """[t0, t1): the tiles along one axis that the square u +- r lists, by the mode's rule:
    3DGS's getRect (its pixel centres are at integers, drlab's at i + 1/2, hence u - 1/2) or
    gsplat's isect_tiles."""
    if mode == "3dgs":
        t0, t1 = math.floor((u - 0.5 - r) / 16), math.floor((u - 0.5 + r + 15) / 16)
    else:
        t0, t1 = math.floor((u - r) / 16), math.ceil((u + r) / 16)
    return min(max(t0, 0), n_tiles), min(max(t1, 0), n_tiles)


def culled(u: float, v: float, r: float, width: int, height: int, mode: str) -> bool:
    """3DGS: its getRect rectangle is empty; gsplat: the square misses the image."""
    if mode == "3dgs":
        x0, x1 = square_tiles(u, r, (width + 15) // 16, mode)
        y0, y1 = square_tiles(v, r, (height + 15) // 16, mode)
        return (x1 - x0) * (y1 - y0) == 0
    return u + r <= 0 or u - r >= width or v + r <= 0 or v - r >= height


def project(params: dict, cam, sh_degree: int | None = None, antialiased: bool = False, mode: str = "3dgs",
            radius_floor: float | None = None, dilation: float | None = None) -> dict:
    """Per-splat projection (kernels/splat/projection.py) of float64 parameters; radius 0 = culled.
    `radius_floor` overrides the mode's floor of the radius's eigenvalue term (for tests), `dilation`
    the low-pass dilation 0.3 px^2 added to every 2D covariance."""
    s = DILATION if dilation is None else dilation
    floor = RADIUS_FLOOR[mode] if radius_floor is None else radius_floor
    means, log_scales, quats = params["means"], params["log_scales"], params["quats"]
    logits, sh = params["opacity_logits"], params["sh"]
    n = len(means)
    deg = int(round(math.sqrt(sh.shape[1]))) - 1 if sh_degree is None else sh_degree
    fx, fy, cx, cy, near, far = cam.params()
    Rw, tw = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    centre = -Rw.T @ tw
    out = {"means2d": np.zeros((n, 2)), "conics": np.zeros((n, 3)), "depths": np.zeros(n),
           "radii": np.zeros(n, dtype=np.int64), "colors": np.zeros((n, 3)), "opacities": np.zeros(n)}
    for i in range(n):
        x, y, z = Rw @ means[i] + tw
        if z < near or z > far:
            continue
        R = quat_to_rotmat(quats[i])
        S = np.diag(np.exp(log_scales[i]))
        sigma_cam = Rw @ (R @ S @ S.T @ R.T) @ Rw.T
        lens = getattr(cam, "lens", None)
        if lens is None:
            lxn, lxp, lyn, lyp = frustum_limits(cam, mode)
            xc = z * min(max(x / z, -lxn), lxp)
            yc = z * min(max(y / z, -lyn), lyp)
            J = np.array([[fx / z, 0.0, -fx * xc / z**2], [0.0, fy / z, -fy * yc / z**2]])
            u, v = fx * x / z + cx, fy * y / z + cy
        else:  # a lens model (kernels/reference/lens.py): J of the full projection at the mean, no clamp
            uv, ok = lens_reference.pixels(lens, cam.K, np.array([[x, y, z]]))
            if not ok[0]:
                continue
            J = np.diag([fx, fy]) @ lens_reference.jacobian(lens, np.array([[x, y, z]]))[0]
            u, v = uv[0]
        cov = J @ sigma_cam @ J.T
        cov_dilated = cov + s * np.eye(2)
        det = np.linalg.det(cov_dilated)
        if det <= 0:
            continue
        half_trace = 0.5 * np.trace(cov_dilated)
        lam_max = half_trace + math.sqrt(max(floor, half_trace**2 - det))
        radius = math.ceil(3.0 * math.sqrt(lam_max))
        if culled(u, v, radius, cam.width, cam.height, mode):
            continue
        conic = np.linalg.inv(cov_dilated)
        direction = (means[i] - centre) / np.linalg.norm(means[i] - centre)
        basis = sh_basis(direction, deg)
        opacity = 1.0 / (1.0 + math.exp(-logits[i]))
        if antialiased:
            opacity *= math.sqrt(max(AA_FLOOR[mode], np.linalg.det(cov) / det))
        out["means2d"][i] = u, v
        out["conics"][i] = conic[0, 0], conic[0, 1], conic[1, 1]
        out["depths"][i] = z
        out["radii"][i] = radius
        out["colors"][i] = np.maximum(basis @ sh[i, : len(basis)] + 0.5, 0.0)
        out["opacities"][i] = opacity
    return out


def binned_tiles(m2, conic, opacity, radius, tiles_x, tiles_y, square: bool = False, mode: str = "3dgs") -> list[int]:
    """Tiles the square mean2d +- radius lists by the mode's rule (`square_tiles`), cut (unless
    `square`) to those met by the bounding box of the ellipse d^T Q d <= 2 ln(255 o), outside which
    alpha < 1/255."""
    if radius <= 0:
        return []
    x0, x1 = square_tiles(m2[0], radius, tiles_x, mode)
    y0, y1 = square_tiles(m2[1], radius, tiles_y, mode)
    if not square:
        if 255 * opacity < 1:
            return []
        cov = np.linalg.inv([[conic[0], conic[1]], [conic[1], conic[2]]])
        k2 = 2 * math.log(255 * opacity)
        ex, ey = min(radius, math.sqrt(k2 * cov[0, 0])), min(radius, math.sqrt(k2 * cov[1, 1]))
        x0 = max(x0, min(max(math.floor((m2[0] - ex) / 16), 0), tiles_x))
        x1 = min(x1, min(max(math.ceil((m2[0] + ex) / 16), 0), tiles_x))
        y0 = max(y0, min(max(math.floor((m2[1] - ey) / 16), 0), tiles_y))
        y1 = min(y1, min(max(math.ceil((m2[1] + ey) / 16), 0), tiles_y))
    return [ty * tiles_x + tx for ty in range(y0, y1) for tx in range(x0, x1)]


def tile_lists(m2, conics, opacities, radii, depths, width, height, square=False,
               mode: str = "3dgs") -> dict[int, list[int]]:
    """Splats of every tile, front to back (stable in the splat index)."""
    tiles_x, tiles_y = (width + 15) // 16, (height + 15) // 16
    lists: dict[int, list[int]] = {t: [] for t in range(tiles_x * tiles_y)}
    for i in np.argsort(depths, kind="stable"):
        for t in binned_tiles(m2[i], conics[i], opacities[i], radii[i], tiles_x, tiles_y, square, mode):
            lists[t].append(int(i))
    return lists


def _pixel_blends(m2, conics, opacities, lists, tiles_x, px, py, mode):
    """The splats pixel (px, py) blends, front to back: (i, alpha_i, T_i, clamped_i, d_i = mean2d_i - p),
    and T_final."""
    a_max = ALPHA_MAX[mode]
    T, blended = 1.0, []
    for i in lists[(py // 16) * tiles_x + px // 16]:
        d = m2[i] - (px + 0.5, py + 0.5)
        Q = np.array([[conics[i, 0], conics[i, 1]], [conics[i, 1], conics[i, 2]]])
        power = -0.5 * d @ Q @ d
        if power > 0:
            continue
        raw = opacities[i] * math.exp(power)
        a = min(a_max, raw)
        if a < 1.0 / 255.0:
            continue
        test_T = T * (1 - a)
        if test_T < 1e-4 or (mode == "gsplat" and test_T <= 1e-4):
            break
        blended.append((int(i), a, T, raw > a_max, d))
        T *= 1 - a
    return blended, T


def rasterize(m2, conics, colors, opacities, depths, radii, width, height, background, mode: str = "3dgs"):
    """The mode's rasteriser (3DGS's renderCUDA or gsplat's rasterize_to_pixels): each pixel blends
    the splats whose square mean2d +- radius lists its tile, front to back.

    (The kernel bins by a smaller box that only leaves out pixels with alpha < 1/255,
    so it must give the same image.)"""
    lists = tile_lists(m2, conics, opacities, radii, depths, width, height, square=True, mode=mode)
    tiles_x = (width + 15) // 16
    rgb, alpha, depth = np.zeros((height, width, 3)), np.zeros((height, width)), np.zeros((height, width))
    for py in range(height):
        for px in range(width):
            C, D = np.zeros(3), 0.0
            blended, T = _pixel_blends(m2, conics, opacities, lists, tiles_x, px, py, mode)
            for i, a, t_i, _, _ in blended:
                C += colors[i] * a * t_i
                D += depths[i] * a * t_i
            rgb[py, px] = C + T * background
            alpha[py, px] = 1 - T
            depth[py, px] = D
    return rgb, alpha, depth


def mean2d_pixel_terms(m2, conics, colors, opacities, depths, radii, width, height, background, grad_rgb,
                       grad_alpha, grad_depth, mode: str = "3dgs") -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's term of dL/dmean2d, summed per splat two ways: (sum_p g_p, sum_p |g_p| per component),
    the second AbsGS's statistic (kernels/splat/raster.py, `absgrad`).

    Written from the forward, not the kernel's back-to-front recursion: with pixel p's blended splats
    front to back, out = sum_i f_i alpha_i T_i + T_final bg (f = colour and depth, bg 0 for depth) and
    alpha_out = 1 - T_final,
        dout/dalpha_i = f_i T_i - (sum_{j > i} f_j alpha_j T_j + T_final bg) / (1 - alpha_i),
        dalpha_out/dalpha_i = T_final / (1 - alpha_i),
        g_p = dL/dalpha_i * (-alpha_i Q_i d_i), zero where the clamp alpha = a_max is active."""
    lists = tile_lists(m2, conics, opacities, radii, depths, width, height, square=True, mode=mode)
    tiles_x = (width + 15) // 16
    total, absolute = np.zeros((len(m2), 2)), np.zeros((len(m2), 2))
    for py in range(height):
        for px in range(width):
            blended, T = _pixel_blends(m2, conics, opacities, lists, tiles_x, px, py, mode)
            g_f = np.append(grad_rgb[py, px], grad_depth[py, px])  # cotangents of (r, g, b, depth)
            f = [np.append(colors[i], depths[i]) for i, *_ in blended]
            behind = T * np.append(background, 0.0)  # sum over j > i of f_j alpha_j T_j, plus T_final bg
            for k in range(len(blended) - 1, -1, -1):
                i, a, t_i, clamped, d = blended[k]
                dl_da = (f[k] * t_i - behind / (1 - a)) @ g_f + grad_alpha[py, px] * T / (1 - a)
                behind = behind + f[k] * a * t_i
                if clamped:
                    continue
                Q = np.array([[conics[i, 0], conics[i, 1]], [conics[i, 1], conics[i, 2]]])
                g_p = dl_da * (-a * Q @ d)
                total[i] += g_p
                absolute[i] += np.abs(g_p)
    return total, absolute


def render(params: dict, cam, background: np.ndarray, sh_degree: int | None = None,
           antialiased: bool = False, mode: str = "3dgs",
           radius_floor: float | None = None, dilation: float | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb, alpha, depth) of the whole chain for float64 parameters and a SplatCamera."""
    p = project(params, cam, sh_degree, antialiased, mode, radius_floor, dilation)
    return rasterize(p["means2d"], p["conics"], p["colors"], p["opacities"], p["depths"], p["radii"], cam.width,
                     cam.height, background, mode)
