"""Gradient checks of the Gaussian-splatting kernels (kernels/splat), float64.

Each stage is checked on its own (projection, rasterisation) and the whole chain
(project + bin + sort + rasterise) per parameter group. The test scenes are the
hard case: a dozen splats that overlap on the same pixels and straddle tile
borders, anisotropic (per-axis scales differ by up to 3x) and rotated (random
quaternions, unnormalised), with SH degree 3, some at opacity high enough that
the 0.99 clamp is active and stacks deep enough that the T < 1e-4 stop fires.

Finite differences are only meaningful on a smooth piece of the forward, so
every scene is screened (`discontinuity_margins`) and re-drawn from the next
sub-seed until every discontinuity is far from the inputs compared with the
FD step (1e-6):
  * the 1/255 alpha skip, the 0.99 clamp and the T < 1e-4 stop: relative
    distance of o G from 1/255 and 0.99, and of T (1 - alpha) from 1e-4, at every
    (pixel, splat) pair the rasteriser visits, at least MARGIN;
  * tile culling: every edge of a splat's binning box (the mode's square rule and
    the alpha >= 1/255 ellipse's box, kernels.splat.bin_tiles) at least MARGIN_PX from
    a tile border (and, in "gsplat" mode, the square's far edges from the image's), and
    3 sqrt(lambda_max) at least MARGIN from an integer (the ceil of the radius);
  * depth order: depths pairwise at least MARGIN_DEPTH apart;
  * the colour clamp at 0 and the Jacobian's frustum clamp: at least MARGIN away.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kernels import splat as ks
from kernels.reference import splat as ref
from research.gradcheck import GradcheckResult, check_vjp, register_check

MARGIN = 1e-3
MARGIN_PX = 1e-2
MARGIN_DEPTH = 1e-3
MAX_REDRAWS = 200

PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh")


@dataclass
class Scene:
    params: dict[str, np.ndarray]  # means, log_scales, quats, opacity_logits, sh
    camera: ks.SplatCamera
    background: np.ndarray


def _rotation(rng: np.random.Generator, max_angle: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = rng.uniform(-max_angle, max_angle)
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx


def random_scene(rng: np.random.Generator, n: int = 12, width: int = 40, height: int = 36, sh_k: int = 16,
                 off_frustum: bool = False, big: int = 0, near_clamp: str | None = None) -> Scene:
    """Overlapping, anisotropic, rotated splats in front of a slightly rotated camera 4 units away.

    With `off_frustum`, splat 0 sits right of the image beyond the Jacobian clamp (x/z = 0.75
    against limits of 0.52 in "3dgs" and 0.51 in "gsplat" mode) and is large enough to reach into it.
    With `big`, splats 1..big get scales near 3 (3 sigma of 95-130 px) and opacity 0.1-0.3: each
    covers the whole image, and its radius hits the clamp of kernels/splat/projection.py (drawn
    after everything else, so the other splats are those of the same rng without `big`). With
    `near_clamp` (a mode), splat 0 sits 0.004
    beyond the mode's Jacobian clamp on the right (x/z) and splat 1 0.004 inside it at the top (y/z),
    both centred off the image and large enough to reach into it.
    """
    R = _rotation(rng, 0.3)
    view = np.eye(4)
    view[:3, :3] = R
    view[:3, 3] = [0.05, -0.03, 4.0]
    K = np.array([[50.0, 0.0, width / 2 + 0.3], [0.0, 48.0, height / 2 - 0.4], [0.0, 0.0, 1.0]])
    camera = ks.SplatCamera(view, K, width, height)
    # Points in the camera frame, then to the world.
    pc = np.column_stack([rng.uniform(-0.45, 0.45, n), rng.uniform(-0.4, 0.4, n), 4.0 + rng.uniform(-0.6, 0.6, n)])
    log_scales = rng.uniform(-2.4, -1.3, (n, 3))
    logits = rng.uniform(-1.0, 3.0, n)
    # A stack of 4 near-opaque splats on nearly one line of sight: the first is blended at the
    # 0.99 clamp and the stack drives T below 1e-4, so the stop fires at the pixels behind its core.
    stack = slice(n - 4, n)
    pc[stack, :2] = rng.uniform(-0.15, 0.15, 2) + rng.uniform(-0.02, 0.02, (4, 2))
    pc[stack, 2] = 3.5 + 0.25 * np.arange(4) + rng.uniform(-0.05, 0.05, 4)
    log_scales[stack] = np.log(0.3) + rng.uniform(-0.25, 0.25, (4, 3))
    logits[stack] = [rng.uniform(7.0, 9.0), *rng.uniform(3.0, 4.0, 3)]
    if off_frustum:
        pc[0] = [0.75 * 4.2, 0.1, 4.2]
        log_scales[0] = [math.log(0.9), math.log(0.5), math.log(0.7)]
    if near_clamp is not None:
        lxn, lxp, lyn, lyp = ref.frustum_limits(camera, near_clamp)
        pc[0] = [(lxp + 0.004) * 4.2, 0.05 * 4.2, 4.2]
        pc[1] = [-0.05 * 3.9, -(lyn - 0.004) * 3.9, 3.9]
        log_scales[:2] = [[math.log(0.6), math.log(0.4), math.log(0.5)], [math.log(0.4), math.log(0.6), math.log(0.5)]]
    means = (pc - view[:3, 3]) @ R
    quats = rng.normal(size=(n, 4)) * rng.uniform(0.5, 2.0, (n, 1))
    sh = rng.normal(0.0, 0.15, (n, sh_k, 3))
    sh[:, 0, :] = (rng.uniform(0.3, 0.8, (n, 3)) - 0.5) / ks.SH_C0
    background = rng.uniform(0.1, 0.9, 3)
    if big:
        grow = slice(1, 1 + big)
        pc[grow, :2] = rng.uniform(-0.2, 0.2, (big, 2))
        log_scales[grow] = np.log(3.0) + rng.uniform(-0.15, 0.15, (big, 3))
        logits[grow] = rng.uniform(-2.2, -0.85, big)
        means = (pc - view[:3, 3]) @ R
    params = {"means": means, "log_scales": log_scales, "quats": quats, "opacity_logits": logits, "sh": sh}
    return Scene(params, camera, background)


# ----------------------------------------------------------------------------- margins


def _pixel_margins(m2: np.ndarray, conic: np.ndarray, opac: np.ndarray, order: list[int], px: float,
                   py: float, alpha_max: float = ks.ALPHA_MAX) -> tuple[float, int, bool]:
    """Smallest relative distance to the skip / clamp / stop thresholds along one pixel's list,
    the number of splats blended at the alpha clamp, and whether the T stop fired."""
    worst = math.inf
    clamped = 0
    T = 1.0
    for g in order:
        dx, dy = m2[g, 0] - px, m2[g, 1] - py
        power = -0.5 * (conic[g, 0] * dx * dx + conic[g, 2] * dy * dy) - conic[g, 1] * dx * dy
        raw = opac[g] * math.exp(power)
        worst = min(worst, abs(raw - ks.ALPHA_MIN) / ks.ALPHA_MIN, abs(raw - alpha_max) / alpha_max)
        alpha = min(alpha_max, raw)
        if power > 0 or alpha < ks.ALPHA_MIN:
            continue
        nxt = T * (1.0 - alpha)
        worst = min(worst, abs(nxt - ks.T_MIN) / ks.T_MIN)
        if nxt < ks.T_MIN:
            return worst, clamped, True
        clamped += raw > alpha_max
        T = nxt
    return worst, clamped, False


def discontinuity_margins(scene: Scene, sh_degree: int | None = None, antialiased: bool = False,
                          mode: str = ks.DEFAULT_MODE, dilation: float | None = None) -> dict[str, float]:
    """Distances of `scene` from every discontinuity of the forward (module docstring)."""
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    proj = ks.project(g, scene.camera, sh_degree=sh_degree, antialiased=antialiased, mode=mode, dilation=dilation)
    m2, conic, depth = proj.means2d, proj.conics, proj.depths
    radii, opac = proj.radii, proj.opacities
    cam = scene.camera
    vis = np.flatnonzero(radii > 0)
    out = {"visible": float(len(vis))}

    # Tile borders (of the binning extents) and the ceil of the radius.
    px_margin = math.inf
    ceil_margin = math.inf
    for i in vis:
        u, v, r = m2[i, 0], m2[i, 1], radii[i]
        ex, ey = binning_extents(m2[i], conic[i], opac[i], math.inf)
        edges = [u - ex, u + ex, v - ey, v + ey]
        if mode == "3dgs":  # getRect's square
            edges += [u - 0.5 - r, u - 0.5 + r + 15, v - 0.5 - r, v - 0.5 + r + 15]
        else:
            edges += [u - r, u + r, v - r, v + r]
            for c, size in ((u - r, cam.width), (v - r, cam.height)):
                px_margin = min(px_margin, abs(c - size))
        for c in edges:
            px_margin = min(px_margin, abs(c - ks.TILE * round(c / ks.TILE)))
        a, b, c = _cov2d_from_conic(conic[i])
        half_tr = 0.5 * (a + c)
        det = a * c - b * b
        r = 3.0 * math.sqrt(half_tr + math.sqrt(max(ks.RADIUS_FLOOR_OF[mode], half_tr * half_tr - det)))
        if r > radii[i]:
            continue  # the radius hit the clamp: its ceil no longer matters
        ceil_margin = min(ceil_margin, abs(r - round(r)))
    out["tile_px"] = px_margin
    out["radius_ceil"] = ceil_margin
    d = np.sort(depth[vis])
    out["depth_gap"] = float(np.min(np.diff(d))) if len(d) > 1 else math.inf

    # Colour clamp at 0 (on the pre-clamp value) and the Jacobian clamp.
    out["color"] = float(np.min(proj.colors[vis])) if len(vis) else math.inf
    p = scene.params["means"] @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    lxn, lxp, lyn, lyp = ref.frustum_limits(cam, mode)
    lims = [lxp, -lxn, lyp, -lyn]
    jac = math.inf
    for i in vis:
        xr, yr = p[i, 0] / p[i, 2], p[i, 1] / p[i, 2]
        jac = min(jac, abs(xr - lims[0]), abs(xr - lims[1]), abs(yr - lims[2]), abs(yr - lims[3]))
    out["jacobian_clamp"] = jac

    # Thresholds along every pixel's list (tile membership as the binning computes it).
    worst = math.inf
    n_clamped = n_stopped = 0
    tiles_x, tiles_y = cam.tiles
    members: dict[int, list[int]] = {t: [] for t in range(tiles_x * tiles_y)}
    for i in vis:
        for t in ref.binned_tiles(m2[i], conic[i], opac[i], radii[i], tiles_x, tiles_y, mode=mode):
            members[t].append(i)
    alpha_max = ks.ALPHA_MAX_OF[mode]
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            order = sorted(members[ty * tiles_x + tx], key=lambda i: (depth[i], i))
            for py in range(ty * ks.TILE, min((ty + 1) * ks.TILE, cam.height)):
                for px in range(tx * ks.TILE, min((tx + 1) * ks.TILE, cam.width)):
                    w, c, stopped = _pixel_margins(m2, conic, opac, order, px + 0.5, py + 0.5, alpha_max)
                    worst = min(worst, w)
                    n_clamped += c
                    n_stopped += stopped
    out["alpha_thresholds"] = worst
    out["clamped_pairs"] = float(n_clamped)
    out["stopped_pixels"] = float(n_stopped)
    return out


def binning_extents(m2: np.ndarray, conic: np.ndarray, opacity: float, radius: float) -> tuple[float, float]:
    """Half-sizes (x, y) of the box a splat is binned with: its square radius, cut to the
    bounding box of the ellipse where its alpha reaches 1/255; (0, 0) if it never does."""
    if radius <= 0 or 255.0 * opacity < 1.0:
        return 0.0, 0.0
    k2 = 2.0 * math.log(255.0 * opacity)
    det = conic[0] * conic[2] - conic[1] ** 2
    return min(radius, math.sqrt(k2 * conic[2] / det)), min(radius, math.sqrt(k2 * conic[0] / det))


def _cov2d_from_conic(q: np.ndarray) -> tuple[float, float, float]:
    inv = np.linalg.inv(np.array([[q[0], q[1]], [q[1], q[2]]]))
    return inv[0, 0], inv[0, 1], inv[1, 1]


def margins_ok(m: dict[str, float], require_events: bool = False, mode: str = ks.DEFAULT_MODE) -> bool:
    """Clear of every discontinuity; with `require_events`, the clamp and the stop also occur.

    In "gsplat" mode only the stop is required: its clamp 0.999 lies within 1e-3 (MARGIN) of every
    opacity up to 1, so no splat can be blended at the clamp clear of it; the clamp's branch is the
    same code as in "3dgs" mode with another constant, which the "3dgs" checks cover."""
    clamp_needed = mode == "3dgs"
    if require_events and ((clamp_needed and m["clamped_pairs"] < 1) or m["stopped_pixels"] < 1):
        return False
    return (m["tile_px"] >= MARGIN_PX and m["radius_ceil"] >= MARGIN and m["depth_gap"] >= MARGIN_DEPTH
            and m["color"] >= MARGIN and m["jacobian_clamp"] >= MARGIN and m["alpha_thresholds"] >= MARGIN)


def smooth_scene(seed: int, *, antialiased: bool = False, sh_degree: int | None = None, require_events: bool = False,
                 mode: str = ks.DEFAULT_MODE, dilation: float | None = None, **kwargs) -> Scene:
    """The first scene from `seed`'s stream that is at least the margins away from every discontinuity
    (and, with `require_events`, blends a splat at the 0.99 clamp and stops some pixel at T < 1e-4)."""
    rng = np.random.default_rng(seed)
    for _ in range(MAX_REDRAWS):
        scene = random_scene(rng, **kwargs)
        if margins_ok(discontinuity_margins(scene, sh_degree, antialiased, mode, dilation), require_events, mode):
            return scene
    raise RuntimeError(f"no scene clear of the discontinuities in {MAX_REDRAWS} draws (seed {seed})")


# ----------------------------------------------------------------------------- stage functions


def project_fn(camera: ks.SplatCamera, sh_degree: int | None, antialiased: bool, mode: str = ks.DEFAULT_MODE,
               dilation: float | None = None):
    def f(means, log_scales, quats, opacity_logits, sh):
        g = ks.gaussian_inputs(means, log_scales, quats, opacity_logits, sh)
        p = ks.project(g, camera, sh_degree=sh_degree, antialiased=antialiased, mode=mode, dilation=dilation)
        return {"means2d": p.means2d, "conics": p.conics, "depths": p.depths, "colors": p.colors,
                "opacities": p.opacities}

    def vjp(inputs, cot):
        g = ks.gaussian_inputs(*(inputs[k] for k in PARAMS))
        p = ks.project(g, camera, sh_degree=sh_degree, antialiased=antialiased, mode=mode, dilation=dilation)
        grads = ks.project_backward(g, camera, p.radii, cot["means2d"], cot["conics"], cot["depths"], cot["colors"],
                                    cot["opacities"], sh_degree=sh_degree, antialiased=antialiased, mode=mode,
                                    dilation=dilation)
        return grads

    return f, vjp


def rasterize_fn(radii: np.ndarray, width: int, height: int, mode: str = ks.DEFAULT_MODE):
    def f(means2d, conics, colors, opacities, depths, background):
        s = ks.splats_2d(means2d, conics, colors, opacities, depths, radii)
        r, _ = ks.rasterize(s, width, height, background, mode=mode)
        return {"rgb": r.rgb, "alpha": r.alpha, "depth": r.depth}

    def vjp(inputs, cot):
        s = ks.splats_2d(*(inputs[k] for k in ("means2d", "conics", "colors", "opacities", "depths")), radii)
        r, tiles = ks.rasterize(s, width, height, inputs["background"], mode=mode)
        grads = ks.rasterize_backward(s, width, height, inputs["background"], tiles, r, cot["rgb"], cot["alpha"],
                                      cot["depth"], mode=mode)
        return grads

    return f, vjp


def render_fn(camera: ks.SplatCamera, sh_degree: int | None, antialiased: bool, mode: str = ks.DEFAULT_MODE,
              dilation: float | None = None):
    def f(means, log_scales, quats, opacity_logits, sh, background):
        g = ks.gaussian_inputs(means, log_scales, quats, opacity_logits, sh)
        r = ks.render(g, camera, background, sh_degree=sh_degree, antialiased=antialiased, mode=mode,
                      dilation=dilation)
        return {"rgb": r.rgb, "alpha": r.alpha, "depth": r.depth}

    def vjp(inputs, cot):
        g = ks.gaussian_inputs(*(inputs[k] for k in PARAMS))
        r = ks.render(g, camera, inputs["background"], sh_degree=sh_degree, antialiased=antialiased, mode=mode,
                      dilation=dilation)
        grads = ks.render_backward(g, r, cot["rgb"], cot["alpha"], cot["depth"])
        return {k: v for k, v in grads.items() if k != "means2d"}

    return f, vjp


# ----------------------------------------------------------------------------- checks


def _tag(mode: str, antialiased: bool, dilation: float | None = None) -> str:
    return f"{mode},{'aa' if antialiased else 'classic'}{'' if dilation is None else f',dilation={dilation:g}'}"


def check_project(seed: int, antialiased: bool, sh_degree: int | None = None, off_frustum: bool = False,
                  mode: str = ks.DEFAULT_MODE, dilation: float | None = None) -> list[GradcheckResult]:
    scene = smooth_scene(seed, antialiased=antialiased, sh_degree=sh_degree, off_frustum=off_frustum, mode=mode,
                         dilation=dilation)
    f, vjp = project_fn(scene.camera, sh_degree, antialiased, mode, dilation)
    name = (f"splat.project[{_tag(mode, antialiased, dilation)},deg={sh_degree},seed={seed}"
            f"{',off' if off_frustum else ''}]")
    return check_vjp(f, vjp, scene.params, seed=seed, name=name)


def check_rasterize(seed: int, mode: str = ks.DEFAULT_MODE) -> list[GradcheckResult]:
    scene = smooth_scene(seed, require_events=True, mode=mode)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    p = ks.project(g, scene.camera, mode=mode)
    inputs = {"means2d": p.means2d, "conics": p.conics, "colors": p.colors, "opacities": p.opacities,
              "depths": p.depths, "background": scene.background}
    f, vjp = rasterize_fn(p.radii, scene.camera.width, scene.camera.height, mode)
    return check_vjp(f, vjp, inputs, seed=seed, name=f"splat.rasterize[{mode},seed={seed}]")


def check_render(seed: int, antialiased: bool, big: int = 0, mode: str = ks.DEFAULT_MODE,
                 off_frustum: bool = False, dilation: float | None = None) -> list[GradcheckResult]:
    scene = smooth_scene(seed, antialiased=antialiased, require_events=not antialiased, big=big, mode=mode,
                         off_frustum=off_frustum, dilation=dilation)
    f, vjp = render_fn(scene.camera, None, antialiased, mode, dilation)
    inputs = dict(scene.params, background=scene.background)
    name = (f"splat.render[{_tag(mode, antialiased, dilation)},seed={seed}{f',big={big}' if big else ''}"
            f"{',off' if off_frustum else ''}]")
    return check_vjp(f, vjp, inputs, seed=seed, name=name)


@register_check("splat.project")
def project_checks() -> list[GradcheckResult]:
    out = []
    for seed in (0, 1):
        out += check_project(seed, antialiased=False)
        out += check_project(seed, antialiased=True)
    out += check_project(2, antialiased=False, sh_degree=1)
    out += check_project(3, antialiased=True, off_frustum=True)
    # gsplat's conventions (kernels/splat/modes.py), both with a splat beyond the frustum clamp.
    out += check_project(4, antialiased=False, off_frustum=True, mode="gsplat")
    out += check_project(5, antialiased=True, off_frustum=True, mode="gsplat")
    # A non-default low-pass dilation (the `dilation` parameter, kernels/splat/modes.py), with and without
    # the compensation that compares the covariance before and after it.
    out += check_project(6, antialiased=True, dilation=0.1)
    out += check_project(7, antialiased=False, dilation=0.0)
    return out


@register_check("splat.rasterize")
def rasterize_checks() -> list[GradcheckResult]:
    return check_rasterize(0) + check_rasterize(1) + check_rasterize(2) + check_rasterize(3, mode="gsplat")


@register_check("splat.render")
def render_checks() -> list[GradcheckResult]:
    # The last two: splats whose radius hits the clamp (kernels/splat/projection.py).
    return (check_render(0, False) + check_render(1, True) + check_render(2, False) + check_render(3, False, big=2)
            + check_render(4, True, big=1) + check_render(5, False, off_frustum=True)
            + check_render(6, False, mode="gsplat", off_frustum=True) + check_render(7, True, mode="gsplat"))


# ----------------------------------------------------------------------------- camera gradients


def camera_render_fn(scene: Scene, mode: str, antialiased: bool, dilation: float | None = None):
    """The render as a function of the splats, a pose twist xi (6,) and the intrinsics (4,):
    camera = scene.camera with intrinsics (fx, fy, cx, cy), then viewmat <- exp(xi^) viewmat. Its
    VJP is render_backward(want_camera=True), the gradient at xi = 0: the checks pass xi = 0, where
    the finite differences of xi are exactly the left-perturbation derivative."""
    base = scene.camera

    def f(means, log_scales, quats, opacity_logits, sh, xi, intrinsics):
        g = ks.gaussian_inputs(means, log_scales, quats, opacity_logits, sh)
        r = ks.render(g, base.with_intrinsics(*intrinsics).perturbed(xi), scene.background, mode=mode,
                      antialiased=antialiased, dilation=dilation)
        return {"rgb": r.rgb, "alpha": r.alpha, "depth": r.depth}

    def vjp(inputs, cot):
        g = ks.gaussian_inputs(*(inputs[k] for k in PARAMS))
        cam = base.with_intrinsics(*inputs["intrinsics"]).perturbed(inputs["xi"])
        r = ks.render(g, cam, scene.background, mode=mode, antialiased=antialiased, dilation=dilation)
        grads = ks.render_backward(g, r, cot["rgb"], cot["alpha"], cot["depth"], want_camera=True)
        return {**{k: grads[k] for k in PARAMS}, "xi": grads["pose"], "intrinsics": grads["intrinsics"]}

    return f, vjp


def _camera_inputs(scene: Scene) -> dict[str, np.ndarray]:
    return dict(scene.params, xi=np.zeros(6), intrinsics=scene.camera.params()[:4].copy())


def check_camera(seed: int, mode: str, antialiased: bool, near_clamp: bool = True,
                 dilation: float | None = None) -> list[GradcheckResult]:
    scene = smooth_scene(seed, antialiased=antialiased, require_events=not antialiased, mode=mode,
                         near_clamp=mode if near_clamp else None, dilation=dilation)
    f, vjp = camera_render_fn(scene, mode, antialiased, dilation)
    name = f"splat.camera[{_tag(mode, antialiased, dilation)},seed={seed}{',near_clamp' if near_clamp else ''}]"
    return check_vjp(f, vjp, _camera_inputs(scene), seed=seed, name=name)


def depth_target(scene: Scene, mode: str, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(measured depth, mask, min_alpha) for a depth-loss check: the scene's expected depth plus noise
    (sd 0.05), a random 70% mask, a few missing (0) measurements, and the min_alpha of 0.3-0.7 farthest
    from every pixel's alpha; residuals and alphas at least 1e-4 from the loss's kinks."""
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    r = ks.render(g, scene.camera, scene.background, mode=mode)
    rng = np.random.default_rng(seed)
    z_hat = r.depth / np.maximum(r.alpha, 1e-12)
    measured = z_hat + rng.normal(0.0, 0.05, z_hat.shape)
    while np.min(np.abs(measured - z_hat)) < 1e-4:
        measured = z_hat + rng.normal(0.0, 0.05, z_hat.shape)
    measured[rng.random(z_hat.shape) < 0.05] = 0.0
    mask = rng.random(z_hat.shape) < 0.7
    candidates = np.linspace(0.3, 0.7, 41)
    gaps = [np.min(np.abs(r.alpha - c)) for c in candidates]
    min_alpha = float(candidates[int(np.argmax(gaps))])
    if max(gaps) < 1e-4:
        raise RuntimeError(f"no min_alpha clear of the alphas (seed {seed})")
    return measured, mask, min_alpha


