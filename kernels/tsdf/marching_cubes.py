"""Marching cubes on a TSDF grid, skipping cells that contain an unobserved voxel (Lorensen and Cline,
"Marching cubes", SIGGRAPH 1987; Paul Bourke's tables, kernels/tsdf/tables.py).

Nodes are the voxel centres x_ijk = origin + (i + 1/2, j + 1/2, k + 1/2) h of kernels/tsdf/volume.py,
with value D_ijk and weight W_ijk; a node is *observed* when W >= min_weight (> 0). A cell is the cube
of 8 nodes (i + a, j + b, k + c), a, b, c in {0, 1}; corner q sits at tables.CORNERS[q]. The cell is
*valid* when all 8 corners are observed (Open3D's rule), and its case is

    case = sum_q 2^q [D_q < iso]                        (bit q set: corner q is inside)

An edge joins a node n to n + e_a (axis a = x, y, z) and carries a vertex when both ends are observed,
exactly one end is inside, and at least one of the (up to 4) cells around it is valid; the vertex is

    x = x_n + t h e_a,   t = (iso - D_n) / (D_{n+e_a} - D_n)     (linear interpolation, in [0, 1])

with the colour interpolated the same way when the volume keeps one. Each valid cell emits the
triangles TRIANGLES[case] of tables.py, each (e0, e1, e2) as the face (v(e0), v(e2), v(e1)), so that
faces wind counter-clockwise seen from outside (D >= iso) and their normals (x1 - x0) x (x2 - x0) point
out of the surface, towards increasing D (checked on a sphere in tests/kernels/test_tsdf_mc.py).

Order (deterministic, the same on every device and thread count): vertices by edge id
3 ((i ny + j) nz + k) + a, faces by cell id ((i (ny - 1) + j) (nz - 1) + k), then by the table's order.
Three passes, each writing only its own slots: count per edge and per cell, an exclusive prefix sum
(`wp.utils.array_scan`), then write.

Why not `warp.geometry.IsoSurfaceMarchingCubes` (warp 1.19): it runs on the CPU and uses the same
table and linear interpolation (its vertices equal ours on a fully observed sphere SDF, tested), but
takes float32 fields only and has no notion of unobserved nodes: a TSDF grid's never-seen voxels and
the far side of the truncation band would produce spurious surfaces there. It has no gradient, and
neither does this routine (the triangulation is discrete).
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A
from kernels.tsdf.tables import CORNERS, TRIANGLES

wp.set_module_options({"enable_backward": False})

# (node offset from the cell origin, axis) of each of the 12 cell edges (tables.EDGE_CORNERS).
EDGE_NODES = ((0, 0, 0, 0), (1, 0, 0, 1), (0, 1, 0, 0), (0, 0, 0, 1), (0, 0, 1, 0), (1, 0, 1, 1),
              (0, 1, 1, 0), (0, 0, 1, 1), (0, 0, 0, 2), (1, 0, 0, 2), (1, 1, 0, 2), (0, 1, 0, 2))


def _flat_tables() -> tuple[np.ndarray, np.ndarray]:
    start = np.zeros(257, dtype=np.int32)
    start[1:] = np.cumsum([len(t) for t in TRIANGLES])
    return start, np.array([e for t in TRIANGLES for e in t], dtype=np.int32)


TRI_START, TRI_EDGES = _flat_tables()


@dataclass
class Mesh:
    """A triangle mesh: vertices (V, 3), faces (F, 3) int32 (counter-clockwise seen from outside), colors
    (V, 3) or None."""

    vertices: Any
    faces: Any
    colors: Any = None


@wp.func
def observed(weight: wp.array(dtype=typing.Any), n: int, min_weight: typing.Any):
    return weight[n] >= min_weight


@wp.kernel
def _case_kernel(tsdf: wp.array(dtype=typing.Any), weight: wp.array(dtype=typing.Any), iso: typing.Any,
                 min_weight: typing.Any, ny: int, nz: int, cases: wp.array(dtype=wp.int32),
                 n_tri: wp.array(dtype=wp.int32), tri_start: wp.array(dtype=wp.int32), offset: int):
    cid = wp.tid() + offset
    ci = cid // ((ny - 1) * (nz - 1))
    cj = (cid // (nz - 1)) % (ny - 1)
    ck = cid % (nz - 1)
    code = int(0)
    valid = int(1)
    for q in range(8):
        n = ((ci + wp.static(CORNERS[q][0])) * ny + cj + wp.static(CORNERS[q][1])) * nz + ck + wp.static(CORNERS[q][2])
        if not observed(weight, n, min_weight):
            valid = 0
        if tsdf[n] < iso:
            code += wp.static(1 << q)
    if valid == 0:
        cases[cid] = -1
        n_tri[cid] = 0
    else:
        cases[cid] = code
        n_tri[cid] = (tri_start[code + 1] - tri_start[code]) // 3


@wp.func
def cell_valid(cases: wp.array(dtype=wp.int32), ci: int, cj: int, ck: int, nx: int, ny: int, nz: int):
    if ci < 0 or cj < 0 or ck < 0 or ci >= nx - 1 or cj >= ny - 1 or ck >= nz - 1:
        return False
    return cases[(ci * (ny - 1) + cj) * (nz - 1) + ck] >= 0


@wp.func
def edge_active(tsdf: wp.array(dtype=typing.Any), weight: wp.array(dtype=typing.Any), iso: typing.Any,
                min_weight: typing.Any, cases: wp.array(dtype=wp.int32), e: int, nx: int, ny: int, nz: int):
    n = e // 3
    ax = e % 3
    i = n // (ny * nz)
    j = (n // nz) % ny
    k = n % nz
    di = wp.where(ax == 0, 1, 0)
    dj = wp.where(ax == 1, 1, 0)
    dk = wp.where(ax == 2, 1, 0)
    if i + di >= nx or j + dj >= ny or k + dk >= nz:
        return False
    m = ((i + di) * ny + j + dj) * nz + k + dk
    if not (observed(weight, n, min_weight) and observed(weight, m, min_weight)):
        return False
    if (tsdf[n] < iso) == (tsdf[m] < iso):
        return False
    # The cells around the edge: offsets 0 or -1 along the two other axes.
    for s in range(4):
        oa = -(s % 2)
        ob = -(s // 2)
        ci = i + wp.where(ax == 0, 0, oa)
        cj = j + wp.where(ax == 1, 0, wp.where(ax == 0, oa, ob))
        ck = k + wp.where(ax == 2, 0, ob)
        if cell_valid(cases, ci, cj, ck, nx, ny, nz):
            return True
    return False


@wp.kernel
def _edge_count_kernel(tsdf: wp.array(dtype=typing.Any), weight: wp.array(dtype=typing.Any), iso: typing.Any,
                       min_weight: typing.Any, cases: wp.array(dtype=wp.int32), nx: int, ny: int, nz: int,
                       count: wp.array(dtype=wp.int32), offset: int):
    e = wp.tid() + offset
    count[e] = wp.where(edge_active(tsdf, weight, iso, min_weight, cases, e, nx, ny, nz), 1, 0)


@wp.kernel
def _edge_write_kernel(tsdf: wp.array(dtype=typing.Any), weight: wp.array(dtype=typing.Any),
                       color: wp.array2d(dtype=typing.Any), has_color: int, iso: typing.Any,
                       min_weight: typing.Any, cases: wp.array(dtype=wp.int32), origin: wp.array(dtype=typing.Any),
                       h: typing.Any, nx: int, ny: int, nz: int, first: wp.array(dtype=wp.int32),
                       vertex_of: wp.array(dtype=wp.int32), vertices: wp.array2d(dtype=typing.Any),
                       vcolors: wp.array2d(dtype=typing.Any), offset: int):
    e = wp.tid() + offset
    if not edge_active(tsdf, weight, iso, min_weight, cases, e, nx, ny, nz):
        vertex_of[e] = -1
        return
    n = e // 3
    ax = e % 3
    i = n // (ny * nz)
    j = (n // nz) % ny
    k = n % nz
    m = n + wp.where(ax == 0, ny * nz, wp.where(ax == 1, nz, 1))
    t = (iso - tsdf[n]) / (tsdf[m] - tsdf[n])
    out = first[e]
    vertex_of[e] = out
    half = h.dtype(0.5)
    vertices[out, 0] = origin[0] + (h.dtype(float(i)) + half + wp.where(ax == 0, t, h.dtype(0.0))) * h
    vertices[out, 1] = origin[1] + (h.dtype(float(j)) + half + wp.where(ax == 1, t, h.dtype(0.0))) * h
    vertices[out, 2] = origin[2] + (h.dtype(float(k)) + half + wp.where(ax == 2, t, h.dtype(0.0))) * h
    if has_color != 0:
        for ch in range(3):
            vcolors[out, ch] = color[n, ch] + t * (color[m, ch] - color[n, ch])


@wp.kernel
def _face_kernel(cases: wp.array(dtype=wp.int32), tri_start: wp.array(dtype=wp.int32),
                 tri_edges: wp.array(dtype=wp.int32), edge_nodes: wp.array2d(dtype=wp.int32),
                 vertex_of: wp.array(dtype=wp.int32), first: wp.array(dtype=wp.int32), ny: int, nz: int,
                 faces: wp.array2d(dtype=wp.int32), offset: int):
    cid = wp.tid() + offset
    code = cases[cid]
    if code < 0:
        return
    ci = cid // ((ny - 1) * (nz - 1))
    cj = (cid // (nz - 1)) % (ny - 1)
    ck = cid % (nz - 1)
    out = first[cid]
    for s in range(tri_start[code], tri_start[code + 1]):
        le = tri_edges[s]
        node = ((ci + edge_nodes[le, 0]) * ny + cj + edge_nodes[le, 1]) * nz + ck + edge_nodes[le, 2]
        t = (s - tri_start[code]) // 3
        corner = (s - tri_start[code]) % 3
        slot = wp.where(corner == 0, 0, 3 - corner)  # (e0, e1, e2) -> (v0, v2, v1)
        faces[out + t, slot] = vertex_of[3 * node + edge_nodes[le, 3]]


A.declare_float_overloads(_case_kernel)
A.declare_float_overloads(_edge_count_kernel)
A.declare_float_overloads(_edge_write_kernel)


def _exclusive_scan(a: A.Inputs, counts: wp.array) -> tuple[wp.array, int]:
    first = a.zeros(counts.shape[0], dtype=wp.int32)
    wp.utils.array_scan(counts, first, inclusive=False)
    n = counts.shape[0]
    total = int(first[n - 1:n].numpy()[0]) + int(counts[n - 1:n].numpy()[0])
    return first, total


def marching_cubes(tsdf: Any, weight: Any, origin: Any, voxel_size: float, *, iso: float = 0.0,
                   min_weight: float = 1.0, color: Any = None, device: Any = None) -> Mesh:
    """The iso-surface of a TSDF grid (module docstring) as a Mesh in the kind of `tsdf`.

    tsdf, weight (nx, ny, nz), each n >= 2; color (nx, ny, nz, 3) or None; origin (3,) the grid's lower
    corner (voxel centres at origin + (idx + 1/2) h); voxel_size h > 0; iso: the level; min_weight > 0:
    the weight from which a node counts as observed. NaN in tsdf is refused (ValueError).
    """
    a = A.Inputs(device, tsdf, weight, color)
    if not A.is_array(tsdf) or len(tsdf.shape) != 3 or min(tsdf.shape) < 2:
        shape = tuple(tsdf.shape) if A.is_array(tsdf) else type(tsdf).__name__
        raise ValueError(f"tsdf: expected an (nx, ny, nz) array with every n >= 2, got {shape}")
    nx, ny, nz = (int(s) for s in tsdf.shape)
    if nx * ny * nz * 3 > 2**31 - 1:
        raise ValueError(f"tsdf: {nx}x{ny}x{nz} nodes exceed the int32 edge indices")
    d = a.floats("tsdf", tsdf.reshape(-1) if isinstance(tsdf, np.ndarray) else tsdf.flatten())
    w = a.floats("weight", weight.reshape(-1) if isinstance(weight, np.ndarray) else weight.flatten())
    A.check_shape("weight", weight, (nx, ny, nz))
    if color is not None:
        A.check_shape("color", color, (nx, ny, nz, 3))
        col = a.floats("color", color.reshape(-1, 3) if isinstance(color, np.ndarray) else color.reshape((-1, 3)))
    origin = np.asarray(origin, dtype=np.float64)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise ValueError(f"origin: expected 3 finite numbers, got {origin.tolist()}")
    h = A.check_float("voxel_size", voxel_size, positive=True)
    iso = float(iso)
    if not np.isfinite(iso):
        raise ValueError(f"iso: expected a finite number, got {iso}")
    min_weight = A.check_float("min_weight", min_weight, positive=True)

    n_cells = (nx - 1) * (ny - 1) * (nz - 1)
    n_edges = 3 * nx * ny * nz
    tri_start = wp.array(TRI_START, dtype=wp.int32, device=a.device)
    tri_edges = wp.array(TRI_EDGES, dtype=wp.int32, device=a.device)
    edge_nodes = wp.array(np.array(EDGE_NODES, dtype=np.int32), dtype=wp.int32, device=a.device)
    cases = a.empty(n_cells, dtype=wp.int32)
    n_tri = a.empty(n_cells, dtype=wp.int32)
    a.launch(_case_kernel, n_cells, [d, w, a.s(iso), a.s(min_weight), ny, nz, cases, n_tri, tri_start])
    counts = a.empty(n_edges, dtype=wp.int32)
    a.launch(_edge_count_kernel, n_edges, [d, w, a.s(iso), a.s(min_weight), cases, nx, ny, nz, counts])
    first_v, n_vert = _exclusive_scan(a, counts)
    vertices = a.empty((n_vert, 3))
    vcolors = a.empty((n_vert, 3)) if color is not None else a.zeros((1, 3))
    vertex_of = a.empty(n_edges, dtype=wp.int32)
    wp_origin = wp.array(origin, dtype=a.scalar, device=a.device)
    a.launch(_edge_write_kernel, n_edges,
             [d, w, col if color is not None else a.zeros((1, 3)), int(color is not None), a.s(iso), a.s(min_weight),
              cases, wp_origin, a.s(h), nx, ny, nz, first_v, vertex_of, vertices, vcolors])
    first_f, n_face = _exclusive_scan(a, n_tri)
    faces = a.empty((n_face, 3), dtype=wp.int32)
    a.launch(_face_kernel, n_cells, [cases, tri_start, tri_edges, edge_nodes, vertex_of, first_f, ny, nz, faces])
    return Mesh(a.out(vertices), a.out(faces), a.out(vcolors) if color is not None else None)
