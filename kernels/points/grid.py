"""A uniform hash grid over a point cloud, and the k nearest neighbours and ball query on it.

Grid. For a cloud P = {p_0 .. p_{N-1}} in R^3, a cell size h > 0 and the origin o = min_j p_j (per
axis), point p lies in the cell

    c(p) = floor((p - o) / h)                  (per axis; 0 <= c_a < D_a = floor(extent_a / h) + 1).

The cells are wrapped into a table of W_x W_y W_z buckets (W_a <= D_a, halved along the longest axis
until the table holds at most 2N + 8 buckets, so memory follows N and not the extent):

    bucket(c) = ((c_x mod W_x) W_y + (c_y mod W_y)) W_z + (c_z mod W_z).

The points are sorted by bucket with a stable radix sort (so each bucket's run is in index order);
start[b] .. end[b] - 1 is bucket b's run. A bucket may hold several cells; a visit of cell c reads
bucket(c) and skips the points whose own cell is not c, so no point is seen twice by one query.

Squared distances are d2(q, p) = (q_x - p_x)^2 + (q_y - p_y)^2 + (q_z - p_z)^2, evaluated in that
order in the working dtype (kernels/reference/points.py evaluates the same expression, so the two
agree bit for bit on the CPU, where Warp contracts no multiply-add; docs/warp.md section 10).

k nearest neighbours (`knn`). For a query q, the k indices j with the smallest keys (d2(q, p_j), j)
in lexicographic order: nearest first, ties broken by the smaller index; with their d2 (squared
distances, as PyTorch3D's knn_points and Open3D return them). A query that is also a point of the
cloud finds itself first (d2 = 0). The search visits Chebyshev rings s = s0, s0 + 1, ... of cells
around c(q) (s0: the ring that first meets the cloud's cells), clipped to the cloud's cells. After
ring s every unseen point lies outside the box of visited cells, at a distance >= delta_s from q
(the distance from q to the nearest face of that box that has cloud cells beyond it). The search
stops once k candidates are held and d2_k (1 + 8u) < (delta_s - m h)^2, with u the unit roundoff and
m = 16 u (max D + 2) cells a margin for the rounding of c(p); or when every cell has been visited.
So the result is exact: the k smallest keys of the whole cloud.

Ball query (`ball_query`, PointNet++'s query_ball_point: Qi et al., "PointNet++: Deep Hierarchical
Feature Learning on Point Sets in a Metric Space", NeurIPS 2017). For a query q, radius r > 0 and
K >= 1: the first K indices j, in increasing index order, with d2(q, p_j) < r^2 (strict, as
PointNet++'s kernel tests it). Padding: when only n < K are found, slots n .. K - 1 repeat the
first (smallest) index found, PointNet++'s convention; a query with no point within r gets -1 in
every slot (PointNet++ leaves 0 there, a valid index). The count n is returned beside. The visit
covers every cell that meets the cube [q - r, q + r] (widened by the margin m), clipped to the cloud.

Every kernel writes only its own query's row (or its own point's slot), so all of them run split
over CPU threads (kernels.launch, docs/warp.md section 2). No gradients: the results are indices.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

wp.set_module_options({"enable_backward": False})

# Cells per axis are int32; a grid finer than this along an axis is refused (cell_size too small).
MAX_CELLS_PER_AXIS = 1 << 28


# =========================================================================== device functions


@wp.func
def sq_dist(qx: Any, qy: Any, qz: Any, px: Any, py: Any, pz: Any):
    """d2 = (qx - px)^2 + (qy - py)^2 + (qz - pz)^2, in this order."""
    dx = qx - px
    dy = qy - py
    dz = qz - pz
    return dx * dx + dy * dy + dz * dz


@wp.func
def cell_coord(x: Any, o: Any, h: Any):
    """floor((x - o) / h) as an int, clamped to [-2^29, 2^29] (far-away queries stay inside int32)."""
    c = wp.floor((x - o) / h)
    return int(wp.clamp(c, type(x)(-536870912.0), type(x)(536870912.0)))


@wp.func
def bucket_of(cx: int, cy: int, cz: int, wx: int, wy: int, wz: int):
    """((cx mod wx) wy + (cy mod wy)) wz + (cz mod wz), with non-negative remainders."""
    bx = ((cx % wx) + wx) % wx
    by = ((cy % wy) + wy) % wy
    bz = ((cz % wz) + wz) % wz
    return (bx * wy + by) * wz + bz


@wp.func
def key_less(d2: Any, j: int, e2: Any, i: int):
    """(d2, j) < (e2, i) lexicographically."""
    return d2 < e2 or (d2 == e2 and j < i)


# =========================================================================== grid construction


@wp.kernel
def _cells_kernel(points: wp.array2d(dtype=typing.Any), origin: wp.array(dtype=typing.Any), h: typing.Any,
                  wx: int, wy: int, wz: int, cells: wp.array2d(dtype=wp.int32), keys: wp.array(dtype=wp.int32),
                  values: wp.array(dtype=wp.int32), offset: int):
    i = wp.tid() + offset
    cx = cell_coord(points[i, 0], origin[0], h)
    cy = cell_coord(points[i, 1], origin[1], h)
    cz = cell_coord(points[i, 2], origin[2], h)
    cells[i, 0] = cx
    cells[i, 1] = cy
    cells[i, 2] = cz
    keys[i] = bucket_of(cx, cy, cz, wx, wy, wz)
    values[i] = i


@wp.kernel
def _runs_kernel(keys: wp.array(dtype=wp.int32), n: int, start: wp.array(dtype=wp.int32),
                 end: wp.array(dtype=wp.int32), offset: int):
    # The first and last position of each key's run in the sorted keys: distinct slots per thread.
    t = wp.tid() + offset
    k = keys[t]
    if t == 0 or keys[t - 1] != k:
        start[k] = t
    if t == n - 1 or keys[t + 1] != k:
        end[k] = t + 1


@wp.kernel
def _gather_kernel(points: wp.array2d(dtype=typing.Any), cells: wp.array2d(dtype=wp.int32),
                   order: wp.array(dtype=wp.int32), sorted_points: wp.array2d(dtype=typing.Any),
                   sorted_cells: wp.array2d(dtype=wp.int32), offset: int):
    t = wp.tid() + offset
    j = order[t]
    for a in range(3):
        sorted_points[t, a] = points[j, a]
        sorted_cells[t, a] = cells[j, a]


for _k in (_cells_kernel, _gather_kernel):
    A.declare_float_overloads(_k)


@dataclass
class PointGrid:
    """A cloud sorted into a uniform hash grid (module docstring). Arrays live on `device`.

    sorted_points (N, 3) and sorted_cells (N, 3): the points and their cells in bucket order;
    order (N,): the original index of each sorted point; start, end (buckets,): each bucket's run;
    origin (3,), cell_size h, dims D (cells per axis), wrap W (buckets per axis).
    """

    sorted_points: wp.array
    sorted_cells: wp.array
    order: wp.array
    start: wp.array
    end: wp.array
    origin: wp.array
    cell_size: float
    dims: tuple[int, int, int]
    wrap: tuple[int, int, int]
    n: int
    scalar: Any
    device: Any

    @property
    def margin(self) -> float:
        """m: the rounding margin of c(p), in cells (module docstring)."""
        u = float(np.finfo(A.NP_OF_WP[self.scalar]).eps) / 2.0
        return 16.0 * u * (max(self.dims) + 2)

    @property
    def slack(self) -> float:
        """1 + 8u: the relative rounding allowance on a squared distance (module docstring)."""
        return 1.0 + 4.0 * float(np.finfo(A.NP_OF_WP[self.scalar]).eps)


def check_cloud(a: A.Inputs, name: str, x: Any) -> wp.array:
    """An (N, 3) float cloud with N >= 1 and finite values; ValueError naming `name` otherwise."""
    arr = a.floats(name, x, (None, 3), finite=False)
    if x.shape[0] == 0:
        raise ValueError(f"{name}: expected a non-empty cloud of shape (N, 3) with N >= 1, got shape {tuple(x.shape)}")
    if A.values_checked() and not A.all_finite(x):
        raise ValueError(f"{name}: expected finite coordinates, found NaN or infinite entries")
    return arr


def check_count(name: str, v: Any, minimum: int, n: int) -> int:
    """An integer in [minimum, n], n the cloud's number of points; ValueError naming `name` otherwise."""
    v = A.check_int(name, v, minimum=minimum)
    if v > n:
        raise ValueError(f"{name}: expected an integer in [{minimum}, {n}] (at most the number of points), got {v}")
    return v


