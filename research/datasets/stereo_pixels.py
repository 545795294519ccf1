"""What the stereo benchmark readers share (research.datasets.stereo_benchmarks and middlebury2003).

The left and right images of a StereoPair are linear RGBA: the stored 8- or 16-bit codes scaled to
[0, 1], decoded from sRGB, grey repeated into three channels, alpha 1 (`linear_rgba`). The stored
codes themselves are kept beside them (StereoPair.left_image, right_image).
"""

from __future__ import annotations

import numpy as np

from research import io


def linear_rgba(img: np.ndarray) -> np.ndarray:
    """Stored uint8/uint16 codes, grey (H, W) or colour (H, W, 3), as sRGB-decoded linear RGBA float32 (alpha 1)."""
    unit = img.astype(np.float32) / np.float32(np.iinfo(img.dtype).max)
    rgb = np.repeat(unit[..., None], 3, axis=2) if unit.ndim == 2 else unit
    return np.concatenate([io.srgb_to_linear(rgb), np.ones(rgb.shape[:2] + (1,), np.float32)], axis=2)
