"""One helper of the splat family's host code: an `Inputs` for a later stage of a checked chain.

`gaussian_inputs` and `splats_2d` resolve the device, the float type and the output kind once;
the stages after them (project, bin, rasterise and the backwards) reuse those three instead of
resolving them again from arrays they made themselves.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from kernels import _arrays as A


def inputs_like(device: wp.Device, scalar: Any, as_numpy: bool) -> A.Inputs:
    """An `Inputs` on `device` whose scalar type and output kind are already known."""
    a = A.Inputs(device)
    a.scalar = scalar
    a.as_numpy = as_numpy
    return a
