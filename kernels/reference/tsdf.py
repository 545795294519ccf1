"""NumPy references of kernels/tsdf: projective TSDF integration and masked marching cubes.

The same equations as kernels/tsdf/integrate.py and kernels/tsdf/marching_cubes.py (their docstrings
state them), written over whole arrays, in the inputs' dtype, with the same output order.
"""

from __future__ import annotations

import numpy as np

from kernels.tsdf.marching_cubes import EDGE_NODES
from kernels.tsdf.tables import CORNERS, TRIANGLES


def voxel_centres(origin, voxel_size, shape, dtype=np.float64) -> np.ndarray:
    """(nx, ny, nz, 3): origin + (idx + 1/2) h."""
    axes = [origin[a] + (np.arange(shape[a], dtype=dtype) + dtype(0.5)) * dtype(voxel_size) for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def integrate_reference(tsdf, weight, color, origin, voxel_size, truncation, depth, K, w2c, rgb=None):
    """One depth map fused into copies of (tsdf, weight, color) (nx, ny, nz[, 3]); color may be None.

    Returns (tsdf, weight, color, uv): the updated arrays and the projections (nx, ny, nz, 2) in pixels
    (NaN behind the camera), for tests that skip voxels on a pixel border."""
    dt = tsdf.dtype.type
    tsdf, weight = tsdf.copy(), weight.copy()
    color = None if color is None else color.copy()
    x = voxel_centres(np.asarray(origin, dtype=dt), voxel_size, tsdf.shape, dt)
    R, t = np.asarray(w2c, dtype=dt)[:3, :3], np.asarray(w2c, dtype=dt)[:3, 3]
    p = x @ R.T + t
    z = p[..., 2]
    fx, fy, cx, cy = (dt(v) for v in (K[0][0], K[1][1], K[0][2], K[1][2]))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = fx * p[..., 0] / z + cx
        v = fy * p[..., 1] / z + cy
    H, W = depth.shape
    ok = (z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    c = np.where(ok, u, 0).astype(np.int64)
    r = np.where(ok, v, 0).astype(np.int64)
    d = np.where(ok, depth[r, c], 0)
    ok &= d > 0
    dx = (c + dt(0.5) - cx) / fx
    dy = (r + dt(0.5) - cy) / fy
    sdf = (d - z) * np.sqrt(dt(1) + dx * dx + dy * dy)
    ok &= sdf > -dt(truncation)
    f = np.minimum(dt(1), sdf / dt(truncation))
    w0 = weight[ok]
    tsdf[ok] = (tsdf[ok] * w0 + f[ok]) / (w0 + 1)
    if color is not None:
        color[ok] = (color[ok] * w0[:, None] + rgb[r[ok], c[ok]]) / (w0 + 1)[:, None]
    weight[ok] = w0 + 1
    uv = np.where((z > 0)[..., None], np.stack([u, v], axis=-1), np.nan)
    return tsdf, weight, color, uv


def marching_cubes_reference(tsdf, weight, origin, voxel_size, iso=0.0, min_weight=1.0, color=None):
    """(vertices (V, 3), faces (F, 3) int32, colors or None) in kernels/tsdf/marching_cubes.py's order."""
    dt = tsdf.dtype.type
    nx, ny, nz = tsdf.shape
    inside = tsdf < dt(iso)
    seen = weight >= dt(min_weight)
    # Cells: valid when all 8 corners are observed; case bits from the corners inside.
    case = np.zeros((nx - 1, ny - 1, nz - 1), dtype=np.int64)
    valid = np.ones_like(case, dtype=bool)
    for q, (a, b, c) in enumerate(CORNERS):
        sl = (slice(a, a + nx - 1), slice(b, b + ny - 1), slice(c, c + nz - 1))
        valid &= seen[sl]
        case += inside[sl].astype(np.int64) << q
    case[~valid] = -1
    # Edges (node, axis): both ends observed, a sign change, and a valid cell around it.
    pad = np.zeros((nx, ny, nz), dtype=bool)
    pad[1:, 1:, 1:] = valid  # pad[i + 1, j + 1, k + 1] = cell (i, j, k) valid; index 0 = outside
    active = np.zeros((nx, ny, nz, 3), dtype=bool)
    ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    for ax in range(3):
        e = np.eye(3, dtype=int)[ax]
        m = (ii + e[0] < nx) & (jj + e[1] < ny) & (kk + e[2] < nz)
        i2, j2, k2 = np.minimum(ii + e[0], nx - 1), np.minimum(jj + e[1], ny - 1), np.minimum(kk + e[2], nz - 1)
        m &= seen & seen[i2, j2, k2] & (inside != inside[i2, j2, k2])
        around = np.zeros_like(m)
        others = [o for o in range(3) if o != ax]
        for s in range(4):
            off = np.zeros(3, dtype=int)
            off[others[0]], off[others[1]] = -(s % 2), -(s // 2)
            ci, cj, ck = ii + off[0], jj + off[1], kk + off[2]
            inb = (ci >= 0) & (cj >= 0) & (ck >= 0) & (ci < nx - 1) & (cj < ny - 1) & (ck < nz - 1)
            around |= inb & pad[np.clip(ci, -1, nx - 2) + 1, np.clip(cj, -1, ny - 2) + 1, np.clip(ck, -1, nz - 2) + 1]
        active[..., ax] = m & around
    flat = active.reshape(-1)
    vertex_of = np.full(flat.shape, -1, dtype=np.int64)
    vertex_of[flat] = np.arange(int(flat.sum()))
    eid = np.nonzero(flat)[0]
    node, ax = eid // 3, eid % 3
    i, j, k = node // (ny * nz), (node // nz) % ny, node % nz
    step = np.array([ny * nz, nz, 1])[ax]
    tf = tsdf.reshape(-1)
    t = (dt(iso) - tf[node]) / (tf[node + step] - tf[node])
    idx = np.stack([i, j, k], axis=1).astype(dt) + dt(0.5)
    idx[np.arange(len(ax)), ax] += t
    vertices = np.asarray(origin, dtype=dt) + idx * dt(voxel_size)
    colors = None
    if color is not None:
        cf = color.reshape(-1, 3)
        colors = cf[node] + t[:, None] * (cf[node + step] - cf[node])
    faces = []
    for ci, cj, ck in zip(*np.nonzero(case >= 0)):
        tris = TRIANGLES[case[ci, cj, ck]]
        for s in range(0, len(tris), 3):
            vs = []
            for le in tris[s:s + 3]:
                a, b, c, axis = EDGE_NODES[le]
                vs.append(vertex_of[3 * (((ci + a) * ny + cj + b) * nz + ck + c) + axis])
            faces.append((vs[0], vs[2], vs[1]))
    return vertices, np.array(faces, dtype=np.int32).reshape(-1, 3), colors
