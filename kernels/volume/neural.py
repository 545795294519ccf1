"""Neural radiance fields: an encoding feeding the MLP of kernels.volume.mlp, and an output head.

    HashGridField: enc = hash encoding (instant-ngp, kernels.volume.hashgrid), MLP [L F, 64, 64, 4]
    PEMLPField:    enc = frequency encoding (NeRF, kernels.volume.encoding),  MLP [3 + 6K, 64, 64, 4]

The MLP's 4 outputs y are mapped by the output head to

    sigma = act(y_0 + density_bias)    (exp as in instant-ngp, or softplus)
    rgb   = sigmoid(y_1 .. y_3)

and a point outside the field's box gets sigma = 0, rgb = 0 and no gradient. The colour does not
depend on the view direction (the scenes fitted here are diffuse; this keeps the CPU cost down).

Backward: the head's adjoint dy_0 = g_sigma act'(y_0 + bias), dy_c = g_c s_c (1 - s_c) (a Warp
kernel, one thread per point), then the MLP backward (kernels.volume.mlp), then -- for the hash
grid -- the encoding's scatter into the table with dL/denc = dL/dx of the MLP. Points follow the
array contract of kernels.volume.field.

On the CPU the intermediate arrays of a call (the encoding, the MLP's activations and gradients, the
table's gradient) are blocks of the field's own HostPool (`field.pool`, at most POOL_BYTES kept): a
block returns there when its array is dropped and the next call of a similar size takes it back with
its pages mapped, instead of faulting in fresh memory (without it, 347k page faults, 1.4 GB, a 1M-point
forward + backward).
"""

from __future__ import annotations

import typing
from typing import Any, Sequence

import warp as wp

from kernels import _arrays as A
from kernels.volume import _act
from kernels.volume._act import density_act, density_act_grad, sigmoid, sigmoid_vjp
from kernels.volume._checks import check_bbox, check_dtype
from kernels.volume.encoding import PositionalEncoding
from kernels.volume.field import Field, FieldOutput
from kernels.volume.hashgrid import HashEncoding
from kernels.volume.mlp import MLP, init_mlp_params
from kernels.volume.workspace import Workspace, check_workspace

wp.set_module_options({"enable_backward": False})


@wp.func
def inside_box(points: wp.array2d(dtype=typing.Any), n: int, bbox: wp.array2d(dtype=typing.Any)) -> int:
    inside = int(1)
    for a in range(3):
        if points[n, a] < bbox[0, a] or points[n, a] > bbox[1, a]:
            inside = 0
    return inside


@wp.kernel
def _head_forward_kernel(
    raw: wp.array2d(dtype=typing.Any), points: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any),
    density_bias: typing.Any, act_kind: int,
    out_sigma: wp.array(dtype=typing.Any), out_rgb: wp.array2d(dtype=typing.Any), offset: int,
):
    n = wp.tid() + offset
    zero = raw.dtype(0.0)
    if inside_box(points, n, bbox) == 0:
        out_sigma[n] = zero
        for c in range(3):
            out_rgb[n, c] = zero
        return
    out_sigma[n] = density_act(raw[n, 0] + density_bias, act_kind)
    for c in range(3):
        out_rgb[n, c] = sigmoid(raw[n, 1 + c])


@wp.kernel
def _head_backward_kernel(
    raw: wp.array2d(dtype=typing.Any), points: wp.array2d(dtype=typing.Any), bbox: wp.array2d(dtype=typing.Any),
    density_bias: typing.Any, act_kind: int, rgb: wp.array2d(dtype=typing.Any),
    grad_sigma: wp.array(dtype=typing.Any), grad_rgb: wp.array2d(dtype=typing.Any),
    grad_raw: wp.array2d(dtype=typing.Any), offset: int,
):
    n = wp.tid() + offset
    zero = raw.dtype(0.0)
    if inside_box(points, n, bbox) == 0:
        for c in range(4):
            grad_raw[n, c] = zero
        return
    grad_raw[n, 0] = grad_sigma[n] * density_act_grad(raw[n, 0] + density_bias, act_kind)
    for c in range(3):
        grad_raw[n, 1 + c] = sigmoid_vjp(grad_rgb[n, c], rgb[n, c])


