"""Weight-free RAFT-style optical flow on top of kernels.corr, plus flow metrics and colour coding.

RAFT (Teed and Deng 2020) matches learned features through an all-pairs
correlation pyramid and lets a trained GRU read windowed lookups around the
current estimate. No trained weights can be had here, so both learned parts are
replaced by fixed ones:

* Features (`fixed_features`): at stride s (RAFT uses 8), each feature pixel
  holds 5 x 5 colour patches from the image blurred at SCALES = 4 scales (tap
  spacing s 2^k, Gaussian blur sigma = spacing / 2). Each scale's block is made
  zero-mean and unit-norm, so f1 . f2 / SCALES is a mean normalised
  cross-correlation (NCC) in [-1, 1]; flat regions get near-zero features. The
  coarse scales vary slowly, so they survive the pyramid's 2x2 pooling of frame
  2 and give the coarse levels something to match (with one or two fine scales
  the coarse levels were noise and diverged).
* Update (`CorrFlow.estimate`): T lookups of radius r around coords0 + flow.
  Iteration t reads level l(t) = L - 1 - floor(t L / T) (coarse to fine, T / L
  iterations per level). That level's window of NCC values is
    1. averaged over 2^l frame-1 pixels around p, weighted by texture (cost
       aggregation: the pyramid pools frame 2 only);
    2. restricted to samples inside frame 2 (zero padding would outbid negative
       correlations);
    3. read by a soft-argmax, softmax(NCC / temperature), over the 3 x 3 samples
       around its peak (sub-pixel, and not pulled to the window's centre by a broad
       correlation surface), in RAFT's channel order (x offset slowest);
  giving a step in level pixels and a confidence (peak NCC minus the best NCC two
  or more samples away, times texture: ~0 on flat or periodic texture). The steps
  are averaged over a (2^(l+1) + 1)^2 box weighted by confidence and scaled down
  where the box's mean confidence is below `min_confidence`, then flow += 2^l step.
  The flow at feature resolution is finally upsampled bilinearly by s.
* Memory: the dense pyramid takes 4 H W sum_l H_l W_l bytes at feature resolution
  (2.7 GB for a 741x500 frame at stride 4), so by default `CorrFlow` keeps it only
  below MEMORY_BUDGET_MIB = 1024 MiB and otherwise uses the on-the-fly lookup
  (the same flow to float rounding, without the volume).

Metrics (`flow_metrics`): EPE = mean |flow - gt| over a mask, and F1-all, the
KITTI 2015 outlier rate: the percentage of pixels with EPE > 3 px AND
EPE > 5% of |gt|. Colours (`flow_to_color`): the Middlebury colour wheel of
Baker et al. (2011), hue = direction, saturation = magnitude; a pixel whose flow is NaN or
infinite (or outside an optional `valid` mask) has no direction and is drawn black, the colour
no valid flow can take (valid colours have at least one channel at 1), and the scale comes from
the valid pixels only.

Images: `CorrFlow` takes uint8, uint16 or float colour images in [0, 1] (grey ones are repeated
into three channels), and `lucas_kanade` / `pyramidal_lucas_kanade` here wrap kernels.lucas_kanade
with research.images.to_unit_grey (uint8 / 255, uint16 / 65535, colour by Rec. 601 luma, a float
image outside [0, 1] refused; float64 frames stay float64, so existing callers get identical flow).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp
from scipy import ndimage

from kernels import _arrays as A
from kernels import corr
from research import values
from research.images import to_unit, unit_grey_pair

PATCH = 5
SCALES = 4
MEMORY_BUDGET_MIB = 1024  # CorrFlow keeps the dense pyramid below this, else looks up on the fly


# --------------------------------------------------------------------------- images and features


def srgb(rgba_linear: np.ndarray) -> np.ndarray:
    """(H, W, 3) display-referred colours in [0, 1] from linear premultiplied RGBA (black background)."""
    rgb = np.clip(np.asarray(rgba_linear, dtype=np.float64)[..., :3], 0.0, 1.0)
    return np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * rgb ** (1 / 2.4) - 0.055)


def grey(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of (H, W, 3) colours."""
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def feature_shape(height: int, width: int, stride: int) -> tuple[int, int]:
    return height // stride, width // stride


