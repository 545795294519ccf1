"""Reusable output buffers for kernels called again and again with varying sizes.

A fresh `wp.empty` of hundreds of megabytes is cheap to ask for and expensive to use: on the CPU
every page faults on first touch. For `composite_backward` at 65536 rays x 128 samples (134 MB of
gradients) that costs more than the kernel itself: 66-88 ms per call against 19-23 ms with the
same buffers reused, on 2 cores (`drlab bench volume` reports both ways for forward + backward).
A `Workspace` allocates each named buffer once, at the largest size asked for so far (grown by
half again when it must grow), and hands out views of its leading rows.

A view is overwritten by the next request for the same name: results computed into a workspace
live until the next call that uses it (in a training loop, until the next iteration). Names are
fixed by the callers ("composite.rgb", "grid.grad.density", ...), so give each pipeline (one field,
one training loop) its own workspace.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

GROWTH = 1.5


class Workspace:
    """Named, growable buffers on one device; `array(name, shape, dtype)` returns a view."""

    def __init__(self, device: str | wp.Device | None = None):
        self.device = A.get_device(device)
        self._buffers: dict[str, wp.array] = {}

    def array(self, name: str, shape: tuple[int, ...], dtype: Any) -> wp.array:
        """A contiguous (shape) view of buffer `name` (contents undefined), grown if needed.

        The leading dimension may vary between calls; the trailing ones and the dtype of a name
        are fixed by its first use (a different request reallocates it).
        """
        shape = tuple(int(s) for s in shape)
        if not shape or any(s < 0 for s in shape):
            raise ValueError(f"shape: expected a non-empty tuple of sizes >= 0, got {shape}")
        buf = self._buffers.get(name)
        same_layout = buf is not None and buf.dtype == dtype and tuple(buf.shape[1:]) == shape[1:]
        if not same_layout or buf.shape[0] < shape[0]:
            rows = max(shape[0], int(np.ceil(buf.shape[0] * GROWTH))) if same_layout else shape[0]
            buf = wp.empty((max(rows, 1),) + shape[1:], dtype=dtype, device=self.device)
            self._buffers[name] = buf
        return buf[: shape[0]]

    def nbytes(self) -> int:
        """Bytes held by every buffer."""
        return sum(b.capacity for b in self._buffers.values())


def check_workspace(workspace: Any, device: wp.Device) -> None:
    """None, or a Workspace on `device`; ValueError otherwise (before any launch)."""
    if workspace is not None and (not isinstance(workspace, Workspace) or workspace.device != device):
        raise ValueError(f"workspace: expected a kernels.volume.Workspace on {device}")
