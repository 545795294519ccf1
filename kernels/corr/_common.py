"""What the stages of kernels.corr share: the windowed sampling (3)-(4) and its adjoint, pooling (2), checks.

Lookup window. For a pixel p = (h, w) of frame 1 at level l with radius r, the
(2r + 1)^2 samples of (4) share one fraction: with u0 = x_p / 2^l - 1/2 - r,
the window's taps start at column i0 = floor(u0) with fraction fx = u0 - i0
(and j0, fy from y_p the same way) (`pixel_window`). A map S = s[p] is sampled
by (3) one window column a at a time (`sample_window`: sample b's lower taps are
sample b + 1's upper taps), taps outside s[p] reading 0. The dense lookup samples
V^l[p] from (j0, i0), up to four levels a launch (`sample_levels`, one thread per
pixel; on the CPU `window_cpu.sample_levels_cpu` does the same in C++, bit for
bit); the on-the-fly lookup samples its tap patch from (0, 0), or blocks of
rows of V^l (`sample_windows`, one level a launch).

Adjoint of a window (`sample_windows_adjoint`), with g = d loss / d out:
  * d S[tap] += (weight of tap in (3)) g, into s[p] only, so per-pixel threads
    never collide;
  * d x_p += 2^-l sum_{a,b} g dS/du and d y_p += 2^-l sum_{a,b} g dS/dv, with
    dS/du = (1-fy)(S[j,i+1] - S[j,i]) + fy (S[j+1,i+1] - S[j+1,i]) and dS/dv the
    same with the roles of x and y swapped. (3) is piecewise
    bilinear: its derivative jumps where u or v crosses an integer.

Pooling (2) over the last two axes of an (N, H, W) array, odd trailing rows and
columns dropped (avg_pool2d with kernel 2, stride 2):

    out[n, h, w] = 1/4 sum_{a, b in {0, 1}} x[n, 2h + a, 2w + b],

and its adjoint adds g[n, h // 2, w // 2] / 4 into every fine pixel (h, w) that
has a coarse pixel. Given a gradient for every level of a pyramid, the total
gradient of level 0 runs that adjoint from the coarsest level down: level l's
total is its own gradient plus the adjoint applied to level l + 1's total.

Vectors. `pack_rows` packs a (K, M) array into 8-wide vectors along its rows
(zero-padded), for the blocked product and the channels-last features.

Checks: the pyramid depth `levels` (frame 2 must keep a pixel at the coarsest
level), the window `radius`, the coordinates (2, H, W), and lists of pyramid
levels whose shapes follow `level_shapes`.
"""

from __future__ import annotations

import typing
from typing import Any, Sequence

import warp as wp

from kernels import fast_paths
from kernels._arrays import Inputs, check_int, declare_float_overloads

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

VEC = 8  # SIMD width of the vector types below
vec8f = wp.types.vector(length=VEC, dtype=wp.float32)
vec8d = wp.types.vector(length=VEC, dtype=wp.float64)
VEC_OF = {wp.float32: vec8f, wp.float64: vec8d}

Array = Any  # np.ndarray or wp.array


# --------------------------------------------------------------------------- device functions


@wp.func
def _window_origin(coords: wp.array3d(dtype=typing.Any), axis: int, h: int, w: int, scale: typing.Any, radius: int):
    """Integer tap origin and fraction of the window's first sample: coords[axis, h, w] * scale - 1/2 - r split."""
    u0 = coords[axis, h, w] * scale - coords.dtype(0.5) - coords.dtype(radius)
    i0 = wp.floor(u0)
    return int(i0), u0 - i0


@wp.func
def pixel_window(coords: wp.array3d(dtype=typing.Any), p: int, scale: typing.Any, radius: int):
    """Pixel p's row h and column w, and its window's origin and fractions: (h, w, i0, fx, j0, fy)."""
    width = coords.shape[2]
    h = p // width
    w = p % width
    i0, fx = _window_origin(coords, 0, h, w, scale, radius)
    j0, fy = _window_origin(coords, 1, h, w, scale, radius)
    return h, w, i0, fx, j0, fy


@wp.func
def _tap(s: wp.array3d(dtype=typing.Any), p: int, row: int, col: int):
    """S[p, row, col], or 0 outside the level's image."""
    if row < 0 or col < 0 or row >= s.shape[1] or col >= s.shape[2]:
        return s.dtype(0.0)
    return s[p, row, col]