def fixed_features(rgb: np.ndarray, stride: int = 4, patch: int = PATCH, scales: int = SCALES) -> np.ndarray:
    """(3 patch^2 scales, H // stride, W // stride) float32 features: normalised multi-scale colour patches."""
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb: expected an (H, W, 3) image, got shape {rgb.shape}")
    h, w = feature_shape(rgb.shape[0], rgb.shape[1], stride)
    if h < 1 or w < 1:
        raise ValueError(f"stride: {stride} leaves no feature pixel in a {rgb.shape[0]}x{rgb.shape[1]} image")
    # Feature pixel centres in image index coordinates (pixel centres at +0.5 in continuous coordinates).
    cy = (np.arange(h) + 0.5) * stride - 0.5
    cx = (np.arange(w) + 0.5) * stride - 0.5
    offsets = np.arange(patch) - patch // 2
    blocks = []
    for k in range(scales):
        spacing = stride * 2 ** k
        blurred = ndimage.gaussian_filter(rgb, sigma=(0.5 * spacing, 0.5 * spacing, 0), mode="nearest")
        taps = []
        for dy in offsets:
            for dx in offsets:
                yy, xx = np.meshgrid(cy + dy * spacing, cx + dx * spacing, indexing="ij")
                for c in range(3):
                    taps.append(ndimage.map_coordinates(blurred[..., c], [yy, xx], order=1, mode="nearest"))
        block = np.stack(taps)
        block -= block.mean(axis=0, keepdims=True)
        norm = np.sqrt((block ** 2).sum(axis=0, keepdims=True))
        # A flat patch has no direction: its block fades to zero instead of amplifying noise.
        blocks.append(block / np.maximum(norm, 0.02 * np.sqrt(block.shape[0])))
    return np.concatenate(blocks).astype(np.float32)


def pixel_centres(height: int, width: int) -> np.ndarray:
    """(2, H, W) continuous coordinates (x, y) of every pixel centre: the zero-flow lookup positions."""
    return np.stack(np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)).astype(np.float32)


def upsample_flow(flow: np.ndarray, stride: int, height: int, width: int) -> np.ndarray:
    """Feature-resolution flow (2, h, w) in feature pixels -> (H, W, 2) image pixels, bilinear."""
    yy, xx = np.meshgrid((np.arange(height) + 0.5) / stride - 0.5, (np.arange(width) + 0.5) / stride - 0.5,
                         indexing="ij")
    return np.stack([stride * ndimage.map_coordinates(flow[k], [yy, xx], order=1, mode="nearest")
                     for k in range(2)], axis=-1)


# --------------------------------------------------------------------------- the estimator


@dataclass(frozen=True)
class CorrFlowConfig:
    """Settings of `CorrFlow.estimate` (module docstring); each is checked when the config is made."""

    levels: int = 4
    radius: int = 4
    iterations: int = 12
    temperature: float = 0.05
    smooth_radius: int = 1
    min_confidence: float = 0.02
    aggregate: int = 1

    def __post_init__(self) -> None:
        A.check_int("levels", self.levels, minimum=1)
        A.check_int("radius", self.radius, minimum=1)  # the soft-argmax reads 3 x 3 samples around the peak
        A.check_int("iterations", self.iterations, minimum=1)
        values.number("temperature", self.temperature, 0, low_open=True)
        A.check_int("smooth_radius", self.smooth_radius, minimum=0)
        values.number("min_confidence", self.min_confidence, 0, low_open=True)
        A.check_int("aggregate", self.aggregate, minimum=0)


def _unit_rgb(image: np.ndarray, name: str) -> np.ndarray:
    """Colour in [0, 1] by research.images' unit rule; a grey (H, W) image repeated into 3 channels."""
    unit = to_unit(image, name)
    return np.repeat(unit[..., None], 3, axis=2) if unit.ndim == 2 else unit


