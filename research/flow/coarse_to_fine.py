"""Coarse-to-fine correlation flow: normalised-patch correlation lookups with warping, and a TV-L1 step.

Built on kernels.corr's windowed lookup (4), for real images. An image pyramid
I^k (k = 0 finest; each level a Gaussian blur sigma = 1 then 2x decimation) is
walked from the coarsest level to the finest, the flow u (in level-k pixels)
carried between levels by bilinear upsampling times 2. At each level, `warps`
times:

1. Warp. Frame 2 is resampled at the current flow, J(p) = I_2^k(p + u(p))
   (bilinear, borders clamped), so the remaining motion is small.
2. Features (`patch_features`). Every pixel of I_1^k and J gets its P x P patch
   (each colour channel), made zero-mean and unit-norm over the patch: f1 . f2 is
   the patches' normalised cross-correlation (NCC), invariant to gain and offset
   between the frames. A patch whose spread (root-mean-square about its mean) is
   below `texture_floor` is flat: its feature is scaled down towards 0.
3. Lookup. NCC(p, d) = f1(p) . f2(p + d) for the (2r + 1)^2 integer offsets d of
   a radius-r window: `kernels.corr.lookup` in a one-level correlation pyramid
   when that pyramid fits `memory_budget_mib` (its size is H W H W 4 bytes), else
   `kernels.corr.lookup_onthefly` (H W (2r + 2)^2 values at a time). Offsets
   landing outside frame 2 are excluded.
4. Match. The best offset d* and a sub-pixel correction per axis from a parabola
   through NCC at d* - e, d*, d* + e: delta = (c_- - c_+) / (2 (c_- - 2 c_0 + c_+)),
   clipped to +-1/2; the matched flow is m = u + d* + delta. Its confidence is
   w = max(0, NCC(d*) - max NCC over offsets >= 2 away from d*), times the patch's
   texture weight: ~0 where the peak is not distinct (flat, periodic, occluded),
   and 0 where the window's patches reach warped pixels whose p + u(p) left
   frame 2 (the warp repeats frame 2's border there: a made-up match).
5. Regularise (TV-L1). u = argmin_u sum_p lambda w_p |u_p - m_p|_1 + TV(u), with
   TV(u) = sum_p |grad u_x(p)| + |grad u_y(p)| (isotropic per component), solved by
   `tv_iterations` steps of the primal-dual algorithm of Chambolle and Pock
   (2011), tau = sigma = 1/sqrt(8): the dual step p <- proj_{|p| <= 1}(p + sigma
   grad u_bar), the primal step u <- prox(u + tau div p), where prox is the
   soft-threshold of u towards m by tau lambda w_p, and u_bar = 2 u_new - u_old.
   Where no distinct match exists (w = 0) the flow is filled from its neighbours.

The flow of the finest level is the result, (H, W, 2) in pixels, x right and y
down, frame 1 -> frame 2.

Images: uint8, uint16 or float colour/grey in [0, 1] (research.images.to_unit);
the NCC features need no further normalisation, and the texture floor is in the
[0, 1] units of that rule.

Defaults (`C2FConfig`) were chosen on held-out data only: research.flow.texture's
tuning split (the lower half of the photograph; flows of seeds 100 and 101) and
raft_flow's quick Mitsuba pairs (scene `objects`, 2 pairs) rendered with seed 7,
a seed no table reports; never on the pairs reported (the photograph's upper
half with seeds 0-3, Mitsuba seeds 0-2). One setting at a time was varied from
levels 5, radius 4, warps 2, patch 5, tv_weight 4, tv_iterations 60. Mean EPE
on the photograph's tuning pairs (Farneback 1.28 px, DIS 0.23, zero flow 4.18):
0.139 there; tv_weight 1 / 16: 0.150 / 0.276; radius 2: 0.142; warps 1: 0.159;
patch 3 / 7: 0.183 / 0.138; tv_iterations 30: 0.152. The border rule of step 4
came from the error maps of the held-out Mitsuba pairs: EPE there went from
1.57 to 1.10 px clean and 1.42 to 1.13 stressed (Farneback 1.19 / 1.27), 0.139
to 0.137 on the photograph. Then on the Mitsuba pairs (clean / stressed):
patch 7: 0.97 / 1.06 (chosen: best on both held-out sets, at about twice the
lookup cost of patch 5); levels 4: 1.13 / 1.14; tv_weight 2 / 8: 1.36 / 1.37
and 2.59 / 1.36. The last shows the method's weak spot: a periodic texture
(the checkered floor) can lock a region onto the wrong period at a coarse level,
which the finer levels' +-r windows cannot undo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp
from scipy import ndimage

from kernels import _arrays as A
from kernels import corr
from research import values
from research.images import to_unit


@dataclass(frozen=True)
class C2FConfig:
    """Settings of `coarse_to_fine_flow` (module docstring); each is checked when the config is made."""

    levels: int = 5  # image pyramid levels (the coarsest is shrunk to at least 2 r + 2 pixels)
    radius: int = 4  # lookup window radius r, in level pixels
    warps: int = 2  # lookups (warp, match, regularise) per level
    patch: int = 7  # P: side of the normalised patches
    tv_weight: float = 4.0  # lambda: data weight against TV (larger: less smoothing)
    tv_iterations: int = 60
    texture_floor: float = 0.01  # patch spread (in [0, 1] units) below which a patch counts as flat
    memory_budget_mib: float = 256.0  # above it, the on-the-fly lookup instead of the dense one

    def __post_init__(self) -> None:
        A.check_int("levels", self.levels, minimum=1)
        A.check_int("radius", self.radius, minimum=1)  # the parabola reads d* +- 1
        A.check_int("warps", self.warps, minimum=1)
        A.check_int("patch", self.patch, minimum=3)
        if self.patch % 2 == 0:
            raise ValueError(f"patch: expected an odd side >= 3, got {self.patch}")
        values.number("tv_weight", self.tv_weight, 0, low_open=True)
        A.check_int("tv_iterations", self.tv_iterations, minimum=0)
        values.number("texture_floor", self.texture_floor, 0, low_open=True)
        values.number("memory_budget_mib", self.memory_budget_mib, 0, low_open=True)


# --------------------------------------------------------------------------- pyramid, warping, features


def image_pyramid(img: np.ndarray, levels: int, min_size: int) -> list[np.ndarray]:
    """[I^0 = img, I^1, ...] (H_k, W_k, ch): blur sigma = 1 then keep every other pixel, while a level
    keeps at least `min_size` pixels on each side (so at most `levels` levels)."""
    out = [img]
    while len(out) < levels and min(out[-1].shape[:2]) // 2 >= min_size:
        blurred = ndimage.gaussian_filter(out[-1], sigma=(1.0, 1.0, 0.0), mode="nearest")
        out.append(blurred[::2, ::2])
    return out


def warp(img: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J(p) = img(p + flow(p)), bilinear, borders clamped, and where p + flow(p) lies inside img
    (elsewhere J repeats img's border); img (H, W, ch), flow (2, H, W)."""
    h, w = img.shape[:2]
    yy, xx = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64), indexing="ij")
    sy, sx = yy + flow[1], xx + flow[0]
    real = (sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1)
    pos = [np.clip(sy, 0, h - 1), np.clip(sx, 0, w - 1)]
    return np.stack([ndimage.map_coordinates(img[..., c], pos, order=1, mode="nearest")
                     for c in range(img.shape[2])], axis=-1), real


