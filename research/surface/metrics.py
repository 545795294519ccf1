"""Mesh-to-ground-truth scores on sampled points (predicted P, true G, each with unit normals).

With d(x, S) = min over s in S of |x - s| (Euclidean; the nearest point found by kernels.points.knn):

    accuracy       mean over p in P of d(p, G)
    completeness   mean over g in G of d(g, P)
    chamfer        (accuracy + completeness) / 2            (the symmetric "chamfer-L1" of DTU-style tables)
    precision(t)   fraction of p in P with d(p, G) < t
    recall(t)      fraction of g in G with d(g, P) < t
    F(t)           2 precision recall / (precision + recall)  (0 when both are 0)
                   (Knapitsch et al., "Tanks and Temples", SIGGRAPH 2017)
    normal consistency  mean of |n_p . n_g(p)| over P and of |n_g . n_p(g)| over G, averaged (Mescheder
                   et al., "Occupancy Networks", CVPR 2019); the absolute value makes it independent of
                   the orientation of one-sided shapes.

An empty prediction scores accuracy and completeness inf, precision, recall and F 0, and normal
consistency NaN.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def nearest(queries: np.ndarray, points: np.ndarray, device: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """(distance, index) of the nearest of `points` to each query (exact kNN, kernels.points.knn)."""
    from kernels.points import knn

    res = knn(np.ascontiguousarray(points, dtype=np.float64), 1,
              queries=np.ascontiguousarray(queries, dtype=np.float64), device=device)
    return np.sqrt(res.sq_dist[:, 0]), res.idx[:, 0]


def fscore(precision: float, recall: float) -> float:
    return 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)


def surface_metrics(pred: np.ndarray, pred_normals: np.ndarray, gt: np.ndarray, gt_normals: np.ndarray,
                    thresholds: list[float], device: Any = None) -> dict[str, Any]:
    """The module docstring's scores; thresholds in scene units. Returns a dict of floats, with the per-point
    distances d(p, G) and d(g, P) as arrays under "pred_distances" and "gt_distances" (pop them for JSON)."""
    for name, x in (("pred", pred), ("pred_normals", pred_normals), ("gt", gt), ("gt_normals", gt_normals)):
        if np.ndim(x) != 2 or np.shape(x)[1] != 3:
            raise ValueError(f"{name}: expected an (N, 3) array, got shape {np.shape(x)}")
    if len(gt) == 0:
        raise ValueError("gt: expected at least one ground-truth point")
    if len(pred) == 0:
        return {"accuracy": float("inf"), "completeness": float("inf"), "chamfer": float("inf"),
                "normal_consistency": float("nan"),
                "per_threshold": [{"threshold": t, "precision": 0.0, "recall": 0.0, "fscore": 0.0} for t in thresholds]}
    d_pg, i_pg = nearest(pred, gt, device)
    d_gp, i_gp = nearest(gt, pred, device)
    nc = 0.5 * (np.abs(np.sum(pred_normals * gt_normals[i_pg], axis=1)).mean()
                + np.abs(np.sum(gt_normals * pred_normals[i_gp], axis=1)).mean())
    rows = []
    for t in thresholds:
        p, r = float(np.mean(d_pg < t)), float(np.mean(d_gp < t))
        rows.append({"threshold": float(t), "precision": p, "recall": r, "fscore": fscore(p, r)})
    acc, comp = float(d_pg.mean()), float(d_gp.mean())
    return {"accuracy": acc, "completeness": comp, "chamfer": 0.5 * (acc + comp), "normal_consistency": float(nc),
            "per_threshold": rows, "pred_distances": d_pg, "gt_distances": d_gp}