class NeuralField(Field):
    """Encoding -> MLP -> head (module docstring). Subclasses provide `_encode` and `_encode_backward`."""

    def __init__(self, bbox: Any, enc_params: dict[str, wp.array], n_enc: int, hidden: Sequence[int],
                 density_bias: float, density_activation: str, seed: int, dtype: Any, device: wp.Device,
                 backend: str | None) -> None:
        self.act_code = _act.density_code("density_activation", density_activation)
        self.density_bias = A.check_float("density_bias", density_bias)
        self.bbox = check_bbox("bbox", bbox)
        self.density_activation = density_activation
        self.sizes = [n_enc, *[A.check_int("hidden", h, minimum=1) for h in hidden], 4]
        params = dict(enc_params)
        params.update(init_mlp_params(self.sizes, seed + 1, dtype, device))
        super().__init__(params, dtype, device)
        self.backend = MLP(self.sizes, self.params, backend).backend
        # The blocks of the intermediate arrays (encoding, MLP activations and gradients) of earlier calls,
        # recycled by the next ones (kernels.volume.mlp.empty_array): no first-touch page faults.
        self.pool = A.HostPool(limit=self.POOL_BYTES)

    # Bytes of freed intermediate blocks the field keeps for its next calls (a 1M-point hash-grid
    # forward + backward uses ~1.4 GB of them); they are freed with the field.
    POOL_BYTES = 2 << 30

    def _mlp(self) -> MLP:
        return MLP(self.sizes, self.params, self.backend, pool=self.pool)

    def _encode(self, p: wp.array) -> wp.array:
        raise NotImplementedError

    def _encode_backward(self, p: wp.array, grad_enc: wp.array,
                         workspace: Workspace | None) -> dict[str, wp.array]:
        raise NotImplementedError

    def _head_static(self, a: A.Inputs) -> list:
        return [wp.array(self.bbox, dtype=self.dtype, device=self.device), a.s(self.density_bias), self.act_code]

    def forward(self, points: A.ArrayLike, dirs: A.ArrayLike | None = None) -> FieldOutput:
        a, p, _ = self._inputs(points, dirs)
        n = p.shape[0]
        raw, mlp_cache = self._mlp().forward(self._encode(p))
        sigma, rgb = a.empty(n), a.empty((n, 3))
        a.launch(_head_forward_kernel, n, [raw, p, *self._head_static(a), sigma, rgb])
        return self._result(a, sigma, rgb, {"raw": raw, "mlp": mlp_cache})

    def backward(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                 grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        a, p, _, _, rgb, gs, gr = self._backward_inputs(points, dirs, out, grad_sigma, grad_rgb)
        check_workspace(workspace, self.device)
        n = p.shape[0]
        raw = out.cache["raw"]
        grad_raw = a.empty((n, 4))
        a.launch(_head_backward_kernel, n, [raw, p, *self._head_static(a), rgb, gs, gr, grad_raw])
        needs_enc_grad = any(k not in self._mlp_names() for k in self.params)
        grads, grad_enc = self._mlp().backward(out.cache["mlp"], grad_raw, need_input_grad=needs_enc_grad,
                                               input_grad_feature_major=True)
        if needs_enc_grad:
            grads.update(self._encode_backward(p, grad_enc, workspace))
        return {k: grads[k] for k in self.params}

    def _mlp_names(self) -> set[str]:
        return {f"{w}{l}" for l in range(len(self.sizes) - 1) for w in ("W", "b")}


class HashGridField(NeuralField):
    """Hash encoding + MLP (instant-ngp). Parameters: table (L T, F), W0, b0, W1, b1, W2, b2."""

    name = "hashgrid"

    def __init__(self, bbox: Any, n_levels: int = 16, n_features: int = 2, log2_table_size: int = 19,
                 base_resolution: int = 16, max_resolution: int = 512, hidden: Sequence[int] = (64, 64),
                 density_bias: float = 0.0, density_activation: str = "exp", table_init_scale: float = 1e-4,
                 seed: int = 0, dtype: Any = wp.float32, device: str | wp.Device | None = None,
                 backend: str | None = None) -> None:
        device = A.get_device(device)
        check_dtype("dtype", dtype)
        self.encoding = HashEncoding(bbox, n_levels, n_features, log2_table_size, base_resolution, max_resolution)
        table = self.encoding.init_table(seed, dtype, device, table_init_scale)
        super().__init__(bbox, {"table": table}, self.encoding.n_outputs, hidden, density_bias, density_activation,
                         seed, dtype, device, backend)

    def _encode(self, p: wp.array) -> wp.array:
        return self.encoding.encode(p, self.params["table"], pool=self.pool)

    def _encode_backward(self, p: wp.array, grad_enc: wp.array,
                         workspace: Workspace | None) -> dict[str, wp.array]:
        # With a workspace the table's gradient (the largest one) is a view into it, as for the grid fields.
        out = None if workspace is None else workspace.array(f"{self.name}.grad.table", self.encoding.table_shape,
                                                             self.dtype)
        return {"table": self.encoding.backward(p, self.params["table"], grad_enc, out=out, pool=self.pool)}


class PEMLPField(NeuralField):
    """Frequency encoding + MLP (NeRF). Parameters: W0, b0, W1, b1, W2, b2."""

    name = "pe_mlp"

    def __init__(self, bbox: Any, n_freqs: int = 8, hidden: Sequence[int] = (64, 64), density_bias: float = 0.0,
                 density_activation: str = "exp", seed: int = 0, dtype: Any = wp.float32,
                 device: str | wp.Device | None = None, backend: str | None = None) -> None:
        device = A.get_device(device)
        check_dtype("dtype", dtype)
        self.encoding = PositionalEncoding(bbox, n_freqs)
        super().__init__(bbox, {}, self.encoding.n_outputs, hidden, density_bias, density_activation, seed, dtype,
                         device, backend)

    def _encode(self, p: wp.array) -> wp.array:
        return self.encoding.encode(p, pool=self.pool)

    def _encode_backward(self, p: wp.array, grad_enc: wp.array,
                         workspace: Workspace | None) -> dict[str, wp.array]:
        return {}


A.declare_float_overloads(_head_forward_kernel)
A.declare_float_overloads(_head_backward_kernel)
