"""Scene contraction for unbounded scenes (mip-NeRF 360) and the spacing of its ray samples.

Contraction (Barron et al., "Mip-NeRF 360", CVPR 2022, eq. 10), with the L2 norm as in the paper
(nerfacc's and instant-ngp's variants use the L-inf norm; this module uses L2 throughout). A world
point p is first normalised by the scene's centre c and radius R (the part of the scene that gets
the field's full resolution), x = (p - c) / R, r = ||x||_2, then

    contract(x) = x                          r <= 1,
                  (2 - 1/r) x / r            r > 1,

which maps all of space into the ball of radius 2: the unit ball unchanged, and distance r beyond
it to 2 - 1/r (a point at infinity lands on the sphere of radius 2). A field on the box [-2, 2]^3
behind it (ContractedField) covers all of space.

Jacobian. With a(r) = 2/r - 1/r^2 (so contract(x) = a(r) x beyond the ball) and
a'(r) = 2/r^3 - 2/r^2, dy/dx = a I + (a' / r) x x^T; the vector-Jacobian product of a cotangent g
of y is

    dL/dx = a g + (a' / r) (x . g) x,     dL/dp = dL/dx / R      (r > 1),
    dL/dp = g / R                                                 (r <= 1).

At r = 1, a = 1 and a' = 0: the map and its Jacobian are continuous (one-sided maths only in the
second derivative). The gradient with respect to c is -dL/dp; none is returned (the centre and
radius are constants of a fit).

Spacing (mip-NeRF 360's s-space, section 2). Samples along a ray are placed uniformly in a
normalised coordinate s in [0, 1] and mapped to the ray distance t by
t = g^{-1}(s g(t_far) + (1 - s) g(t_near)). mip-NeRF 360 takes g(t) = 1/t (uniform in disparity);
this module uses the piecewise form of nerfstudio's UniformLinDispPiecewiseSampler, linear up to a
distance tau and in disparity beyond:

    g(t) = t / tau                  t <= tau,
           2 - tau / t              t > tau,          g(inf) = 2,
    g^{-1}(u) = tau u               u <= 1,
                tau / (2 - u)       1 < u <= 2,       g^{-1}(2) = inf,

the 1D form of the contraction, so samples uniform in s are about uniform in the contracted
space. t_far may be infinite (the last edge is then at infinity); t_near >= 0. The map has no
gradient here (sample positions are constants of the render). One thread per element; generic
over float32 and float64. kernels/reference/volume_unbounded.py holds the NumPy forwards.
"""

from __future__ import annotations

import math
import typing
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.volume._checks import check_bbox
from kernels.volume.field import Field, FieldOutput
from kernels.volume.workspace import Workspace

wp.set_module_options({"enable_backward": False})


@wp.func
def _scale(r: typing.Any):
    """(a(r), a'(r) / r) of the module docstring, for r > 1."""
    one = type(r)(1.0)
    two = type(r)(2.0)
    inv = one / r
    return (two - inv) * inv, (two * inv - two) * inv * inv * inv


@wp.kernel
def _contract_kernel(points: wp.array2d(dtype=typing.Any), center: wp.array(dtype=typing.Any),
                     inv_radius: typing.Any, out: wp.array2d(dtype=typing.Any), offset: int):
    n = wp.tid() + offset
    x0 = (points[n, 0] - center[0]) * inv_radius
    x1 = (points[n, 1] - center[1]) * inv_radius
    x2 = (points[n, 2] - center[2]) * inv_radius
    r = wp.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    s = type(r)(1.0)
    if r > type(r)(1.0):
        s, _d = _scale(r)
    out[n, 0] = s * x0
    out[n, 1] = s * x1
    out[n, 2] = s * x2


