"""The 3DGS photometric loss, (1 - lambda) L1 + lambda (1 - SSIM) with lambda = 0.2, and a masked
expected-depth loss against a measured depth map.

L1 is the mean absolute error over pixels and channels; SSIM is kernels/ssim.py
(11 x 11 Gaussian window, zero padding, as the 3DGS training code). The gradient
with respect to the rendered image is returned with the value.

Depth (`depth_loss`): the rasteriser's depth output is D = sum_i z_i alpha_i T_i and its alpha
A = 1 - T_final, so the expected z-depth of the splats a pixel sees is z_hat = D / A. Over the
valid pixels V (mask, measured depth finite and > 0, and A > min_alpha: the silhouette the
SplaTAM-style tracking loss uses), with r = z_hat - measured and M = |V|,

    L = (1/M) sum_V |r|   ("l1")   or   (1/M) sum_V r^2   ("l2"),   0 when V is empty,
    dL/dD = dL/dz_hat / A,  dL/dA = -dL/dz_hat D / A^2,  dL/dz_hat = sign(r)/M or 2 r/M,

zero outside V. render_backward(..., grad_alpha=dL/dA, grad_depth=dL/dD, want_camera=True) then
gives its gradients with respect to the splats, the pose and the intrinsics.
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


DEPTH_KINDS = ("l1", "l2")


def depth_loss(depth: np.ndarray, alpha: np.ndarray, measured: np.ndarray, mask: np.ndarray | None = None, *,
               min_alpha: float = 0.5, kind: str = "l1") -> tuple[float, np.ndarray, np.ndarray]:
    """(loss, dloss/ddepth, dloss/dalpha) of the masked expected-depth loss (module docstring) for the
    render's depth and alpha outputs (H, W) and a measured z-depth map (H, W); `mask` (H, W) bool
    selects pixels (None: all). Gradients in the dtype of `depth`."""
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.dtype not in (np.float32, np.float64):
        raise ValueError(f"depth: expected a float32 or float64 (H, W) array, got {depth.dtype} {depth.shape}")
    alpha = np.asarray(alpha)
    if alpha.shape != depth.shape or alpha.dtype != depth.dtype:
        raise ValueError(f"alpha: expected {depth.dtype} {depth.shape} like depth, got {alpha.dtype} {alpha.shape}")
    measured = np.asarray(measured)
    if measured.shape != depth.shape or not np.issubdtype(measured.dtype, np.floating):
        raise ValueError(f"measured: expected a float {depth.shape} depth map, got {measured.dtype} {measured.shape}")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != depth.shape or mask.dtype != bool:
            raise ValueError(f"mask: expected a bool {depth.shape} array, got {mask.dtype} {mask.shape}")
    if not isinstance(min_alpha, (int, float)) or not 0.0 <= min_alpha < 1.0:
        raise ValueError(f"min_alpha: expected a number in [0, 1), got {min_alpha!r}")
    if kind not in DEPTH_KINDS:
        raise ValueError(f"kind: expected one of {', '.join(repr(k) for k in DEPTH_KINDS)}, got {kind!r}")
    if not np.all(np.isfinite(depth)) or not np.all(np.isfinite(alpha)):
        raise ValueError("depth, alpha: expected finite values")
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(measured) & (measured > 0) & (alpha > min_alpha)
    if mask is not None:
        valid &= mask
    g_depth = np.zeros(depth.shape, dtype=np.float64)
    g_alpha = np.zeros(depth.shape, dtype=np.float64)
    m = int(valid.sum())
    if m == 0:
        return 0.0, g_depth.astype(depth.dtype), g_alpha.astype(depth.dtype)
    d = depth[valid].astype(np.float64)
    a = alpha[valid].astype(np.float64)
    r = d / a - measured[valid].astype(np.float64)
    if kind == "l1":
        loss, g_z = float(np.abs(r).sum() / m), np.sign(r) / m
    else:
        loss, g_z = float((r * r).sum() / m), 2.0 * r / m
    g_depth[valid] = g_z / a
    g_alpha[valid] = -g_z * d / (a * a)
    return loss, g_depth.astype(depth.dtype), g_alpha.astype(depth.dtype)
