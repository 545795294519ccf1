"""The interface every radiance field implements (no kernels here).

A field maps points x (N, 3) and unit view directions d (N, 3) to a density sigma(x) >= 0 (N,)
and a colour c(x, d) in [0, 1]^3 (N, 3). Its learnable parameters are named wp.arrays in
`params`. `backward` returns, for cotangents (g_sigma, g_rgb), the gradient of
<g_sigma, sigma> + <g_rgb, c> with respect to every parameter (positions and directions are
constants: no gradient flows to them).

Array kinds (kernels._arrays): `forward` returns sigma and rgb in the kind of `points` (NumPy, or
wp.arrays on the field's device); `backward` returns a dict name -> wp.array, the kind of the
parameters it differentiates. Points must have the field's dtype and live on its device.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.volume._checks import check_dtype
from kernels.volume.workspace import Workspace, check_workspace


@dataclass
class FieldOutput:
    sigma: A.ArrayLike  # (N,)
    rgb: A.ArrayLike  # (N, 3)
    cache: dict[str, Any] = field(default_factory=dict)  # what backward needs from the forward (wp.arrays)


class Field(ABC):
    """Base class: dtype, device, named parameters, forward and backward (module docstring)."""

    name = "field"
    needs_dirs = False

    def __init__(self, params: dict[str, wp.array], dtype: Any, device: Any) -> None:
        self.params = params
        self.dtype = check_dtype("dtype", dtype)
        self.device = A.get_device(device)

    # ------------------------------------------------------------------ parameters
    def param_shapes(self) -> dict[str, tuple[int, ...]]:
        return {k: tuple(v.shape) for k, v in self.params.items()}

    def n_params(self) -> int:
        return int(sum(v.size for v in self.params.values()))

    def set_params(self, values: dict[str, Any]) -> None:
        """Replace parameters by arrays of the same shapes: NumPy (cast to the field's dtype) or
        wp.arrays of its dtype on its device (used as they are, not copied); unknown names raise."""
        for k, v in values.items():
            if k not in self.params:
                raise ValueError(f"params: unknown parameter {k!r}; expected one of {sorted(self.params)}")
            x = v if isinstance(v, wp.array) else np.asarray(v, dtype=A.NP_OF_WP[self.dtype])
            a = A.Inputs(self.device, x)
            a.scalar = self.dtype
            self.params[k] = a.floats(k, x, tuple(self.params[k].shape))

    def params_numpy(self) -> dict[str, np.ndarray]:
        return {k: v.numpy().copy() for k, v in self.params.items()}

    # ------------------------------------------------------------------ evaluation
    def _inputs(self, points: A.ArrayLike, dirs: A.ArrayLike | None
                ) -> tuple[A.Inputs, wp.array, wp.array | None]:
        """(the call's Inputs, points (N, 3), dirs (N, 3) or None) as wp.arrays on the field's device."""
        a = A.Inputs(self.device, points, dirs)
        for name, x in (("points", points), ("dirs", dirs)):
            if A.is_array(x) and A.float_dtype(name, x) != self.dtype:
                raise ValueError(f"{name}: expected dtype {A.type_name(self.dtype)} (the field's), "
                                 f"got {A.type_name(A.float_dtype(name, x))}")
        p = a.floats("points", points, (None, 3))
        if dirs is None:
            if self.needs_dirs:
                raise ValueError(f"dirs: the {self.name} field is view-dependent and needs directions (N, 3)")
            return a, p, None
        return a, p, a.floats("dirs", dirs, (p.shape[0], 3))

    def _backward_inputs(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                         grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None) -> tuple:
        """(Inputs, points, dirs or None, out.sigma, out.rgb, grad_sigma, grad_rgb) of a backward call,
        as wp.arrays on the field's device; a missing cotangent is zeros."""
        a, p, d = self._inputs(points, dirs)
        n = p.shape[0]
        if not isinstance(out, FieldOutput):
            raise ValueError(f"out: expected the FieldOutput of forward, got {type(out).__name__}")
        sigma = a.floats("out.sigma", out.sigma, (n,), finite=False)
        rgb = a.floats("out.rgb", out.rgb, (n, 3), finite=False)
        gs, gr = a.floats_or_zeros("grad_sigma", grad_sigma, (n,)), a.floats_or_zeros("grad_rgb", grad_rgb, (n, 3))
        return a, p, d, sigma, rgb, gs, gr

    def _result(self, a: A.Inputs, sigma: wp.array, rgb: wp.array, cache: dict[str, Any] | None = None
                ) -> FieldOutput:
        return FieldOutput(a.out(sigma), a.out(rgb), cache or {})

    @abstractmethod
    def forward(self, points: A.ArrayLike, dirs: A.ArrayLike | None = None) -> FieldOutput:
        """sigma (N,) and rgb (N, 3) at the points, in the kind of `points`."""

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

    def _scatter_grads(self, kernel: Any, n: int, inputs: list, workspace: Workspace | None) -> dict[str, wp.array]:
        """Zeroed gradients (`_zero_grads`), then one launch of `kernel` over the n points with `inputs`
        followed by the gradient arrays in parameter order, which it scatters into with atomic adds
        (one launch: no Warp atomic is atomic between concurrent CPU launches, docs/warp.md)."""
        grads = self._zero_grads(workspace)
        if n:
            wp.launch(kernel, dim=n, inputs=inputs + list(grads.values()), device=self.device)
        return grads

    @abstractmethod
    def backward(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                 grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        """Gradient of <grad_sigma, sigma> + <grad_rgb, rgb> for every parameter: a dict name ->
        wp.array of the parameter's shape, on the field's device.

        With a `workspace`, fields whose gradients are large (grid, spheres, the hash grid's table)
        return views into it, valid until its next use; the MLP's gradients are small and always new
        arrays.
        """

    def density(self, points: A.ArrayLike) -> A.ArrayLike:
        """sigma at the points, in their kind (for occupancy-grid updates)."""
        dirs = None
        if self.needs_dirs:
            d = np.zeros((points.shape[0], 3), dtype=A.NP_OF_WP[self.dtype])
            d[:, 2] = 1.0
            dirs = d if isinstance(points, np.ndarray) else wp.array(d, dtype=self.dtype, device=self.device)
        return self.forward(points, dirs).sigma
