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

Array kinds (kernels._arrays): the rendered rgb, depth and opacity are in the kind of the rays
(`origins` for render_rays, the samples' points for render_samples): NumPy, or wp.arrays on the
field's device; with a `workspace` they are wp.arrays (views into it) whatever the rays' kind.
The samples, field outputs and compositing state kept in a RenderResult are wp.arrays.
`render_backward` returns a dict name -> wp.array, the kind of the field's parameters.
"""

from __future__ import annotations

import inspect
import typing
from dataclasses import dataclass
from typing import Any

import warp as wp

from kernels import _arrays as A
from kernels.launch import launch_split
from kernels.volume.composite import (DEFAULT_T_THRESHOLD, CompositeResult, check_backpropagatable,
                                      check_keep_factor, composite_backward, composite_buffers, composite_forward,
                                      composite_grad_buffers)
from kernels.volume.field import Field, FieldOutput
from kernels.volume.sampling import Samples, pack_samples, sample_rays
from kernels.volume.workspace import Workspace, check_workspace


wp.set_module_options({"enable_backward": False})


@wp.kernel
def _add_scaled_kernel(g: wp.array(dtype=typing.Any), x: wp.array(dtype=typing.Any), scale: typing.Any,
                       offset: int):
    i = wp.tid() + offset
    g[i] = g[i] + scale * x[i]


@dataclass
class RenderResult:
    rgb: A.ArrayLike  # (R, 3)
    depth: A.ArrayLike  # (R,) expected z-depth (sum_k w_k z_k)
    opacity: A.ArrayLike  # (R,)
    samples: Samples  # wp.arrays
    field_out: FieldOutput  # wp.arrays
    composite: CompositeResult  # wp.arrays
    background: Any


def _on_device(field: Field, samples: Samples) -> tuple[A.Inputs, Samples]:
    """`samples` as wp.arrays on the field's device (NumPy samples are copied there), and the call's Inputs."""
    if not isinstance(samples, Samples):
        raise ValueError(f"samples: expected kernels.volume.Samples, got {type(samples).__name__}")
    a = A.Inputs(field.device, samples.points)
    if A.float_dtype("samples.points", samples.points) != field.dtype:
        raise ValueError(f"samples: expected {A.type_name(field.dtype)} on {field.device} (the field's)")
    n = samples.points.shape[0]
    floats = {k: a.floats(f"samples.{k}", getattr(samples, k), shape, finite=False)
              for k, shape in (("points", (n, 3)), ("dirs", (n, 3)), ("t", (n,)), ("delta", (n,)), ("z", (n,)))}
    ints = {k: a.ints(f"samples.{k}", getattr(samples, k), shape)
            for k, shape in (("ray_index", (n,)), ("ray_offsets", (None,)))}
    return a, Samples(**floats, **ints)


def _render(a: A.Inputs, field: Field, samples: Samples, background: Any, t_threshold: float,
            workspace: Workspace | None, keep_factor: bool) -> RenderResult:
    out = field.forward(samples.points, samples.dirs if field.needs_dirs else None)
    buffers = None if workspace is None else composite_buffers(workspace, samples.n_rays, samples.n_samples,
                                                                field.dtype, keep_factor)
    comp = composite_forward(out.sigma, out.rgb, samples.delta, samples.z, samples.ray_offsets, background,
                             t_threshold, field.device, out=buffers, keep_factor=keep_factor)
    kind = (lambda x: x) if workspace is not None else a.out
    return RenderResult(kind(comp.rgb), kind(comp.depth), kind(comp.opacity), samples, out, comp, background)


def render_samples(field: Field, samples: Samples, background: Any = (0.0, 0.0, 0.0),
                   t_threshold: float = DEFAULT_T_THRESHOLD, workspace: Workspace | None = None,
                   keep_factor: bool = True) -> RenderResult:
    """Evaluate `field` at the packed samples and composite them per ray.

    rgb, depth and opacity come back in the kind of `samples.points`; with a `workspace` they are
    views into it (wp.arrays), valid until its next use. keep_factor=False: a render that will not be
    backpropagated keeps no per-sample compositing state (composite_forward; the same rgb, depth and
    opacity bit for bit), and render_backward refuses it.
    """
    check_workspace(workspace, field.device)
    check_keep_factor(keep_factor)  # before the field's forward runs
    a, samples = _on_device(field, samples)
    return _render(a, field, samples, background, t_threshold, workspace, keep_factor)


# The keyword options of kernels.volume.sample_rays and their defaults, read from its signature.
_SAMPLING_DEFAULTS = {k: p.default for k, p in inspect.signature(sample_rays).parameters.items()
                      if p.kind is p.KEYWORD_ONLY and k != "device"}


def render_rays(
    field: Field,
    origins: A.ArrayLike,
    dirs: A.ArrayLike,
    bbox: Any,
    *,
    background: Any = (0.0, 0.0, 0.0),
    t_threshold: float = DEFAULT_T_THRESHOLD,
    workspace: Workspace | None = None,
    keep_factor: bool = True,
    **sampling: Any,
) -> RenderResult:
    """Render rays (R, 3) through `field` inside `bbox`.

    `sampling` holds the keyword options of kernels.volume.sample_rays (near, far, n_samples, step,
    z_scale, occupancy, jitter, seed). rgb, depth and opacity come back in the kind of `origins`;
    with a `workspace` they are views into it (wp.arrays), valid until its next use.
    keep_factor=False: for renders that will not be backpropagated (render_samples).
    """
    check_workspace(workspace, field.device)
    check_keep_factor(keep_factor)  # before the field's forward runs
    unknown = set(sampling) - set(_SAMPLING_DEFAULTS)
    if unknown:
        raise ValueError(f"sampling: unknown options {sorted(unknown)}; expected some of {sorted(_SAMPLING_DEFAULTS)} "
                         "(rays are rendered on the field's device)")
    if A.is_array(origins) and A.float_dtype("origins", origins) != field.dtype:
        raise ValueError(f"origins: expected dtype {A.type_name(field.dtype)} (the field's)")
    a = A.Inputs(field.device, origins, dirs)
    samples = pack_samples(a, origins, dirs, bbox, **{**_SAMPLING_DEFAULTS, **sampling})
    return _render(a, field, samples, background, t_threshold, workspace, keep_factor)


def optical_depth_sum(result: RenderResult) -> float:
    """sum_k sigma_k delta_k over every sample of the render (the sparsity penalty's value at lambda 1)."""
    return float((result.field_out.sigma.numpy().astype(float) * result.samples.delta.numpy()).sum())


def render_backward(field: Field, result: RenderResult, grad_rgb: A.ArrayLike | None = None,
                    grad_depth: A.ArrayLike | None = None, grad_opacity: A.ArrayLike | None = None,
                    sigma_l1: float = 0.0, workspace: Workspace | None = None) -> dict[str, wp.array]:
    """Gradient of <grad_rgb, C> + <grad_depth, D> + <grad_opacity, A> + sigma_l1 sum_k sigma_k delta_k
    for every field parameter: a dict name -> wp.array of the parameter's shape, on the field's device.

    The cotangents are NumPy arrays or wp.arrays on the field's device (missing ones count as
    zero). `workspace` (optional) holds the per-sample gradients between the compositing and field
    backward passes, and the parameter gradients of fields that use it (Field.backward), so
    repeated calls reuse their memory; the returned arrays are then valid until its next use.
    """
    sigma_l1 = A.check_float("sigma_l1", sigma_l1)
    check_workspace(workspace, field.device)
    if not isinstance(result, RenderResult):
        raise ValueError(f"result: expected the RenderResult of render_rays, got {type(result).__name__}")
    check_backpropagatable("result", result.composite)
    s, out = result.samples, result.field_out
    buffers = None if workspace is None else composite_grad_buffers(workspace, s.n_samples, field.dtype)
    g_sigma, g_rgb = composite_backward(out.sigma, out.rgb, s.delta, s.z, s.ray_offsets, result.composite,
                                        grad_rgb, grad_depth, grad_opacity, result.background, field.device,
                                        out=buffers)
    if sigma_l1 != 0.0 and s.n_samples:
        launch_split(_add_scaled_kernel, s.n_samples, [g_sigma, s.delta, field.dtype(sigma_l1)], device=field.device)
    return field.backward(s.points, s.dirs if field.needs_dirs else None, out, g_sigma, g_rgb, workspace)


A.declare_float_overloads(_add_scaled_kernel)
