"""Domain checks of tracker and filter settings: each raises one ValueError naming the field.

The scalar checks (integer, number, probability, flag) are research.values', re-exported here.
Used by the configurations' `__post_init__` (SortConfig, ByteTrackConfig, HistogramConfig), the
Kalman models (kalman.LinearGaussianModel, kinematic_model) and the box helpers (boxes.py), so a
bad value (max_age -1, iou_threshold NaN, a negative q, an asymmetric covariance) is refused when
it is given, not silently used.
"""

from __future__ import annotations

import numpy as np

from research.values import flag, integer, number, probability  # noqa: F401 (re-exported)

SYMMETRY_RTOL = 1e-9  # |A - A^T| allowed, relative to max |A| (and 1)
PSD_RTOL = 1e-9  # smallest eigenvalue allowed below 0, relative to max |A| (and 1)


def covariance(name: str, a, size: int | None = None) -> np.ndarray:
    """A finite, symmetric, positive semi-definite square matrix (within SYMMETRY_RTOL / PSD_RTOL)."""
    m = np.asarray(a, dtype=float)
    if m.ndim != 2 or m.shape[0] != m.shape[1] or (size is not None and m.shape[0] != size):
        want = f"({size}, {size})" if size is not None else "a square matrix"
        raise ValueError(f"{name}: expected {want}, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    scale = max(1.0, float(np.abs(m).max())) if m.size else 1.0
    asym = np.abs(m - m.T).max(initial=0.0)
    if asym > SYMMETRY_RTOL * scale:
        raise ValueError(f"{name}: expected a symmetric covariance matrix, largest |A - A^T| is {asym:.3g}")
    low = np.linalg.eigvalsh(0.5 * (m + m.T)).min() if m.size else 0.0
    if low < -PSD_RTOL * scale:
        raise ValueError(f"{name}: expected a positive semi-definite covariance matrix, smallest eigenvalue is "
                         f"{low:.3g}")
    return m


def boxes(name: str, b, allow_empty_box: bool = True) -> np.ndarray:
    """xyxy boxes (N, 4): finite, with x2 >= x1 and y2 >= y1 (w, h >= 0; > 0 unless allow_empty_box)."""
    arr = np.asarray(b, dtype=float)
    if arr.size and arr.shape[-1] != 4:
        raise ValueError(f"{name}: expected xyxy boxes (..., 4), got shape {arr.shape}")
    arr = arr.reshape(-1, 4)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: boxes must be finite, found NaN or infinite coordinates")
    w, h = arr[:, 2] - arr[:, 0], arr[:, 3] - arr[:, 1]
    bad = (w < 0) | (h < 0) if allow_empty_box else (w <= 0) | (h <= 0)
    if np.any(bad):
        i = int(np.argmax(bad))
        rule = "w, h >= 0" if allow_empty_box else "w, h > 0"
        raise ValueError(f"{name}: expected boxes [x1, y1, x2, y2] with {rule}, got row {i} {arr[i].tolist()}")
    return arr