def camera_loss_fn(scene: Scene, mode: str, loss):
    """A scalar loss of the render as a function of the splats, the pose twist xi and the intrinsics:
    `loss(render) -> (L, dL/dC, dL/dA, dL/dD)`, dL/dC None where the loss does not read the colour."""
    base = scene.camera

    def render(inputs):
        g = ks.gaussian_inputs(*(inputs[k] for k in PARAMS))
        cam = base.with_intrinsics(*inputs["intrinsics"]).perturbed(inputs["xi"])
        return g, ks.render(g, cam, scene.background, mode=mode)

    def f(**inputs):
        return {"loss": np.array([loss(render(inputs)[1])[0]])}

    def vjp(inputs, cot):
        g, r = render(inputs)
        _, g_rgb, g_alpha, g_depth = loss(r)
        c = float(cot["loss"][0])
        g_rgb = np.zeros(r.rgb.shape) if g_rgb is None else c * g_rgb
        grads = ks.render_backward(g, r, g_rgb, c * g_alpha, c * g_depth, want_camera=True)
        return {**{k: grads[k] for k in PARAMS}, "xi": grads["pose"], "intrinsics": grads["intrinsics"]}

    return f, vjp


def depth_loss_fn(scene: Scene, mode: str, measured: np.ndarray, mask: np.ndarray, min_alpha: float, kind: str):
    """research.splats.loss.depth_loss of the render, as a function of the splats, xi and the intrinsics."""
    from research.splats.loss import depth_loss

    def loss(r):
        value, g_depth, g_alpha = depth_loss(r.depth, r.alpha, measured, mask, min_alpha=min_alpha, kind=kind)
        return value, None, g_alpha, g_depth

    return camera_loss_fn(scene, mode, loss)