@wp.func
def _scatter_tap(g: wp.array3d(dtype=typing.Any), p: int, row: int, col: int, value: typing.Any):
    """g[p, row, col] += value where that tap exists."""
    if row >= 0 and col >= 0 and row < g.shape[1] and col < g.shape[2]:
        g[p, row, col] = g[p, row, col] + value


# --------------------------------------------------------------------------- window sampling (4) and its adjoint


@wp.func
def _row_taps(s: wp.array3d(dtype=typing.Any), p: int, row: int, cl: int, cr: int, okl: bool, okr: bool,
              gx: typing.Any, fx: typing.Any):
    """gx S[p, row, left] + fx S[p, row, right] of (3), each tap 0 outside s[p] (cl, cr: the columns
    clamped into the image, read only where okl, okr say the unclamped ones exist)."""
    zero = s.dtype(0.0)
    if row < 0 or row >= s.shape[1]:
        return gx * zero + fx * zero  # not a literal 0: a NaN position gives NaN, as tap by tap
    left = wp.where(okl, s[p, row, cl], zero)
    right = wp.where(okr, s[p, row, cr], zero)
    return gx * left + fx * right


@wp.func
def sample_window(s: wp.array3d(dtype=typing.Any), p: int, row0: int, col0: int, fx: typing.Any, fy: typing.Any,
                  out: wp.array3d(dtype=typing.Any), channel0: int, h: int, w: int, side: int):
    """out[channel0 + a side + b, h, w] = (3) of S = s[p] at taps (row0 + b, col0 + a), a, b < side.

    Column a's samples share its two tap columns, and sample b's lower taps are sample b + 1's
    upper taps, so each row of taps is read once per column. A window whose taps all lie inside
    s[p] (every patch, most level-0 windows) reads them without tests; otherwise each column's
    two tap columns are tested once and each row once (`_row_taps`), and a column whose taps all
    lie outside writes (3) of zero taps. Both branches compute the same expression, tap by tap.
    """
    one = s.dtype(1.0)
    zero = s.dtype(0.0)
    gx = one - fx
    gy = one - fy
    height = s.shape[1]
    width = s.shape[2]
    if row0 >= 0 and col0 >= 0 and row0 + side < height and col0 + side < width:
        for a in range(side):
            col = col0 + a
            ch = channel0 + a * side
            top = gx * s[p, row0, col] + fx * s[p, row0, col + 1]
            for b in range(side):
                row = row0 + b + 1
                bottom = gx * s[p, row, col] + fx * s[p, row, col + 1]
                out[ch + b, h, w] = gy * top + fy * bottom
                top = bottom
    else:
        for a in range(side):
            col = col0 + a
            ch = channel0 + a * side
            okl = col >= 0 and col < width
            okr = col >= -1 and col + 1 < width
            if okl or okr:
                cl = wp.clamp(col, 0, width - 1)
                cr = wp.clamp(col + 1, 0, width - 1)
                top = _row_taps(s, p, row0, cl, cr, okl, okr, gx, fx)
                for b in range(side):
                    bottom = _row_taps(s, p, row0 + b + 1, cl, cr, okl, okr, gx, fx)
                    out[ch + b, h, w] = gy * top + fy * bottom
                    top = bottom
            else:
                row_taps = gx * zero + fx * zero  # as `_row_taps` outside (NaN for a NaN position)
                for b in range(side):
                    out[ch + b, h, w] = gy * row_taps + fy * row_taps


@wp.kernel
def sample_windows(s: wp.array3d(dtype=typing.Any), coords: wp.array3d(dtype=typing.Any),
                   out: wp.array3d(dtype=typing.Any),
                   scale: typing.Any, radius: int, channel0: int, from_patch: int, block0: int, offset: int):
    """Equation (4) for one level, sampling S = s[p - block0] by (3) (`sample_window`); thread =
    pixel p = block0 + thread index.

    Levels: s holds the rows of V^l (B, H_l, W_l) of pixels block0 .. block0 + B - 1, read from
    each window's origin (j0, i0). Patches (`from_patch` = 1): s holds the tap patches
    (B, 2r+2, 2r+2), read from (0, 0).
    """
    row = wp.tid() + offset
    p = row + block0
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    if from_patch != 0:
        i0 = 0
        j0 = 0
    sample_window(s, row, j0, i0, fx, fy, out, channel0, h, w, 2 * radius + 1)


