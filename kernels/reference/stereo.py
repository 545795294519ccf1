"""Plain NumPy references of kernels.stereo's forward passes (float64, pixel by pixel).

The conventions and the math are those of kernels.stereo: images (H, W), features (C, H, W),
cost volumes (H, W, D) over the hypotheses d_k = dmin + k, the left pixel (x, y) matching the
right pixel (x - d_k, y). These loop over pixels and window cells for clarity, so keep inputs small.
"""

from __future__ import annotations

import numpy as np

# (dy, dx) of the semi-global matching paths; the first four are the 4-path set.
SGM_DIRECTIONS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1))


# =========================================================================== costs


def _window_cells(H: int, W: int, x: int, y: int, d: int, r: int) -> list[tuple[int, int]]:
    """Left cells (u, v) of the window around (x, y), cut to the image and to columns whose match exists."""
    return [(u, v) for v in range(max(0, y - r), min(H - 1, y + r) + 1)
            for u in range(max(0, x - r), min(W - 1, x + r) + 1) if 0 <= u - d < W]


def _window_mean_volume(L: np.ndarray, R: np.ndarray, dmin: int, dmax: int, r: int, cell_cost) -> np.ndarray:
    """Mean of cell_cost(v, u, u - d) over the window of every (y, x, d) whose match exists; the rest get the
    range of all pixel values (the out-of-range cost of SAD and BT)."""
    H, W = L.shape[:2]
    invalid = max(L.max(), R.max()) - min(L.min(), R.min())
    out = np.full((H, W, dmax - dmin), invalid, dtype=np.float64)
    for y in range(H):
        for x in range(W):
            for k, d in enumerate(range(dmin, dmax)):
                if 0 <= x - d < W:
                    out[y, x, k] = np.mean([cell_cost(v, u, u - d) for u, v in _window_cells(H, W, x, y, d, r)])
    return out


def sad_cost(L: np.ndarray, R: np.ndarray, dmin: int, dmax: int, r: int) -> np.ndarray:
    """Mean |L - R| over the window; out of range: the range of all pixel values."""
    return _window_mean_volume(L, R, dmin, dmax, r, lambda v, u, ur: abs(float(L[v, u]) - float(R[v, ur])))


def zncc_cost(L: np.ndarray, R: np.ndarray, dmin: int, dmax: int, r: int, eps: float) -> np.ndarray:
    """1 - cov(L, R) / sqrt((var L + eps) (var R + eps)) over the window; out of range: 2."""
    H, W = L.shape
    out = np.full((H, W, dmax - dmin), 2.0)
    for y in range(H):
        for x in range(W):
            for k, d in enumerate(range(dmin, dmax)):
                if 0 <= x - d < W:
                    cells = _window_cells(H, W, x, y, d, r)
                    lv = np.array([L[v, u] for u, v in cells], dtype=np.float64)
                    rv = np.array([R[v, u - d] for u, v in cells], dtype=np.float64)
                    cov = np.mean((lv - lv.mean()) * (rv - rv.mean()))
                    out[y, x, k] = 1.0 - cov / np.sqrt((lv.var() + eps) * (rv.var() + eps))
    return out


def census_transform(img: np.ndarray, ry: int, rx: int, eps: float = 0.0) -> np.ndarray:
    """Bit [I(q) < I(p) - eps] per neighbour q of the (2 ry + 1) x (2 rx + 1) window, raster order, clamped."""
    H, W = img.shape
    out = np.zeros((H, W), dtype=np.uint64)
    for y in range(H):
        for x in range(W):
            bits = 0
            for dy in range(-ry, ry + 1):
                for dx in range(-rx, rx + 1):
                    if dy or dx:
                        q = img[min(max(y + dy, 0), H - 1), min(max(x + dx, 0), W - 1)]
                        bits = (bits << 1) | int(q < img[y, x] - eps)
            out[y, x] = bits
    return out


def census_cost(L: np.ndarray, R: np.ndarray, dmin: int, dmax: int, ry: int, rx: int, eps: float = 0.0) -> np.ndarray:
    """Hamming distance of the census bit strings; out of range: the number of bits."""
    cl, cr = census_transform(L, ry, rx, eps), census_transform(R, ry, rx, eps)
    H, W = L.shape
    nbits = (2 * ry + 1) * (2 * rx + 1) - 1
    out = np.full((H, W, dmax - dmin), float(nbits))
    for y in range(H):
        for x in range(W):
            for k, d in enumerate(range(dmin, dmax)):
                if 0 <= x - d < W:
                    out[y, x, k] = bin(int(cl[y, x]) ^ int(cr[y, x - d])).count("1")
    return out