def _host(pts: wp.array) -> np.ndarray:
    """A host view (CPU) or copy (CUDA) of a checked cloud."""
    h = A.host_view(pts)
    return pts.numpy() if h is None else h


def _bounds(a: A.Inputs, pts: wp.array) -> tuple[np.ndarray, np.ndarray]:
    """(min corner, max corner) of a checked cloud, float64 host values."""
    h = _host(pts)
    return h.min(axis=0).astype(np.float64), h.max(axis=0).astype(np.float64)


def density_cell_size(points: np.ndarray, k: int) -> float:
    """h = 0.75 (k / rho)^(1/3), rho the density of the cloud's central box (the 10th to 90th percentile
    per axis, each side floored at 1e-3 of the largest): a cell then holds about k / 2 points where the
    cloud is dense. 1 when all points coincide. Any h gives the same neighbours; this one is fast on
    even and on Gaussian clouds (research/bench/points.py). k < 2 is taken as 2: cells of about half a
    point made a 1-NN search 1.6x slower than cells of one (20000 uniform points, measured)."""
    k = max(k, 2)
    lo, hi = np.percentile(points, [10.0, 90.0], axis=0)
    ext = hi - lo
    big = float(ext.max())
    if not big > 0.0:
        ext_all = points.max(axis=0) - points.min(axis=0)
        if not float(ext_all.max()) > 0.0:
            return 1.0
        return float(ext_all.max()) / max(points.shape[0], 1) ** (1.0 / 3.0)
    ext = np.maximum(ext, 1e-3 * big)
    inside = np.all((points >= lo) & (points <= hi), axis=1).sum()
    rho = max(int(inside), 1) / float(np.prod(ext))
    return 0.75 * float((k / rho) ** (1.0 / 3.0))


