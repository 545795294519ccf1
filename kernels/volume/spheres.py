"""Analytic soft spheres: the Video and 3D Vision textbook chapter's volume-rendering scene, with gradients.

Sphere k has centre c_k, radius r_k, colour col_k and sharpness s_k (the chapter's per-sphere
"sigma"). At a point p, with m_k = max(0, |p - c_k| - r_k),

    d_k(p)   = s_k exp(-s_k m_k)                    density of sphere k (s_k inside the sphere)
    sigma(p) = sum_k d_k
    rgb(p)   = sum_k d_k col_k / sigma   if sigma > 1e-6, else sum_k d_k col_k

(the chapter's `jnp.where(density > 1e-6, colour / density, colour)`). Colour does not depend
on the view direction. Backward, for cotangents (g_s, g):

    dL/dd_k   = g_s + g . (col_k - rgb) / sigma      (g_s + g . col_k below the threshold)
    dL/dcol_k = g d_k / sigma                         (g d_k below the threshold)
    dL/ds_k   = dL/dd_k exp(-s_k m_k) (1 - s_k m_k)
    dL/dr_k   = dL/dd_k s_k d_k,   dL/dc_k = dL/dd_k s_k d_k (p - c_k) / |p - c_k|   (outside, m_k > 0)

This module is the host side: `SphereField` (a kernels.volume.field.Field; points follow its array
contract), its argument checks and the launch schedules. The kernels are elsewhere:

    spheres_kernels  the plain Warp kernels: the field, its adjoint (one launch of atomic adds into
                     the few sphere parameters), and render_dense fused into one kernel per ray;
                     the CUDA path, and the CPU's with the fast paths off (kernels.fast_paths)
    spheres_passes   the CPU passes in Warp around NumPy's exp, four samples at a time ("quads")
    spheres_cpu      render_dense's CPU passes in C++, eight rays in vector lanes (float32, AVX2)

render_dense has one NumPy reference (kernels.reference.volume), one plain Warp kernel and four CPU
routes, all but the plain kernel bit for bit render_samples on dense_samples (tested). Each is kept
for a measured reason: 64x64 rays x 64 samples of the textbook scene, medians of 21 interleaved
calls, shared 2-core x86 host under load (the ratios held over repeated runs):

    route (who runs it)                               float32   float64
    plain kernel (CUDA; the CPU with fast paths off)  14.3 ms   46.9 ms   Warp's exp: not the
                                                                          general path's bits
    C++, one launch a chunk (AVX2, _npexp agrees)      1.7 ms      -      the CPU fast path
    C++, three launches, np.exp between (AVX2, where   3.0 ms      -      vs 6.9 ms for the Warp
      kernels._npexp's exp differs from np.exp)                            quads that would run
    Warp passes, four samples a quad (S % 4 == 0;      6.9 ms   33.3 ms   2x the one-at-a-time
      float64, CPUs without AVX2 such as ARM)                             passes in float32
    Warp passes, one sample at a time (S % 4 != 0)    13.2 ms   40.0 ms   any sample count

The switches _NATIVE_ON_CPU, _FUSED_EXP_ON_CPU, _QUADS_ON_CPU and _FUSED_ON_CPU below pick a route
for the tests, which hold the CPU routes to each other's bits and the plain kernel to them within
the rounding of its exponentials.

`SphereField.render_dense` is the forward of kernels.volume.render_samples(field,
dense_samples(o, d, t, delta)) fused, one thread per ray: x_k = o + t_k d, the field at x_k, and
the compositing of kernels.volume.composite (z_k = t_k, early termination as there), without the
packed sample, field-output and factor arrays of the general path (their allocation, first-touch
page faults and memory traffic are most of the textbook task's time on the general path).
Forward only.

On the CPU forward and render_dense run in passes around NumPy instead (spheres_passes), over
blocks of points (or rays) of at most _FALLOFF_BLOCK values: pass 1 writes the exponents -s_k m_k,
NumPy's vectorised exp turns them into the falloffs in place (split over the launch threads), and
the last pass does the rest of the field; render_dense has a pass between them for the
compositing factors exp(-(sigma_k delta_k)). So on the CPU render_dense forms every sample, field
value, factor and sum as dense_samples, SphereField.forward and composite_forward do, in the same
order with the same exponentials: its image, depth and opacity are those of render_samples on
dense_samples bit for bit (tested). Against the one-kernel versions the only change is the
exponentials' rounding: NumPy's float32 exp is within 2.4 ulp (Warp's 0.5), so on the textbook
scene float32 images differ from the fused kernel's by about 1e-6 (depth 4e-6), float64 by about
1e-15. The backward evaluates its own exponentials. On CUDA the one-kernel versions run.

C++ on the CPU (float32, CPUs with AVX2): render_dense's three passes run in
kernels.volume.spheres_cpu instead, eight rays in the lanes of a vector (sample j of eight rays at
once, each lane the operations above in the same order, the blends of eight rays side by side), and
where kernels._npexp's copy of NumPy's float32 exp gives np.exp's bits (checked once a process), in one
launch a chunk that applies it between the passes on each group's values. The same
outputs bit for bit (tested); float64, CUDA and CPUs without AVX2 keep the Warp passes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels import _npexp, fast_paths
from kernels.volume import spheres_cpu
from kernels.volume._checks import check_dtype
from kernels.volume.composite import DEFAULT_T_THRESHOLD
from kernels.volume.field import Field, FieldOutput
from kernels.launch import default_threads, guided_bounds, parallel_items
from kernels.volume.spheres_kernels import (_VEC3, _VEC4, _pack_spheres_kernel, _spheres_backward_kernel,
                                            _spheres_forward_kernel, center_offset, point_cotangents,
                                            sphere_density_cotangent)
from kernels.volume.spheres_passes import _FIELD_PASSES, _RENDER_DENSE, _RENDER_DENSE4
from kernels.volume.workspace import Workspace

# center_offset, point_cotangents and sphere_density_cotangent are imported from here by
# kernels.volume.field_points.
__all__ = ["COLOR_NORMALIZE_EPS", "TEXTBOOK_SPHERES", "SphereField", "center_offset", "point_cotangents",
           "sphere_density_cotangent"]

COLOR_NORMALIZE_EPS = 1e-6
# forward and render_dense on the CPU run the two-pass paths (NumPy's exp between Warp passes, and C++);
# True, or the CPU fast paths off (kernels.fast_paths), runs the one-kernel paths there too (CUDA's).
_FUSED_ON_CPU = False
# render_dense's CPU passes take four samples at a time when S % 4 == 0; False runs the one-at-a-time
# passes there too (for tests: the same results bit for bit).
_QUADS_ON_CPU = True
# Falloff values per block of the CPU passes (8 MB in float32): their memory stays bounded at any size.
_FALLOFF_BLOCK = 1 << 21
# The CPU passes' chunks (SphereField._two_passes, and render_dense's three-launch C++ route): no chunk of
# fewer items than hold this many falloff values (~0.1-0.2 ms of kernel a pass, against 20-40 us of Python
# a launch; a 64x64 x 64 render_dense on the Warp passes is cut into 6 chunks at 2 threads).
_CHUNK_VALUES = 1 << 17
# render_dense's C++ passes (float32 on CPUs with AVX2, kernels.volume.spheres_cpu); False runs the Warp
# passes there too (for tests: the same results bit for bit).
_NATIVE_ON_CPU = True
# Those passes run in one launch a chunk, calling NumPy's float32 exp loop themselves, where it was found
# (kernels._npexp.numpy_agrees); False runs three launches a chunk with np.exp between them (for tests).
_FUSED_EXP_ON_CPU = True
# ... with chunks of at least this many falloff values (~0.8 ms of one core; nothing is stored between the
# passes, so no cache size bounds them): the textbook image (786432 values) runs as 2/3 and 1/3 on 2
# threads, which on the loaded 2-core host was as fast as one chunk or faster, where 6 guided chunks
# of 2^17 or two halves lost 0.5-1.5 ms of median wall time waiting for the other thread.
_CHUNK_VALUES_ONE_LAUNCH = 1 << 19

# The chapter's scene: (centre, radius, colour, sharpness).
TEXTBOOK_SPHERES = (
    ((0.0, 0.0, 4.0), 0.8, (1.0, 0.2, 0.2), 5.0),
    ((1.5, 0.5, 5.0), 0.6, (0.2, 1.0, 0.2), 5.0),
    ((-1.0, -0.5, 3.5), 0.5, (0.2, 0.2, 1.0), 5.0),
)


class SphereField(Field):
    """Soft spheres (module docstring). Parameters: centers (K, 3), radii (K,), colors (K, 3), sharpness (K,)."""

    name = "spheres"

    def __init__(self, centers: Any, radii: Any, colors: Any, sharpness: Any,
                 dtype: Any = wp.float32, device: str | wp.Device | None = None) -> None:
        check_dtype("dtype", dtype)
        vals = {"centers": centers, "radii": radii, "colors": colors, "sharpness": sharpness}
        vals = {k: np.asarray(v.numpy() if isinstance(v, wp.array) else v, dtype=np.float64) for k, v in vals.items()}
        c = vals["centers"]
        if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] < 1:
            raise ValueError(f"centers: expected shape (K, 3) with K >= 1, got {c.shape}")
        k = c.shape[0]
        for name, shape in (("radii", (k,)), ("colors", (k, 3)), ("sharpness", (k,))):
            A.check_shape(name, vals[name], shape)
        for name, v in vals.items():
            A.check_finite(name, v)
        A.check_at_least("radii", vals["radii"], 0.0)
        A.check_at_least("sharpness", vals["sharpness"], 0.0)
        np_t = A.NP_OF_WP[dtype]
        device = A.get_device(device)
        super().__init__({n: wp.array(v.astype(np_t), dtype=dtype, device=device) for n, v in vals.items()},
                         dtype, device)

    @classmethod
    def textbook(cls, dtype: Any = wp.float32, device: str | wp.Device | None = None) -> "SphereField":
        c, r, col, s = zip(*TEXTBOOK_SPHERES)
        return cls(c, r, col, s, dtype=dtype, device=device)

    def _param_args(self) -> list[wp.array]:
        P = self.params
        return [P["centers"], P["radii"], P["colors"], P["sharpness"]]

    # (the parameters' bytes, geometry, appearance) of the last CPU packing (_packed)
    _packed_host: tuple[bytes, wp.array, wp.array] | None = None

    def _packed(self) -> tuple[wp.array, wp.array]:
        """(geometry, appearance): the parameters as K vec4s (c_k, r_k) and (col_k, s_k)."""
        v4 = _VEC4[self.dtype]
        if self.device.is_cpu:  # K rows packed on the host from zero-copy views
            P = {k: v.numpy() for k, v in self.params.items()}
            # Packed again only when a parameter's value changed (an optimiser updates them in place):
            # the K rows' bytes are compared, a few microseconds against two new arrays a call.
            key = b"".join(P[k].tobytes() for k in ("centers", "radii", "colors", "sharpness"))
            cached = self._packed_host
            if cached is not None and cached[0] == key:
                return cached[1], cached[2]
            geometry = wp.array(np.concatenate([P["centers"], P["radii"][:, None]], axis=1), dtype=v4)
            appearance = wp.array(np.concatenate([P["colors"], P["sharpness"][:, None]], axis=1), dtype=v4)
            self._packed_host = (key, geometry, appearance)
            return geometry, appearance
        k = self.params["radii"].shape[0]
        geometry = wp.empty(k, dtype=v4, device=self.device)
        appearance = wp.empty(k, dtype=v4, device=self.device)
        wp.launch(_pack_spheres_kernel, k, [*self._param_args(), geometry, appearance], device=self.device)
        return geometry, appearance

    def _two_passes(self, a: A.Inputs, n_items: int, samples_per_item: int, pass1: Any, pass1_inputs: list[Any],
                    pass2: Any, pass2_inputs: list[Any], geometry: wp.array, appearance: wp.array,
                    quads: bool = False, factor_pass: tuple[Any, list[Any]] | None = None) -> None:
        """The CPU passes (module docstring) over n_items points, rays or quads of samples_per_item
        samples, in blocks of at most _FALLOFF_BLOCK falloff values (bounded memory): `pass1` writes
        the exponents -s_k m_k, NumPy's exp turns them into falloffs in place, `pass2` consumes
        them. With `quads` the kernels see the values as vec4s.

        `factor_pass` (kernel, inputs), for render_dense: between the two, that kernel writes the
        compositing exponents -(sigma delta) of the samples, NumPy's exp turns them into the
        factors in place, and `pass2` takes them as its second argument.

        A block is cut into chunks of items (guided, kernels.launch.guided_bounds, none smaller than
        _CHUNK_VALUES falloff values; one chunk on one thread) and the launch threads take the
        chunks one at a time, each running every pass and exp over its chunk in turn: the items are
        independent, so the outputs are those of pass after pass over the whole block, with one
        hand-off between threads a block instead of one a pass and a chunk's values still in the
        core's cache for the next pass."""
        per_item = samples_per_item * geometry.shape[0]
        block = max(1, min(n_items, _FALLOFF_BLOCK // max(per_item, 1)))
        falloff = a.empty(block * per_item)
        f = falloff.numpy()
        values = _vec_view(falloff, _VEC4, (block * per_item // 4,)) if quads else falloff
        if factor_pass is not None:
            factor = a.empty(block * samples_per_item)
            e = factor.numpy()
            factors = [_vec_view(factor, _VEC4, (block * samples_per_item // 4,)) if quads else factor]
        else:
            factors = []
        min_chunk = max(1, _CHUNK_VALUES // max(per_item, 1))
        threads = default_threads()
        lanes = 4 if quads else 1
        dev = a.device
        for base in range(0, n_items, block):
            nb = min(block, n_items - base)
            bounds = guided_bounds(nb, threads, min_chunk) if threads > 1 and nb >= 2 * min_chunk else [(0, nb)]

            def chunk(j: int, base: int = base, bounds: list[tuple[int, int]] = bounds) -> None:
                # every pass over the chunk's items [lo, lo + n) of the block, one after the other on this
                # thread; the kernels see the chunk's falloffs (and factors) from their start
                lo, n = bounds[j]
                v0, v1 = lo * per_item, (lo + n) * per_item
                fv = _view(falloff.ptr + v0 * f.itemsize, values.dtype, ((v1 - v0) // lanes,), dev)
                wp.launch(pass1, dim=n, inputs=[*pass1_inputs, geometry, appearance, fv, base + lo, 0], device=dev)
                np.exp(f[v0:v1], out=f[v0:v1])
                ev = []
                if factor_pass is not None:
                    e0, e1 = lo * samples_per_item, (lo + n) * samples_per_item
                    ev = [_view(factor.ptr + e0 * e.itemsize, factors[0].dtype, ((e1 - e0) // lanes,), dev)]
                    wp.launch(factor_pass[0], dim=n, inputs=[fv, *factor_pass[1], *ev, base + lo, 0], device=dev)
                    np.exp(e[e0:e1], out=e[e0:e1])
                wp.launch(pass2, dim=n, inputs=[fv, *ev, *pass2_inputs, base + lo, 0], device=dev)

            parallel_items(chunk, len(bounds), threads=threads)

    def _native_passes(self, a: A.Inputs, o: wp.array, d: wp.array, tt: wp.array, dl: wp.array,
                       geometry: wp.array, appearance: wp.array, bg_v: wp.array, t_threshold: float,
                       rgb: wp.array, depth: wp.array, opacity: wp.array) -> None:
        """render_dense's CPU passes in C++ (float32, kernels.volume.spheres_cpu) over groups of eight
        rays, cut into guided chunks of groups, each chunk on one launch thread. Where kernels._npexp's
        exp has np.exp's bits (numpy_agrees), one launch a chunk (chunks of at least
        _CHUNK_VALUES_ONE_LAUNCH falloff values) runs pass 1, the exp, pass 2, the exp and pass 3
        group by group in the chunk's scratch; else, in blocks of at most _FALLOFF_BLOCK falloff
        values, three launches a chunk (chunks of at least _CHUNK_VALUES) with np.exp between them."""
        k1, k2, k3, fused = spheres_cpu.kernels()
        n_rays, n_s = tt.shape
        n_k = geometry.shape[0]
        dev = a.device
        lanes = spheres_cpu.LANES
        n_groups = -(-n_rays // lanes)
        per_group = lanes * n_s * n_k
        fused_exp = _FUSED_EXP_ON_CPU and _npexp.numpy_agrees()
        block = n_groups if fused_exp else max(1, min(n_groups, _FALLOFF_BLOCK // per_group))
        g4 = _view(geometry.ptr, wp.float32, (n_k, 4), dev)
        p4 = _view(appearance.ptr, wp.float32, (n_k, 4), dev)
        bg3 = _view(bg_v.ptr, wp.float32, (3,), dev)
        thr = wp.float32(t_threshold)
        min_chunk = max(1, _CHUNK_VALUES // per_group)
        threads = default_threads()
        if fused_exp:
            min_chunk = max(1, _CHUNK_VALUES_ONE_LAUNCH // per_group)
            # (split as soon as there is more than one chunk's work: the last chunk may be smaller)
            bounds = (guided_bounds(n_groups, threads, min_chunk) if threads > 1 and n_groups > min_chunk
                      else [(0, n_groups)])
            falloff = a.empty(len(bounds) * per_group)
            factor = a.empty(len(bounds) * lanes * n_s)

            def chunk(j: int) -> None:
                lo, n = bounds[j]
                fv = _view(falloff.ptr + j * per_group * 4, wp.float32, (per_group,), dev)
                ev = _view(factor.ptr + j * lanes * n_s * 4, wp.float32, (lanes * n_s,), dev)
                wp.launch(fused, dim=n, inputs=[o, d, tt, dl, g4, p4, bg3, thr, rgb, depth, opacity, fv, ev,
                                                n_rays, lo], device=dev)

            parallel_items(chunk, len(bounds), threads=threads)
            return
        falloff = a.empty(block * per_group)
        factor = a.empty(block * lanes * n_s)
        f, e = falloff.numpy(), factor.numpy()
        for base in range(0, n_groups, block):
            nb = min(block, n_groups - base)
            bounds = guided_bounds(nb, threads, min_chunk) if threads > 1 and nb >= 2 * min_chunk else [(0, nb)]

            def chunk(j: int, base: int = base, bounds: list[tuple[int, int]] = bounds) -> None:
                lo, n = bounds[j]
                g_lo = base + lo
                v0, v1 = lo * per_group, (lo + n) * per_group
                u0, u1 = lo * lanes * n_s, (lo + n) * lanes * n_s
                fv = _view(falloff.ptr + v0 * 4, wp.float32, (v1 - v0,), dev)
                ev = _view(factor.ptr + u0 * 4, wp.float32, (u1 - u0,), dev)
                wp.launch(k1, dim=n, inputs=[o, d, tt, g4, p4, fv, n_rays, g_lo], device=dev)
                np.exp(f[v0:v1], out=f[v0:v1])
                wp.launch(k2, dim=n, inputs=[fv, tt, dl, g4, p4, ev, n_rays, g_lo], device=dev)
                np.exp(e[u0:u1], out=e[u0:u1])
                wp.launch(k3, dim=n, inputs=[fv, ev, tt, g4, p4, bg3, thr, rgb, depth, opacity, n_rays, g_lo],
                          device=dev)

            parallel_items(chunk, len(bounds), threads=threads)

    def forward(self, points: A.ArrayLike, dirs: A.ArrayLike | None = None) -> FieldOutput:
        a, p, _ = self._inputs(points, dirs)
        n = p.shape[0]
        sigma, rgb = a.empty(n), a.empty((n, 3))
        if not self.device.is_cpu or _FUSED_ON_CPU or not fast_paths.enabled():
            a.launch(_spheres_forward_kernel, n, [p, *self._param_args(), sigma, rgb])
            return self._result(a, sigma, rgb)
        # CPU: the falloffs by NumPy's exp between two passes over quads of points (module docstring).
        if n:
            k1, k2 = _FIELD_PASSES[self.dtype]
            geometry, appearance = self._packed()
            sigma4, rgb4 = _vec_view(sigma, _VEC4, (n // 4,)), _vec_view(rgb, _VEC4, (3 * (n // 4),))
            self._two_passes(a, (n + 3) // 4, 4, k1, [_vec_view3(p), n], k2,
                             [appearance, n, sigma, _vec_view3(rgb), sigma4, rgb4], geometry, appearance, quads=True)
        return self._result(a, sigma, rgb)

    def render_dense(self, origins: A.ArrayLike, dirs: A.ArrayLike, t: A.ArrayLike, delta: A.ArrayLike,
                     background: Any = (0.0, 0.0, 0.0), t_threshold: float = DEFAULT_T_THRESHOLD
                     ) -> tuple[A.ArrayLike, A.ArrayLike, A.ArrayLike]:
        """(rgb (R, 3), depth (R,), opacity (R,)) of rays o + t d with explicit samples t (R, S) and
        interval lengths delta (R, S) >= 0 (module docstring: the fused forward of render_samples on
        dense_samples; depth is sum_k w_k t_k). Arrays in the field's dtype; outputs in the kind of
        `origins`. On the CPU, NumPy t and delta whose rows are one row broadcast
        (np.broadcast_to(row, (R, S)), the same samples on every ray) are read as that row, without
        a copy."""
        a = A.Inputs(self.device, origins, dirs, t, delta)
        keep: list[np.ndarray] = []  # NumPy inputs the kernels read in place (_floats_in_place)
        o = _floats_in_place(a, keep, "origins", origins, (None, 3))
        if a.scalar != self.dtype:
            raise ValueError(f"origins: expected dtype {A.type_name(self.dtype)} (the field's), "
                             f"got {A.type_name(a.scalar)}")
        n_rays = o.shape[0]
        d = _floats_in_place(a, keep, "dirs", dirs, (n_rays, 3))
        tt = _floats_in_place(a, keep, "t", t, (n_rays, None))
        dl = _floats_in_place(a, keep, "delta", delta, tuple(tt.shape), finite=False)
        A.check_at_least("delta", delta[0] if _broadcast_rows(delta, a) else dl, 0.0)
        t_threshold = A.check_float("t_threshold", t_threshold, nonnegative=True)
        if not t_threshold < 1.0:
            raise ValueError(f"t_threshold: expected a value in [0, 1), got {t_threshold}")
        bg = np.asarray(background.numpy() if isinstance(background, wp.array) else background, dtype=a.np_dtype)
        if bg.shape != (3,):
            raise ValueError(f"background: expected shape (3,), got {bg.shape}")
        A.check_finite("background", bg)
        rgb, depth, opacity = a.empty((n_rays, 3)), a.empty(n_rays), a.empty(n_rays)
        geometry, appearance = self._packed()
        bg_v = _background_vec3(bg, self.dtype, self.device)
        o3, d3, rgb3 = _vec_view3(o), _vec_view3(d), _vec_view3(rgb)
        fused, k1, kf, k2 = _RENDER_DENSE[self.dtype]
        if not self.device.is_cpu or _FUSED_ON_CPU or not fast_paths.enabled():
            a.launch(fused, n_rays, [o3, d3, tt, dl, geometry, appearance, bg_v, a.s(t_threshold), rgb3, depth,
                                     opacity], min_chunk=16)
            return a.out(rgb), a.out(depth), a.out(opacity)
        # CPU: the sphere falloffs and then the compositing factors by NumPy's exp between three
        # split launches (module docstring), four samples at a time where the samples of a ray come
        # in fours.
        n_s = tt.shape[1]
        if self.dtype == wp.float32 and _NATIVE_ON_CPU and n_rays and n_s and spheres_cpu.available():
            self._native_passes(a, o, d, tt, dl, geometry, appearance, bg_v, t_threshold, rgb, depth, opacity)
            return a.out(rgb), a.out(depth), a.out(opacity)
        if n_s % 4 == 0 and _QUADS_ON_CPU:  # (t and delta: rows contiguous, _floats_in_place)
            k1, kf, k2 = _RENDER_DENSE4[self.dtype]
            t4, dl4 = (_vec_view(x, _VEC4, (n_rays, n_s // 4)) for x in (tt, dl))
            self._two_passes(a, n_rays, n_s, k1, [o3, d3, t4], k2,
                             [t4, appearance, bg_v, a.s(t_threshold), rgb3, depth, opacity], geometry, appearance,
                             quads=True, factor_pass=(kf, [dl4, appearance]))
        else:
            self._two_passes(a, n_rays, n_s, k1, [o3, d3, tt], k2,
                             [tt, appearance, bg_v, a.s(t_threshold), rgb3, depth, opacity], geometry, appearance,
                             factor_pass=(kf, [dl, appearance]))
        return a.out(rgb), a.out(depth), a.out(opacity)

    def backward(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                 grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        a, p, _, sigma, rgb, gs, gr = self._backward_inputs(points, dirs, out, grad_sigma, grad_rgb)
        return self._scatter_grads(_spheres_backward_kernel, p.shape[0], [p, *self._param_args(), sigma, rgb, gs, gr],
                                   workspace)



def _floats_in_place(a: A.Inputs, keep: list[np.ndarray], name: str, x: Any, shape: tuple[Any, ...],
                     finite: bool = True) -> wp.array:
    """a.floats(name, x, shape, finite=finite) (the same checks and errors), except that a non-empty
    NumPy argument of a CPU call is not copied: the result is a non-owning wp.array over its
    contiguous data (the copies and their first-touch page faults were ~0.9 ms of a 64x64 x 64
    render_dense). `keep` holds the NumPy array; the caller keeps `keep` alive
    while the kernels run."""
    if not (isinstance(x, np.ndarray) and a.device.is_cpu and x.size):
        return a.floats(name, x, shape, finite=finite)
    dtype = a.float_dtype(name, x)
    A.check_shape(name, x, shape)
    if _broadcast_rows(x, a):
        # every row is row 0: checked once, and read through a zero row stride
        if finite:
            A.check_finite(name, x[0])
        keep.append(x)
        return _view(x.ctypes.data, dtype, x.shape, a.device, (0, x.strides[1]))
    if finite:
        A.check_finite(name, x)
    h = np.ascontiguousarray(x)
    keep.append(h)
    return _view(h.ctypes.data, dtype, h.shape, a.device)


def _broadcast_rows(x: Any, a: A.Inputs) -> bool:
    """Whether x is a 2-D NumPy array of a CPU call whose rows are all its first row (row stride 0,
    np.broadcast_to) with contiguous entries."""
    return (isinstance(x, np.ndarray) and a.device.is_cpu and x.ndim == 2 and x.size > 0 and x.strides[0] == 0
            and x.strides[1] == x.itemsize)


_BACKGROUNDS: dict[tuple, wp.array] = {}  # (bytes, dtype, device) -> the checked background as one vec3


def _background_vec3(bg: np.ndarray, dtype: Any, device: wp.Device) -> wp.array:
    """The checked background colour bg (3,) as a one-vec3 array, kept for the next call with the same colour."""
    key = (bg.tobytes(), dtype, device.alias)
    arr = _BACKGROUNDS.get(key)
    if arr is None:
        if len(_BACKGROUNDS) >= 64:
            _BACKGROUNDS.clear()
        arr = _BACKGROUNDS[key] = wp.array(bg[None], dtype=_VEC3[dtype], device=device)
    return arr


# Non-owning views kept by (address, dtype, shape, device). A view is nothing but those four, so a
# kept one is the same as a new one; a call's arrays come from the host pool (or NumPy's allocator)
# at the same addresses call after call, and a new wp.array costs ~10 us of Python (about a dozen a
# render_dense call). Bounded: cleared when full.
_VIEWS: dict[tuple, wp.array] = {}
_VIEWS_MAX = 256


def _view(ptr: int, dtype: Any, shape: tuple[int, ...], device: wp.Device,
          strides: tuple[int, ...] | None = None) -> wp.array:
    """wp.array(ptr=ptr, dtype=dtype, shape=shape, strides=strides, device=device), kept in _VIEWS."""
    key = (ptr, dtype, tuple(shape), strides, device.alias)
    v = _VIEWS.get(key)
    if v is None:
        if len(_VIEWS) >= _VIEWS_MAX:
            _VIEWS.clear()
        v = _VIEWS[key] = wp.array(ptr=ptr, dtype=dtype, shape=shape, strides=strides, device=device)
    return v


def _vec_view3(x: wp.array) -> wp.array:
    """A contiguous (N, 3) float array seen as N vec3s (zero-copy)."""
    return _view(x.ptr, _VEC3[x.dtype], (x.shape[0],), x.device)


def _vec_view(x: wp.array, vec: dict[Any, Any], shape: tuple[int, ...]) -> wp.array:
    """A contiguous float array seen as an array of `shape` of vec[x.dtype] vectors (zero-copy; x
    must stay alive while the view is used). A 2-D x whose rows are one row (row stride 0) gives
    rows that are that row's vectors."""
    v = vec[x.dtype]
    if x.ndim == 2 and x.strides[0] == 0:
        return _view(x.ptr, v, shape, x.device, (0, wp.types.type_size_in_bytes(v)))
    return _view(x.ptr, v, shape, x.device)