@wp.kernel
def _contract_vjp_kernel(points: wp.array2d(dtype=typing.Any), center: wp.array(dtype=typing.Any),
                         inv_radius: typing.Any, grad_out: wp.array2d(dtype=typing.Any),
                         grad_points: wp.array2d(dtype=typing.Any), offset: int):
    n = wp.tid() + offset
    x0 = (points[n, 0] - center[0]) * inv_radius
    x1 = (points[n, 1] - center[1]) * inv_radius
    x2 = (points[n, 2] - center[2]) * inv_radius
    g0 = grad_out[n, 0]
    g1 = grad_out[n, 1]
    g2 = grad_out[n, 2]
    r = wp.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    if r > type(r)(1.0):
        a, b = _scale(r)
        xg = b * (x0 * g0 + x1 * g1 + x2 * g2)
        g0 = a * g0 + xg * x0
        g1 = a * g1 + xg * x1
        g2 = a * g2 + xg * x2
    grad_points[n, 0] = g0 * inv_radius
    grad_points[n, 1] = g1 * inv_radius
    grad_points[n, 2] = g2 * inv_radius


@wp.kernel
def _spacing_kernel(s: wp.array2d(dtype=typing.Any), u_near: typing.Any, u_far: typing.Any, tau: typing.Any,
                    out: wp.array2d(dtype=typing.Any), offset: int):
    # One thread per ray (row): t = g^{-1}(s u_far + (1 - s) u_near) of every edge.
    r = wp.tid() + offset
    one = type(tau)(1.0)
    two = type(tau)(2.0)
    for k in range(s.shape[1]):
        u = s[r, k] * u_far + (one - s[r, k]) * u_near
        if u <= one:
            out[r, k] = tau * u
        else:
            out[r, k] = tau / wp.max(two - u, type(tau)(0.0))  # u = 2 (t_far = inf): inf


A.declare_float_overloads(_contract_kernel)
A.declare_float_overloads(_contract_vjp_kernel)
A.declare_float_overloads(_spacing_kernel)


