"""Dr.Jit oracles for splat geometry (kernels/splat/normals.py, kernels/splat/depth.py): normals from a depth
map, each splat's shortest-axis normal and the expected depth, with their VJPs.

Written from the equations of those modules' docstrings (gsplat's depth_to_normal, PGSR's shortest-axis
normal, gsplat's expected depth), with Dr.Jit's reverse-mode AD for the VJPs:

* Normals from depth: P(x, y) = z(x, y) ((x + 1/2 - cx) / fx, (y + 1/2 - cy) / fy, 1); on interior pixels
  c = (P(x, y+1) - P(x, y-1)) x (P(x+1, y) - P(x-1, y)), n = c / max(|c|, 1e-12); 0 on the border.
* Splat normal: k = argmin_j l_j (the first on ties), n = W R(q / |q|) e_k with R the usual rotation
  of the unit quaternion (w, x, y, z), flipped to face the camera: -n where n . (W mu + t) > 0. k and
  the flip are constants of the splat, so only q has a gradient.
* Expected depth: e = D / max(A, 1e-10), from the rasteriser's depth D and alpha A.
"""

from __future__ import annotations

import numpy as np

from research.oracles import backend, check_array

EPS = 1e-12
A_MIN = 1e-10


def depth_normals_oracle(depth: np.ndarray, intrinsics: tuple[float, float, float, float], grad: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(normals (H, W, 3), dL/ddepth (H, W)) for L = sum(grad * normals), in depth's dtype; intrinsics
    (fx, fy, cx, cy)."""
    check_array("depth", depth, (None, None))
    h, w = depth.shape
    check_array("grad", grad, (h, w, 3))
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    if not (fx > 0 and fy > 0):
        raise ValueError(f"intrinsics: expected fx, fy > 0, got {fx}, {fy}")
    be = backend(depth.dtype)
    dr = be.dr
    Z = be.leaf(depth)
    ys, xs = np.mgrid[1:h - 1, 1:w - 1]
    xs, ys = xs.ravel(), ys.ravel()  # the interior pixels

    def point(dx: int, dy: int) -> list:
        x, y = xs + dx, ys + dy
        z = dr.gather(be.Float, Z, be.index(y * w + x))
        return [z * be.const((x + 0.5 - cx) / fx), z * be.const((y + 0.5 - cy) / fy), z]

    down, up, right, left = point(0, 1), point(0, -1), point(1, 0), point(-1, 0)
    a = [down[i] - up[i] for i in range(3)]
    b = [right[i] - left[i] for i in range(3)]
    c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    norm = dr.maximum(dr.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), EPS)
    n = [ci / norm for ci in c]
    dr.eval(*n)
    inner = (slice(1, h - 1), slice(1, w - 1))
    dr.backward(be.dot(n, [np.ascontiguousarray(grad[inner][..., i]) for i in range(3)]))
    normals = np.zeros((h, w, 3), be.np_dtype)
    for i in range(3):
        normals[inner][..., i] = be.numpy(n[i], (h - 2, w - 2)) if h > 2 and w > 2 else 0.0
    return normals, be.grad(Z, depth.shape)


def splat_normals_oracle(means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray, viewmat: np.ndarray,
                         grad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(normals (N, 3) in the camera frame, dL/dquats (N, 4)) for L = sum(grad * normals), in means' dtype."""
    check_array("means", means, (None, 3))
    n = means.shape[0]
    check_array("quats", quats, (n, 4))
    check_array("log_scales", log_scales, (n, 3))
    check_array("viewmat", np.asarray(viewmat, np.float64), (4, 4))
    check_array("grad", grad, (n, 3))
    be = backend(means.dtype)
    dr = be.dr
    Q = be.leaf(quats)
    q = [dr.gather(be.Float, Q, be.arange(n) * 4 + j) for j in range(4)]
    qn = dr.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w, x, y, z = (v / qn for v in q)
    R = [[1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
         [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
         [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)]]
    k = np.argmin(log_scales, axis=1)  # the first smallest, as drlab
    pick = [be.Bool(k == j) for j in range(3)]
    axis = [dr.select(pick[0], R[r][0], dr.select(pick[1], R[r][1], R[r][2])) for r in range(3)]
    view = np.asarray(viewmat, np.float64)
    cam_axis = [sum(float(view[r, j]) * axis[j] for j in range(3)) for r in range(3)]
    p = np.asarray(means, np.float64) @ view[:3, :3].T + view[:3, 3]
    facing = sum(dr.detach(cam_axis[r]) * be.const(np.ascontiguousarray(p[:, r])) for r in range(3))
    sign = dr.select(facing > 0.0, -1.0, 1.0)
    normals = [sign * v for v in cam_axis]
    dr.eval(*normals)
    dr.backward(be.dot(normals, [np.ascontiguousarray(grad[:, r]) for r in range(3)]))
    return np.stack([be.numpy(v, (n,)) for v in normals], axis=1), be.grad(Q, quats.shape)


def expected_depth_oracle(depth: np.ndarray, alpha: np.ndarray, grad: np.ndarray
                          ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """(e (H, W), (dL/ddepth, dL/dalpha)) for L = sum(grad * e), in depth's dtype."""
    check_array("depth", depth, (None, None))
    check_array("alpha", alpha, depth.shape)
    check_array("grad", grad, depth.shape)
    if np.any(alpha < 0):
        raise ValueError("alpha: expected values >= 0")
    be = backend(depth.dtype)
    dr = be.dr
    D, A = be.leaf(depth), be.leaf(alpha)
    e = D / dr.maximum(A, A_MIN)
    dr.eval(e)
    dr.backward(be.dot([e], [grad]))
    return be.numpy(e, depth.shape), (be.grad(D, depth.shape), be.grad(A, alpha.shape))