def bt_cost(L: np.ndarray, R: np.ndarray, dmin: int, dmax: int, r: int) -> np.ndarray:
    """Window mean of the Birchfield-Tomasi dissimilarity (channel mean for colour (H, W, C) images);
    out of range: the range of all pixel values."""
    L, R = np.asarray(L, np.float64), np.asarray(R, np.float64)
    if L.ndim == 2:
        L, R = L[..., None], R[..., None]
    H, W, C = L.shape

    def half_range(img, y, x, c):
        v = img[y, x, c]
        vm, vp = 0.5 * (v + img[y, max(x - 1, 0), c]), 0.5 * (v + img[y, min(x + 1, W - 1), c])
        return min(vm, vp, v), max(vm, vp, v)

    def bt(y, x, u):
        total = 0.0
        for c in range(C):
            lmin, lmax = half_range(L, y, x, c)
            rmin, rmax = half_range(R, y, u, c)
            e_lr = max(0.0, L[y, x, c] - rmax, rmin - L[y, x, c])
            e_rl = max(0.0, R[y, u, c] - lmax, lmin - R[y, u, c])
            total += min(e_lr, e_rl)
        return total / C

    return _window_mean_volume(L, R, dmin, dmax, r, bt)


def sobel_x_clipped(img: np.ndarray, cap: float) -> np.ndarray:
    """(clip(Sobel_x I, -cap, cap) + cap) / (2 cap) per channel, rows and columns clamped at the border."""
    img = np.asarray(img, np.float64)
    H, W = img.shape[:2]
    out = np.empty_like(img)
    for y in range(H):
        for x in range(W):
            g = 0.0
            for dy, w in ((-1, 1.0), (0, 2.0), (1, 1.0)):
                v = min(max(y + dy, 0), H - 1)
                g = g + w * (img[v, min(x + 1, W - 1)] - img[v, max(x - 1, 0)])
            out[y, x] = (np.clip(g, -cap, cap) + cap) / (2.0 * cap)
    return out


def adcensus_cost(L: np.ndarray, R: np.ndarray, dmin: int, dmax: int, *, grey=None, census_radii=(3, 4),
                  radius: int = 2, grad_cap: float = 0.25, lambda_census: float = 30.0, lambda_grad: float = 0.04,
                  bt_weight: float = 0.0, lambda_bt: float = 0.04, census_eps: float = 0.0) -> np.ndarray:
    """rho(census, l_c) + rho(BT on the clipped x-gradient, l_g) + w_bt rho(BT, l_bt), rho(c, l) = 1 - exp(-c / l)."""
    gl, gr = (L, R) if grey is None else grey
    rho = lambda c, lam: 1.0 - np.exp(-c / lam)  # noqa: E731
    total = rho(census_cost(gl, gr, dmin, dmax, *census_radii, census_eps), lambda_census)
    total = total + rho(bt_cost(sobel_x_clipped(L, grad_cap), sobel_x_clipped(R, grad_cap), dmin, dmax, radius),
                        lambda_grad)
    if bt_weight > 0:
        total = total + bt_weight * rho(bt_cost(L, R, dmin, dmax, radius), lambda_bt)
    return total


def feature_correlation(FL: np.ndarray, FR: np.ndarray, dmin: int, dmax: int) -> np.ndarray:
    """<F_L(x, y), F_R(x - d_k, y)> / sqrt(C); 0 out of range."""
    C, H, W = FL.shape
    out = np.zeros((H, W, dmax - dmin))
    for y in range(H):
        for x in range(W):
            for k, d in enumerate(range(dmin, dmax)):
                if 0 <= x - d < W:
                    out[y, x, k] = np.dot(FL[:, y, x].astype(np.float64), FR[:, y, x - d]) / np.sqrt(C)
    return out


# =========================================================================== aggregation