def _check_frame(center: Any, radius: Any) -> tuple[np.ndarray, float]:
    c = np.asarray(center, dtype=np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise ValueError(f"center: expected 3 finite numbers, got {center!r}")
    return c, A.check_float("radius", radius, positive=True)


def _contract_inputs(points: Any, center: Any, radius: Any, device: Any) -> tuple[A.Inputs, wp.array, list]:
    a = A.Inputs(device, points)
    p = a.floats("points", points, (None, 3))
    c, rad = _check_frame(center, radius)
    return a, p, [wp.array(c, dtype=a.scalar, device=a.device), a.s(1.0 / rad)]


def contract(points: Any, center: Any = (0.0, 0.0, 0.0), radius: float = 1.0, *, device: Any = None) -> Any:
    """contract((p - center) / radius) (N, 3) of points p (N, 3), L2 norm (module docstring); in the
    points' kind."""
    a, p, frame = _contract_inputs(points, center, radius, device)
    out = a.empty((p.shape[0], 3))
    a.launch(_contract_kernel, p.shape[0], [p, *frame, out])
    return a.out(out)


def contract_backward(points: Any, grad_out: Any, center: Any = (0.0, 0.0, 0.0), radius: float = 1.0, *,
                      device: Any = None) -> Any:
    """dL/dp (N, 3) from dL/dy (N, 3) of y = `contract(points, center, radius)` (the Jacobian's VJP)."""
    a, p, frame = _contract_inputs(points, center, radius, device)
    g = a.floats("grad_out", grad_out, (p.shape[0], 3))
    out = a.empty((p.shape[0], 3))
    a.launch(_contract_vjp_kernel, p.shape[0], [p, *frame, g, out])
    return a.out(out)


def spacing(t: float, tau: float) -> float:
    """g(t) of the module docstring (a Python float; g(inf) = 2)."""
    return t / tau if t <= tau else 2.0 - tau / t


def s_to_t(s: Any, near: float, far: float, tau: float = 1.0, *, device: Any = None) -> Any:
    """Ray distances t (R, K) of normalised positions s (R, K) in [0, 1]: t = g^{-1}(s g(far) + (1 - s)
    g(near)) (module docstring); far may be inf. In the kind of `s`."""
    a = A.Inputs(device, s)
    sa = a.floats("s", s, ndim=2)
    near = A.check_float("near", near, nonnegative=True)
    tau = A.check_float("tau", tau, positive=True)
    if not (isinstance(far, (int, float)) and (math.isinf(far) or math.isfinite(far)) and far > near):
        raise ValueError(f"far: expected a distance > near ({near}) or inf, got {far!r}")
    if A.values_checked():
        h = A.host_view(sa)
        if h is not None and h.size and (h.min() < 0.0 or h.max() > 1.0):
            raise ValueError(f"s: expected values in [0, 1], got [{h.min()}, {h.max()}]")
    out = a.empty(tuple(sa.shape))
    a.launch(_spacing_kernel, sa.shape[0], [sa, a.s(spacing(near, tau)), a.s(spacing(float(far), tau)), a.s(tau),
                                           out])
    return a.out(out)


class ContractedField(Field):
    """A field on the contracted space: sigma(p), c(p, d) = inner(contract((p - c) / R), d).

    `inner` is any Field whose box is [-2, 2]^3 (the ball of radius 2 that the contraction fills), e.g.
    a HashGridField or GridField built with `CONTRACTED_BOX`. Parameters are the inner field's (the same
    dict); the backward is the inner field's at the contracted points (no gradient to the points,
    as for every Field). `contract_backward` is the chain rule for callers that need one.
    """

    def __init__(self, inner: Field, center: Any = (0.0, 0.0, 0.0), radius: float = 1.0) -> None:
        if not isinstance(inner, Field):
            raise ValueError(f"inner: expected a kernels.volume Field, got {type(inner).__name__}")
        box = getattr(inner, "bbox", None)
        if box is None or not np.allclose(check_bbox("inner.bbox", box), CONTRACTED_BOX):
            raise ValueError(f"inner: expected a field on the box {CONTRACTED_BOX.tolist()} (CONTRACTED_BOX), "
                             f"got {None if box is None else np.asarray(box).tolist()}")
        self.inner = inner
        self.center, self.radius = _check_frame(center, radius)
        self.name = f"contracted_{inner.name}"
        self.needs_dirs = inner.needs_dirs
        super().__init__(inner.params, inner.dtype, inner.device)

    def forward(self, points: A.ArrayLike, dirs: A.ArrayLike | None = None) -> FieldOutput:
        a, p, d = self._inputs(points, dirs)
        y = contract(p, self.center, self.radius)
        out = self.inner.forward(y, d)
        return FieldOutput(a.out(out.sigma), a.out(out.rgb), {**out.cache, "contracted": y})

    def backward(self, points: A.ArrayLike, dirs: A.ArrayLike | None, out: FieldOutput,
                 grad_sigma: A.ArrayLike | None, grad_rgb: A.ArrayLike | None,
                 workspace: Workspace | None = None) -> dict[str, wp.array]:
        if not isinstance(out, FieldOutput) or "contracted" not in out.cache:
            raise ValueError("out: expected the FieldOutput of this ContractedField's forward")
        y = out.cache["contracted"]
        a = A.Inputs(self.device, y)
        inner_out = FieldOutput(a.floats("out.sigma", out.sigma, (y.shape[0],), finite=False),
                                a.floats("out.rgb", out.rgb, (y.shape[0], 3), finite=False), out.cache)
        conv = (lambda name, g, shape: None if g is None else a.floats(name, g, shape))
        d = None if dirs is None else a.floats("dirs", dirs, (y.shape[0], 3))
        return self.inner.backward(y, d, inner_out, conv("grad_sigma", grad_sigma, (y.shape[0],)),
                                   conv("grad_rgb", grad_rgb, (y.shape[0], 3)), workspace)


CONTRACTED_BOX = np.array([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]])