def patch_features(img: np.ndarray, patch: int, texture_floor: float) -> tuple[np.ndarray, np.ndarray]:
    """(ch P^2, H, W) float32 zero-mean unit-norm patches and the (H, W) texture weight in [0, 1]."""
    h, w, ch = img.shape
    half = patch // 2
    padded = np.pad(img.astype(np.float32), ((half, half), (half, half), (0, 0)), mode="edge")
    # (H, W, ch, P, P) windows as one copy, ordered channel, then row dy, then column dx.
    windows = np.lib.stride_tricks.sliding_window_view(padded, (patch, patch), axis=(0, 1))
    f = np.ascontiguousarray(windows.transpose(2, 3, 4, 0, 1)).reshape(ch * patch * patch, h, w)
    f -= f.mean(axis=0, keepdims=True)
    spread = np.sqrt((f ** 2).mean(axis=0))  # RMS about the patch mean, in image units
    texture = np.clip(spread / texture_floor, 0.0, 1.0)
    f /= np.maximum(np.sqrt((f ** 2).sum(axis=0)), 1e-12)
    return (f * texture).astype(np.float32), texture


def upsample(flow: np.ndarray, height: int, width: int) -> np.ndarray:
    """A level-(k+1) flow (2, h, w) as level-k flow (2, H, W): bilinear, times 2."""
    h, w = flow.shape[1:]
    yy = (np.arange(height) + 0.5) * h / height - 0.5
    xx = (np.arange(width) + 0.5) * w / width - 0.5
    grid = np.meshgrid(yy, xx, indexing="ij")
    return np.stack([2 * ndimage.map_coordinates(flow[c], grid, order=1, mode="nearest") for c in range(2)])


