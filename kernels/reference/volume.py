"""Plain NumPy references of the volume family's forward passes (kernels.volume), in float64.

Each function is written from the equations in the docstring of the kernel module it mirrors,
one ray or one point at a time where that reads more clearly; no Warp.

    composite          front-to-back compositing (kernels.volume.composite)
    ray_aabb           slab test (kernels.volume.sampling)
    midpoint_strata    S equal strata per ray, samples at their midpoints (kernels.volume.sampling)
    occupied           occupancy-grid lookup (kernels.volume.occupancy)
    spheres            soft spheres (kernels.volume.spheres)
    grid               trilinear voxel grid, RGB or spherical harmonics (kernels.volume.grid)
    total_variation    the grid's regulariser (kernels.volume.grid.add_tv_grad is its gradient)
    hash_encoding      multiresolution hash encoding (kernels.volume.hashgrid)
    positional_encoding  frequency encoding (kernels.volume.encoding)
    mlp                ReLU MLP (kernels.volume.mlp)
    neural_head        the neural fields' output head (kernels.volume.neural)
    render_spheres     slab test + midpoint strata + soft spheres + compositing, end to end
    camera_rays        pinhole rays of pixels from world-to-camera and (fx, fy, cx, cy) (kernels.volume.rays)
    ndc_rays           NeRF's forward-facing NDC map of world rays (kernels.volume.rays.ndc_rays)
"""

from __future__ import annotations

import numpy as np

from kernels.reference.sh import sh_basis

PRIME_Y = 2654435761  # the spatial hash of instant-ngp (Mueller et al. 2022)
PRIME_Z = 805459861


def softplus(x: np.ndarray) -> np.ndarray:
    return np.logaddexp(0.0, x)


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


# --------------------------------------------------------------------------- compositing


def composite(sigma, rgb, delta, z, offsets, background, t_threshold):
    """(rgb (R, 3), depth (R,), opacity (R,), n_used (R,)) of packed samples, one ray at a time.

    Early termination: the loop stops before a sample once T < t_threshold.
    """
    n_rays = len(offsets) - 1
    bg = np.broadcast_to(np.asarray(background, dtype=np.float64).reshape(-1, 3), (n_rays, 3))
    out_rgb, depth, opacity, n_used = np.zeros((n_rays, 3)), np.zeros(n_rays), np.zeros(n_rays), np.zeros(n_rays, int)
    for r in range(n_rays):
        T, C, D = 1.0, np.zeros(3), 0.0
        for k in range(offsets[r], offsets[r + 1]):
            if T < t_threshold:
                break
            alpha = 1.0 - np.exp(-sigma[k] * delta[k])
            w = T * alpha
            C += w * rgb[k]
            D += w * z[k]
            T *= 1.0 - alpha
            n_used[r] += 1
        out_rgb[r], depth[r], opacity[r] = C + T * bg[r], D, 1.0 - T
    return out_rgb, depth, opacity, n_used


# --------------------------------------------------------------------------- sampling


def ray_aabb(o, d, box, near, far):
    """(t_enter, t_exit, hit) of every ray with the box, clipped to [near, far]; misses get 0, 0, 0."""
    t0s, t1s, hits = [], [], []
    for oi, di in zip(o, d):
        t0, t1, hit = near, far, True
        for a in range(3):
            if di[a] == 0.0:
                hit &= box[0, a] <= oi[a] <= box[1, a]
            else:
                ta, tb = (box[0, a] - oi[a]) / di[a], (box[1, a] - oi[a]) / di[a]
                t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        hit &= t1 > t0
        t0s.append(t0 if hit else 0.0)
        t1s.append(t1 if hit else 0.0)
        hits.append(int(hit))
    return np.array(t0s), np.array(t1s), np.array(hits)


def midpoint_strata(t0, t1, n_samples):
    """t (R, S) and delta (R,) of S equal strata of [t0, t1] per ray, samples at the midpoints."""
    h = (t1 - t0) / n_samples
    return t0[:, None] + (np.arange(n_samples) + 0.5) * h[:, None], h


def occupied(points, grid_occ, box, res):
    """The occupancy bit of the cell holding each point (points outside clamp to the nearest cell)."""
    u = (points - box[0]) / (box[1] - box[0]) * np.array(res)
    idx = np.clip(np.floor(u).astype(int), 0, np.array(res) - 1)
    return grid_occ.reshape(res[2], res[1], res[0])[idx[:, 2], idx[:, 1], idx[:, 0]]


