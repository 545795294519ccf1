"""Mapping: the splat map's initialisation, densification and optimisation over a keyframe window.

New splats (SplaTAM): every `stride`-th pixel u with measured depth z > 0 in a frame whose
world-to-camera pose is T gives one isotropic splat at the back-projected point
mu = T^-1 (z K^-1 (u + 1/2, 1)), radius r = stride z / f (f = (fx + fy) / 2: the footprint of a
stride x stride block of pixels at that depth), opacity `init_opacity` (0.95; SplaTAM starts at 1/2),
identity rotation and the pixel's colour as its SH DC term (c - 1/2) / C0 (the map is rendered at SH
degree 0).

Densification (SplaTAM's "non-presence" mask): with the map rendered at the frame's tracked pose,
expected depth z_hat = D / A and alpha A,

    add where z > 0 and (A < a_min  or  (z < z_hat and |z_hat - z| > k median_S |z_hat - z|)),

the silhouette being too thin or a surface in front of the map's (S: pixels with A > a_min and
z > 0; a_min = 0.5, k = 50 as SplaTAM).

Optimisation (the window): `iters` Adam steps (research.splats.optim's groups, kernels.optim.Adam), each
on one keyframe of the window drawn at random (the newest keyframe every other step), of

    L = w_c mean |C - I|  +  w_d (1/|V|) sum_V |D/A - z|,   V = {z > 0, A > a_d = 0.01},

the colour term over every pixel (premultiplied on a black background, so empty pixels pull alpha
down) and the depth term over measured pixels; the gradients are the renderer's hand-written
backward. Means, log-scales, opacity logits and the DC colour move; rotations and higher SH stay
(isotropic, view-independent splats, as SplaTAM). Afterwards splats with opacity below 0.005 are
removed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from kernels import splat as ks
from kernels.sh import SH_C0
from kernels.optim import Adam
from research.splats.loss import depth_loss
from research.splats.model import SH_COEFFS, GaussianModel
from research.slam.tracking import host
from research.splats.optim import make_adam


@dataclass(frozen=True)
class MapConfig:
    """Mapping settings: SplaTAM's densification rule and thresholds; init_opacity (0.95 against 0.5) picked
    from the frame-0 map of experiments/splat_slam.py's seed-0 sequence; the rates were set once, untuned."""

    iters: int = 30
    stride: int = 2  # pixel stride of new splats
    min_alpha: float = 0.5  # densify where the silhouette is below this
    depth_factor: float = 50.0  # ... or the depth disagrees by more than this x the median error
    color_weight: float = 0.5
    depth_weight: float = 1.0
    lr_means: float = 0.001  # scene units per step
    lr_log_scales: float = 0.001
    lr_opacity: float = 0.05
    lr_color: float = 0.0025
    prune_opacity: float = 0.005
    depth_min_alpha: float = 0.01  # the depth term counts pixels whose rendered alpha exceeds this
    init_opacity: float = 0.95  # opacity of new splats (SplaTAM: 0.5; opaque from the start suits the CPU budget)

    def __post_init__(self) -> None:
        for name in ("iters", "stride"):
            v = getattr(self, name)
            if int(v) != v or v < (0 if name == "iters" else 1):
                raise ValueError(f"{name}: expected an integer >= {0 if name == 'iters' else 1}, got {v!r}")
        if not 0.0 < self.init_opacity < 1.0:
            raise ValueError(f"init_opacity: expected a value in (0, 1), got {self.init_opacity!r}")
        if not 0.0 <= self.depth_min_alpha < 1.0:
            raise ValueError(f"depth_min_alpha: expected a value in [0, 1), got {self.depth_min_alpha!r}")
        if not 0.0 < self.min_alpha < 1.0:
            raise ValueError(f"min_alpha: expected a value in (0, 1), got {self.min_alpha!r}")
        for name in ("depth_factor", "lr_means", "lr_log_scales", "lr_opacity", "lr_color"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name}: expected a positive value, got {v!r}")


