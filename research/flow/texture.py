"""Real-texture flow pairs: a photograph warped by a known smooth flow.

The photograph is `grace_hopper.jpg` (600 x 512, RGB), which ships with
matplotlib (a dependency) in its sample data: a real camera image with hair,
fabric, medals and flat background, none of it made here.

`smooth_flow(shape, median_px, seed)`: a random flow field (2, H, W): a 4 x 4 grid
of standard-normal vectors (per seed), upsampled bicubically to the image and
scaled so that the median magnitude is `median_px` (4 px by default: the motion
of the reported real-photograph case).

`warped_pair(src, flow)`: frame 2 = src and frame 1(p) = src(p + flow(p)) (cubic
spline interpolation), so the flow from frame 1 to frame 2 is exactly `flow`
(x right, y down, in pixels); pixels whose p + flow(p) leaves the image are
marked invalid and excluded from the metrics.

Splits (so defaults are chosen on data the reported numbers never see):
  * tuning: the lower half of the photograph (rows 300-599), flow seeds 100-103;
  * evaluation: the upper half (rows 0-299), flow seeds 0-3.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

PHOTO = "grace_hopper.jpg"
TUNING_SEEDS = (100, 101, 102, 103)
EVAL_SEEDS = (0, 1, 2, 3)


def photograph() -> np.ndarray:
    """grace_hopper.jpg from matplotlib's sample data, (600, 512, 3) uint8."""
    import matplotlib.cbook as cbook
    import matplotlib.image as mpimg

    img = mpimg.imread(Path(cbook.get_sample_data(PHOTO, asfileobj=False)))  # a JPEG reads as uint8 RGB
    return np.ascontiguousarray(img[..., :3], dtype=np.uint8)


def split(name: str, image: np.ndarray | None = None) -> np.ndarray:
    """The 'tuning' (lower half) or 'eval' (upper half) part of the photograph, uint8 (300, 512, 3)."""
    img = photograph() if image is None else image
    half = img.shape[0] // 2
    if name == "tuning":
        return img[half:]
    if name == "eval":
        return img[:half]
    raise ValueError(f"split: expected 'tuning' or 'eval', got {name!r}")


def smooth_flow(shape: tuple[int, int], median_px: float = 4.0, seed: int = 0) -> np.ndarray:
    """(2, H, W) smooth random flow with median magnitude `median_px` (module docstring)."""
    h, w = shape
    coarse = np.random.default_rng(seed).standard_normal((2, 4, 4))
    zoom = ((h + 3) / 4, (w + 3) / 4)
    flow = np.stack([ndimage.zoom(c, zoom, order=3)[:h, :w] for c in coarse])
    mag = np.median(np.hypot(flow[0], flow[1]))
    return flow * (median_px / max(mag, 1e-9))


def warped_pair(src: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame1, frame2, valid): frame 2 = src, frame 1(p) = src(p + flow(p)); uint8 like src."""
    h, w = src.shape[:2]
    yy, xx = np.indices((h, w), dtype=np.float64)
    sy, sx = yy + flow[1], xx + flow[0]
    valid = (sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1)
    chans = src[..., None] if src.ndim == 2 else src
    out = np.stack([ndimage.map_coordinates(chans[..., c].astype(np.float64), [sy, sx], order=3, mode="nearest")
                    for c in range(chans.shape[2])], axis=-1)
    frame1 = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return (frame1[..., 0] if src.ndim == 2 else frame1), src.copy(), valid


def pairs(name: str, median_px: float = 4.0) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """[(frame1, frame2, gt (H, W, 2), valid)] for every flow seed of the split."""
    src = split(name)
    seeds = TUNING_SEEDS if name == "tuning" else EVAL_SEEDS
    out = []
    for seed in seeds:
        flow = smooth_flow(src.shape[:2], median_px, seed)
        f1, f2, valid = warped_pair(src, flow)
        out.append((f1, f2, np.moveaxis(flow, 0, -1), valid))
    return out