# --------------------------------------------------------------------------- fields


def spheres(p, centers, radii, colors, sharpness):
    """(sigma (N,), rgb (N, 3)) of the soft spheres at points p (N, 3)."""
    sigma, rgb = np.zeros(len(p)), np.zeros((len(p), 3))
    for i, x in enumerate(p):
        num = np.zeros(3)
        for c, r, col, s in zip(centers, radii, colors, sharpness):
            d = s * np.exp(-s * max(0.0, np.linalg.norm(x - c) - r))
            sigma[i] += d
            num += d * col
        rgb[i] = num / sigma[i] if sigma[i] > 1e-6 else num
    return sigma, rgb


def trilinear(values, res, box, p):
    """Trilinear value at one point p of `values` (nz, ny, nx, C) on the vertex grid: the 8-corner sum."""
    u = (p - box[0]) / (box[1] - box[0]) * (np.array(res) - 1)
    i = np.minimum(np.floor(u).astype(int), np.array(res) - 2)
    f = u - i
    out = np.zeros(values.shape[-1])
    for bx in (0, 1):
        for by in (0, 1):
            for bz in (0, 1):
                w = ((f[0] if bx else 1 - f[0]) * (f[1] if by else 1 - f[1]) * (f[2] if bz else 1 - f[2]))
                out += w * values[i[2] + bz, i[1] + by, i[0] + bx]
    return out


def grid(density, color, resolution, bbox, sh_degree, density_bias, density_scale, activation, p, d):
    """(sigma, rgb) of the voxel grid at points p (N, 3) with directions d; points outside get zeros.

    density (V,), color (V, 3 n_coef) in the kernel's vertex order (x fastest).
    """
    nx, ny, nz = resolution
    n_coef = 1 if sh_degree is None else (sh_degree + 1) ** 2
    dens = np.asarray(density, dtype=np.float64).reshape(nz, ny, nx, 1)
    col = np.asarray(color, dtype=np.float64).reshape(nz, ny, nx, 3 * n_coef)
    Y = np.ones((len(p), 1)) if sh_degree is None else sh_basis(d, sh_degree)  # kernels/reference/sh.py
    act = softplus if activation == "softplus" else np.exp
    sigma, rgb = np.zeros(len(p)), np.zeros((len(p), 3))
    for i, x in enumerate(p):
        if np.any(x < bbox[0]) or np.any(x > bbox[1]):
            continue
        sigma[i] = density_scale * act(trilinear(dens, resolution, bbox, x)[0] + density_bias)
        k = trilinear(col, resolution, bbox, x).reshape(3, -1)
        rgb[i] = sigmoid(k @ Y[i])
    return sigma, rgb


def total_variation(values, resolution) -> float:
    """sum over vertices, axes and channels of (x[v + e_a] - x[v])^2, for values (V,) or (V, C)."""
    nx, ny, nz = resolution
    x = np.asarray(values, dtype=np.float64).reshape(nz, ny, nx, -1)
    return float(sum(np.sum(np.diff(x, axis=a) ** 2) for a in range(3)))


def hash_encoding(bbox, resolutions, table_size, n_features, p, table):
    """enc (N, L F) of the multiresolution hash encoding with a (L T, F) table."""
    T, F = table_size, n_features
    x = np.clip((p - bbox[0]) / (bbox[1] - bbox[0]), 0.0, 1.0)
    out = np.zeros((len(p), len(resolutions) * F))
    for l, res in enumerate(resolutions):
        res = int(res)
        dense = (res + 1) ** 3 <= T
        for n in range(len(p)):
            u = x[n] * res
            i = np.clip(np.floor(u).astype(int), 0, res - 1)
            f = u - i
            for b in np.ndindex(2, 2, 2):
                v = i + np.array(b)
                w = np.prod([f[a] if b[a] else 1 - f[a] for a in range(3)])
                if dense:
                    h = v[0] + (res + 1) * (v[1] + (res + 1) * v[2])
                else:
                    h = int((np.uint32(v[0]) ^ np.uint32((int(v[1]) * PRIME_Y) % 2**32)
                             ^ np.uint32((int(v[2]) * PRIME_Z) % 2**32)) % np.uint32(T))
                out[n, l * F:(l + 1) * F] += w * table[l * T + h]
    return out