@wp.func
def _sample_level(v: wp.array3d(dtype=typing.Any), coords: wp.array3d(dtype=typing.Any), p: int,
                  out: wp.array3d(dtype=typing.Any), scale: typing.Any, radius: int, channel0: int):
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    sample_window(v, p, j0, i0, fx, fy, out, channel0, h, w, 2 * radius + 1)


LEVELS_PER_LAUNCH = 4  # pyramid levels one `sample_levels` launch covers


@wp.kernel
def sample_levels(v0: wp.array3d(dtype=typing.Any), v1: wp.array3d(dtype=typing.Any),
                  v2: wp.array3d(dtype=typing.Any), v3: wp.array3d(dtype=typing.Any), n_levels: int,
                  coords: wp.array3d(dtype=typing.Any), out: wp.array3d(dtype=typing.Any),
                  scale0: typing.Any, radius: int, channel0: int, offset: int):
    """Equation (4) for up to four consecutive levels v0..v3 (the first `n_levels` of them, level k
    at scale scale0 / 2^k and channels from channel0 + k (2r+1)^2); thread = pixel.

    One launch for the levels instead of one per level: a launch costs tens of microseconds of
    Python, and a split launch several launches.
    """
    p = wp.tid() + offset
    per = (2 * radius + 1) * (2 * radius + 1)
    half = coords.dtype(0.5)
    _sample_level(v0, coords, p, out, scale0, radius, channel0)
    if n_levels > 1:
        _sample_level(v1, coords, p, out, scale0 * half, radius, channel0 + per)
    if n_levels > 2:
        _sample_level(v2, coords, p, out, scale0 * half * half, radius, channel0 + 2 * per)
    if n_levels > 3:
        _sample_level(v3, coords, p, out, scale0 * half * half * half, radius, channel0 + 3 * per)


@wp.kernel
def sample_windows_adjoint(s: wp.array3d(dtype=typing.Any), coords: wp.array3d(dtype=typing.Any),
                           grad_out: wp.array3d(dtype=typing.Any), grad_s: wp.array3d(dtype=typing.Any),
                           grad_coords: wp.array3d(dtype=typing.Any),
                           scale: typing.Any, radius: int, channel0: int, from_patch: int, offset: int):
    """Adjoint of `sample_windows`; thread = pixel. Adds into row p of grad_s (which it first zeroes
    when `from_patch`: the patch's gradient buffer serves every level) and pixel p of grad_coords only."""
    p = wp.tid() + offset
    side = 2 * radius + 1
    h, w, i0, fx, j0, fy = pixel_window(coords, p, scale, radius)
    row0 = j0
    col0 = i0
    if from_patch != 0:
        row0 = 0
        col0 = 0
        for ty in range(grad_s.shape[1]):
            for tx in range(grad_s.shape[2]):
                grad_s[p, ty, tx] = s.dtype(0.0)
    one = s.dtype(1.0)
    gx = s.dtype(0.0)
    gy = s.dtype(0.0)
    for a in range(side):
        col = col0 + a
        for b in range(side):
            row = row0 + b
            g = grad_out[channel0 + a * side + b, h, w]
            s00 = _tap(s, p, row, col)
            s01 = _tap(s, p, row, col + 1)
            s10 = _tap(s, p, row + 1, col)
            s11 = _tap(s, p, row + 1, col + 1)
            gx += g * ((one - fy) * (s01 - s00) + fy * (s11 - s10))
            gy += g * ((one - fx) * (s10 - s00) + fx * (s11 - s01))
            _scatter_tap(grad_s, p, row, col, (one - fx) * (one - fy) * g)
            _scatter_tap(grad_s, p, row, col + 1, fx * (one - fy) * g)
            _scatter_tap(grad_s, p, row + 1, col, (one - fx) * fy * g)
            _scatter_tap(grad_s, p, row + 1, col + 1, fx * fy * g)
    grad_coords[0, h, w] = grad_coords[0, h, w] + gx * scale
    grad_coords[1, h, w] = grad_coords[1, h, w] + gy * scale


