"""Appearance embeddings for re-identification, DeepSORT style (Wojke, Bewley & Paulus, ICIP 2017).

DeepSORT compares a track and a detection by the cosine distance
d(a, b) = 1 - a.b / (|a| |b|) between appearance descriptors. Its descriptor is
a CNN embedding; here it is a colour histogram of the pixels inside the
detection box, which needs no training and is computed from the image alone:

* pixels are converted to HSV (through a lookup table on colours quantised
  to 5 bits per channel); chromatic pixels (saturation >= sat_min and
  value >= val_min) vote into a hue x saturation histogram (hue_bins x
  sat_bins), the others into val_bins grey-level bins;
* the counts are square-rooted (so the cosine becomes the Bhattacharyya
  coefficient of the normalised histograms) and scaled to unit norm.

Hue-saturation histograms ignore most brightness changes (Swain & Ballard 1991;
Comaniciu et al. 2003 use colour histograms the same way for tracking). A box
that is partly occluded or misplaced mixes in other colours, so its embedding
degrades, as a learnt embedding would.

A track keeps an exponential moving average of its embeddings,
f <- normalise(alpha f + (1 - alpha) e) (as in FairMOT and BoT-SORT).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from research.tracking import checks


@dataclass(frozen=True)
class HistogramConfig:
    hue_bins: int = 12
    sat_bins: int = 3
    val_bins: int = 4
    sat_min: float = 0.2
    val_min: float = 0.15
    shrink: float = 0.1  # trim this fraction of width/height on each side before counting

    def __post_init__(self) -> None:
        for name in ("hue_bins", "sat_bins", "val_bins"):
            checks.integer(name, getattr(self, name), 1)
        checks.probability("sat_min", self.sat_min)
        checks.probability("val_min", self.val_min)
        checks.number("shrink", self.shrink, 0.0, 0.49)

    @property
    def dim(self) -> int:
        return self.hue_bins * self.sat_bins + self.val_bins


def rgb_to_hsv(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RGB in [0, 1] (..., 3) -> hue in [0, 1), saturation and value in [0, 1]."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    v = rgb.max(axis=-1)
    c = v - rgb.min(axis=-1)
    s = np.where(v > 0, c / np.where(v > 0, v, 1.0), 0.0)
    safe_c = np.where(c > 0, c, 1.0)
    h = np.where(
        v == r, ((g - b) / safe_c) % 6.0, np.where(v == g, (b - r) / safe_c + 2.0, (r - g) / safe_c + 4.0)
    )
    h = np.where(c > 0, h / 6.0, 0.0)
    return h, s, v


def _bin_of_hsv(h: np.ndarray, s: np.ndarray, v: np.ndarray, config: HistogramConfig) -> np.ndarray:
    chromatic = (s >= config.sat_min) & (v >= config.val_min)
    hi = np.minimum((h * config.hue_bins).astype(int), config.hue_bins - 1)
    si = np.clip(((s - config.sat_min) / (1.0 - config.sat_min) * config.sat_bins).astype(int), 0, config.sat_bins - 1)
    vi = np.minimum((v * config.val_bins).astype(int), config.val_bins - 1)
    return np.where(chromatic, hi * config.sat_bins + si, config.hue_bins * config.sat_bins + vi)


@functools.lru_cache(maxsize=8)
def _lookup_table(config: HistogramConfig) -> np.ndarray:
    """Histogram bin of every colour quantised to 5 bits per channel (32^3 entries)."""
    levels = (np.arange(32) * 8 + 4) / 255.0  # centre of each 8-wide uint8 interval
    rgb = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1).reshape(-1, 3)
    return _bin_of_hsv(*rgb_to_hsv(rgb), config).astype(np.intp)


def color_histogram(image: np.ndarray, box: np.ndarray, config: HistogramConfig = HistogramConfig()) -> np.ndarray:
    """Unit-norm histogram embedding of `image` (H, W, 3) uint8 inside the xyxy `box`.

    Colours are quantised to 5 bits per channel and binned through a lookup
    table (the HSV bin of each quantised colour's centre). Returns the zero
    vector when the box holds no pixel (cosine distance 1 to anything).
    """
    height, width = image.shape[:2]
    x1, y1, x2, y2 = (float(c) for c in box)
    dx, dy = config.shrink * (x2 - x1), config.shrink * (y2 - y1)
    c0, c1 = int(np.clip(np.floor(x1 + dx), 0, width)), int(np.clip(np.ceil(x2 - dx), 0, width))
    r0, r1 = int(np.clip(np.floor(y1 + dy), 0, height)), int(np.clip(np.ceil(y2 - dy), 0, height))
    if c1 <= c0 or r1 <= r0:
        return np.zeros(config.dim)
    q = (image[r0:r1, c0:c1] >> 3).astype(np.intp)
    idx = _lookup_table(config)[(q[..., 0] << 10) | (q[..., 1] << 5) | q[..., 2]]
    out = np.sqrt(np.bincount(idx.ravel(), minlength=config.dim).astype(float))
    return out / np.linalg.norm(out)


def embed_boxes(image: np.ndarray, boxes: np.ndarray, config: HistogramConfig = HistogramConfig()) -> np.ndarray:
    """Embeddings (N, dim) of each xyxy box; rows with a non-finite box are zero."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    out = np.zeros((len(boxes), config.dim))
    for i, b in enumerate(boxes):
        if np.all(np.isfinite(b)):
            out[i] = color_histogram(image, b, config)
    return out


def cosine_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise 1 - cos(a_i, b_j) for rows a (N, D), b (M, D); zero vectors are at distance 1."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    na = np.linalg.norm(a, axis=1, keepdims=True)
    nb = np.linalg.norm(b, axis=1, keepdims=True)
    an = np.divide(a, na, out=np.zeros_like(a), where=na > 0)
    bn = np.divide(b, nb, out=np.zeros_like(b), where=nb > 0)
    return 1.0 - an @ bn.T


def ema_feature(track_feature: np.ndarray | None, new: np.ndarray, alpha: float) -> np.ndarray:
    """Unit-norm exponential moving average of embeddings (alpha weights the past)."""
    if track_feature is None or not np.any(track_feature):
        f = new
    else:
        f = alpha * track_feature + (1.0 - alpha) * new
    n = np.linalg.norm(f)
    return f / n if n > 0 else f