def check_depth_loss(seed: int, mode: str, kind: str) -> list[GradcheckResult]:
    scene = smooth_scene(seed, mode=mode, near_clamp=mode)
    measured, mask, min_alpha = depth_target(scene, mode, seed)
    f, vjp = depth_loss_fn(scene, mode, measured, mask, min_alpha, kind)
    # One scalar (a mean over ~1000 pixels, about 0.05) whose splat gradients are as small as 1e-7:
    # central differences at the default step 1e-6 lost up to 9.9e-7 of them (relative) to rounding,
    # 2.5e-7 at 1e-5, which is still 10x inside every discontinuity margin (the scene's MARGIN, and
    # 1e-4 for the residuals' and alphas' kinks in depth_target). The pose and intrinsics keep the
    # default step, where the larger step's truncation error grew (6e-7 against 1e-8 on xi).
    eps = {k: 1e-5 for k in PARAMS}
    return check_vjp(f, vjp, _camera_inputs(scene), seed=seed, eps=eps,
                     name=f"splat.depth_loss[{mode},{kind},seed={seed}]")


@register_check("splat.camera")
def camera_checks() -> list[GradcheckResult]:
    # Pose (left se(3) twist) and intrinsics gradients of rgb, alpha and depth, beside the splats'.
    return (check_camera(0, "3dgs", False) + check_camera(1, "3dgs", True) + check_camera(2, "gsplat", False)
            + check_camera(3, "gsplat", True, near_clamp=False)
            # The pose refinement's path with a non-default low-pass dilation (kernels/splat/modes.py).
            + check_camera(4, "3dgs", True, dilation=0.1))


@register_check("splat.depth_loss")
def depth_loss_checks() -> list[GradcheckResult]:
    return check_depth_loss(0, "3dgs", "l1") + check_depth_loss(1, "gsplat", "l2")