for _k in (sample_windows, sample_levels, sample_windows_adjoint):
    declare_float_overloads(_k)


# --------------------------------------------------------------------------- 8-wide vectors


@wp.kernel
def _pack_rows_v(x: wp.array2d(dtype=typing.Any), out_v: wp.array2d(dtype=typing.Any), offset: int):
    """out_v[k, j] = x[k, 8j : 8j + 8] as one vector of out_v's type, zero past x's last column (float16 rows
    widen exactly)."""
    t = wp.tid() + offset
    k = t // out_v.shape[1]
    j = t % out_v.shape[1]
    v = out_v.dtype()
    for t in range(VEC):
        col = j * VEC + t
        if col < x.shape[1]:
            v[t] = v.dtype(x[k, col])
    out_v[k, j] = v


declare_float_overloads(_pack_rows_v, vector_types=VEC_OF)
for _vec in VEC_OF.values():  # float16 features widened (kernels.corr.stored off the CPU)
    wp.overload(_pack_rows_v, {"x": wp.array2d(dtype=wp.float16), "out_v": wp.array2d(dtype=_vec)})


def pack_rows(x: wp.array, n_vec: int, a: Inputs) -> wp.array:
    """x (K, M) as (K, n_vec) 8-wide vectors of the call's scalar type, row by row, zero past x's last
    column (n_vec >= M / 8); x float16 or of the call's type.

    x may be a strided view: the on-the-fly lookup packs f (C, N) channels-last as pack_rows(f^T).
    """
    out = a.empty((x.shape[0], n_vec), VEC_OF[a.scalar])
    a.launch(_pack_rows_v, out.size, [x, out])
    return out


# --------------------------------------------------------------------------- 2x2 average pooling


@wp.func
def _nhw(t: int, height: int, width: int):
    """(n, h, w) of the flat index t = (n * height + h) * width + w."""
    per = height * width
    return t // per, (t % per) // width, t % width


@wp.kernel
def _pool2x2(x: wp.array3d(dtype=typing.Any), out: wp.array3d(dtype=typing.Any), offset: int):
    """out[n, h, :] = means of x[n, 2h : 2h + 2, 2w : 2w + 2] for every w (equation (2)); thread = (n, h).

    A thread per coarse row, not per coarse pixel: the row's loop reads two contiguous fine rows
    (the pooling is memory-bound, and a thread per pixel spent more on indexing than on reading).
    """
    t = wp.tid() + offset
    n = t // out.shape[1]
    h = t % out.shape[1]
    quarter = x.dtype(0.25)
    for w in range(out.shape[2]):
        s = x[n, 2 * h, 2 * w] + x[n, 2 * h, 2 * w + 1] + x[n, 2 * h + 1, 2 * w] + x[n, 2 * h + 1, 2 * w + 1]
        out[n, h, w] = s * quarter


@wp.kernel
def _pool2x2_adjoint_add(g_coarse: wp.array3d(dtype=typing.Any), g_fine: wp.array3d(dtype=typing.Any), offset: int):
    """g_fine[n, h, w] += g_coarse[n, h // 2, w // 2] / 4 where that coarse pixel exists (adjoint of (2))."""
    n, h, w = _nhw(wp.tid() + offset, g_fine.shape[1], g_fine.shape[2])
    hc = h // 2
    wc = w // 2
    if hc < g_coarse.shape[1] and wc < g_coarse.shape[2]:
        g_fine[n, h, w] = g_fine[n, h, w] + g_coarse[n, hc, wc] * g_fine.dtype(0.25)


for _k in (_pool2x2, _pool2x2_adjoint_add):
    declare_float_overloads(_k)


