"""kernels/splat/filter3d.py against its Dr.Jit oracle (research/oracles/mip.py), written in the covariance
form: filtered log-scales and logits and their VJPs, in float64 (float32 is reported by oracle_conformance)."""

from __future__ import annotations

import numpy as np
import pytest

from kernels.splat import filter3d as kf
from research.oracles.mip import filter_3d_oracle
from tests.oracles.conftest import close64


@pytest.mark.parametrize("seed, n", [(0, 300), (1, 7)])
def test_float64_filter_and_vjp_match_the_oracle(seed, n):
    rng = np.random.default_rng(seed)
    log_scales, logits = rng.uniform(-5.0, -1.0, (n, 3)), rng.uniform(-4.0, 4.0, n)
    sigma = rng.uniform(0.0, 0.06, n)
    g_scales, g_logits = rng.normal(size=(n, 3)), rng.normal(size=n)
    scales, out_logits = kf.filter_3d(log_scales, logits, sigma)
    d_scales, d_logits = kf.filter_3d_backward(log_scales, logits, sigma, g_scales, g_logits)
    (want_scales, want_logits), (want_ds, want_dl) = filter_3d_oracle(log_scales, logits, sigma, g_scales, g_logits)
    close64("log_scales'", scales, want_scales)
    close64("logits'", out_logits, want_logits)
    close64("dL/dlog_scales", d_scales, want_ds)
    close64("dL/dlogits", d_logits, want_dl)
