"""A non-learned shape classifier: the D2 shape distribution plus PCA eigenvalues, with k nearest neighbours.

Features of a normalised cloud (research.pointnet.shapes.normalise: centred, farthest point at 1):
  * D2 (Osada, Funkhouser, Chazelle and Dobkin, "Shape Distributions", ACM TOG 2002): the histogram
    of the distances between all pairs of points (scipy.spatial.distance.pdist), `bins` equal bins
    over [0, 2] (the largest distance in the unit ball), as frequencies summing to 1;
  * the covariance's eigenvalues, descending, divided by their sum (how elongated and how flat).
Both are invariant to rotation and to the order of the points. The features are standardised by
the training set's mean and standard deviation, and a test cloud takes the majority class of its k
nearest training clouds in Euclidean distance (scipy.spatial.distance.cdist); a tie between classes
goes to the class of the nearest neighbour among them. k is chosen from `K_CHOICES` by accuracy on the
validation split (the smallest k on a tie), never on the test split.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import cdist, pdist

K_CHOICES = (1, 3, 5, 7, 9, 15)


def d2_pca_features(clouds: np.ndarray, bins: int = 32) -> np.ndarray:
    """(M, bins + 3) features of normalised clouds (M, N, 3): D2 frequencies, then normalised eigenvalues."""
    clouds = np.asarray(clouds, float)
    if clouds.ndim != 3 or clouds.shape[2] != 3 or clouds.shape[1] < 2:
        raise ValueError(f"clouds: expected (M, N, 3) clouds with N >= 2, got shape {clouds.shape}")
    if not np.all(np.isfinite(clouds)):
        raise ValueError("clouds: expected finite coordinates, found NaN or infinite entries")
    if int(bins) < 1:
        raise ValueError(f"bins: expected an integer >= 1, got {bins}")
    out = np.empty((len(clouds), bins + 3))
    for i, p in enumerate(clouds):
        hist, _ = np.histogram(pdist(p), bins=bins, range=(0.0, 2.0))
        out[i, :bins] = hist / hist.sum()
        ev = np.linalg.eigvalsh(np.cov(p.T))[::-1]
        out[i, bins:] = ev / ev.sum()
    return out


def knn_predict(train_x: np.ndarray, train_y: np.ndarray, x: np.ndarray, k: int, n_classes: int) -> np.ndarray:
    """Majority class of the k nearest rows of train_x for each row of x (ties: the nearer class)."""
    d = cdist(x, train_x)
    order = np.argsort(d, axis=1, kind="stable")[:, :k]
    votes = np.zeros((len(x), n_classes))
    for rank in range(order.shape[1]):
        # one vote each, plus a bonus below one vote that favours nearer neighbours: breaks ties only
        np.add.at(votes, (np.arange(len(x)), train_y[order[:, rank]]), 1.0 + 0.5 ** (rank + 1))
    return np.argmax(votes, axis=1)


@dataclass
class BaselineResult:
    k: int
    val_accuracy: dict[int, float]  # k -> validation accuracy
    test_pred: np.ndarray
    seconds: float  # features of every split, the choice of k and the test predictions


def run_baseline(train, val, test, n_classes: int, bins: int = 32) -> BaselineResult:
    """Features, standardisation on train, k chosen on val, predictions on test (module docstring)."""
    import time

    t0 = time.perf_counter()
    f_tr, f_va, f_te = (d2_pca_features(s.points, bins) for s in (train, val, test))
    mu, sd = f_tr.mean(axis=0), f_tr.std(axis=0)
    sd[sd == 0] = 1.0
    f_tr, f_va, f_te = ((f - mu) / sd for f in (f_tr, f_va, f_te))
    val_acc = {k: float(np.mean(knn_predict(f_tr, train.labels, f_va, k, n_classes) == val.labels))
               for k in K_CHOICES if k <= len(f_tr)}
    best = max(val_acc, key=lambda k: (val_acc[k], -k))
    pred = knn_predict(f_tr, train.labels, f_te, best, n_classes)
    return BaselineResult(best, val_acc, pred, time.perf_counter() - t0)