def lucas_kanade(frame1: np.ndarray, frame2: np.ndarray, **kwargs):
    """kernels.lucas_kanade.lucas_kanade on frames normalised by research.images.to_unit_grey (module docstring)."""
    from kernels import lucas_kanade as lk

    f1, f2 = unit_grey_pair(frame1, frame2, ("frame1", "frame2"), dtype=None)
    return lk.lucas_kanade(f1, f2, **kwargs)


def pyramidal_lucas_kanade(frame1: np.ndarray, frame2: np.ndarray, **kwargs):
    """kernels.lucas_kanade.pyramidal_lucas_kanade on frames normalised like `lucas_kanade` here."""
    from kernels import lucas_kanade as lk

    f1, f2 = unit_grey_pair(frame1, frame2, ("frame1", "frame2"), dtype=None)
    return lk.pyramidal_lucas_kanade(f1, f2, **kwargs)


class CorrFlow:
    """Correlation state for one frame pair; `estimate` runs the iterative update for any levels <= max_levels."""

    def __init__(self, rgb1: np.ndarray, rgb2: np.ndarray, *, stride: int = 4, max_levels: int = 4,
                 onthefly: bool | None = None, device: str = "cpu", memory_budget_mib: float = MEMORY_BUDGET_MIB):
        """`onthefly`: True for the on-the-fly lookup, False for the dense pyramid, None (default) for the
        dense pyramid only while it fits `memory_budget_mib` (MEMORY_BUDGET_MIB, 1 GiB), else on the fly."""
        rgb1, rgb2 = _unit_rgb(rgb1, "rgb1"), _unit_rgb(rgb2, "rgb2")
        if rgb1.shape != rgb2.shape:
            raise ValueError(f"rgb2: expected the shape of rgb1 {rgb1.shape}, got {rgb2.shape}")
        A.check_int("stride", stride, minimum=1)
        A.check_int("max_levels", max_levels, minimum=1)
        if not (onthefly is None or isinstance(onthefly, bool)):
            raise ValueError(f"onthefly: expected True, False or None (by the memory budget), got {onthefly!r}")
        values.number("memory_budget_mib", memory_budget_mib, 0, low_open=True)
        self.stride = stride
        self.image_shape = rgb1.shape[:2]
        self.f1 = fixed_features(rgb1, stride)
        self.f2 = fixed_features(rgb2, stride)
        if onthefly is None:
            fh, fw = self.f1.shape[1:]
            onthefly = corr.dense_bytes(fh, fw, max_levels) > memory_budget_mib * 2 ** 20
        self.onthefly = onthefly
        self.device = device
        self.channels, self.h, self.w = self.f1.shape
        # wp.arrays stay on the device between lookups (NumPy inputs would be copied in on every call).
        f1, f2 = (wp.array(f, device=device) for f in (self.f1, self.f2))
        if onthefly:
            self.f1_wp = f1
            self.f2_pyramid = corr.pool_features(f2, max_levels)
        else:
            self.pyramid = corr.correlation_pyramid(corr.correlation_volume(f1, f2), max_levels)
        self.max_levels = max_levels
        self.feature_norm = np.sqrt((self.f1.astype(np.float64) ** 2).sum(axis=0)) / np.sqrt(SCALES)
        self.lookups = 0

    def lookup(self, coords: np.ndarray, levels: int, radius: int) -> np.ndarray:
        self.lookups += 1
        xy = wp.array(np.ascontiguousarray(coords, dtype=np.float32), device=self.device)
        if self.onthefly:
            return corr.lookup_onthefly(self.f1_wp, self.f2_pyramid[:levels], xy, radius).numpy()
        return corr.lookup(self.pyramid[:levels], xy, radius).numpy()

    def memory_bytes(self, levels: int, radius: int) -> int:
        if self.onthefly:
            return corr.onthefly_bytes(self.h, self.w, self.channels, levels, radius)
        return corr.dense_bytes(self.h, self.w, levels)

    def estimate(self, cfg: CorrFlowConfig) -> np.ndarray:
        """Flow (H, W, 2) at image resolution."""
        if not 1 <= cfg.levels <= self.max_levels:
            raise ValueError(f"levels: expected 1..{self.max_levels}, got {cfg.levels}")
        side = 2 * cfg.radius + 1
        # Offsets of the window's samples in RAFT's order: channel a * side + b <-> (a - r, b - r).
        a, b = np.meshgrid(np.arange(side) - cfg.radius, np.arange(side) - cfg.radius, indexing="ij")
        offsets = (a.ravel()[:, None, None], b.ravel()[:, None, None])
        coords0 = pixel_centres(self.h, self.w)
        flow = np.zeros((2, self.h, self.w))
        ncc_scale = np.sqrt(self.channels) / SCALES  # corr = f1.f2 / sqrt(C); f1.f2 / SCALES is the NCC
        for t in range(cfg.iterations):
            level = cfg.levels - 1 - (t * cfg.levels) // cfg.iterations
            out = self.lookup((coords0 + flow).astype(np.float32), cfg.levels, cfg.radius)
            ncc = out[level * side * side:(level + 1) * side * side].astype(np.float64) * ncc_scale
            if cfg.aggregate:
                # Cost aggregation over frame 1: average each window sample over 2^l frame-1 pixels around p
                # (weighted by texture), as coarse levels only pool frame 2.
                ncc = _aggregate(ncc, self.feature_norm, 2 ** level * cfg.aggregate)
            pos = (coords0 + flow) / 2.0 ** level
            inside = _inside(pos, offsets, self.h >> level, self.w >> level)
            step, distinct = _window_step(ncc, inside, offsets, cfg.temperature)
            confidence = distinct * self.feature_norm
            # Coarse steps are smoothed over the same image extent as fine ones: 2^l times wider.
            flow = flow + 2.0 ** level * self._smooth(step, confidence, cfg.smooth_radius * 2 ** level,
                                                       cfg.min_confidence)
        return upsample_flow(flow, self.stride, *self.image_shape)

    @staticmethod
    def _smooth(step: np.ndarray, confidence: np.ndarray, radius: int, min_confidence: float) -> np.ndarray:
        """Confidence-weighted box average of the step, scaled down where the neighbourhood is unsure."""
        size = 2 * radius + 1
        den = ndimage.uniform_filter(confidence, size, mode="nearest")
        num = np.stack([ndimage.uniform_filter(confidence * s, size, mode="nearest") for s in step])
        mean = np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0)
        return mean * np.clip(den / min_confidence, 0.0, 1.0)


