"""Training and evaluation of the point-cloud classifiers (research.pointnet.model).

Mini-batch training: each epoch visits the training clouds in a fresh random order (from `seed`), in
batches of `batch_size` (the last one shorter); every cloud of a batch is rotated by its own
uniformly random rotation (research.pointnet.shapes.random_rotations: the test clouds come in random
poses, so the classifier must see every orientation); softmax cross-entropy; one Adam step
(kernels.optim.Adam) per batch. After each epoch the validation accuracy is measured, and the
parameters of the epoch with the best validation accuracy (the earliest on a tie) are the ones
returned: the number of epochs is thereby chosen on the validation split, never on the test split.

The set-abstraction model's FPS and ball-query indices are computed once per cloud before training
(rotations preserve them: research.pointnet.model).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from kernels import _arrays as A
from kernels import pointnet as kpn
from kernels.optim import Adam
from research.pointnet.model import PointNetSA, softmax_cross_entropy
from research.pointnet.shapes import Split, random_rotations, rotate


@dataclass(frozen=True)
class TrainConfig:
    epochs: int = 30
    batch_size: int = 32
    lr: float = 1e-3
    augment: bool = True  # a random rotation per cloud and batch

    def validate(self) -> "TrainConfig":
        for name in ("epochs", "batch_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {getattr(self, name)}")
        if not (self.lr > 0 and np.isfinite(self.lr)):
            raise ValueError(f"lr: expected a finite value > 0, got {self.lr}")
        return self


@dataclass
class TrainResult:
    best_epoch: int  # 1-based
    train_loss: list[float] = field(default_factory=list)  # mean batch loss per epoch
    val_accuracy: list[float] = field(default_factory=list)
    seconds: float = 0.0  # training, with the per-epoch validation and the indices


def _take(idx: kpn.GroupIndices | None, rows: np.ndarray) -> kpn.GroupIndices | None:
    if idx is None:
        return None
    return kpn.GroupIndices(idx.centers[rows], idx.neighbors[rows], idx.count[rows])


def indices_for(model: Any, points: np.ndarray, batch: int = 256) -> kpn.GroupIndices | None:
    """The model's grouping indices of every cloud (None for a model without grouping)."""
    if not isinstance(model, PointNetSA):
        return None
    parts = [model.indices(points[i:i + batch]) for i in range(0, len(points), batch)]
    return kpn.GroupIndices(*(np.concatenate([getattr(p, f) for p in parts])
                              for f in ("centers", "neighbors", "count")))


def predict(model: Any, points: np.ndarray, indices: kpn.GroupIndices | None = None, batch: int = 64) -> np.ndarray:
    """Class scores (M, classes) of clouds `points` (M, N, 3)."""
    out = []
    with A.value_checks(False):
        for i in range(0, len(points), batch):
            rows = np.arange(i, min(i + batch, len(points)))
            out.append(model.forward(points[rows], _take(indices, rows)).logits)
    return np.concatenate(out)


def accuracy(model: Any, split: Split, indices: kpn.GroupIndices | None = None) -> float:
    return float(np.mean(np.argmax(predict(model, split.points, indices), axis=1) == split.labels))


def train(model: Any, train_split: Split, val_split: Split, cfg: TrainConfig, seed: int,
          progress: Callable[[int, float, float], None] | None = None) -> TrainResult:
    """Train `model` in place (module docstring); it ends holding the best-validation epoch's parameters.
    `progress(epoch, train_loss, val_accuracy)` is called after each epoch."""
    cfg = cfg.validate()
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    tr_idx = indices_for(model, train_split.points)
    va_idx = indices_for(model, val_split.points)
    opt = Adam(model.params, lr=cfg.lr)
    result = TrainResult(best_epoch=0)
    best_acc, best_state = -1.0, None
    n = len(train_split.points)
    with A.value_checks(False):  # the clouds were checked when the splits were made
        for epoch in range(1, cfg.epochs + 1):
            order = rng.permutation(n)
            losses = []
            for i in range(0, n, cfg.batch_size):
                rows = order[i:i + cfg.batch_size]
                pts = train_split.points[rows]
                if cfg.augment:
                    pts = rotate(pts, random_rotations(rng, len(rows)))
                fwd = model.forward(pts, _take(tr_idx, rows))
                loss, g = softmax_cross_entropy(fwd.logits, train_split.labels[rows])
                grads, _ = model.backward(fwd, g)
                opt.step(grads)
                losses.append(loss)
            acc = accuracy(model, val_split, va_idx)
            result.train_loss.append(float(np.mean(losses)))
            result.val_accuracy.append(acc)
            if acc > best_acc:
                best_acc, best_state, result.best_epoch = acc, model.state(), epoch
            if progress is not None:
                progress(epoch, result.train_loss[-1], acc)
    model.load(best_state)
    result.seconds = time.perf_counter() - t0
    return result