def build_grid(points: Any, cell_size: float, *, device: Any = None) -> PointGrid:
    """Sort a cloud (N, 3) into the uniform hash grid of cell size h = `cell_size` (module docstring)."""
    a = A.Inputs(device, points)
    pts = check_cloud(a, "points", points)
    h = A.check_float("cell_size", cell_size, positive=True)
    return _build(a, pts, h)


def _build(a: A.Inputs, pts: wp.array, h: float) -> PointGrid:
    n = int(pts.shape[0])
    lo, hi = _bounds(a, pts)
    dims_f = np.floor((hi - lo) / h) + 1
    if dims_f.max() > MAX_CELLS_PER_AXIS:
        raise ValueError(f"cell_size: expected a cell size giving at most {MAX_CELLS_PER_AXIS} cells along an axis, "
                         f"got {h:g} for extents {tuple(float(e) for e in hi - lo)}")
    dims = [int(d) for d in dims_f]
    wrap = list(dims)
    while math.prod(wrap) > 2 * n + 8:
        i = int(np.argmax(wrap))
        wrap[i] = (wrap[i] + 1) // 2
    n_buckets = math.prod(wrap)
    dev = a.device
    origin = wp.array(lo.astype(a.np_dtype), dtype=a.scalar, device=dev)
    cells = wp.empty((n, 3), dtype=wp.int32, device=dev)
    keys = wp.empty(2 * n, dtype=wp.int32, device=dev)  # radix_sort_pairs needs room for 2n (docs/warp.md)
    order = wp.empty(2 * n, dtype=wp.int32, device=dev)
    a.launch(_cells_kernel, n, [pts, origin, a.s(h), wrap[0], wrap[1], wrap[2], cells, keys, order])
    wp.utils.radix_sort_pairs(keys, order, n)  # stable: each bucket's run stays in index order
    start = wp.zeros(n_buckets, dtype=wp.int32, device=dev)
    end = wp.zeros(n_buckets, dtype=wp.int32, device=dev)
    a.launch(_runs_kernel, n, [keys, n, start, end])
    sorted_points = wp.empty((n, 3), dtype=a.scalar, device=dev)
    sorted_cells = wp.empty((n, 3), dtype=wp.int32, device=dev)
    order = order[:n]
    a.launch(_gather_kernel, n, [pts, cells, order, sorted_points, sorted_cells])
    return PointGrid(sorted_points, sorted_cells, order, start, end, origin, h, tuple(dims), tuple(wrap), n,
                     a.scalar, dev)


