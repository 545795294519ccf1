"""Plain NumPy references of the point-cloud kernels (kernels/points): brute force over all pairs.

Each function states the same definition as its kernel's docstring and computes it directly, in the
input's dtype where the kernel's result is exact (indices chosen by comparing squared distances, which
both evaluate as (q_x - p_x)^2 + (q_y - p_y)^2 + (q_z - p_z)^2 in that order), in float64 otherwise.
"""

from __future__ import annotations

import numpy as np


def sq_dists(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(M, N) matrix of d2(q_i, p_j) = (dx^2 + dy^2) + dz^2 in the inputs' dtype, in that order."""
    d = q[:, None, :] - p[None, :, :]
    s = d * d
    return (s[..., 0] + s[..., 1]) + s[..., 2]


def knn(points: np.ndarray, k: int, queries: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(idx (M, k), sq_dist (M, k)): the k smallest (d2, index) keys per query, ascending."""
    queries = points if queries is None else queries
    d2 = sq_dists(queries, points)
    order = np.empty((len(queries), k), np.int64)
    j = np.arange(points.shape[0])
    for i in range(len(queries)):
        order[i] = np.lexsort((j, d2[i]))[:k]  # by d2, then by index
    return order.astype(np.int32), np.take_along_axis(d2, order, axis=1)


def ball_query(points: np.ndarray, queries: np.ndarray, radius: float, max_neighbors: int
               ) -> tuple[np.ndarray, np.ndarray]:
    """(idx (M, K), count (M,)): the first K indices with d2 < r^2 ascending, padded with the first; -1 if none."""
    d2 = sq_dists(queries, points)
    r2 = np.asarray(radius, points.dtype) * np.asarray(radius, points.dtype)
    idx = np.full((len(queries), max_neighbors), -1, np.int32)
    count = np.zeros(len(queries), np.int32)
    for i in range(len(queries)):
        found = np.flatnonzero(d2[i] < r2)[:max_neighbors]
        count[i] = len(found)
        if len(found):
            idx[i] = found[0]
            idx[i, :len(found)] = found
    return idx, count


def farthest_point_sampling(points: np.ndarray, n_samples: int, start: int = 0) -> np.ndarray:
    """Indices (S,): s_0 = start; s_t = argmax_i min_{u < t} d2(p_i, p_{s_u}), ties to the smallest index."""
    mind = np.full(points.shape[0], np.inf, points.dtype)
    out = np.empty(n_samples, np.int32)
    last = start
    for t in range(n_samples):
        out[t] = last
        mind = np.minimum(mind, sq_dists(points[last][None], points)[0])
        last = int(np.argmax(mind))  # np.argmax returns the first maximum
    return out


def normals(points: np.ndarray, k: int, viewpoint=(0.0, 0.0, 0.0), degenerate_ratio: float = 1e-6
            ) -> tuple[np.ndarray, np.ndarray]:
    """(normals (N, 3), valid (N,)) by PCA over each point's k nearest (itself included), float64.

    C = (1/k) sum_j (p_j - mu)(p_j - mu)^T; the normal is the unit eigenvector of C's smallest eigenvalue,
    flipped so that n . (viewpoint - p) >= 0; NaN with valid False where lambda_1 <= ratio * lambda_2
    (fewer than 3 distinct points, or collinear).
    """
    idx, _ = knn(points, k)
    p = points.astype(np.float64)
    nb = p[idx]                                           # (N, k, 3)
    d = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", d, d) / k
    lam, vec = np.linalg.eigh(cov)                        # ascending eigenvalues
    n = vec[:, :, 0]
    flip = np.einsum("ni,ni->n", n, np.asarray(viewpoint, np.float64) - p) < 0
    n[flip] *= -1
    valid = lam[:, 1] > degenerate_ratio * lam[:, 2]
    n[~valid] = np.nan
    return n, valid


def chamfer(x: np.ndarray, y: np.ndarray) -> float:
    """CD(X, Y) = (1/|X|) sum_x min_y |x - y|^2 + (1/|Y|) sum_y min_x |x - y|^2, in float64."""
    d2 = sq_dists(x.astype(np.float64), y.astype(np.float64))
    return float(d2.min(axis=1).mean() + d2.min(axis=0).mean())


def chamfer_grad(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dCD/dx, dCD/dy) in float64, nearest neighbours by (d2, index)."""
    x, y = x.astype(np.float64), y.astype(np.float64)
    d2 = sq_dists(x, y)
    nx, ny = d2.argmin(axis=1), d2.argmin(axis=0)        # first minimum: ties by index
    gx = 2.0 / len(x) * (x - y[nx])
    gy = 2.0 / len(y) * (y - x[ny])
    r = 2.0 / len(y) * (x[ny] - y)                       # d/dx_{ny(j)} of |y_j - x_{ny(j)}|^2 / |Y|
    np.add.at(gx, ny, r)
    np.add.at(gy, nx, -2.0 / len(x) * (x - y[nx]))
    return gx, gy
