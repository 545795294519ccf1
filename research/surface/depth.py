"""Depth maps rendered from fitted models, for fusion: z-depth where the render is opaque enough, else 0.

Both renderers return an opacity-weighted depth, sum_k w_k z_k (kernels/splat: the alpha-weighted sum of
the splats' z-depths; research.nerf.render_image: the compositing weights times the samples' z-depths).
The expected depth of the surface is that sum divided by the opacity sum_k w_k; pixels with opacity
below `min_opacity` (default 0.5: a pixel at least half covered; fixed in advance, not tuned) get 0, the
fusion's "no measurement".
"""

from __future__ import annotations

from typing import Any

import numpy as np

DEFAULT_MIN_OPACITY = 0.5


def expected_depth(weighted: np.ndarray, opacity: np.ndarray, min_opacity: float = DEFAULT_MIN_OPACITY) -> np.ndarray:
    """sum w z / sum w where the opacity reaches min_opacity, else 0 (float32)."""
    weighted, opacity = np.asarray(weighted, dtype=np.float64), np.asarray(opacity, dtype=np.float64)
    keep = opacity >= min_opacity
    out = np.zeros(weighted.shape, dtype=np.float32)
    out[keep] = weighted[keep] / opacity[keep]
    return out


def splat_depths(model: Any, cameras: list, sh_degree: int, device: Any = None, mode: str = "3dgs",
                 min_opacity: float = DEFAULT_MIN_OPACITY) -> np.ndarray:
    """(V, H, W) expected z-depths of a research.splats GaussianModel in the given views."""
    from research.splats.model import render

    out = []
    for cam in cameras:
        r = render(model, cam, sh_degree=sh_degree, device=device, mode=mode)
        out.append(expected_depth(r.depth.numpy(), r.alpha.numpy(), min_opacity))
    return np.stack(out)


def field_depths(field: Any, occupancy: Any, bbox: np.ndarray, step: float, cameras: list,
                 min_opacity: float = DEFAULT_MIN_OPACITY) -> np.ndarray:
    """(V, H, W) expected z-depths of a radiance field (kernels.volume Field) in the given views."""
    from research.nerf.render import render_image

    out = []
    for cam in cameras:
        img = render_image(cam, field, bbox, step=step, occupancy=occupancy)
        out.append(expected_depth(img.depth, img.opacity, min_opacity))
    return np.stack(out)
