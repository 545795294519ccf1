"""Rendering rays through a radiance field: sampling -> field -> compositing, and its adjoint.

    C(r) = composite_k( sigma(x_k), c(x_k, d) ; delta_k, z_k )      (kernels.volume.composite)

with the samples x_k of kernels.volume.sampling. The sample positions do not depend on the
field's parameters (the occupancy grid only decides which strata are sampled), so the chain
rule is

    dL/dtheta = sum_k [ dL/dsigma_k dsigma_k/dtheta + dL/dc_k . dc_k/dtheta ]

with dL/dsigma_k, dL/dc_k from the compositing backward and the field's own backward
(kernels.volume.field.Field.backward) for the rest. An optional sparsity penalty
lambda * sum_k sigma_k delta_k (the optical depth of every sample; an L1 prior on density in the
spirit of Plenoxels' sparsity loss) adds lambda * delta_k to dL/dsigma_k.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Any

import warp as wp

from kernels.launch import launch_split

from kernels.volume import _util as U
from kernels.volume.composite import (DEFAULT_T_THRESHOLD, CompositeResult, composite_backward, composite_buffers,
                                      composite_forward, composite_grad_buffers)
from kernels.volume.field import Field, FieldOutput
from kernels.volume.occupancy import OccupancyGrid
from kernels.volume.sampling import Samples, sample_rays
from kernels.volume.workspace import Workspace, check_workspace


wp.set_module_options({"enable_backward": False})


@wp.kernel
def _add_scaled_kernel(g: wp.array(dtype=typing.Any), x: wp.array(dtype=typing.Any), scale: typing.Any,
                       offset: int):
    i = wp.tid() + offset
    g[i] = g[i] + scale * x[i]


@dataclass
class RenderResult:
    rgb: wp.array  # (R, 3)
    depth: wp.array  # (R,) expected z-depth (sum_k w_k z_k)
    opacity: wp.array  # (R,)
    samples: Samples
    field_out: FieldOutput
    composite: CompositeResult
    background: Any


def render_samples(field: Field, samples: Samples, background: Any = (0.0, 0.0, 0.0),
                   t_threshold: float = DEFAULT_T_THRESHOLD, workspace: Workspace | None = None) -> RenderResult:
    """Evaluate `field` at the packed samples and composite them per ray.

    With a `workspace` the per-ray outputs are views into it, valid until its next use.
    """
    if samples.points.dtype != field.dtype or samples.points.device != field.device:
        raise ValueError(f"samples: expected {field.dtype} on {field.device} (the field's)")
    check_workspace(workspace, field.device)
    out = field.forward(samples.points, samples.dirs if field.needs_dirs else None)
    buffers = None if workspace is None else composite_buffers(workspace, samples.ray_offsets.shape[0] - 1,
                                                                samples.n_samples, field.dtype)
    comp = composite_forward(out.sigma, out.rgb, samples.delta, samples.z, samples.ray_offsets, background,
                             t_threshold, field.device, out=buffers)
    return RenderResult(comp.rgb, comp.depth, comp.opacity, samples, out, comp, background)


def render_rays(
    field: Field,
    origins: U.ArrayLike,
    dirs: U.ArrayLike,
    bbox: Any,
    *,
    near: float = 0.0,
    far: float = 1e10,
    n_samples: int | None = None,
    step: float | None = None,
    z_scale: U.ArrayLike | None = None,
    occupancy: OccupancyGrid | None = None,
    jitter: bool = False,
    seed: int = 0,
    background: Any = (0.0, 0.0, 0.0),
    t_threshold: float = DEFAULT_T_THRESHOLD,
    workspace: Workspace | None = None,
) -> RenderResult:
    """Render rays (R, 3) through `field` inside `bbox` (see sample_rays for the sampling options).

    `workspace` (optional) holds the compositing outputs across calls, as in render_samples.
    """
    check_workspace(workspace, field.device)
    if U.float_dtype("origins", origins) != field.dtype:
        raise ValueError(f"origins: expected dtype {U.NP_TYPES[field.dtype].__name__} (the field's)")
    samples = sample_rays(origins, dirs, bbox, near=near, far=far, n_samples=n_samples, step=step, z_scale=z_scale,
                          occupancy=occupancy, jitter=jitter, seed=seed, device=field.device)
    return render_samples(field, samples, background, t_threshold, workspace)


def optical_depth_sum(result: RenderResult) -> float:
    """sum_k sigma_k delta_k over every sample of the render (the sparsity penalty's value at lambda 1)."""
    return float((result.field_out.sigma.numpy().astype(float) * result.samples.delta.numpy()).sum())


def render_backward(field: Field, result: RenderResult, grad_rgb: U.ArrayLike | None = None,
                    grad_depth: U.ArrayLike | None = None, grad_opacity: U.ArrayLike | None = None,
                    sigma_l1: float = 0.0, workspace: Workspace | None = None) -> dict[str, wp.array]:
    """Gradient of <grad_rgb, C> + <grad_depth, D> + <grad_opacity, A> + sigma_l1 sum_k sigma_k delta_k
    for every field parameter.

    `workspace` (optional) holds the per-sample gradients between the compositing and field
    backward passes, and the parameter gradients of fields that use it (Field.backward), so
    repeated calls reuse their memory; the returned arrays are then valid until its next use.
    """
    if not math.isfinite(sigma_l1):
        raise ValueError(f"sigma_l1: expected a finite weight, got {sigma_l1}")
    check_workspace(workspace, field.device)
    s, out = result.samples, result.field_out
    buffers = None if workspace is None else composite_grad_buffers(workspace, s.n_samples, field.dtype)
    g_sigma, g_rgb = composite_backward(out.sigma, out.rgb, s.delta, s.z, s.ray_offsets, result.composite,
                                        grad_rgb, grad_depth, grad_opacity, result.background, field.device,
                                        out=buffers)
    if sigma_l1 != 0.0 and s.n_samples:
        launch_split(_add_scaled_kernel, s.n_samples, [g_sigma, s.delta, field.dtype(sigma_l1)], device=field.device)
    return field.backward(s.points, s.dirs if field.needs_dirs else None, out, g_sigma, g_rgb, workspace)
