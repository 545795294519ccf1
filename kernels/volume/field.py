"""The interface every radiance field implements (no kernels here).

A field maps points x (N, 3) and unit view directions d (N, 3) to a density sigma(x) >= 0 (N,)
and a colour c(x, d) in [0, 1]^3 (N, 3). Its learnable parameters are named wp.arrays in
`params`. `backward` returns, for cotangents (g_sigma, g_rgb), the gradient of
<g_sigma, sigma> + <g_rgb, c> with respect to every parameter (positions and directions are
constants: no gradient flows to them).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import warp as wp

from kernels.volume import _util as U
from kernels.volume.workspace import Workspace, check_workspace


@dataclass
class FieldOutput:
    sigma: wp.array  # (N,)
    rgb: wp.array  # (N, 3)
    cache: dict[str, Any] = field(default_factory=dict)  # what backward needs from the forward


class Field(ABC):
    """Base class: dtype, device, named parameters, forward and backward (module docstring)."""

    name = "field"
    needs_dirs = False

    def __init__(self, params: dict[str, wp.array], dtype: Any, device: wp.Device) -> None:
        self.params = params
        self.dtype = dtype
        self.device = device

    # ------------------------------------------------------------------ parameters
    def param_shapes(self) -> dict[str, tuple[int, ...]]:
        return {k: tuple(v.shape) for k, v in self.params.items()}

    def n_params(self) -> int:
        return int(sum(v.size for v in self.params.values()))

    def set_params(self, values: dict[str, Any]) -> None:
        """Replace parameters by arrays of the same shapes (NumPy or wp.array); unknown names raise."""
        for k, v in values.items():
            if k not in self.params:
                raise ValueError(f"params: unknown parameter {k!r}; expected one of {sorted(self.params)}")
            U.check_shape(k, v, tuple(self.params[k].shape))
            U.check_finite(k, v)
            self.params[k] = U.to_warp(k, np.asarray(v, dtype=U.NP_TYPES[self.dtype])
                                       if not isinstance(v, wp.array) else v, self.dtype, self.device)

    def params_numpy(self) -> dict[str, np.ndarray]:
        return {k: v.numpy().copy() for k, v in self.params.items()}

    # ------------------------------------------------------------------ evaluation
    def _points(self, points: U.ArrayLike, dirs: U.ArrayLike | None) -> tuple[wp.array, wp.array | None]:
        if len(points.shape) != 2 or points.shape[1] != 3:
            raise ValueError(f"points: expected shape (N, 3), got {tuple(points.shape)}")
        if U.float_dtype("points", points) != self.dtype:
            raise ValueError(f"points: expected dtype {U.NP_TYPES[self.dtype].__name__} (the field's)")
        U.check_finite("points", points)
        p = U.to_warp("points", points, self.dtype, self.device)
        if dirs is None:
            if self.needs_dirs:
                raise ValueError(f"dirs: the {self.name} field is view-dependent and needs directions (N, 3)")
            return p, None
        U.check_shape("dirs", dirs, (points.shape[0], 3))
        if U.float_dtype("dirs", dirs) != self.dtype:
            raise ValueError(f"dirs: expected dtype {U.NP_TYPES[self.dtype].__name__} (the field's)")
        U.check_finite("dirs", dirs)
        return p, U.to_warp("dirs", dirs, self.dtype, self.device)

    def _cotangents(self, n: int, grad_sigma: U.ArrayLike | None, grad_rgb: U.ArrayLike | None
                    ) -> tuple[wp.array, wp.array]:
        out = []
        for name, g, shape in (("grad_sigma", grad_sigma, (n,)), ("grad_rgb", grad_rgb, (n, 3))):
            if g is None:
                out.append(wp.zeros(shape, dtype=self.dtype, device=self.device))
                continue
            U.check_shape(name, g, shape)
            if U.float_dtype(name, g) != self.dtype:
                raise ValueError(f"{name}: expected dtype {U.NP_TYPES[self.dtype].__name__} (the field's)")
            U.check_finite(name, g)
            out.append(U.to_warp(name, g, self.dtype, self.device))
        return out[0], out[1]

    @abstractmethod
    def forward(self, points: U.ArrayLike, dirs: U.ArrayLike | None = None) -> FieldOutput:
        """sigma (N,) and rgb (N, 3) at the points."""

    def _zero_grads(self, workspace: Workspace | None) -> dict[str, wp.array]:
        """Zeroed gradient arrays shaped like the parameters: new ones, or views into `workspace`
        (a dense grid's gradients are tens of megabytes, whose fresh pages cost more than the
        scatter that fills them)."""
        if workspace is None:
            return {k: wp.zeros(v.shape, dtype=self.dtype, device=self.device) for k, v in self.params.items()}
        check_workspace(workspace, self.device)
        grads = {}
        for k, v in self.params.items():
            grads[k] = workspace.array(f"{self.name}.grad.{k}", tuple(v.shape), self.dtype)
            grads[k].zero_()
        return grads

    @abstractmethod
    def backward(self, points: U.ArrayLike, dirs: U.ArrayLike | None, out: FieldOutput,
                 grad_sigma: U.ArrayLike | None, grad_rgb: U.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        """Gradient of <grad_sigma, sigma> + <grad_rgb, rgb> for every parameter (same shapes).

        With a `workspace`, fields whose gradients are large (grid, spheres) return views into it,
        valid until its next use; the neural fields' gradients are small and always new arrays.
        """

    def density(self, points: U.ArrayLike) -> wp.array:
        """sigma at the points (for occupancy-grid updates)."""
        dirs = None
        if self.needs_dirs:
            d = np.zeros((points.shape[0], 3), dtype=U.NP_TYPES[self.dtype])
            d[:, 2] = 1.0
            dirs = d
        return self.forward(points, dirs).sigma
