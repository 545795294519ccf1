"""Dr.Jit oracles for PointNet's max-pool and PointNet++'s grouping in local coordinates (kernels/pointnet.py).

Written from the definitions in kernels/pointnet.py's docstring:

    y[g, c] = max_k x[g, k, c]                                 (a chain of Dr.Jit maxima over k),
    u[b, s, k] = (p[b, j[b, s, k]] - p[b, c[b, s]]) / r        (gathers of the points).

The VJPs are Dr.Jit's reverse-mode derivatives of <cotangent, output>: the maximum's adjoint routes
the cotangent to the larger argument (the inputs must hold no ties), and a gather's adjoint is a
scatter-add, the grouping's sum over every (s, k) that uses a point.
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array


def max_pool_oracle(x: np.ndarray, grad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y (G, C), dL/dx (G, K, C)) for L = sum(grad * y), in x's dtype."""
    check_array("x", x, (None, None, None))
    g, k, c = x.shape
    check_array("grad", grad, (g, c))
    be = backend(x.dtype)
    dr = be.dr
    X = be.leaf(x)
    lane = be.arange(g * c)
    base = (lane // c) * (k * c) + lane % c  # x[g, 0, c]
    y = dr.gather(be.Float, X, base)
    for row in range(1, k):
        y = dr.maximum(y, dr.gather(be.Float, X, base + row * c))
    dr.eval(y)
    dr.backward(be.dot([y], [grad]))
    return be.numpy(y, (g, c)), be.grad(X, x.shape)


def group_local_oracle(points: np.ndarray, centers: np.ndarray, neighbors: np.ndarray, radius: float,
                       grad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u (B, S, K, 3), dL/dpoints (B, N, 3)) for L = sum(grad * u), in points' dtype."""
    check_array("points", points, (None, None, 3))
    b, n, _ = points.shape
    centers, neighbors = np.asarray(centers), np.asarray(neighbors)
    if centers.ndim != 2 or centers.shape[0] != b or neighbors.shape[:2] != centers.shape or neighbors.ndim != 3:
        raise ValueError(f"centers, neighbors: expected shapes (B, S) and (B, S, K) with B = {b}, got "
                         f"{centers.shape} and {neighbors.shape}")
    if radius <= 0:
        raise ValueError(f"radius: expected > 0, got {radius}")
    s, k = neighbors.shape[1:]
    check_array("grad", grad, (b, s, k, 3))
    be = backend(points.dtype)
    dr = be.dr
    P = be.leaf(points)
    cloud = np.arange(b)[:, None, None] * n
    nb = (cloud + neighbors).ravel() * 3
    ce = (cloud + np.broadcast_to(centers[:, :, None], neighbors.shape)).ravel() * 3
    u = [(dr.gather(be.Float, P, be.index(nb + d)) - dr.gather(be.Float, P, be.index(ce + d))) / float(radius)
         for d in range(3)]
    dr.eval(*u)
    dr.backward(be.dot(u, [np.ascontiguousarray(grad[..., d]) for d in range(3)]))
    return np.stack([be.numpy(v, (b, s, k)) for v in u], axis=-1), be.grad(P, points.shape)