# --------------------------------------------------------------------------- lookup and match


def ncc_window(f1: np.ndarray, f2: np.ndarray, radius: int, budget_mib: float, device: str) -> tuple[np.ndarray, str]:
    """NCC(p, d) (side^2, H, W) for the integer offsets d of the window, in RAFT's channel order
    (x offset slowest), by the dense or the on-the-fly lookup (module docstring, step 3)."""
    channels, h, w = f1.shape
    centres = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)).astype(np.float32)
    x1, x2, xy = (wp.array(a, device=device) for a in (f1, f2, centres))
    if corr.dense_bytes(h, w, 1) <= budget_mib * 2 ** 20:
        out, path = corr.lookup([corr.correlation_volume(x1, x2)], xy, radius), "dense"
    else:
        out, path = corr.lookup_onthefly(x1, [x2], xy, radius), "on the fly"
    return out.numpy() * np.float32(math.sqrt(channels)), path


def match(ncc: np.ndarray, radius: int, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Step d* + delta (2, H, W) and distinctiveness (H, W) from a window of NCC values (module docstring, 4);
    `inside` (side^2, H, W) marks the offsets that land in frame 2."""
    side = 2 * radius + 1
    h, w = ncc.shape[1:]
    flat = np.where(inside, ncc, -np.inf)
    best = np.argmax(flat, axis=0)
    ia, ib = best // side, best % side
    rows, cols = np.indices((h, w))
    top = flat[best, rows, cols]
    found = np.isfinite(top)

    def at(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        valid = (a >= 0) & (a < side) & (b >= 0) & (b < side)
        return np.where(valid, flat[np.clip(a, 0, side - 1) * side + np.clip(b, 0, side - 1), rows, cols], -np.inf)

    def parabola(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        ok = found & np.isfinite(lo) & np.isfinite(hi)
        lo, hi, c0 = (np.where(ok, v, 0.0) for v in (lo, hi, top))
        den = lo - 2.0 * c0 + hi
        ok &= den < -1e-9
        return np.where(ok, np.clip((lo - hi) / np.where(ok, 2.0 * den, 1.0), -0.5, 0.5), 0.0)

    dx = ia - radius + parabola(at(ia - 1, ib), at(ia + 1, ib))
    dy = ib - radius + parabola(at(ia, ib - 1), at(ia, ib + 1))
    # The rival: the best offset two or more samples away from d*, i.e. outside its 3 x 3 neighbourhood.
    for da in (-1, 0, 1):
        for db in (-1, 0, 1):
            a, b = ia + da, ib + db
            ok = (a >= 0) & (a < side) & (b >= 0) & (b < side)
            flat[np.where(ok, a * side + b, best), rows, cols] = -np.inf
    rival = flat.max(axis=0)
    distinct = np.where(found, top - np.where(np.isfinite(rival), rival, 0.0), 0.0)  # no rival: the peak itself
    step = np.where(found, np.stack([dx, dy]), 0.0)
    return step, np.clip(distinct, 0.0, None)


def window_inside(flow: np.ndarray, radius: int) -> np.ndarray:
    """(side^2, H, W): whether p + u(p) + d lies inside frame 2 (where the warped frame is real), in the
    lookup's channel order (x offset slowest)."""
    side = 2 * radius + 1
    h, w = flow.shape[1:]
    d = np.arange(side) - radius
    sx = np.arange(w)[None, None, :] + flow[0][None] + d[:, None, None]
    sy = np.arange(h)[None, :, None] + flow[1][None] + d[:, None, None]
    ix = (sx >= 0) & (sx <= w - 1)
    iy = (sy >= 0) & (sy <= h - 1)
    return (ix[:, None] & iy[None, :]).reshape(side * side, h, w)


# --------------------------------------------------------------------------- TV-L1


def _grad(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences along x and y of (..., H, W), zero across the last column / row."""
    gx = np.zeros_like(u)
    gy = np.zeros_like(u)
    gx[..., :, :-1] = u[..., :, 1:] - u[..., :, :-1]
    gy[..., :-1, :] = u[..., 1:, :] - u[..., :-1, :]
    return gx, gy


def _div(px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """The discrete divergence, -(adjoint of `_grad`), of (..., H, W) fields."""
    d = np.zeros_like(px)
    d[..., :, 0] = px[..., :, 0]
    d[..., :, 1:-1] = px[..., :, 1:-1] - px[..., :, :-2]
    d[..., :, -1] = -px[..., :, -2]
    d[..., 0, :] += py[..., 0, :]
    d[..., 1:-1, :] += py[..., 1:-1, :] - py[..., :-2, :]
    d[..., -1, :] -= py[..., -2, :]
    return d


def tv_l1(m: np.ndarray, weight: np.ndarray, lam: float, iterations: int, u0: np.ndarray) -> np.ndarray:
    """argmin_u sum lam w |u - m| + TV(u), each flow component on its own (module docstring, step 5), from u0."""
    tau = sigma = 1.0 / math.sqrt(8.0)
    u = u0.copy()
    ubar = u.copy()
    px = np.zeros_like(u)
    py = np.zeros_like(u)
    thr = (tau * lam) * weight[None]
    for _ in range(iterations):
        gx, gy = _grad(ubar)
        px += sigma * gx
        py += sigma * gy
        norm = np.maximum(1.0, np.hypot(px, py))
        px /= norm
        py /= norm
        r = u + tau * _div(px, py) - m
        u_new = m + np.sign(r) * np.maximum(np.abs(r) - thr, 0.0)
        ubar = 2.0 * u_new - u
        u = u_new
    return u


# --------------------------------------------------------------------------- the estimator


def coarse_to_fine_flow(frame1: np.ndarray, frame2: np.ndarray, cfg: C2FConfig = C2FConfig(), *,
                        device: str = "cpu", info: dict | None = None) -> np.ndarray:
    """Flow (H, W, 2) from frame 1 to frame 2 (module docstring). `info`, if given, receives the
    lookup path used at each level ("dense" or "on the fly") and the pyramid's level sizes."""
    i1, i2 = to_unit(frame1, "frame1"), to_unit(frame2, "frame2")
    if i1.shape != i2.shape:
        raise ValueError(f"frame2: expected the shape of frame1 {i1.shape}, got {i2.shape}")
    i1 = (i1[..., None] if i1.ndim == 2 else i1).astype(np.float64)
    i2 = (i2[..., None] if i2.ndim == 2 else i2).astype(np.float64)
    min_size = 2 * cfg.radius + 2
    if min(i1.shape[:2]) < min_size:
        raise ValueError(f"frame1: expected at least {min_size}x{min_size} pixels for radius {cfg.radius}, "
                         f"got {i1.shape[0]}x{i1.shape[1]}")
    p1 = image_pyramid(i1, cfg.levels, min_size)
    p2 = image_pyramid(i2, len(p1), min_size)
    flow = np.zeros((2,) + p1[-1].shape[:2], dtype=np.float32)  # float32 throughout: TV-L1 3x faster than float64
    paths = []
    for k in range(len(p1) - 1, -1, -1):
        h, w = p1[k].shape[:2]
        if flow.shape[1:] != (h, w):
            flow = upsample(flow, h, w)
        f1, texture = patch_features(p1[k], cfg.patch, cfg.texture_floor)
        for _ in range(cfg.warps):
            warped, real = warp(p2[k], flow)
            f2, _tex2 = patch_features(warped, cfg.patch, cfg.texture_floor)
            ncc, path = ncc_window(f1, f2, cfg.radius, cfg.memory_budget_mib, device)
            step, distinct = match(ncc, cfg.radius, window_inside(flow, cfg.radius))
            # A match whose window reaches warped pixels that repeat frame 2's border is made up: no weight.
            real_window = ndimage.minimum_filter(real, size=cfg.patch + 2 * cfg.radius, mode="nearest")
            weight = (distinct * texture * real_window).astype(np.float32)
            m = (flow + step).astype(np.float32)
            flow = tv_l1(m, weight, cfg.tv_weight, cfg.tv_iterations, np.where(weight > 0, m, flow).astype(np.float32))
        paths.append(path)
    if info is not None:
        info["lookup"] = paths[::-1]
        info["level_sizes"] = [tuple(p.shape[:2]) for p in p1]
    return np.moveaxis(flow, 0, -1).astype(np.float64)