# =========================================================================== k nearest neighbours


@wp.func
def push_nearest(sq: wp.array2d(dtype=typing.Any), idx: wp.array2d(dtype=wp.int32), q: int, cnt: int, k: int,
                 d2: typing.Any, j: int):
    """Insert (d2, j) into row q of the (d2, index)-sorted list of at most k entries; the new count."""
    if cnt == k:
        if not key_less(d2, j, sq[q, k - 1], idx[q, k - 1]):
            return cnt
    m = cnt
    if cnt == k:
        m = k - 1
    while m > 0 and key_less(d2, j, sq[q, m - 1], idx[q, m - 1]):
        sq[q, m] = sq[q, m - 1]
        idx[q, m] = idx[q, m - 1]
        m -= 1
    sq[q, m] = d2
    idx[q, m] = j
    return wp.min(cnt + 1, k)


@wp.func
def visit_nearest(g_pts: wp.array2d(dtype=typing.Any), g_cells: wp.array2d(dtype=wp.int32),
                  g_order: wp.array(dtype=wp.int32), start: wp.array(dtype=wp.int32), end: wp.array(dtype=wp.int32),
                  wx: int, wy: int, wz: int, x: int, y: int, z: int, qx: typing.Any, qy: typing.Any, qz: typing.Any,
                  sq: wp.array2d(dtype=typing.Any), idx: wp.array2d(dtype=wp.int32), q: int, cnt: int, k: int):
    """Offer every point of cell (x, y, z) to row q; the new count."""
    b = bucket_of(x, y, z, wx, wy, wz)
    c = cnt
    for t in range(start[b], end[b]):
        if g_cells[t, 0] == x and g_cells[t, 1] == y and g_cells[t, 2] == z:
            d2 = sq_dist(qx, qy, qz, g_pts[t, 0], g_pts[t, 1], g_pts[t, 2])
            c = push_nearest(sq, idx, q, c, k, d2, g_order[t])
    return c


@wp.func
def face_gap(qa: typing.Any, oa: typing.Any, h: typing.Any, ca: int, s: int, da: int, big: typing.Any):
    """Distance from coordinate qa to the nearer face, along one axis, of the box of cells ca - s .. ca + s
    that has cloud cells (0 .. da - 1) beyond it; `big` when neither has."""
    g = big
    if ca - s > 0:
        g = wp.min(g, qa - (oa + type(qa)(ca - s) * h))
    if ca + s + 1 < da:
        g = wp.min(g, (oa + type(qa)(ca + s + 1) * h) - qa)
    return g


