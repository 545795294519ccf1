"""Bad inputs to the on-the-fly lookup's feature storage: one ValueError naming the argument, before any launch."""

from __future__ import annotations

import numpy as np
import pytest

from kernels import corr

C, H, W, LEVELS = 8, 8, 8, 2


def _inputs(scale: float = 1.0):
    rng = np.random.default_rng(0)
    f1 = (rng.standard_normal((C, H, W)) * scale).astype(np.float32)
    pyramid = corr.pool_features((rng.standard_normal((C, H, W)) * scale).astype(np.float32), LEVELS)
    coords = np.stack(np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)).astype(np.float32)
    return f1, pyramid, coords


def _lookup(feature_dtype, scale=1.0, coords=None):
    f1, pyramid, xy = _inputs(scale)
    return corr.lookup_onthefly(f1, pyramid, xy if coords is None else coords, 1, feature_dtype=feature_dtype)


def _store(feature_dtype, scale=1.0):
    f1, pyramid, _ = _inputs(scale)
    return corr.onthefly_features(f1, pyramid, feature_dtype=feature_dtype)


def _lookup_stored(features=None, coords=None):
    f1, pyramid, xy = _inputs()
    features = corr.onthefly_features(f1, pyramid) if features is None else features
    return corr.lookup_onthefly_features(features, xy if coords is None else coords, 1)


def _backward(feature_dtype):
    f1, pyramid, xy = _inputs()
    return corr.lookup_onthefly_backward(f1, pyramid, xy, 1, np.zeros((LEVELS * 9, H, W), np.float32),
                                         feature_dtype=feature_dtype)


CASES = [
    ("lookup_feature_dtype_float8", lambda: _lookup("float8"), "feature_dtype: expected one of 'float32', 'float16'"),
    ("lookup_feature_dtype_upper", lambda: _lookup("FLOAT16"), "feature_dtype: expected one of"),
    ("lookup_feature_dtype_numpy_type", lambda: _lookup(np.float16), "feature_dtype: expected one of"),
    ("lookup_feature_dtype_none", lambda: _lookup(None), "feature_dtype: expected one of"),
    ("store_feature_dtype_bfloat16", lambda: _store("bfloat16"), "feature_dtype: expected one of"),
    ("held_bytes_feature_dtype_float64",
     lambda: corr.onthefly_held_bytes(H, W, C, LEVELS, feature_dtype="float64"), "feature_dtype: expected one of"),
    ("store_float16_overflow", lambda: _store("float16", scale=1e5),
     r"feature_dtype: float16 storage holds \|values\|"),
    ("lookup_float16_overflow", lambda: _lookup("float16", scale=1e5), r"feature_dtype: float16 storage holds"),
    ("lookup_float16_bad_coords", lambda: _lookup("float16", coords=np.zeros((2, H, W + 1), np.float32)),
     r"coords: expected shape \(2, 8, 8\)"),
    ("backward_float16", lambda: _backward("float16"), "feature_dtype: the on-the-fly lookup with float16 features is "
                                                      "forward-only"),
    ("backward_unknown", lambda: _backward("half"), "feature_dtype: expected one of"),
    ("stored_lookup_not_features", lambda: _lookup_stored(features=np.zeros((C, H, W), np.float32)),
     "features: expected the OnTheFlyFeatures of onthefly_features, got ndarray"),
    ("stored_lookup_float64_coords", lambda: _lookup_stored(coords=np.zeros((2, H, W))),
     "coords: expected dtype float32"),
    ("stored_lookup_coords_shape", lambda: _lookup_stored(coords=np.zeros((2, H + 1, W), np.float32)),
     r"coords: expected shape \(2, 8, 8\)"),
]


@pytest.mark.parametrize("call, message", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_raises(call, message):
    with pytest.raises(ValueError, match=message):
        call()
