"""research/pointnet: the shape clouds, the rotation augmentation, order invariance, the classifiers against
the NumPy reference, bad input, and a tiny classification problem that the trained network must solve."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels.reference import pointnet as ref
from kernels.reference.volume import mlp as ref_mlp
from research.pointnet import baseline, shapes
from research.pointnet.model import PointNet, PointNetSA, softmax_cross_entropy
from research.pointnet.train import TrainConfig, accuracy, indices_for, train

# --------------------------------------------------------------------------- data


def test_parametric_shapes_lie_on_their_surfaces_and_are_area_uniform():
    rng = np.random.default_rng(0)
    n = 20000
    s = shapes.sphere(rng, n)
    np.testing.assert_allclose(np.linalg.norm(s, axis=1), 1.0, atol=1e-12)
    c = shapes.cube(rng, n)
    assert np.allclose(np.abs(c).max(axis=1), 1.0)
    cyl = shapes.cylinder(rng, n)
    caps = np.isclose(np.abs(cyl[:, 2]), 1.0) & (np.hypot(cyl[:, 0], cyl[:, 1]) < 1 - 1e-9)
    assert abs(caps.mean() - 1 / 3) < 0.02  # caps 2 pi of the area 6 pi (binomial sd 0.003)
    cone = shapes.cone(rng, n)
    side = ~np.isclose(cone[:, 2], -1.0)
    np.testing.assert_allclose(np.hypot(cone[side, 0], cone[side, 1]), (1 - cone[side, 2]) / 2, atol=1e-12)
    assert abs(side.mean() - np.sqrt(5) / (1 + np.sqrt(5))) < 0.02
    # area-uniform on the side: the half nearer the apex (z > 0) holds a quarter of the side's area
    assert abs(np.mean(cone[side, 2] > 0) - 0.25) < 0.02
    t = shapes.torus(rng, n)
    ring = np.hypot(t[:, 0], t[:, 1]) - shapes.TORUS_R
    np.testing.assert_allclose(np.hypot(ring, t[:, 2]), shapes.TORUS_r, atol=1e-12)
    # the outer half (ring > 0) has the larger area: (pi R + 2 r) / (2 pi R) of it
    assert abs(np.mean(ring > 0) - (np.pi * shapes.TORUS_R + 2 * shapes.TORUS_r) / (2 * np.pi * shapes.TORUS_R)) < 0.02


def test_mesh_sampling_is_uniform_over_equal_faces():
    v, f = shapes.MESHES["octahedron"]
    p = shapes.sample_mesh(np.random.default_rng(1), 16000, v, f)
    np.testing.assert_allclose(np.abs(p).sum(axis=1), 1.0, atol=1e-12)  # on the surface |x| + |y| + |z| = 1
    octant = (p[:, 0] > 0) * 4 + (p[:, 1] > 0) * 2 + (p[:, 2] > 0)
    frac = np.bincount(octant, minlength=8) / len(p)
    assert np.all(np.abs(frac - 1 / 8) < 0.015)
    lv, lf = shapes.MESHES["l_prism"]
    areas = 0.5 * np.linalg.norm(np.cross(lv[lf[:, 1]] - lv[lf[:, 0]], lv[lf[:, 2]] - lv[lf[:, 0]]), axis=1)
    assert np.isclose(areas.sum(), 2 * 3 + 8)  # two L caps of area 3, walls of perimeter 8 and height 1


def test_splits_are_normalised_seeded_and_independent():
    a = shapes.make_splits(5, {"train": 2, "test": 2}, 40)
    b = shapes.make_splits(5, {"train": 2, "test": 2}, 40)
    np.testing.assert_array_equal(a["train"].points, b["train"].points)
    assert not np.allclose(a["train"].points, a["test"].points)
    p = a["train"].points.astype(np.float64)
    np.testing.assert_allclose(p.mean(axis=1), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(p, axis=2).max(axis=1), 1.0, rtol=1e-6)
    assert a["train"].labels.tolist() == np.repeat(np.arange(len(shapes.CLASSES)), 2).tolist()


def test_rotation_augmentation_is_a_rotation_and_keeps_the_groups():
    rng = np.random.default_rng(2)
    r = shapes.random_rotations(rng, 16)
    np.testing.assert_allclose(r @ r.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (16, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    assert np.abs(r - np.eye(3)).max() > 0.5  # not the identity
    clouds = shapes.make_splits(3, {"train": 2}, 64)["train"].points[:16].astype(np.float64)
    rot = shapes.rotate(clouds, r)
    d = np.linalg.norm(clouds[:, :, None] - clouds[:, None], axis=-1)
    np.testing.assert_allclose(np.linalg.norm(rot[:, :, None] - rot[:, None], axis=-1), d, atol=1e-12)
    # the FPS and ball-query indices the training reuses for rotated copies are those of the rotated clouds
    model = PointNetSA(3, centers=8, radius=0.4, neighbors=8, dtype=wp.float64)
    i0, i1 = model.indices(clouds), model.indices(rot)
    np.testing.assert_array_equal(i0.centers, i1.centers)
    np.testing.assert_array_equal(i0.neighbors, i1.neighbors)


# --------------------------------------------------------------------------- models


def _tiny(cls, backend=None, dtype=wp.float64, seed=0):
    if cls is PointNet:
        return PointNet(4, point_hidden=(8,), feature=6, head_hidden=(5,), seed=seed, dtype=dtype, backend=backend)
    return PointNetSA(4, centers=6, radius=0.5, neighbors=5, sa_hidden=(6, 4), global_hidden=(7,), feature=6,
                      head_hidden=(5,), seed=seed, dtype=dtype, backend=backend)


def _sub(state, prefix):
    return {k.split(".", 1)[1]: v for k, v in state.items() if k.startswith(prefix + ".")}


@pytest.mark.parametrize("backend", ["numpy", "warp"])
def test_classifiers_equal_the_numpy_reference(backend):
    pts = np.random.default_rng(0).normal(size=(3, 30, 3)) * 0.5
    net = _tiny(PointNet, backend)
    st = net.state()
    want = ref.pointnet_logits(pts, _sub(st, "point"), 2, _sub(st, "head"), 2)
    np.testing.assert_allclose(net.forward(pts).logits, want, rtol=1e-12, atol=1e-12)
    sa = _tiny(PointNetSA, backend)
    st = sa.state()
    xyz, f1 = ref.set_abstraction(pts, _sub(st, "sa"), 2, 6, 0.5, 5)
    z = np.concatenate([xyz, f1], axis=2).reshape(-1, 7)
    g = ref.max_pool(ref_mlp(_sub(st, "global"), z, 2).reshape(3, 6, -1))[0]
    np.testing.assert_allclose(sa.forward(pts).logits, ref_mlp(_sub(st, "head"), g, 2), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("dtype", [wp.float32, wp.float64])
def test_pointnet_is_invariant_to_the_order_of_the_points(dtype):
    """Bit-equal with the plain Warp MLP (each row the same loop wherever it sits, the maximum order-free);
    with BLAS a row may round differently by its place in a block, so to rounding (model docstring)."""
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(4, 50, 3)) * 0.5
    perm = np.stack([rng.permutation(50) for _ in range(4)])
    shuffled = np.take_along_axis(pts, perm[:, :, None], axis=1)
    warp_net = _tiny(PointNet, "warp", dtype)
    assert np.array_equal(warp_net.forward(pts).logits, warp_net.forward(shuffled).logits)
    blas_net = _tiny(PointNet, "numpy", dtype)
    tol = 1e-5 if dtype == wp.float32 else 1e-13
    np.testing.assert_allclose(blas_net.forward(pts).logits, blas_net.forward(shuffled).logits, rtol=tol, atol=tol)
    # the set-abstraction model, given the same groups (indices mapped through the permutation)
    sa = _tiny(PointNetSA, "warp", dtype)
    idx = sa.indices(pts)
    inv = np.argsort(perm, axis=1).astype(np.int32)
    rows = np.arange(4)
    idx_p = type(idx)(inv[rows[:, None], idx.centers], inv[rows[:, None, None], idx.neighbors], idx.count)
    assert np.array_equal(sa.forward(pts, idx).logits, sa.forward(shuffled, idx_p).logits)


def test_cross_entropy_matches_its_definition():
    z = np.array([[1.0, 2.0, 0.5], [0.0, -1.0, 3.0]])
    y = np.array([1, 2])
    loss, g = softmax_cross_entropy(z, y)
    p = np.exp(z) / np.exp(z).sum(axis=1, keepdims=True)
    assert np.isclose(loss, -np.mean(np.log(p[[0, 1], y])))
    np.testing.assert_allclose(g, (p - np.eye(3)[y]) / 2)


@pytest.mark.parametrize("call, message", [
    (lambda: _tiny(PointNet).forward(np.zeros((2, 0, 3))), "points: expected B >= 1 non-empty"),
    (lambda: _tiny(PointNet).forward(np.zeros((0, 5, 3))), "points: expected B >= 1 non-empty"),
    (lambda: _tiny(PointNet).forward(np.zeros((2, 5, 2))), "points: expected clouds of shape"),
    (lambda: _tiny(PointNet).forward(np.full((1, 5, 3), np.nan)), "points: expected finite"),
    (lambda: _tiny(PointNetSA).forward(np.full((1, 8, 3), np.inf)), "points: expected finite"),
    (lambda: _tiny(PointNetSA).forward(np.zeros((1, 4, 3))), "n_centers: expected an integer in"),
    (lambda: softmax_cross_entropy(np.zeros((2, 3)), np.array([0, 3])), "labels: expected values in"),
    (lambda: softmax_cross_entropy(np.zeros((2, 3)), np.array([0])), "labels: expected 2"),
    (lambda: shapes.normalise(np.full((1, 4, 3), np.nan)), "clouds: expected finite"),
    (lambda: shapes.normalise(np.zeros((1, 0, 3))), "clouds: expected a"),
    (lambda: shapes.normalise(np.ones((1, 4, 3))), "clouds: cloud 0 has all its points at one place"),
    (lambda: shapes.make_splits(0, {"train": 0}, 10), "per_class"),
    (lambda: shapes.sample_shape("cat", np.random.default_rng(0), 3), "name: expected one of"),
    (lambda: baseline.d2_pca_features(np.zeros((1, 1, 3))), "clouds: expected"),
    (lambda: TrainConfig(epochs=0).validate(), "epochs:"),
])
def test_bad_input_is_refused_naming_the_argument(call, message):
    with pytest.raises(ValueError, match="^" + message.replace("(", r"\(")):
        call()


def test_the_classifiers_and_the_baseline_beat_chance_on_a_tiny_problem():
    """Three classes (sphere, plane patch, cube), 32 points, 48 training clouds: chance is 1/3, and 30 test
    clouds reach 0.5 by chance with probability 0.02. Measured: PointNet 0.70, PointNet++ 0.77, baseline 0.83."""
    classes = ("sphere", "plane", "cube")
    sp = shapes.make_splits(8, {"train": 16, "val": 6, "test": 10}, 32, classes=classes)
    cfg = TrainConfig(epochs=25, batch_size=8, lr=1e-2)
    net = PointNet(3, point_hidden=(16,), feature=32, head_hidden=(16,), seed=0)
    res = train(net, sp["train"], sp["val"], cfg, seed=0)
    assert res.train_loss[-1] < res.train_loss[0]
    assert accuracy(net, sp["test"]) > 0.5
    sa = PointNetSA(3, centers=8, radius=0.5, neighbors=8, sa_hidden=(16,), global_hidden=(16,), feature=32,
                    head_hidden=(16,), seed=0)
    train(sa, sp["train"], sp["val"], cfg, seed=0)
    assert accuracy(sa, sp["test"], indices_for(sa, sp["test"].points)) > 0.5
    b = baseline.run_baseline(sp["train"], sp["val"], sp["test"], 3)
    assert np.mean(b.test_pred == sp["test"].labels) > 0.5
