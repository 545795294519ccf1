"""A small fully connected ReLU network (NeRF's and instant-ngp's MLP), forward and backward.

Layers l = 0 .. L-1 with weights W_l (n_{l+1}, n_l) and biases b_l (n_{l+1},):

    a_0 = x (N, n_0),   z_l = a_l W_l^T + b_l,   a_{l+1} = relu(z_l) (l < L-1),   y = z_{L-1}

Backward, for the cotangent g = dL/dy (the standard back-propagation recursion):

    dz_{L-1} = g,   dW_l = dz_l^T a_l,   db_l = sum_n dz_l[n],   da_l = dz_l W_l,
    dz_{l-1} = da_l * [z_{l-1} > 0],     dL/dx = da_0.

The forward keeps only the activations a_l (relu(z_l) overwrites z_l): the mask [z_{l-1} > 0] is
[a_l > 0], the same set, so the pre-activations need no memory of their own.

Two backends compute the same thing:
  * "warp": every step is a Warp kernel. The three products are one kernel, C = A B (+ bias,
    ReLU), with one thread per output element ((n, j) for z, (n, k) for da, (j, k) for dW) and
    the transposes W^T, dz^T passed as strided views; j for db. Each is a gather with disjoint
    writes, so launch_split is safe. It runs on the CPU and on CUDA.
  * "numpy" (the default on the CPU, unless its fast paths are off: kernels.fast_paths): the three matrix products (z = a W^T, dW = dz^T a,
    da = dz W) are NumPy/BLAS products written straight into the Warp arrays' memory, with the
    per-sample parts (+ bias and ReLU after z, the ReLU mask after da) applied by NumPy to each
    block of 2048 rows right after its product, while it is in the cache; the forward takes each
    block through every layer before the next block, and so does the backward's chain of input
    gradients (then dW and db of each layer from the stored dz). A Warp CPU launch runs
    on one thread (docs/warp.md), so a (N x 64) x (64 x 64) product is tens of times faster in BLAS.
The tests check both backends against a NumPy reference and against each other. The MLP works on
wp.arrays (the neural fields' intermediate values) and returns wp.arrays.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import warp as wp

from kernels import _arrays as A, fast_paths
from kernels.launch import launch_split, parallel_items, parallel_ranges

wp.set_module_options({"enable_backward": False})

BACKENDS = ("numpy", "warp")


@wp.kernel
def _matmul_kernel(
    a: wp.array2d(dtype=typing.Any), b: wp.array2d(dtype=typing.Any), bias: wp.array(dtype=typing.Any),
    has_bias: int, relu: int, out: wp.array2d(dtype=typing.Any), act: wp.array2d(dtype=typing.Any), offset: int,
):
    # out = a b (+ bias) and act = relu(out); a and b may be strided (transposed) views.
    t = wp.tid() + offset
    n_cols = out.shape[1]
    i = t / n_cols
    j = t - i * n_cols
    s = out.dtype(0.0)
    if has_bias != 0:
        s = bias[j]
    for k in range(a.shape[1]):
        s += a[i, k] * b[k, j]
    out[i, j] = s
    if relu != 0:
        act[i, j] = wp.max(s, out.dtype(0.0))


def _matmul(a: wp.array, b: wp.array, out: wp.array, bias: wp.array | None = None, act: wp.array | None = None,
            min_chunk: int | None = None) -> None:
    """out = a b (+ bias); act = relu(out) when given. One thread per element of `out`."""
    if bias is None:  # a placeholder the kernel does not read
        bias = wp.zeros(1, dtype=out.dtype, device=out.device)
        has_bias = 0
    else:
        has_bias = 1
    inputs = [a, b, bias, has_bias, int(act is not None), out, act if act is not None else out]
    if out.size:
        kwargs = {} if min_chunk is None else {"min_chunk": min_chunk}
        launch_split(_matmul_kernel, out.shape[0] * out.shape[1], inputs, device=out.device, **kwargs)


@wp.kernel
def _relu_backward_kernel(
    da: wp.array2d(dtype=typing.Any), act: wp.array2d(dtype=typing.Any), offset: int,
):
    # act = relu(z) of the layer below: act > 0 exactly where z > 0.
    n = wp.tid() + offset
    for j in range(act.shape[1]):
        if not (act[n, j] > act.dtype(0.0)):
            da[n, j] = act.dtype(0.0)


@wp.kernel
def _grad_bias_kernel(
    dz: wp.array2d(dtype=typing.Any), db: wp.array(dtype=typing.Any), offset: int,
):
    j = wp.tid() + offset
    s = dz.dtype(0.0)
    for n in range(dz.shape[0]):
        s += dz[n, j]
    db[j] = s


# Rows per block of the dW = dz^T a reduction. One multithreaded OpenBLAS sgemm with a long inner
# dimension (N ~ 1e5) and a 64 x 64 result ran ~100x slower than blocks of this size on the project's
# machines (2.1 s vs 0.02 s for N = 88000), so the product is accumulated block by block.
_BLAS_BLOCK = 8192
# Below this many rows a product is one BLAS call; above, row blocks run on the launch threads.
_SPLIT_ROWS = 4096
# Rows per block: the product, the bias and the ReLU (or the ReLU mask) are applied to one block while
# it is in the cache (2048 x 64 float32 = 512 kB), instead of as separate passes over (N, 64) arrays.
_SUB_ROWS = 2048

_blas_controller = None


def empty_array(shape: tuple[int, ...], dtype: Any, device: wp.Device, pool: A.HostPool | None = None) -> wp.array:
    """wp.empty(shape), or, given a pool (kernels._arrays.HostPool) and a CPU device, a recycled block of it
    for an array of at least HostPool.MIN_BYTES (contents undefined either way).

    The neural fields' intermediate arrays (encodings, activations, their gradients: 1.4 GB a forward
    + backward at 1M points) come from the field's own pool: fresh, every page of them faulted on first
    touch, ~30% of the CPU time of a hash-grid forward + backward (4.21 -> 2.96 s of CPU on one thread at
    1M points with every intermediate array from a pool)."""
    shape = tuple(int(s) for s in shape)
    if pool is not None and device.is_cpu and wp.types.type_size_in_bytes(dtype) * int(np.prod(shape)) >= \
            A.HostPool.MIN_BYTES:
        return pool.empty(shape, dtype, device)
    return wp.empty(shape, dtype=dtype, device=device)


def _one_blas_thread():
    """A context in which BLAS runs on the calling thread alone (threadpoolctl).

    The products are split over the launch threads here (kernels.launch.parallel_ranges), each a
    single-threaded BLAS call: OpenBLAS's own threads, on a machine whose cores are also busy with
    other work, made the hash-grid field's backward 10x slower than its kernels (9.4 s of a 19.5 s forward +
    backward at 262144 points on a loaded 2-core host). The limit is process-wide while the block lasts.
    """
    global _blas_controller
    if _blas_controller is None:
        from threadpoolctl import ThreadpoolController

        _blas_controller = ThreadpoolController()
    return _blas_controller.limit(limits=1, user_api="blas")


def _row_blocks(fn, n: int) -> None:
    """fn(lo, hi) over the row blocks [j S, (j + 1) S) of S = _SUB_ROWS rows covering [0, n), the last
    one taking the remainder (S .. 2 S - 1 rows); once n >= _SPLIT_ROWS the launch threads pull the
    blocks one at a time (single-threaded BLAS).

    The blocks do not depend on the thread count, so neither do the results (each block is the same
    single-threaded BLAS call whatever the thread count). None is short: OpenBLAS may compute a
    product of a few hundred rows with another kernel than a longer one; which rounding a shape gets
    is BLAS's choice, and the tests bound the difference instead of assuming one
    (tests/kernels/test_volume_fields.py, research.checks.rounding)."""
    if n < _SPLIT_ROWS:
        fn(0, n)
        return
    n_blocks = n // _SUB_ROWS

    def block(j: int) -> None:
        fn(j * _SUB_ROWS, n if j == n_blocks - 1 else (j + 1) * _SUB_ROWS)

    with _one_blas_thread():
        parallel_items(block, n_blocks)


def _forward_blas(x: np.ndarray, weights: list[np.ndarray], biases: list[np.ndarray], outs: list[np.ndarray]
                  ) -> None:
    """outs[l] = z_l = a_l W_l^T + b_l for every layer, then relu(z_l) in place but for the last layer
    (a_0 = x, a_{l+1} = outs[l]), one row block at a time through all the layers: a block's activations
    are still in the cache when the next layer's product reads them (2048 x 64 float32 = 512 kB).

    The sum z + b and the maximum are the same single IEEE operations as the Warp kernels', so only
    the products' rounding is BLAS's, and each product is the same BLAS call on the same block as one
    layer at a time would make. `x` may be a strided view (a feature-major encoding, whose row blocks
    are column-major blocks that BLAS reads as transposed)."""
    wts = [w.T for w in weights]
    last = len(weights) - 1

    def block(lo: int, hi: int) -> None:
        a = x[lo:hi]
        for l, (wt, b, out) in enumerate(zip(wts, biases, outs)):
            zb = out[lo:hi]
            np.matmul(a, wt, out=zb)
            zb += b
            if l < last:
                np.maximum(zb, zb.dtype.type(0.0), out=zb)
            a = zb

    _row_blocks(block, x.shape[0])


def _input_grads_blas(dz: np.ndarray, weights: list[np.ndarray], acts: list[np.ndarray | None],
                      outs: list[np.ndarray]) -> None:
    """The input-gradient chain from the top layer down, one row block at a time through every layer:
    outs[0] = dz W[0], then outs[k] = outs[k-1] W[k], each multiplied by [acts[k] > 0] (the ReLU of the
    layer below: act = relu(z) > 0 exactly where z > 0) when acts[k] is given. A block of outs[k-1] is
    still in the cache when the next product reads it; each product is the same BLAS call on the same
    block as one layer at a time would make. An `out` may be the transpose of a C-contiguous (n_in, N)
    array: its row blocks are then written as (W^T dz_block^T).

    Multiplying by 0 gives the same value as setting 0 for every finite entry (a negative one
    becomes -0.0, equal to 0.0); an infinite or NaN entry of dz W under an inactive unit would
    become NaN instead of 0."""
    feature_major = [not out.flags.c_contiguous and out.T.flags.c_contiguous for out in outs]

    def block(lo: int, hi: int) -> None:
        src = dz[lo:hi]
        for w, act, out, fm in zip(weights, acts, outs, feature_major):
            ob = out[lo:hi]
            if fm:
                np.matmul(w.T, src.T, out=ob.T)
            else:
                np.matmul(src, w, out=ob)
            if act is not None:  # times the mask as 0/1: 15x faster than a masked copy (np.copyto where=)
                np.multiply(ob, act[lo:hi] > 0, out=ob)
            src = ob

    _row_blocks(block, dz.shape[0])


def _weight_grad_blas(dz: np.ndarray, a: np.ndarray, out: np.ndarray) -> None:
    """out = dz^T a as the sum over row blocks of _BLAS_BLOCK, added in block order (the products of
    the blocks run on the launch threads, so the sum is the same whatever the thread count)."""
    starts = list(range(0, dz.shape[0], _BLAS_BLOCK))
    parts = np.empty((len(starts), *out.shape), dtype=out.dtype)

    def blocks(lo: int, hi: int) -> None:
        for j in range(lo, hi):
            s = starts[j]
            np.matmul(dz[s:s + _BLAS_BLOCK].T, a[s:s + _BLAS_BLOCK], out=parts[j])

    with _one_blas_thread():
        parallel_ranges(blocks, len(starts), min_chunk=1)
    out[:] = 0.0
    for j in range(len(starts)):
        out += parts[j]


@dataclass
class MLPCache:
    """What the backward needs: the input a_l of every layer (a_{l+1} = relu(z_l) is also the ReLU's
    mask, a_{l+1} > 0 exactly where z_l > 0), the output, and the parameters they came from."""

    inputs: list[wp.array]  # a_l, the input of layer l
    output: wp.array  # y = z_{L-1}
    params: dict[str, wp.array]

    @property
    def pre(self) -> list[wp.array]:
        """The pre-activations z_l, recomputed from a_l (for checks; the forward keeps only a_l)."""
        pre = []
        for l in range(1, len(self.inputs)):
            a = self.inputs[l - 1].numpy()
            w, b = self.params[f"W{l - 1}"].numpy(), self.params[f"b{l - 1}"].numpy()
            pre.append(wp.array(a @ w.T + b, dtype=self.output.dtype, device="cpu"))
        return [*pre, self.output]


def init_mlp_params(sizes: Sequence[int], seed: int, dtype: Any, device: wp.Device) -> dict[str, wp.array]:
    """W_l, b_l ~ U(-1/sqrt(n_l), 1/sqrt(n_l)) (PyTorch's nn.Linear default), from `seed`."""
    rng = np.random.default_rng(seed)
    np_t = A.NP_OF_WP[dtype]
    params = {}
    for l, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        bound = 1.0 / np.sqrt(n_in)
        params[f"W{l}"] = wp.array(rng.uniform(-bound, bound, (n_out, n_in)).astype(np_t), dtype=dtype, device=device)
        params[f"b{l}"] = wp.array(rng.uniform(-bound, bound, n_out).astype(np_t), dtype=dtype, device=device)
    return params


class MLP:
    """ReLU MLP with layer sizes `sizes` = [n_in, hidden..., n_out] (module docstring)."""

    def __init__(self, sizes: Sequence[int], params: dict[str, wp.array], backend: str | None = None,
                 pool: A.HostPool | None = None) -> None:
        if len(sizes) < 2:
            raise ValueError(f"sizes: expected at least [n_in, n_out], got {list(sizes)}")
        self.sizes = [A.check_int("sizes", s, minimum=1) for s in sizes]
        self.params = params
        for l, (n_in, n_out) in enumerate(zip(self.sizes[:-1], self.sizes[1:])):
            for name, shape in ((f"W{l}", (n_out, n_in)), (f"b{l}", (n_out,))):
                if name not in params:
                    raise ValueError(f"params: missing {name!r}")
                A.check_shape(name, params[name], shape)
        self.dtype = params["W0"].dtype
        self.device = params["W0"].device
        if backend is None:
            backend = "numpy" if self.device.is_cpu and fast_paths.enabled() else "warp"
        if backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
        if backend == "numpy" and self.device.is_cuda:
            raise ValueError("backend: 'numpy' needs CPU arrays; use 'warp' on CUDA")
        self.backend = backend
        self.pool = pool  # where the activations and gradients come from on the CPU (empty_array)

    @property
    def n_layers(self) -> int:
        return len(self.sizes) - 1

    def _empty(self, shape: tuple[int, ...]) -> wp.array:
        return empty_array(shape, self.dtype, self.device, self.pool)

    def forward(self, x: wp.array) -> tuple[wp.array, MLPCache]:
        """y = MLP(x) for x (N, n_in) on the MLP's device and dtype; the cache feeds `backward`."""
        if not isinstance(x, wp.array):
            raise ValueError(f"x: expected a wp.array, got {type(x).__name__}")
        A.check_shape("x", x, (None, self.sizes[0]))
        if x.dtype != self.dtype or x.device != self.device:
            raise ValueError(f"x: expected a wp.array of {self.dtype} on {self.device}")
        n = x.shape[0]
        # relu(z_l) overwrites z_l: the backward needs only a_{l+1}
        outs = [self._empty((n, self.sizes[l + 1])) for l in range(self.n_layers)]
        inputs = [x, *outs[:-1]]
        if n and self.backend == "numpy":
            _forward_blas(x.numpy(), [self.params[f"W{l}"].numpy() for l in range(self.n_layers)],
                          [self.params[f"b{l}"].numpy() for l in range(self.n_layers)], [z.numpy() for z in outs])
        elif n:
            for l in range(self.n_layers):
                relu = l < self.n_layers - 1
                _matmul(inputs[l], self.params[f"W{l}"].transpose(), outs[l], self.params[f"b{l}"],
                        outs[l] if relu else None)
        a = outs[-1]
        return a, MLPCache(inputs, a, self.params)

    def backward(self, cache: MLPCache, grad_out: wp.array, need_input_grad: bool = False,
                 input_grad_feature_major: bool = False) -> tuple[dict[str, wp.array], wp.array | None]:
        """(gradients of every W_l, b_l; dL/dx or None) for the cotangent grad_out (N, n_out).

        With `input_grad_feature_major` (numpy backend), dL/dx (N, n_in) is the transposed view of a
        contiguous (n_in, N) array: each input feature's gradient is contiguous over the points (the
        hash encoding's per-level backward reads it so, kernels.volume.hashgrid)."""
        n = cache.inputs[0].shape[0]
        A.check_shape("grad_out", grad_out, (n, self.sizes[-1]))
        if not isinstance(grad_out, wp.array) or grad_out.dtype != self.dtype or grad_out.device != self.device:
            raise ValueError(f"grad_out: expected a wp.array of {A.type_name(self.dtype)} on {self.device}")
        grads: dict[str, wp.array] = {}
        if self.backend == "numpy":
            return self._backward_numpy(cache, grad_out, need_input_grad, input_grad_feature_major)
        dz = grad_out
        grad_x = None
        for l in reversed(range(self.n_layers)):
            W, a = self.params[f"W{l}"], cache.inputs[l]
            dW = self._empty(tuple(W.shape))
            db = self._empty((W.shape[0],))
            need_da = l > 0 or need_input_grad
            da = self._empty((n, W.shape[1])) if need_da else None
            _matmul(dz.transpose(), a, dW, min_chunk=64)
            launch_split(_grad_bias_kernel, W.shape[0], [dz, db], device=self.device, min_chunk=16)
            if need_da:
                _matmul(dz, W, da)
            grads[f"W{l}"], grads[f"b{l}"] = dW, db
            if l > 0:
                if n:
                    launch_split(_relu_backward_kernel, n, [da, a], device=self.device, min_chunk=256)
                dz = da
            else:
                grad_x = da
        return grads, grad_x

    def _backward_numpy(self, cache: MLPCache, grad_out: wp.array, need_input_grad: bool,
                        input_grad_feature_major: bool) -> tuple[dict[str, wp.array], wp.array | None]:
        """`backward` with BLAS: first the input gradients da_l (masked: dz_{l-1}) of every layer, block by
        block through the layers (_input_grads_blas), then each layer's dW_l and db_l from dz_l."""
        n = cache.inputs[0].shape[0]
        da: dict[int, wp.array] = {}  # da_l (l > 0: times the mask [a_l > 0], i.e. dz_{l-1}), layers top down
        for l in reversed(range(self.n_layers)):
            if l > 0 or need_input_grad:
                n_in = self.sizes[l]
                da[l] = (self._empty((n_in, n)).transpose() if l == 0 and input_grad_feature_major
                         else self._empty((n, n_in)))
        if n and da:
            _input_grads_blas(grad_out.numpy(), [self.params[f"W{l}"].numpy() for l in da],
                              [cache.inputs[l].numpy() if l > 0 else None for l in da], [d.numpy() for d in da.values()])
        grads: dict[str, wp.array] = {}
        for l in reversed(range(self.n_layers)):
            W = self.params[f"W{l}"]
            dz_np = (grad_out if l == self.n_layers - 1 else da[l + 1]).numpy()
            dW = self._empty(tuple(W.shape))
            db = self._empty((W.shape[0],))
            _weight_grad_blas(dz_np, cache.inputs[l].numpy(), dW.numpy())
            db.numpy()[:] = dz_np.sum(axis=0)
            grads[f"W{l}"], grads[f"b{l}"] = dW, db
        return grads, da.get(0)


for _kernel in (_matmul_kernel, _relu_backward_kernel, _grad_bias_kernel):
    A.declare_float_overloads(_kernel)
