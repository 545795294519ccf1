"""Dr.Jit oracle for Mip-Splatting's 3D smoothing filter (kernels/splat/filter3d.py) and its VJP.

Written from Yu et al.'s definition (Mip-Splatting, CVPR 2024, section 5.1) in the covariance form,
not drlab's log-space one: for a splat with scales s_k = exp(l_k), opacity o = sigmoid(a) and filter
standard deviation sigma (held fixed),

    s'_k^2 = s_k^2 + sigma^2,    o' = o sqrt(det Sigma / det Sigma') = o prod_k s_k / s'_k,

returned as the renderer's parameters l'_k = log s'_k and a' = log(o' / (1 - o')). The VJPs for
cotangents (g_l', g_a') are Dr.Jit's reverse-mode derivatives of sum(g_l' l') + sum(g_a' a') with
respect to l and a.
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array


def filter_3d_oracle(log_scales: np.ndarray, opacity_logits: np.ndarray, sigma: np.ndarray,
                     grad_log_scales: np.ndarray, grad_opacity_logits: np.ndarray
                     ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """((l' (N, 3), a' (N,)), (dL/dl, dL/da)) in log_scales' dtype."""
    check_array("log_scales", log_scales, (None, 3))
    n = log_scales.shape[0]
    check_array("opacity_logits", opacity_logits, (n,))
    check_array("sigma", sigma, (n,))
    if np.any(sigma < 0):
        raise ValueError("sigma: expected values >= 0")
    check_array("grad_log_scales", grad_log_scales, (n, 3))
    check_array("grad_opacity_logits", grad_opacity_logits, (n,))
    be = backend(log_scales.dtype)
    dr = be.dr
    L, a = be.leaf(log_scales), be.leaf(opacity_logits)
    var = dr.square(be.const(sigma))
    idx = be.arange(n)
    o = 1.0 / (1.0 + dr.exp(-a))
    ratio = be.Float(1.0)  # prod_k s_k / s'_k
    out_scales = []
    for k in range(3):
        s = dr.exp(dr.gather(be.Float, L, idx * 3 + k))
        s_filtered = dr.sqrt(dr.square(s) + var)
        ratio = ratio * s / s_filtered
        out_scales.append(dr.log(s_filtered))
    q = o * ratio
    out_logit = dr.log(q / (1.0 - q))
    dr.eval(out_logit, *out_scales)
    dr.backward(be.dot([*out_scales, out_logit],
                       [*(np.ascontiguousarray(grad_log_scales[:, k]) for k in range(3)), grad_opacity_logits]))
    scales = np.stack([be.numpy(v, (n,)) for v in out_scales], axis=1)
    return (scales, be.numpy(out_logit, (n,))), (be.grad(L, log_scales.shape), be.grad(a, (n,)))