def sgm(C: np.ndarray, p1: float, p2: float, paths: int) -> np.ndarray:
    """S = sum over the first `paths` directions r of the recurrence L_r (kernels.stereo.sgm)."""
    C = C.astype(np.float64)
    H, W, D = C.shape
    S = np.zeros_like(C)
    for dy, dx in SGM_DIRECTIONS[:paths]:
        Lr = np.zeros_like(C)
        # Visit pixels so that the predecessor p - r is always done first.
        for y in (range(H) if dy >= 0 else range(H - 1, -1, -1)):
            for x in (range(W) if dx >= 0 else range(W - 1, -1, -1)):
                py, px = y - dy, x - dx
                if not (0 <= py < H and 0 <= px < W):
                    Lr[y, x] = C[y, x]
                    continue
                prev = Lr[py, px]
                m = prev.min()
                candidates = np.stack([prev,
                                       np.concatenate([[np.inf], prev[:-1]]) + p1,
                                       np.concatenate([prev[1:], [np.inf]]) + p1,
                                       np.full(D, m + p2)])
                Lr[y, x] = C[y, x] + candidates.min(axis=0) - m
        S += Lr
    return S


# =========================================================================== disparity and depth


def _parabola(cm: float, c0: float, cp: float) -> float:
    denom = cm - 2 * c0 + cp
    return (cm - cp) / (2 * denom) if denom > 0 else 0.0


def wta(C: np.ndarray, dmin: int, uniqueness: float = 0.0, subpixel: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Left disparity (first minimum, parabola-refined) and validity (in range, unique)."""
    H, W, D = C.shape
    disp = np.zeros((H, W))
    valid = np.zeros((H, W), dtype=bool)
    for y in range(H):
        for x in range(W):
            c = C[y, x].astype(np.float64)
            k = int(np.argmin(c))  # the first minimum
            ok = 0 <= x - (dmin + k) < W
            if uniqueness > 0:
                others = [j for j in range(D) if abs(j - k) > 1]
                ok = ok and not any(c[j] * (1 - uniqueness) < c[k] for j in others)
            disp[y, x] = dmin + k + (_parabola(c[k - 1], c[k], c[k + 1]) if subpixel and 0 < k < D - 1 else 0.0)
            valid[y, x] = ok
    return disp, valid


def wta_right(C: np.ndarray, dmin: int) -> tuple[np.ndarray, np.ndarray]:
    """Right disparity argmin_k C(x_r + d_k, y, k) from the left volume, parabola-refined, and validity."""
    H, W, D = C.shape
    disp = np.zeros((H, W))
    valid = np.zeros((H, W), dtype=bool)
    for y in range(H):
        for xr in range(W):
            costs = {k: float(C[y, xr + dmin + k, k]) for k in range(D) if 0 <= xr + dmin + k < W}
            if not costs:
                continue
            k = min(costs, key=lambda j: (costs[j], j))
            d = dmin + k
            if 0 < k < D - 1 and (k - 1) in costs and (k + 1) in costs:
                d += _parabola(costs[k - 1], costs[k], costs[k + 1])
            disp[y, xr], valid[y, xr] = d, True
    return disp, valid


def soft_argmin(C: np.ndarray, dmin: int, T: float) -> np.ndarray:
    """sum_k d_k softmax_k(-C / T)."""
    C = C.astype(np.float64)
    e = np.exp(-(C - C.min(axis=2, keepdims=True)) / T)
    p = e / e.sum(axis=2, keepdims=True)
    return (p * (dmin + np.arange(C.shape[2]))).sum(axis=2)


def left_right_check(dl: np.ndarray, dr: np.ndarray, max_diff: float, vl: np.ndarray, vr: np.ndarray) -> np.ndarray:
    """Valid where vl, x_r = round(x - d_L) exists, vr(x_r), and |d_L - d_R(x_r)| <= max_diff."""
    H, W = dl.shape
    out = np.zeros((H, W), dtype=bool)
    for y in range(H):
        for x in range(W):
            xr = int(np.floor(x - float(dl[y, x]) + 0.5))
            out[y, x] = bool(vl[y, x] and 0 <= xr < W and vr[y, xr]
                             and abs(float(dl[y, x]) - float(dr[y, xr])) <= max_diff)
    return out


def depth_from_disparity(disp: np.ndarray, focal: float, baseline: float,
                         valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Z = f b / d where valid, d finite and > 0, and Z finite; elsewhere Z = 0 and invalid.

    The quotient is taken in the disparity's dtype, so whether it overflows (is invalid) depends on it.
    """
    d = np.asarray(disp)
    ok = np.isfinite(d) & (d > 0)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    with np.errstate(divide="ignore", over="ignore"):
        z = d.dtype.type(focal * baseline) / np.where(ok, d, 1)
    ok &= np.isfinite(z)
    return np.where(ok, z, 0).astype(d.dtype), ok
