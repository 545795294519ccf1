"""ICP (kernels/icp.py) against its Dr.Jit oracle (research/oracles/icp.py): per geometry, the residual rows,
robust weights and rho (forward) with the pose Jacobians (in the VJP columns: the derivatives drlab writes
by hand, here against Dr.Jit's reverse mode), and the normal equations: the cost (forward) with H and g
(VJP columns), g both against the oracle's explicit sum and against the AD gradient of the robust cost.

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract). Correspondences:
source points of spread 2 near the origin, targets 0.05 away, every tenth an outlier about 1 away (past
Huber's c = 0.1 and far out on Geman-McClure's tail, s = 0.01). float32 is reported in the table, not asserted
(as for ba): tests/oracles/test_oracle_icp.py asserts float64 at 1e-10.
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: icp_pairs correspondences.
SIZES = {
    "full": dict(icp_pairs=200_000),
    "quick": dict(icp_pairs=20_000),
    "smoke": dict(icp_pairs=200),
}
OUTLIER_EVERY = 10
ROBUST = {"huber": 0.1, "gm": 0.01}


def correspondences(seed: int, m: int, plane: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(source, target, normals or None), float64 holding float32 values; every OUTLIER_EVERY-th an outlier."""
    rng = Rounded(seed)
    source = rng.normal(0.0, 2.0, (m, 3))
    offset = rng.normal(0.0, 0.05, (m, 3))
    offset[::OUTLIER_EVERY] = rng.normal(0.0, 1.0, offset[::OUTLIER_EVERY].shape)
    target = (source + offset).astype(np.float32).astype(np.float64)
    if not plane:
        return source, target, None
    normals = rng.normal(size=(m, 3))
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32).astype(np.float64)
    return source, target, normals


def _builder(plane: bool, robust: str, normal_equations: bool):
    scale = ROBUST[robust]

    def build(dt, S, seed):
        from kernels import icp
        from research.oracles.icp import icp_oracle

        m = S["icp_pairs"]
        data = correspondences(seed, m, plane)
        cast = lambda t: [None if x is None else x.astype(t) for x in data]  # noqa: E731

        def drlab(t):
            if normal_equations:
                ne = icp.normal_equations(*cast(t), robust=robust, scale=scale)
                return [np.asarray(ne.cost)], [ne.H, ne.g, ne.g]
            r = icp.icp_residuals(*cast(t), robust=robust, scale=scale)
            return [r.residuals, r.weights, r.rho], [r.jacobians]

        def oracle(t):
            o = icp_oracle(*[None if x is None else x.astype(dt).astype(t) for x in data], robust=robust,
                           scale=scale)
            if normal_equations:
                return [o["cost"]], [o["H"], o["g"], o["grad_cost"]]
            return [o["residuals"], o["weights"], o["rho"]], [o["jacobians"]]

        return f"{m} correspondences, {robust} (scale {scale})", drlab, oracle

    return build


CASES = [
    Case("ICP point-to-point rows", _builder(False, "huber", False)),
    Case("ICP point-to-point normal equations", _builder(False, "huber", True)),
    Case("ICP point-to-plane rows", _builder(True, "gm", False)),
    Case("ICP point-to-plane normal equations", _builder(True, "gm", True)),
]
