"""Linear assignment (Hungarian / Kuhn-Munkres) wrappers around scipy.

Both functions return (matches (K, 2) int array of [row, col], unmatched
rows, unmatched cols), and accept empty cost matrices.

* `max_iou_assignment` is SORT's rule (Bewley et al. 2016): maximise the total
  IoU over all one-to-one assignments, then discard the pairs with
  IoU < threshold.
* `gated_assignment` is ByteTrack's rule (Zhang et al. 2022, `lap.lapjv` with
  `cost_limit`): minimise the total cost where every row or column may also
  stay unmatched at cost limit / 2, so a pair is used only if it beats leaving
  both ends unmatched. It is solved exactly with scipy on lap's extended
  (N + M) x (M + N) matrix [[C, L], [L, 0]] with L filled with limit / 2.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

_Result = tuple[np.ndarray, np.ndarray, np.ndarray]


def _empty_result(n: int, m: int) -> _Result:
    return np.zeros((0, 2), dtype=int), np.arange(n), np.arange(m)


def _split(matches: list[tuple[int, int]], n: int, m: int) -> _Result:
    arr = np.array(matches, dtype=int).reshape(-1, 2)
    row_free = np.ones(n, bool)
    col_free = np.ones(m, bool)
    row_free[arr[:, 0]] = False
    col_free[arr[:, 1]] = False
    return arr, np.flatnonzero(row_free), np.flatnonzero(col_free)


def max_iou_assignment(iou: np.ndarray, iou_threshold: float) -> _Result:
    """SORT: Hungarian on -IoU, then drop pairs with IoU < iou_threshold."""
    iou = np.asarray(iou, dtype=float)
    n, m = iou.shape
    if n == 0 or m == 0:
        return _empty_result(n, m)
    rows, cols = linear_sum_assignment(-iou)
    keep = iou[rows, cols] >= iou_threshold
    return _split(list(zip(rows[keep], cols[keep])), n, m)


def gated_assignment(cost: np.ndarray, limit: float) -> _Result:
    """Minimum-cost matching in which only pairs with cost <= limit may be used."""
    cost = np.asarray(cost, dtype=float)
    n, m = cost.shape
    if n == 0 or m == 0:
        return _empty_result(n, m)
    big = np.full((n + m, m + n), 0.5 * limit)  # dummy blocks: leave a row or column unmatched
    big[n:, m:] = 0.0
    allowed = np.isfinite(cost) & (cost <= limit)
    big[:n, :m] = np.where(allowed, cost, 2.0 * abs(limit) + 1.0)  # never better than two dummies
    rows, cols = linear_sum_assignment(big)
    matches = [(r, c) for r, c in zip(rows, cols) if r < n and c < m and allowed[r, c]]
    return _split(matches, n, m)
