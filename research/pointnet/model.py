"""PointNet and a one-level PointNet++ classifier on drlab's kernels, with a hand-written backward.

PointNet (vanilla: no input or feature transform nets, no batch normalisation, no dropout):

    h_i = MLP_point(p_i)  (every point, one shared MLP),   g = max_i h_i,   logits = MLP_head(g).

PointNet++ with one set-abstraction level and the global one (the SSG classifier's structure, with
one level instead of two):

    centres c_s (FPS), neighbours j_{s,k} (ball query of radius r, K per centre),
    u_{s,k} = (p_{j_{s,k}} - p_{c_s}) / r,    f_s = max_k MLP_sa(u_{s,k}),
    g = max_s MLP_global([p_{c_s}, f_s]),      logits = MLP_head(g).

Every MLP is kernels.volume.mlp.MLP (ReLU after every layer but the last, which is linear), so the
per-point features are max-pooled before any ReLU; since ReLU is monotone, max then ReLU equals ReLU
then max, and the head's first layer works on the pooled features directly. The normalisation is
the input's alone: clouds centred and scaled into the unit ball (research.pointnet.shapes.normalise).
The max-pools and the grouping are kernels.pointnet. Loss: softmax cross-entropy averaged over the
batch (`softmax_cross_entropy`).

The FPS and ball-query indices depend on the points only through comparisons of distances, which
rotations preserve (in floating point up to rounding, which can flip only near-ties), so they are
computed once per cloud (`GroupIndices`) and reused for its rotated copies during training
(tests/research/test_pointnet_classify.py checks that they are the same). They are piecewise
constant: no gradient flows through them. `backend` picks the MLPs' backend
(kernels.volume.mlp: "numpy" BLAS products on the CPU by default, "warp" the plain kernels).

Order of the points. PointNet is invariant to it exactly: the MLPs treat each row alone and the
maximum is order-free; with the "warp" backend each row's products are the same loop whatever its
position, so the logits of a permuted cloud are the same bits (BLAS may round a row differently by its
position in a block, so with "numpy" they agree to rounding). The set-abstraction model is not: FPS
starts at index 0 and the ball query keeps the *first* K points in index order, as in PointNet++, so a
permutation can pick other centres and neighbours. Given the same groups (indices mapped through the
permutation), its logits are again the same bits. `backward` returns the gradient of every
parameter, and of the points when asked (research/checks/pointnet.py checks both against finite
differences in float64).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import warp as wp

from kernels import pointnet as kpn
from kernels.volume.mlp import MLP, init_mlp_params


def softmax_cross_entropy(logits: np.ndarray, labels: np.ndarray) -> tuple[float, np.ndarray]:
    """(mean over the batch of -log softmax(z_b)[y_b], its gradient (softmax(z) - onehot(y)) / B)."""
    logits = np.asarray(logits)
    labels = np.asarray(labels)
    if logits.ndim != 2 or logits.shape[0] == 0:
        raise ValueError(f"logits: expected a non-empty (B, classes) array, got shape {logits.shape}")
    if labels.shape != (logits.shape[0],) or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels: expected {logits.shape[0]} integer labels, got shape {labels.shape} {labels.dtype}")
    if labels.min() < 0 or labels.max() >= logits.shape[1]:
        raise ValueError(f"labels: expected values in [0, {logits.shape[1]}), got [{labels.min()}, {labels.max()}]")
    z = logits - logits.max(axis=1, keepdims=True)
    logp = z - np.log(np.exp(z).sum(axis=1, keepdims=True))
    b = logits.shape[0]
    loss = -float(logp[np.arange(b), labels].mean())
    grad = np.exp(logp)
    grad[np.arange(b), labels] -= 1.0
    return loss, grad / b


def _mlp(sizes: Sequence[int], seed: int, dtype: Any, device: Any, backend: str | None) -> MLP:
    dev = wp.get_device(device)
    return MLP(list(sizes), init_mlp_params(sizes, seed, dtype, dev), backend=backend)


def _check_clouds(points: Any, n_in: int = 3) -> np.ndarray:
    points = np.asarray(points)
    if points.ndim != 3 or points.shape[2] != n_in:
        raise ValueError(f"points: expected clouds of shape (B, N, {n_in}), got shape {points.shape}")
    if points.shape[0] == 0 or points.shape[1] == 0:
        raise ValueError(f"points: expected B >= 1 non-empty clouds, got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("points: expected finite coordinates, found NaN or infinite entries")
    return points


class _Classifier:
    """Parameters of named MLPs as one dict "<mlp>.<W|b><l>" -> wp.array (the arrays the MLPs update)."""

    mlps: dict[str, MLP]

    def __init__(self, dtype: Any, device: Any) -> None:
        self.dtype = dtype
        self.device = wp.get_device(device)
        self.np_dtype = np.float64 if dtype == wp.float64 else np.float32

    @property
    def params(self) -> dict[str, wp.array]:
        return {f"{m}.{k}": v for m, mlp in self.mlps.items() for k, v in mlp.params.items()}

    def n_params(self) -> int:
        return int(sum(v.size for v in self.params.values()))

    def state(self) -> dict[str, np.ndarray]:
        """A host copy of every parameter."""
        return {k: v.numpy().copy() for k, v in self.params.items()}

    def load(self, state: dict[str, np.ndarray]) -> None:
        """Copy `state` (from `state()`) into the parameters, in place."""
        for k, v in self.params.items():
            v.assign(wp.array(state[k], dtype=self.dtype, device=self.device))

    def _wp(self, x: np.ndarray) -> wp.array:
        return wp.array(np.ascontiguousarray(x, dtype=self.np_dtype), dtype=self.dtype, device=self.device)

    def _mlp_backward(self, name: str, cache: dict[str, Any], d_out: wp.array, grads: dict[str, wp.array],
                      need_input_grad: bool = True) -> wp.array | None:
        """Backward of MLP `name` (its forward cache is cache[name]) for the cotangent `d_out` of its output:
        its parameter gradients go into `grads` as "<name>.<param>"; returns its input gradient (None unless
        need_input_grad)."""
        g, d_in = self.mlps[name].backward(cache[name], d_out, need_input_grad=need_input_grad)
        grads.update({f"{name}.{k}": v for k, v in g.items()})
        return d_in

    @staticmethod
    def _unpool(pool: kpn.MaxPoolResult, d_pooled: wp.array, count: int) -> wp.array:
        """The gradient through max pool `pool` (groups of `count` rows), one row per row of the pool's input."""
        d = kpn.max_pool_backward(pool, d_pooled, count)["x"]
        return d.reshape((d.shape[0] * d.shape[1], d.shape[2]))