def positional_encoding(p, bbox, n_freqs):
    """gamma(x) (N, 3 + 6K) of x = 2 (p - lo) / (hi - lo) - 1: x, then sin and cos of 2^k pi x per k."""
    x = 2.0 * (p - bbox[0]) / (bbox[1] - bbox[0]) - 1.0
    return np.concatenate([x] + [f(2.0**k * np.pi * x) for k in range(n_freqs) for f in (np.sin, np.cos)], axis=1)


def mlp(params, x, n_layers):
    """y of the ReLU MLP with weights params["W<l>"] (n_out, n_in) and biases params["b<l>"]."""
    a = x
    for l in range(n_layers):
        z = a @ params[f"W{l}"].T + params[f"b{l}"]
        a = np.maximum(z, 0.0) if l < n_layers - 1 else z
    return a


def neural_head(raw, p, bbox, density_bias, activation):
    """(sigma, rgb) from the MLP outputs raw (N, 4); points outside the box get zeros."""
    inside = np.all((p >= bbox[0]) & (p <= bbox[1]), axis=1)
    act = softplus if activation == "softplus" else np.exp
    return act(raw[:, 0] + density_bias) * inside, sigmoid(raw[:, 1:]) * inside[:, None]


# --------------------------------------------------------------------------- end to end


def render_spheres(o, d, box, n_samples, centers, radii, colors, sharpness, bg):
    """Slab test, S midpoint strata, the soft-sphere field and front-to-back compositing, per ray."""
    out = np.zeros((len(o), 3))
    t0s, t1s, hits = ray_aabb(o, d, box, 0.0, np.inf)
    for r in range(len(o)):
        T, C = 1.0, np.zeros(3)
        if hits[r]:
            t, h = midpoint_strata(t0s[r:r + 1], t1s[r:r + 1], n_samples)
            x = o[r] + t[0, :, None] * d[r]
            sigma, col = spheres(x, centers, radii, colors, sharpness)
            for k in range(n_samples):
                alpha = 1.0 - np.exp(-sigma[k] * h[0])
                C += T * alpha * col[k]
                T *= 1.0 - alpha
        out[r] = C + T * bg
    return out



def camera_rays(w2c, intrinsics, pixels):
    """Origins, unit world directions and z_scale = cos(angle to the optical axis) of pixel coordinates
    (u, v), for world-to-camera [[R, t], [0, 1]] and intrinsics (fx, fy, cx, cy), OpenCV axes."""
    w2c = np.asarray(w2c, dtype=np.float64)
    fx, fy, cx, cy = np.asarray(intrinsics, dtype=np.float64)
    R, t = w2c[:3, :3], w2c[:3, 3]
    centre = -R.T @ t
    origins, dirs, z_scale = [], [], []
    for u, v in np.asarray(pixels, dtype=np.float64):
        c = np.array([(u - cx) / fx, (v - cy) / fy, 1.0])  # the camera-frame ray through (u, v) at z = 1
        origins.append(centre)
        dirs.append(R.T @ (c / np.linalg.norm(c)))
        z_scale.append(1.0 / np.linalg.norm(c))  # z-depth per unit of distance along the ray
    return np.array(origins).reshape(-1, 3), np.array(dirs).reshape(-1, 3), np.array(z_scale)


def ndc_rays(o, d, near, focal, size, normalize=False):
    """NeRF's `ndc_rays` (run_nerf_helpers.py) in NumPy, float64: shift the origins to the plane
    z = -near, then map to normalised device coordinates with a_x = 2 fx / W, a_y = 2 fy / H."""
    o = np.asarray(o, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    f = np.asarray(focal, dtype=np.float64).reshape(-1)
    fx, fy = (f[0], f[0]) if f.size == 1 else (f[0], f[1])
    W, H = (float(x) for x in size)
    t = -(near + o[:, 2]) / d[:, 2]
    o = o + t[:, None] * d
    o0 = -1.0 / (W / (2.0 * fx)) * o[:, 0] / o[:, 2]
    o1 = -1.0 / (H / (2.0 * fy)) * o[:, 1] / o[:, 2]
    o2 = 1.0 + 2.0 * near / o[:, 2]
    d0 = -1.0 / (W / (2.0 * fx)) * (d[:, 0] / d[:, 2] - o[:, 0] / o[:, 2])
    d1 = -1.0 / (H / (2.0 * fy)) * (d[:, 1] / d[:, 2] - o[:, 1] / o[:, 2])
    d2 = -2.0 * near / o[:, 2]
    dn = np.stack([d0, d1, d2], -1)
    if normalize:
        dn = dn / np.linalg.norm(dn, axis=-1, keepdims=True)
    return np.stack([o0, o1, o2], -1), dn