@wp.kernel
def _knn_kernel(queries: wp.array2d(dtype=typing.Any), g_pts: wp.array2d(dtype=typing.Any),
                g_cells: wp.array2d(dtype=wp.int32), g_order: wp.array(dtype=wp.int32),
                start: wp.array(dtype=wp.int32), end: wp.array(dtype=wp.int32), origin: wp.array(dtype=typing.Any),
                h: typing.Any, margin: typing.Any, slack: typing.Any, dx: int, dy: int, dz: int, wx: int, wy: int, wz: int,
                k: int,
                sq: wp.array2d(dtype=typing.Any), idx: wp.array2d(dtype=wp.int32), offset: int):
    q = wp.tid() + offset
    qx = queries[q, 0]
    qy = queries[q, 1]
    qz = queries[q, 2]
    cx = cell_coord(qx, origin[0], h)
    cy = cell_coord(qy, origin[1], h)
    cz = cell_coord(qz, origin[2], h)
    # the first ring that meets the cloud's cells, and the last one that still adds cells
    s0 = wp.max(wp.max(wp.max(0, -cx), cx - (dx - 1)), wp.max(wp.max(-cy, cy - (dy - 1)), wp.max(-cz, cz - (dz - 1))))
    s1 = wp.max(wp.max(wp.max(cx, dx - 1 - cx), wp.max(cy, dy - 1 - cy)), wp.max(cz, dz - 1 - cz))
    big = type(qx)(1.0e30)
    cnt = int(0)
    s = s0
    done = bool(False)
    while not done and s <= s1:
        for x in range(wp.max(cx - s, 0), wp.min(cx + s, dx - 1) + 1):
            for y in range(wp.max(cy - s, 0), wp.min(cy + s, dy - 1) + 1):
                if wp.abs(x - cx) == s or wp.abs(y - cy) == s:  # a face of the ring: its whole z range
                    for z in range(wp.max(cz - s, 0), wp.min(cz + s, dz - 1) + 1):
                        cnt = visit_nearest(g_pts, g_cells, g_order, start, end, wx, wy, wz, x, y, z, qx, qy, qz,
                                            sq, idx, q, cnt, k)
                else:  # inside the ring's x-y square: only the two z caps
                    if cz - s >= 0 and cz - s < dz:
                        cnt = visit_nearest(g_pts, g_cells, g_order, start, end, wx, wy, wz, x, y, cz - s, qx, qy,
                                            qz, sq, idx, q, cnt, k)
                    if s > 0 and cz + s >= 0 and cz + s < dz:
                        cnt = visit_nearest(g_pts, g_cells, g_order, start, end, wx, wy, wz, x, y, cz + s, qx, qy,
                                            qz, sq, idx, q, cnt, k)
        if cnt == k:
            gap = wp.min(wp.min(face_gap(qx, origin[0], h, cx, s, dx, big), face_gap(qy, origin[1], h, cy, s, dy, big)),
                         face_gap(qz, origin[2], h, cz, s, dz, big))
            gap = gap - margin * h
            if gap >= big * type(qx)(0.5) or (gap > type(qx)(0.0) and sq[q, k - 1] * slack < gap * gap):
                done = True
        s += 1


A.declare_float_overloads(_knn_kernel)


@dataclass
class KnnResult:
    """idx (M, k) int32: the k nearest points of each query, nearest first, ties by index; sq_dist (M, k):
    their squared distances. NumPy or wp.array, as the inputs."""

    idx: Any
    sq_dist: Any


def knn(points: Any, k: int, queries: Any = None, *, cell_size: float | None = None,
        device: Any = None) -> KnnResult:
    """The k nearest points of `points` (N, 3) to each of `queries` (M, 3; default: the points themselves,
    each then finding itself first), exact, ties broken by index (module docstring).

    cell_size: the grid's h; default (V k / N)^(1/3) (`density_cell_size`). Any h gives the same result.
    """
    a = A.Inputs(device, points, queries)
    pts = check_cloud(a, "points", points)
    qs = pts if queries is None else check_cloud(a, "queries", queries)
    n = int(pts.shape[0])
    k = check_count("k", k, 1, n)
    if cell_size is None:
        h = density_cell_size(_host(pts), k)
    else:
        h = A.check_float("cell_size", cell_size, positive=True)
    grid = _build(a, pts, h)
    return knn_grid(a, grid, qs, k)


def knn_grid(a: A.Inputs, grid: PointGrid, qs: wp.array, k: int) -> KnnResult:
    """kNN of checked queries `qs` in a built grid (for callers that reuse a grid)."""
    m = int(qs.shape[0])
    sq = a.empty((m, k))
    idx = a.empty((m, k), dtype=wp.int32)
    dx, dy, dz = grid.dims
    wx, wy, wz = grid.wrap
    a.launch(_knn_kernel, m, [qs, grid.sorted_points, grid.sorted_cells, grid.order, grid.start, grid.end,
                              grid.origin, a.s(grid.cell_size), a.s(grid.margin), a.s(grid.slack), dx, dy, dz, wx, wy, wz, k, sq,
                              idx],
             min_chunk=64)
    return KnnResult(a.out(idx), a.out(sq))


# =========================================================================== ball query


