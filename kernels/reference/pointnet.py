"""Plain NumPy references of kernels/pointnet.py: max-pool, grouping in local coordinates, the
set-abstraction layer, and a PointNet classifier's forward.

Each follows the definition in kernels/pointnet.py's docstring directly. The MLP is
kernels.reference.volume.mlp (ReLU after every layer but the last), the indices are the brute-force
farthest-point sampling and ball query of kernels.reference.points.
"""

from __future__ import annotations

import numpy as np

from kernels.reference import points as ref_points
from kernels.reference.volume import mlp


def max_pool(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y (G, C), argmax (G, C)): the per-channel maximum over axis 1 of x (G, K, C) and its first index."""
    return x.max(axis=1), np.argmax(x, axis=1).astype(np.int32)  # np.argmax returns the first maximum


def max_pool_grad(argmax: np.ndarray, grad: np.ndarray, n_rows: int) -> np.ndarray:
    """dL/dx (G, K, C): grad[g, c] at row argmax[g, c], zero elsewhere."""
    g, c = grad.shape
    out = np.zeros((g, n_rows, c), grad.dtype)
    gi, ci = np.meshgrid(np.arange(g), np.arange(c), indexing="ij")
    out[gi, argmax, ci] = grad
    return out


def group_local(points: np.ndarray, centers: np.ndarray, neighbors: np.ndarray, radius: float) -> np.ndarray:
    """u[b, s, k] = (p[b, neighbors[b, s, k]] - p[b, centers[b, s]]) / radius, shape (B, S, K, 3)."""
    b = np.arange(points.shape[0])[:, None, None]
    return (points[b, neighbors] - points[b[:, :, 0], centers][:, :, None, :]) * (1.0 / radius)


def group_indices(points: np.ndarray, n_centers: int, radius: float, max_neighbors: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(centers (B, S), neighbors (B, S, K)) by brute-force FPS from index 0 and ball query per cloud."""
    centers, neighbors = [], []
    for cloud in points:
        c = ref_points.farthest_point_sampling(cloud, n_centers)
        idx, _ = ref_points.ball_query(cloud, cloud[c], radius, max_neighbors)
        centers.append(c)
        neighbors.append(idx)
    return np.stack(centers), np.stack(neighbors)


def set_abstraction(points: np.ndarray, params: dict, n_layers: int, n_centers: int, radius: float,
                    max_neighbors: int) -> tuple[np.ndarray, np.ndarray]:
    """(centre coordinates (B, S, 3), features (B, S, C)): group_local -> MLP per row -> max over K."""
    centers, neighbors = group_indices(points, n_centers, radius, max_neighbors)
    u = group_local(points, centers, neighbors, radius)
    b, s, k, _ = u.shape
    h = mlp(params, u.reshape(b * s * k, 3), n_layers).reshape(b * s, k, -1)
    feats, _ = max_pool(h)
    xyz = points[np.arange(b)[:, None], centers]
    return xyz, feats.reshape(b, s, -1)


def pointnet_logits(points: np.ndarray, point_params: dict, n_point_layers: int, head_params: dict,
                    n_head_layers: int) -> np.ndarray:
    """PointNet's class scores (B, classes): the point MLP on every point, max over the N points, the head MLP."""
    b, n, c = points.shape
    h = mlp(point_params, points.reshape(b * n, c), n_point_layers).reshape(b, n, -1)
    return mlp(head_params, max_pool(h)[0], n_head_layers)