@dataclass
class Forward:
    """A forward pass: the logits (B, classes) and what the backward needs."""

    logits: np.ndarray
    cache: dict


class PointNet(_Classifier):
    """Vanilla PointNet (module docstring): point MLP [3, *point_hidden, feature], head [feature, *head_hidden,
    n_classes]."""

    def __init__(self, n_classes: int, *, point_hidden: Sequence[int] = (64, 128), feature: int = 256,
                 head_hidden: Sequence[int] = (128,), seed: int = 0, dtype: Any = wp.float32, device: Any = "cpu",
                 backend: str | None = None):
        super().__init__(dtype, device)
        self.mlps = {"point": _mlp([3, *point_hidden, feature], 2 * seed, dtype, device, backend),
                     "head": _mlp([feature, *head_hidden, n_classes], 2 * seed + 1, dtype, device, backend)}

    def forward(self, points: np.ndarray, indices: kpn.GroupIndices | None = None) -> Forward:
        """Logits of clouds `points` (B, N, 3). (`indices` is accepted for a common signature and unused.)"""
        points = _check_clouds(points)
        b, n, _ = points.shape
        h, c_point = self.mlps["point"].forward(self._wp(points.reshape(b * n, 3)))
        pooled = kpn.max_pool(h.reshape((b, n, h.shape[1])))
        logits, c_head = self.mlps["head"].forward(pooled.value)
        return Forward(logits.numpy(), {"point": c_point, "pool": pooled, "head": c_head, "shape": (b, n)})

    def backward(self, fwd: Forward, grad_logits: np.ndarray, need_points_grad: bool = False
                 ) -> tuple[dict[str, wp.array], np.ndarray | None]:
        """(dL/dparam for every parameter, dL/dpoints (B, N, 3) or None) for the cotangent dL/dlogits."""
        c = fwd.cache
        b, n = c["shape"]
        grads: dict[str, wp.array] = {}
        d_pooled = self._mlp_backward("head", c, self._wp(grad_logits), grads)
        d_pts = self._mlp_backward("point", c, self._unpool(c["pool"], d_pooled, n), grads, need_points_grad)
        return grads, (d_pts.numpy().reshape(b, n, 3) if need_points_grad else None)


