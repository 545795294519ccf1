"""A splat's pixel spans: the pixels of a tile its ellipse can reach, from its packed row in closed form.

For a splat with mean2d (u, v), conic Q = (Q00, Q01, Q11) and opacity o, the rasteriser skips
every pixel (centre (px + 1/2, py + 1/2), d = mean2d - centre) with d^T Q d > k, k = 2 ln(255 o)
(alpha < 1/255 there), k widened by a rounding margin (_span_widening: the factor 1 + m, m covering
the difference between the rasteriser's power in the splats' dtype and the exact one). Pixel row py,
dy = v - py - 1/2 with |dy| <= hy, then holds the columns

    px in [(u - 1/2) + S dy - sqrt(B - C dy^2), (u - 1/2) + S dy + sqrt(B - C dy^2)],
    S = Q01 / Q00,  B = k / Q00,  C = det Q / Q00^2,  hy = sqrt(B / C),

which kernels.splat.tiles stores in packed columns 11-15 (S, B, C, hy, dy*; hy < 0: no spans).
Over a band of rows, S dy + sqrt(.) is concave and S dy - sqrt(.) convex, extreme at dy = +-dy*,
dy* = S sqrt(B / (C (C + S^2))): clamped into the band, they bound its columns (band_columns).
span_rows gives the rows, pixel_span the box [col0, col1) x [row0, row1) of a tile that the
rasteriser visits (the whole tile without spans). A conic too elongated for the margin's bound
(1 - |Q01| / sqrt(Q00 Q11) < 1e-3) or not positive definite has no spans. All in float64.
"""

from __future__ import annotations

from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})

# Unit roundoff of each float dtype (the margin of the pixel spans, _span_widening).
UNIT_ROUNDOFF = {wp.float32: 2.0 ** -24, wp.float64: 2.0 ** -53}


@wp.func
def _span_widening(qa: wp.float64, qb: wp.float64, qc: wp.float64, unit: wp.float64):
    """The factor 1 + m by which a splat's spans widen its 1/255 ellipse; 0: no spans.

    The rasteriser evaluates the power in the splats' dtype (unit roundoff `unit`): it differs from
    the exact -1/2 d^T Q d (of the same stored u, v, Q) by at most ~11 unit M, where M = Q00 dx^2 +
    Q11 dy^2 + 2 |Q01 dx dy| <= 2 d^T Q d / (1 - rho), rho = |Q01| / sqrt(Q00 Q11). Widened by
    16 unit / (1 - rho), plus 1e-4 (for the float64 arithmetic of the spans and for storing their
    S, B, C, hy, dy* in the splats' dtype: 1e-4 of B is far more than float32's rounding of B, C and
    S dy, whose relative 6e-8 |S| hy <= 6e-8 sqrt(B) / sqrt(2 (1 - rho))), every pixel outside
    computes a power below the skip threshold. A conic too elongated (1 - rho < 1e-3) or not
    positive definite gets no spans (every pixel of its tiles).
    """
    zero = wp.float64(0.0)
    if qa <= zero or qc <= zero:
        return zero
    gap = wp.float64(1.0) - wp.abs(qb) / wp.sqrt(qa * qc)
    if gap < wp.float64(1e-3) or qa * qc - qb * qb <= zero:
        return zero
    return wp.float64(1.0) + wp.float64(1e-4) + wp.float64(16.0) * unit / gap


@wp.func
def floor_in(x: wp.float64, lo: int, hi: int):
    """floor(x) clamped to [lo, hi] (x clamped first, so any finite x converts safely)."""
    return int(wp.floor(wp.clamp(x, wp.float64(float(lo)), wp.float64(float(hi)))))


@wp.func
def ceil_in(x: wp.float64, lo: int, hi: int):
    """ceil(x) clamped to [lo, hi]."""
    return int(wp.ceil(wp.clamp(x, wp.float64(float(lo)), wp.float64(float(hi)))))


@wp.func
def band_columns(packed: wp.array2d(dtype=Any), i: int, p0: int, p1: int):
    """(left, right): every span column (pixel x index, continuous) of splat i in pixel rows p0..p1.

    Over those rows dy = v - (py + 1/2) runs through [d0, d1]; the columns of row dy are
    (u - 1/2) + S dy -+ sqrt(B - C dy^2) (packed columns 11-15: S, B, C, hy, dy*). S dy + sqrt(.)
    is concave, S dy - sqrt(.) convex, extreme at dy = +-dy*, dy* = S sqrt(B / (C (C + S^2))):
    clamped into [d0, d1], they bound the columns of all those rows. In float64.
    """
    u = wp.float64(packed[i, 0])
    v = wp.float64(packed[i, 1])
    sl = wp.float64(packed[i, 11])
    bb = wp.float64(packed[i, 12])
    cc = wp.float64(packed[i, 13])
    hy = wp.float64(packed[i, 14])
    ds = wp.float64(packed[i, 15])
    h = wp.float64(0.5)
    zero = wp.float64(0.0)
    d0 = wp.clamp(v - wp.float64(float(p1)) - h, -hy, hy)
    d1 = wp.clamp(v - wp.float64(float(p0)) - h, -hy, hy)
    dr = wp.clamp(ds, d0, d1)
    dl = wp.clamp(-ds, d0, d1)
    right = u - h + sl * dr + wp.sqrt(wp.max(zero, bb - cc * dr * dr))
    left = u - h + sl * dl - wp.sqrt(wp.max(zero, bb - cc * dl * dl))
    return left, right


@wp.func
def span_rows(packed: wp.array2d(dtype=Any), i: int, lo: int, hi: int):
    """The pixel rows [r0, r1) within [lo, hi) of splat i's spans (|v - (py + 1/2)| <= hy)."""
    v = wp.float64(packed[i, 1])
    hy = wp.float64(packed[i, 14])
    h = wp.float64(0.5)
    return ceil_in(v - hy - h, lo, hi), floor_in(v + hy - h, lo - 1, hi - 1) + 1


@wp.func
def pixel_span(packed: wp.array2d(dtype=Any), i: int, x_lo: int, x_hi: int, y_lo: int, y_hi: int):
    """The pixel box [col0, col1) x [row0, row1) of the tile [x_lo, x_hi) x [y_lo, y_hi) that splat i can
    reach: the rows of its spans and the columns of any of those rows (span_rows, band_columns); the
    whole tile when the splat has no spans (packed[i, 14] < 0)."""
    row0 = y_lo
    row1 = y_hi
    col0 = x_lo
    col1 = x_hi
    if packed[i, 14] >= packed.dtype(0.0):
        row0, row1 = span_rows(packed, i, y_lo, y_hi)
        if row1 > row0:
            left, right = band_columns(packed, i, row0, row1 - 1)
            col0 = ceil_in(left, x_lo, x_hi)
            col1 = floor_in(right, x_lo - 1, x_hi - 1) + 1
    return row0, row1, col0, col1