def _aggregate(ncc: np.ndarray, weight: np.ndarray, radius: int) -> np.ndarray:
    size = (1, 2 * radius + 1, 2 * radius + 1)
    den = ndimage.uniform_filter(weight, size[1:], mode="nearest")
    return ndimage.uniform_filter(ncc * weight[None], size, mode="nearest") / np.maximum(den, 1e-12)[None]


def _inside(pos: np.ndarray, offsets: tuple[np.ndarray, np.ndarray], height: int, width: int) -> np.ndarray:
    """Which window samples lie between frame 2's outermost pixel centres (level coordinates)."""
    sx, sy = pos[0][None] + offsets[0], pos[1][None] + offsets[1]
    return (sx >= 0.5) & (sx <= width - 0.5) & (sy >= 0.5) & (sy <= height - 0.5)


def _window_step(ncc: np.ndarray, inside: np.ndarray, offsets: tuple[np.ndarray, np.ndarray],
                 temperature: float) -> tuple[np.ndarray, np.ndarray]:
    """Soft-argmax step (2, h, w) in level pixels and its distinctiveness (h, w) from one level's window.

    The soft-argmax is taken over the 3x3 samples around the window's peak: sub-pixel, and not pulled
    towards the window's centre by a broad correlation surface. Distinctiveness is the peak NCC minus
    the best NCC two or more samples away from it, ~0 on flat or periodic texture.
    Samples off frame 2 read zero padding, which would outbid negative correlations, so they are excluded.
    """
    off_x, off_y = offsets
    ncc = np.where(inside, ncc, -np.inf)
    any_inside = inside.any(axis=0)
    ncc[:, ~any_inside] = 0.0
    peak = np.argmax(ncc, axis=0)
    dist = np.maximum(np.abs(off_x - off_x.ravel()[peak][None]), np.abs(off_y - off_y.ravel()[peak][None]))
    logits = np.where(dist <= 1, ncc / temperature, -np.inf)
    weights = np.exp(logits - logits.max(axis=0, keepdims=True))
    weights /= weights.sum(axis=0, keepdims=True)
    step = np.stack([(weights * off_x).sum(0), (weights * off_y).sum(0)])
    top = ncc.max(axis=0)
    rival = np.where(dist >= 2, ncc, -np.inf).max(axis=0)
    distinct = np.where(np.isfinite(rival), top - rival, np.where(any_inside, top, 0.0))
    return np.where(any_inside, step, 0.0), np.clip(distinct, 0.0, None) * any_inside