@wp.kernel
def _ball_kernel(queries: wp.array2d(dtype=typing.Any), g_pts: wp.array2d(dtype=typing.Any),
                 g_cells: wp.array2d(dtype=wp.int32), g_order: wp.array(dtype=wp.int32),
                 start: wp.array(dtype=wp.int32), end: wp.array(dtype=wp.int32), origin: wp.array(dtype=typing.Any),
                 h: typing.Any, margin: typing.Any, r: typing.Any, dx: int, dy: int, dz: int, wx: int, wy: int,
                 wz: int, kmax: int, idx: wp.array2d(dtype=wp.int32), count: wp.array(dtype=wp.int32), offset: int):
    q = wp.tid() + offset
    qx = queries[q, 0]
    qy = queries[q, 1]
    qz = queries[q, 2]
    r2 = r * r
    w = r + margin * h
    x0 = wp.max(cell_coord(qx - w, origin[0], h), 0)
    x1 = wp.min(cell_coord(qx + w, origin[0], h), dx - 1)
    y0 = wp.max(cell_coord(qy - w, origin[1], h), 0)
    y1 = wp.min(cell_coord(qy + w, origin[1], h), dy - 1)
    z0 = wp.max(cell_coord(qz - w, origin[2], h), 0)
    z1 = wp.min(cell_coord(qz + w, origin[2], h), dz - 1)
    cnt = int(0)
    for x in range(x0, x1 + 1):
        for y in range(y0, y1 + 1):
            for z in range(z0, z1 + 1):
                b = bucket_of(x, y, z, wx, wy, wz)
                for t in range(start[b], end[b]):
                    if g_cells[t, 0] == x and g_cells[t, 1] == y and g_cells[t, 2] == z:
                        if sq_dist(qx, qy, qz, g_pts[t, 0], g_pts[t, 1], g_pts[t, 2]) < r2:
                            j = g_order[t]
                            # keep the kmax smallest indices, ascending
                            if cnt < kmax or j < idx[q, kmax - 1]:
                                m = wp.min(cnt, kmax - 1)
                                while m > 0 and j < idx[q, m - 1]:
                                    idx[q, m] = idx[q, m - 1]
                                    m -= 1
                                idx[q, m] = j
                                cnt = wp.min(cnt + 1, kmax)
    count[q] = cnt
    pad = int(-1)
    if cnt > 0:
        pad = idx[q, 0]
    for m in range(cnt, kmax):
        idx[q, m] = pad


A.declare_float_overloads(_ball_kernel)


@dataclass
class BallResult:
    """idx (M, K) int32: the first K indices within r of each query, ascending, padded with the first
    (-1 where none); count (M,) int32: how many were found (<= K)."""

    idx: Any
    count: Any


def ball_query(points: Any, queries: Any, radius: float, max_neighbors: int, *, device: Any = None) -> BallResult:
    """PointNet++'s ball query (module docstring): for each query (M, 3), the first `max_neighbors`
    indices of `points` (N, 3) with squared distance < radius^2, padded with the first found."""
    a = A.Inputs(device, points, queries)
    pts = check_cloud(a, "points", points)
    qs = check_cloud(a, "queries", queries)
    r = A.check_float("radius", radius, positive=True)
    kmax = A.check_int("max_neighbors", max_neighbors, minimum=1)
    lo, hi = _bounds(a, pts)
    h = max(r, float((hi - lo).max()) / (MAX_CELLS_PER_AXIS // 4))  # cells of side r: the 27 around q hold the ball
    grid = _build(a, pts, h)
    m = int(qs.shape[0])
    idx = a.empty((m, kmax), dtype=wp.int32)
    count = a.empty(m, dtype=wp.int32)
    dx, dy, dz = grid.dims
    wx, wy, wz = grid.wrap
    a.launch(_ball_kernel, m, [qs, grid.sorted_points, grid.sorted_cells, grid.order, grid.start, grid.end,
                               grid.origin, a.s(h), a.s(grid.margin), a.s(r), dx, dy, dz, wx, wy, wz, kmax, idx, count],
             min_chunk=64)
    return BallResult(a.out(idx), a.out(count))
