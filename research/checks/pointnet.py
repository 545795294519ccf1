"""Gradient checks of kernels/pointnet.py and the classifiers of research/pointnet, float64.

Non-smooth points and how the inputs avoid them:
  * max-pool: the maximum has a kink where two entries of a set tie. The inputs are a random
    permutation of well-spaced values (gap SPACING between any two of a set, plus jitter far smaller),
    so a finite-difference step (eps = 1e-6) never changes an argmax.
  * grouping: linear in the points for fixed indices; the indices are inputs (integers), not
    differentiated, so any indices do, repeated ones (ball-query padding) included.
  * softmax cross-entropy: smooth.
  * whole classifiers: the MLPs' ReLUs have kinks at 0 and the max-pools at ties. The clouds and
    parameters are redrawn (next sub-seed) until every hidden pre-activation is at least MARGIN from 0
    and every max-pool's winner leads the runner-up by MARGIN (tied copies of one point from the
    ball-query padding excepted: they move together, so they never separate). With |d input| <= eps
    per coordinate and weights of order one, a step moves a pre-activation by far less than MARGIN.
    The FPS and ball-query indices are computed once from the unperturbed clouds and held fixed
    (they are piecewise constant in the points, with zero gradient wherever they are defined).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from kernels import pointnet as kpn
from research.gradcheck import GradcheckResult, check_vjp, register_check
from research.pointnet.model import PointNet, PointNetSA, softmax_cross_entropy

SPACING = 0.05
MARGIN = 1e-4


def spaced_sets(rng: np.random.Generator, g: int, k: int, c: int) -> np.ndarray:
    """(G, K, C) float64 whose K entries of each (g, c) are distinct by at least SPACING / 2."""
    base = (np.arange(k) - k / 2) * SPACING
    x = np.empty((g, k, c))
    for i in range(g):
        for j in range(c):
            x[i, :, j] = rng.permutation(base) + rng.uniform(-SPACING / 4, SPACING / 4, size=k) + rng.normal()
    return x


def check_max_pool(seed: int, g: int, k: int, c: int) -> list[GradcheckResult]:
    x = spaced_sets(np.random.default_rng(seed), g, k, c)

    def f(x):
        return kpn.max_pool(x).value

    def vjp(inputs, cot):
        return kpn.max_pool_backward(kpn.max_pool(inputs["x"]), cot, inputs["x"].shape[1])

    return check_vjp(f, vjp, {"x": x}, seed=seed, name=f"pointnet.max_pool[seed={seed},{g}x{k}x{c}]")


def check_group(seed: int, b: int, n: int, s: int, k: int) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(b, n, 3))
    centers = rng.integers(0, n, size=(b, s)).astype(np.int32)
    neighbors = rng.integers(0, n, size=(b, s, k)).astype(np.int32)
    neighbors[:, :, 0] = centers  # a centre is its own first neighbour, and some indices repeat
    radius = 0.7

    def f(points):
        return kpn.group_local(points, centers, neighbors, radius)

    def vjp(inputs, cot):
        return kpn.group_local_backward(inputs["points"], centers, neighbors, radius, cot)

    return check_vjp(f, vjp, {"points": points}, seed=seed, name=f"pointnet.group_local[seed={seed},{b}x{n}x{s}x{k}]")


def check_cross_entropy(seed: int, b: int, classes: int) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    logits = rng.normal(size=(b, classes)) * 2.0
    labels = rng.integers(0, classes, size=b)

    def f(logits):
        return np.array([softmax_cross_entropy(logits, labels)[0]])

    def vjp(inputs, cot):
        return {"logits": softmax_cross_entropy(inputs["logits"], labels)[1] * float(cot[0])}

    return check_vjp(f, vjp, {"logits": logits}, seed=seed, name=f"pointnet.cross_entropy[seed={seed},{b}x{classes}]")


def _relu_margin(model, fwd) -> float:
    """The smallest |hidden pre-activation| of every MLP of the forward."""
    worst = np.inf
    for key, cache in fwd.cache.items():
        if key in model.mlps:
            for z in cache.pre[:-1]:
                worst = min(worst, float(np.abs(z.numpy()).min()))
    return worst


def _pool_lead(h: np.ndarray) -> float:
    """min over sets and channels of (max - largest value that differs from the max), for h (G, K, C)."""
    top = h.max(axis=1, keepdims=True)
    rest = np.where(h == top, -np.inf, h).max(axis=1)
    lead = (top[:, 0] - rest)
    return float(lead.min()) if np.isfinite(lead).any() else np.inf


def _model_inputs(kind: str, seed: int):
    """A tiny float64 model, clouds, labels and indices whose kinks are all at least MARGIN away."""
    for sub in range(50):
        rng = np.random.default_rng([seed, sub])
        b, n = 3, 24
        points = rng.normal(size=(b, n, 3)) * 0.5
        labels = rng.integers(0, 4, size=b)
        if kind == "pointnet":
            model = PointNet(4, point_hidden=(6,), feature=5, head_hidden=(4,), seed=100 * seed + sub,
                             dtype=wp.float64)
            idx = None
        else:
            model = PointNetSA(4, centers=6, radius=0.6, neighbors=5, sa_hidden=(5, 4), global_hidden=(6,), feature=5,
                               head_hidden=(4,), seed=100 * seed + sub, dtype=wp.float64)
            idx = model.indices(points)
        fwd = model.forward(points, idx)
        relu = _relu_margin(model, fwd)
        leads = [_pool_lead(np.asarray(_pool_input(model, fwd, key))) for key in ("pool", "pool1", "pool2")
                 if key in fwd.cache]
        if min(relu, *leads) > MARGIN:
            return model, points, labels, idx
    raise RuntimeError(f"no non-degenerate draw for {kind} seed {seed}")


def _pool_input(model, fwd, key: str) -> np.ndarray:
    """The (G, K, C) array a max-pool of the forward took: the output of the MLP before it."""
    mlp_key = {"pool": "point", "pool1": "sa", "pool2": "global"}[key]
    out = fwd.cache[mlp_key].output.numpy()
    b = fwd.logits.shape[0]
    if key == "pool":
        return out.reshape(b, -1, out.shape[1])
    _, _, s, k = fwd.cache["shape"]
    return out.reshape(b * s, k, -1) if key == "pool1" else out.reshape(b, s, -1)


def check_model(kind: str, seed: int) -> list[GradcheckResult]:
    """The loss of a whole classifier against every parameter and the points."""
    model, points, labels, idx = _model_inputs(kind, seed)
    names = list(model.params)

    def f(points, **params):
        model.load(params)
        return np.array([softmax_cross_entropy(model.forward(points, idx).logits, labels)[0]])

    def vjp(inputs, cot):
        model.load({k: inputs[k] for k in names})
        fwd = model.forward(inputs["points"], idx)
        _, g = softmax_cross_entropy(fwd.logits, labels)
        grads, d_pts = model.backward(fwd, g * float(cot[0]), need_points_grad=True)
        return {"points": d_pts, **{k: v.numpy() for k, v in grads.items()}}

    inputs = {"points": points, **model.state()}
    # 4 random directions (each a projection of the whole gradient) and 8 random coordinates per input, fewer
    # than check_vjp's defaults (8 and up to 64): each evaluation is a whole classifier's forward, and the
    # max-pool and grouping kernels inside are checked coordinate by coordinate above
    return check_vjp(f, vjp, inputs, seed=seed, n_directions=4, per_coord_limit=8,
                     name=f"pointnet.{kind}[seed={seed}]")


@register_check("pointnet.max_pool")
def max_pool_checks() -> list[GradcheckResult]:
    return check_max_pool(0, 3, 5, 4) + check_max_pool(1, 2, 9, 3) + check_max_pool(2, 1, 1, 6)


@register_check("pointnet.group_local")
def group_checks() -> list[GradcheckResult]:
    return check_group(0, 2, 10, 3, 4) + check_group(1, 1, 5, 4, 6) + check_group(2, 3, 7, 2, 3)


@register_check("pointnet.cross_entropy")
def cross_entropy_checks() -> list[GradcheckResult]:
    return check_cross_entropy(0, 4, 3) + check_cross_entropy(1, 7, 9) + check_cross_entropy(2, 1, 2)


@register_check("pointnet.classifier")
def model_checks() -> list[GradcheckResult]:
    return [r for kind in ("pointnet", "sa") for seed in (0, 1) for r in check_model(kind, seed)]
