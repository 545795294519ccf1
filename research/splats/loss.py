"""The 3DGS photometric loss: (1 - lambda) L1 + lambda (1 - SSIM), lambda = 0.2.

L1 is the mean absolute error over pixels and channels; SSIM is kernels/ssim.py
(11 x 11 Gaussian window, zero padding, as the 3DGS training code). The gradient
with respect to the rendered image is returned with the value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from kernels import ssim as kssim

LAMBDA_DSSIM = 0.2


def l1_dssim(pred: np.ndarray, target: np.ndarray, lambda_dssim: float = LAMBDA_DSSIM,
             device: Any = None) -> tuple[float, np.ndarray, dict[str, float]]:
    """(loss, dloss/dpred, {"l1", "ssim"}) for NumPy images (H, W, C) of one float dtype; SSIM runs on `device`."""
    if pred.shape != target.shape or pred.dtype != target.dtype:
        raise ValueError(f"pred, target: expected equal shapes and dtypes, got {pred.shape} {pred.dtype} "
                         f"and {target.shape} {target.dtype}")
    if not 0.0 <= lambda_dssim <= 1.0:
        raise ValueError(f"lambda_dssim: expected a value in [0, 1], got {lambda_dssim}")
    diff = pred - target
    l1 = float(np.abs(diff).mean(dtype=np.float64))
    ssim_value, dssim_dpred = kssim.ssim(pred, target, device=device)
    grad = (1.0 - lambda_dssim) * np.sign(diff) / diff.size - lambda_dssim * dssim_dpred
    loss = (1.0 - lambda_dssim) * l1 + lambda_dssim * (1.0 - ssim_value)
    return loss, grad.astype(pred.dtype), {"l1": l1, "ssim": ssim_value}