def _pixel_grid(height: int, width: int, stride: int) -> np.ndarray:
    keep = np.zeros((height, width), dtype=bool)
    keep[stride // 2::stride, stride // 2::stride] = True
    return keep


def new_splats(rgb: np.ndarray, alpha: np.ndarray, depth: np.ndarray, K: np.ndarray, w2c: np.ndarray,
               mask: np.ndarray, stride: int, opacity: float = 0.95) -> GaussianModel:
    """Splats for the pixels of `mask` (on the stride grid) with depth > 0 (module docstring); rgb is
    premultiplied linear colour, alpha its coverage (the straight colour is rgb / alpha)."""
    h, w = depth.shape
    sel = mask & (depth > 0) & _pixel_grid(h, w, stride)
    ys, xs = np.nonzero(sel)
    z = depth[ys, xs].astype(np.float64)
    x_cam = np.stack([(xs + 0.5 - K[0, 2]) / K[0, 0] * z, (ys + 0.5 - K[1, 2]) / K[1, 1] * z, z], axis=1)
    c2w = np.linalg.inv(w2c)
    means = x_cam @ c2w[:3, :3].T + c2w[:3, 3]
    a = np.maximum(alpha[ys, xs], 1e-6)[:, None]
    colors = np.clip(rgb[ys, xs] / a, 0.0, 1.0)
    n = len(z)
    radius = stride * z / (0.5 * (K[0, 0] + K[1, 1]))
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    return GaussianModel(means=means, log_scales=np.repeat(np.log(radius)[:, None], 3, axis=1), quats=quats,
                         opacity_logits=np.full(n, np.log(opacity / (1.0 - opacity))),
                         sh_dc=((colors - 0.5) / SH_C0)[:, None, :],
                         sh_rest=np.zeros((n, SH_COEFFS - 1, 3)))


def init_map(rgb: np.ndarray, alpha: np.ndarray, depth: np.ndarray, K: np.ndarray, w2c: np.ndarray,
             stride: int, opacity: float = 0.95) -> GaussianModel:
    """The map from the first RGB-D frame: a splat per measured pixel of the stride grid."""
    model = new_splats(rgb, alpha, depth, K, w2c, np.ones(depth.shape, dtype=bool), stride, opacity)
    if model.n < 4:
        raise ValueError("depth: the first frame has fewer than 4 pixels with depth > 0 to start the map from")
    return model


def densify_mask(render_alpha: np.ndarray, render_depth: np.ndarray, depth: np.ndarray,
                 cfg: MapConfig) -> np.ndarray:
    """Pixels that need new splats (module docstring), from the map's render at the frame's pose."""
    measured = depth > 0
    thin = render_alpha < cfg.min_alpha
    seen = measured & ~thin
    z_hat = np.where(seen, render_depth / np.maximum(render_alpha, 1e-6), 0.0)
    err = np.abs(z_hat - depth)
    med = float(np.median(err[seen])) if seen.any() else 0.0
    in_front = seen & (depth < z_hat) & (err > cfg.depth_factor * med)
    return measured & (thin | in_front)


@dataclass
class Keyframe:
    index: int
    w2c: np.ndarray
    rgb: np.ndarray  # (H, W, 3) premultiplied linear float32
    depth: np.ndarray  # (H, W) float32, 0 = none


def make_map_adam(model: GaussianModel, cfg: MapConfig) -> Adam:
    return make_adam(model, {"means": cfg.lr_means, "log_scales": cfg.lr_log_scales, "quats": 0.0,
                             "opacity_logits": cfg.lr_opacity, "sh_dc": cfg.lr_color,
                             "sh_rest": 0.0})


def mapping_loss(res: ks.Render, kf: Keyframe, cfg: MapConfig) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(L, dL/dC, dL/dA, dL/dD) of the window loss (module docstring) for a render at keyframe `kf`."""
    col = host(res.rgb)
    diff = col - kf.rgb
    lc = float(np.abs(diff).mean(dtype=np.float64))
    g_rgb = (cfg.color_weight * np.sign(diff) / diff.size).astype(col.dtype)
    ld, g_depth, g_alpha = depth_loss(host(res.depth), host(res.alpha), kf.depth, min_alpha=cfg.depth_min_alpha,
                                      kind="l1")
    return (cfg.color_weight * lc + cfg.depth_weight * ld, g_rgb, cfg.depth_weight * g_alpha,
            cfg.depth_weight * g_depth)


def map_window(model: GaussianModel, adam: Adam, window: list[Keyframe], K: np.ndarray, width: int, height: int,
               cfg: MapConfig, rng: np.random.Generator, device: Any = None) -> tuple[GaussianModel, Adam, list[float]]:
    """`cfg.iters` steps over the window's keyframes (the last one is the newest), then pruning.
    Returns the model (pruned: a new object), its optimiser state and the losses."""
    if not window:
        raise ValueError("window: expected at least one keyframe")
    bg = np.zeros(3, dtype=np.float32)
    losses = []
    for it in range(int(cfg.iters)):
        kf = window[-1] if it % 2 == 0 else window[int(rng.integers(len(window)))]
        inputs = model.inputs(device)
        res = ks.render(inputs, ks.SplatCamera(kf.w2c, K, width, height), bg, sh_degree=0)
        loss, g_rgb, g_alpha, g_depth = mapping_loss(res, kf, cfg)
        if not np.isfinite(loss):
            raise RuntimeError(f"mapping: the loss is {loss} at iteration {it + 1}")
        losses.append(loss)
        g = {k: x.numpy() for k, x in ks.render_backward(inputs, res, g_rgb, g_alpha, g_depth).items()}
        adam.step({"means": g["means"], "log_scales": g["log_scales"], "quats": np.zeros_like(model.quats),
                   "opacity_logits": g["opacity_logits"], "sh_dc": np.ascontiguousarray(g["sh"][:, :1]),
                   "sh_rest": np.zeros_like(model.sh_rest)}, params=model.arrays())
    keep = model.opacities >= cfg.prune_opacity
    if not keep.all():
        model = model.select(keep)
        adam.select(keep)
        adam.params = model.arrays()
    return model, adam, losses


def add_splats(model: GaussianModel, adam: Adam, extra: GaussianModel) -> GaussianModel:
    """`model` with `extra` appended, and zero optimiser moments for the new rows."""
    if extra.n == 0:
        return model
    model = model.append(extra)
    adam.append(extra.n)
    adam.params = model.arrays()
    return model