def pool_levels(x: wp.array, levels: int, a: Inputs) -> list[wp.array]:
    """[x, P(x), ..., P^{levels-1}(x)] for x (N, H, W), P the pooling (2)."""
    out = [x]
    for _ in range(1, levels):
        n, h, w = out[-1].shape
        coarse = a.empty((n, h // 2, w // 2))
        a.launch(_pool2x2, n * (h // 2), [out[-1], coarse], min_chunk=64)
        out.append(coarse)
    return out


def pool_levels_adjoint(grads: list[wp.array], a: Inputs) -> wp.array:
    """Total gradient of level 0 given each level's own gradient (3D views (N, H_l, W_l))."""
    acc = grads[-1]
    for lvl in range(len(grads) - 2, -1, -1):
        fine = wp.clone(grads[lvl])
        a.launch(_pool2x2_adjoint_add, fine.size, [acc, fine])
        acc = fine
    return acc


# --------------------------------------------------------------------------- shapes and checks


def full_product_level(height_l: int, width_l: int, radius: int, device: wp.Device) -> bool:
    """Whether level l's taps come from the full product f1^T P^l(f2) by BLAS (CPU only).

    The patch kernel (`patch_cpu`, pixels grouped so that up to 8 share each tap row's vectors)
    forms at most (2r + 2)^2 dot products a pixel, at ~35-43 GMAC/s on one thread; BLAS forms all
    H_l W_l of them at ~32-52 GMAC/s, plus per-level host work (46x62 frames, C = 256, radius 4:
    the 11x15 level took 0.6 ms more through BLAS, the 5x7 level the same either way, on the
    2-vCPU Intel Xeon bench host). So the full product is kept where H_l W_l is at most
    half the patch: RAFT's coarsest level at 1/8 resolution.
    """
    return fast_paths.on(device) and 2 * height_l * width_l <= (2 * radius + 2) ** 2




def level_shapes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    """(H_l, W_l) of each pyramid level: halved and floored, as avg_pool2d(2, stride 2) does."""
    return [(height >> lvl, width >> lvl) for lvl in range(levels)]


def check_levels(levels: Any, height: int | None = None, width: int | None = None) -> int:
    """`levels` as an int >= 1; with a frame size, also that its coarsest level keeps a pixel."""
    levels = check_int("levels", levels, minimum=1)
    need = 2 ** (levels - 1)
    if height is not None and width is not None and (height < need or width < need):
        raise ValueError(f"levels: a pyramid of {levels} levels needs frame 2 at least {need}x{need} pixels "
                         f"(H, W >= 2**(levels-1)), got {height}x{width}; use at most "
                         f"{min(height, width).bit_length()} levels")
    return levels


def check_radius(radius: Any) -> int:
    return check_int("radius", radius, minimum=0)


def check_list(name: str, levels: Any, shape: str) -> None:
    if not isinstance(levels, (list, tuple)) or len(levels) < 1:
        raise ValueError(f"{name}: expected a non-empty list of levels, each {shape}")


def volume_in(a: Inputs, name: str, x: Array, finite: bool = True) -> wp.array:
    """An all-pairs volume (H, W, H, W) (or its gradient) as a wp.array; `finite`: check for NaN and inf.

    Volumes and pyramids come from `correlation_volume`, finite when its features are, and a value
    check reads all H W sum_l H_l W_l of their values, as much as the lookup itself: the forward
    entry points taking them check shapes only (`finite=False`); gradients are checked.
    """
    v = a.floats(name, x, ndim=4, nonempty=True, finite=finite)
    if tuple(v.shape[:2]) != tuple(v.shape[2:]):
        raise ValueError(f"{name}: expected shape (H, W, H, W), got {tuple(v.shape)}")
    return v


def features_in(a: Inputs, name: str, x: Array) -> wp.array:
    """A (C, H, W) feature map (or its gradient) as a wp.array."""
    return a.floats(name, x, ndim=3, nonempty=True)


def levels_in(a: Inputs, name: str, arrays: Sequence[Array], first: wp.array, lead: tuple[int, ...],
              height: int, width: int, finite: bool = True) -> list[wp.array]:
    """Every level of a pyramid list: `first` (level 0, already checked), then level l of shape
    (*lead, H_l, W_l), as wp.arrays of shape (prod(lead), H_l, W_l); `finite` as in `volume_in`."""
    rows = 1
    for s in lead:
        rows *= s
    out = [first.reshape((rows, height, width))]
    for lvl, (hl, wl) in enumerate(level_shapes(height, width, len(arrays))):
        if lvl:
            level = a.floats(f"{name}[{lvl}]", arrays[lvl], (*lead, hl, wl), finite=finite)
            out.append(level.reshape((rows, hl, wl)))
    return out


def coords_in(a: Inputs, coords: Array, height: int, width: int) -> wp.array:
    """Lookup positions (2, H, W): (x, y) in frame 2 for each pixel of frame 1."""
    return a.floats("coords", coords, (2, height, width))
