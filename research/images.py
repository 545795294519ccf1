"""One normalisation of input images for stereo and optical flow: float32 grey in [0, 1].

`to_unit_grey(image, name)`:

* units: uint8 is divided by 255, uint16 by 65535; a float image must already lie in [0, 1]
  (a float image with values up to 255 or 65535 is refused with a message suggesting the
  division, never rescaled by guesswork); bool and other integer types are refused;
* colour: (H, W, 3) becomes grey by Rec. 601 luma, 0.299 R + 0.587 G + 0.114 B (the weights of
  OpenCV's and PIL's RGB-to-grey conversion), computed in float64; (H, W) is kept as it is;
* the result is a C-contiguous float32 (H, W) array in [0, 1].

A float32 grey image in [0, 1] comes back bit-identical, and a float64 one comes back as its
float32 rounding (what the stereo kernels always did with it), so callers that already passed such
images get exactly the results they had. `to_unit_grey(..., dtype=None)` keeps a float64 input
float64 (the Lucas-Kanade kernels run in the input's precision), and `to_unit` applies the unit
rule only, keeping colour (the correlation-flow features are colour patches; the Birchfield-Tomasi
stereo cost has a colour term), and `unit_pair` does so for both images of a pair, as float32. Every check raises
ValueError naming the argument.
"""

from __future__ import annotations

import numpy as np

LUMA_601 = (0.299, 0.587, 0.114)
_INTEGER_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}


def to_unit(image: np.ndarray, name: str = "image") -> np.ndarray:
    """The unit rule alone: uint8 / 255, uint16 / 65535 (as float64), a float image checked to lie in [0, 1]
    and returned as it is; grey (H, W) or colour (H, W, 3), kept."""
    a = np.asarray(image)
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise ValueError(f"{name}: expected a grey (H, W) or colour (H, W, 3) image, got shape {a.shape}")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name}: expected a non-empty image, got shape {a.shape}")
    if a.dtype in _INTEGER_SCALE:
        unit = a.astype(np.float64) / _INTEGER_SCALE[a.dtype]
    elif np.issubdtype(a.dtype, np.floating):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: contains NaN or infinite values")
        lo, hi = float(a.min()), float(a.max())
        if lo < 0.0 or hi > 1.0:
            hint = (" (8-bit values? divide by 255)" if hi <= 255.0 and lo >= 0.0 else
                    " (16-bit values? divide by 65535)" if hi <= 65535.0 and lo >= 0.0 else "")
            raise ValueError(f"{name}: a float image must lie in [0, 1], got values in [{lo:.6g}, {hi:.6g}]{hint}")
        unit = a
    else:
        raise ValueError(f"{name}: expected uint8, uint16 or a float image in [0, 1], got dtype {a.dtype}")
    return unit


def to_unit_grey(image: np.ndarray, name: str = "image", dtype: type | None = np.float32) -> np.ndarray:
    """`image` (H, W) or (H, W, 3), uint8 / uint16 / float in [0, 1] -> grey (H, W) in [0, 1] (module docstring).

    `dtype`: of the result, float32 by default; None keeps a float64 or float32 input's precision
    (integer inputs give float32).
    """
    unit = to_unit(image, name)
    if unit.ndim == 3:
        unit = np.clip(np.asarray(unit, dtype=np.float64) @ np.array(LUMA_601), 0.0, 1.0)  # weights sum to 1
    if dtype is None:
        dtype = np.float64 if np.asarray(image).dtype == np.float64 else np.float32
    return np.ascontiguousarray(unit, dtype=dtype)


def unit_grey_pair(first: np.ndarray, second: np.ndarray, names: tuple[str, str] = ("left", "right"),
                   dtype: type | None = np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Both images of a pair through `to_unit_grey`, which must give one shape and one dtype."""
    a, b = to_unit_grey(first, names[0], dtype), to_unit_grey(second, names[1], dtype)
    if a.dtype != b.dtype:  # dtype=None with a float64 and a float32 frame
        a, b = a.astype(np.float64), b.astype(np.float64)
    if a.shape != b.shape:
        raise ValueError(f"{names[0]}, {names[1]}: expected images of one size, got {a.shape} and {b.shape}")
    return a, b


def unit_pair(first: np.ndarray, second: np.ndarray, names: tuple[str, str] = ("left", "right")
              ) -> tuple[np.ndarray, np.ndarray]:
    """Both images of a pair through `to_unit` (colour kept), as C-contiguous float32 of one shape."""
    a, b = to_unit(first, names[0]), to_unit(second, names[1])
    if a.shape != b.shape:
        raise ValueError(f"{names[0]}, {names[1]}: expected images of one size and channel count, got "
                         f"{a.shape} and {b.shape}")
    return np.ascontiguousarray(a, dtype=np.float32), np.ascontiguousarray(b, dtype=np.float32)