# --------------------------------------------------------------------------- metrics and colours


def flow_metrics(flow: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """EPE (px) and KITTI's F1-all (% of pixels with EPE > 3 px and > 5% of |gt|) over `mask`."""
    if flow.shape != gt.shape or flow.shape[-1] != 2 or mask.shape != flow.shape[:-1]:
        raise ValueError(f"flow {flow.shape}, gt {gt.shape} and mask {mask.shape} must be (H, W, 2), (H, W, 2), "
                         "(H, W)")
    if not mask.any():
        raise ValueError("mask: expected at least one pixel to evaluate")
    epe = np.linalg.norm(flow - gt, axis=-1)[mask]
    mag = np.linalg.norm(gt, axis=-1)[mask]
    outlier = (epe > 3.0) & (epe > 0.05 * mag)
    return {"epe": float(epe.mean()), "f1_all": float(100.0 * outlier.mean()), "pixels": int(mask.sum())}


def _colour_wheel() -> np.ndarray:
    """The 55 colours of the Middlebury wheel: red-yellow-green-cyan-blue-magenta, RGB in [0, 1]."""
    segments = [(15, (1, 0, 0), (1, 1, 0)), (6, (1, 1, 0), (0, 1, 0)), (4, (0, 1, 0), (0, 1, 1)),
                (11, (0, 1, 1), (0, 0, 1)), (13, (0, 0, 1), (1, 0, 1)), (6, (1, 0, 1), (1, 0, 0))]
    rows = []
    for n, start, end in segments:
        t = np.arange(n)[:, None] / n
        rows.append((1 - t) * np.array(start) + t * np.array(end))
    return np.concatenate(rows)


def flow_to_color(flow: np.ndarray, max_flow: float | None = None, valid: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) colours in [0, 1]: hue from direction, saturation from |flow| / max_flow.

    `max_flow`: the magnitude drawn fully saturated (None: the largest valid magnitude). Pixels
    with NaN or infinite flow, or False in `valid` (H, W), are drawn black (module docstring).
    """
    flow = np.asarray(flow, dtype=np.float64)
    if flow.ndim != 3 or flow.shape[-1] != 2:
        raise ValueError(f"flow: expected shape (H, W, 2), got {flow.shape}")
    if max_flow is not None and not (np.isfinite(max_flow) and max_flow > 0):
        raise ValueError(f"max_flow: expected a finite number > 0 or None, got {max_flow!r}")
    ok = np.all(np.isfinite(flow), axis=-1)
    if valid is not None:
        valid = np.asarray(valid)
        if valid.shape != flow.shape[:2]:
            raise ValueError(f"valid: expected shape {flow.shape[:2]}, got {valid.shape}")
        ok &= valid.astype(bool)
    flow = np.where(ok[..., None], flow, 0.0)
    u, v = flow[..., 0], flow[..., 1]
    mag = np.hypot(u, v)
    scale = float(max_flow) if max_flow else max(float(mag.max()) if ok.any() else 0.0, 1e-9)
    wheel = _colour_wheel()
    n = len(wheel)
    angle = np.arctan2(-v, -u) / np.pi  # in [-1, 1]
    pos = (angle + 1) / 2 * (n - 1)
    k0 = np.floor(pos).astype(int)
    k1 = (k0 + 1) % n
    f = (pos - k0)[..., None]
    col = (1 - f) * wheel[k0] + f * wheel[k1]
    sat = np.clip(mag / scale, 0, 1)[..., None]
    return np.where(ok[..., None], 1 - sat * (1 - col), 0.0)