class PointNetSA(_Classifier):
    """PointNet++ with one set-abstraction level (module docstring): `centers` FPS centres, balls of `radius`
    with up to `neighbors` points, MLP_sa [3, *sa_hidden], MLP_global [3 + sa_hidden[-1], *global_hidden,
    feature], head [feature, *head_hidden, n_classes]."""

    def __init__(self, n_classes: int, *, centers: int = 64, radius: float = 0.3, neighbors: int = 32,
                 sa_hidden: Sequence[int] = (32, 64), global_hidden: Sequence[int] = (128,), feature: int = 256,
                 head_hidden: Sequence[int] = (128,), seed: int = 0, dtype: Any = wp.float32, device: Any = "cpu",
                 backend: str | None = None):
        super().__init__(dtype, device)
        if not sa_hidden:
            raise ValueError("sa_hidden: expected at least one layer width")
        self.n_centers, self.radius, self.n_neighbors = int(centers), float(radius), int(neighbors)
        c1 = int(sa_hidden[-1])
        self.mlps = {"sa": _mlp([3, *sa_hidden], 3 * seed, dtype, device, backend),
                     "global": _mlp([3 + c1, *global_hidden, feature], 3 * seed + 1, dtype, device, backend),
                     "head": _mlp([feature, *head_hidden, n_classes], 3 * seed + 2, dtype, device, backend)}

    def indices(self, points: np.ndarray) -> kpn.GroupIndices:
        """The FPS centres and ball-query neighbours of clouds `points` (B, N, 3)."""
        return kpn.group_indices(self._wp(_check_clouds(points)), self.n_centers, self.radius, self.n_neighbors,
                                 device=self.device)

    def forward(self, points: np.ndarray, indices: kpn.GroupIndices | None = None) -> Forward:
        """Logits of clouds `points` (B, N, 3), with their `indices` (computed here when None)."""
        points = _check_clouds(points)
        idx = self.indices(points) if indices is None else indices
        b = points.shape[0]
        s, k = idx.neighbors.shape[1], idx.neighbors.shape[2]
        if idx.neighbors.shape[0] != b:
            raise ValueError(f"indices: expected the indices of {b} clouds, got {idx.neighbors.shape[0]}")
        pts = self._wp(points)
        u = kpn.group_local(pts, idx.centers, idx.neighbors, self.radius)
        h1, c_sa = self.mlps["sa"].forward(u.reshape((b * s * k, 3)))
        pool1 = kpn.max_pool(h1.reshape((b * s, k, h1.shape[1])))
        xyz = points[np.arange(b)[:, None], idx.centers].reshape(b * s, 3)
        z = np.concatenate([xyz.astype(self.np_dtype), pool1.value.numpy()], axis=1)
        h2, c_global = self.mlps["global"].forward(self._wp(z))
        pool2 = kpn.max_pool(h2.reshape((b, s, h2.shape[1])))
        logits, c_head = self.mlps["head"].forward(pool2.value)
        cache = {"sa": c_sa, "pool1": pool1, "global": c_global, "pool2": pool2, "head": c_head,
                 "points": pts, "indices": idx, "shape": (b, points.shape[1], s, k)}
        return Forward(logits.numpy(), cache)

    def backward(self, fwd: Forward, grad_logits: np.ndarray, need_points_grad: bool = False
                 ) -> tuple[dict[str, wp.array], np.ndarray | None]:
        """(dL/dparam for every parameter, dL/dpoints (B, N, 3) or None) for the cotangent dL/dlogits."""
        c = fwd.cache
        b, n, s, k = c["shape"]
        idx = c["indices"]
        grads: dict[str, wp.array] = {}
        d_g = self._mlp_backward("head", c, self._wp(grad_logits), grads)
        d_z = self._mlp_backward("global", c, self._unpool(c["pool2"], d_g, s), grads).numpy()
        d_u = self._mlp_backward("sa", c, self._unpool(c["pool1"], self._wp(d_z[:, 3:]), k), grads, need_points_grad)
        if not need_points_grad:
            return grads, None
        d_pts = kpn.group_local_backward(c["points"], idx.centers, idx.neighbors, self.radius,
                                         d_u.reshape((b, s, k, 3)))["points"].numpy().astype(np.float64)
        # the centres' coordinates p_{c_s} feed MLP_global directly: their gradient goes back to those points
        np.add.at(d_pts, (np.repeat(np.arange(b), s), idx.centers.reshape(-1)), d_z[:, :3])
        return grads, d_pts.astype(self.np_dtype)
