"""Stereo matching pipelines on kernels.stereo, and the KITTI-style disparity metrics.

Pipeline (`match`): cost volume -> aggregation -> winner-take-all with the
sub-pixel parabola (or soft-argmin) -> optional left-right check, where the
right view's disparity comes from the same volume (kernels.stereo.wta_right).
Costs: "sad", "zncc", "census", "bt" (Birchfield-Tomasi, kernels.stereo.bt: sampling-insensitive,
with a colour term: colour images keep their channels), "adcensus" (kernels.stereo.adcensus: census
on the grey images + BT on the clipped x-gradient of the colour images, + optionally BT on intensity,
each squashed by 1 - exp(-c / lambda)), and "corr", the feature correlation on hand-made features
(below), whose similarity is negated into a cost.
Aggregations: "none", "sgm4", "sgm8".
Post-processing (after the left-right check), both off unless set: `border_invalid` acts on the left
columns x < dmax - 1, where some hypotheses fall outside the right image: in each row, with d_b the
disparity of the row's first valid pixel at x >= dmax - 1 (the full range), the pixels x < d_b + 1 are
marked invalid, since the surface there, continued leftwards, would match outside the right image
and any winner is forced (StereoSGBM leaves every such column invalid); the fill below then extends
d_b from the right; `median` (an odd size k >= 3) replaces the disparity by the k x k median of
the filled map (`fill_invalid`; scipy.ndimage.median_filter, border replicated; for k = 3 the same values from
kernels.stereo.fill_median3's two Warp passes), the valid mask kept.

drlab's default configuration, DEFAULT_CONFIG: "adcensus" (census 7x9, l_census 30 bits; x-gradient
clipped at 0.25 with BT radius 2, l_grad 0.04; intensity BT with weight 0.3, l_bt 0.04) + SGM-8
(P1 0.8, P2 6.4) + winner-take-all with the parabola, the left-right check (1 px), border
invalidation and a 3x3 median, on float32 volumes below FLOAT_VOLUME_BUDGET. FAST_DEFAULT_CONFIG is the same
pipeline in compact mode at every size (fast_compact: uint8 costs with step 1 / 110, the BT terms' rho by
kernels.stereo.adcensus' vector polynomial, the int16 SGM of kernels.stereo.sweep): 1.3-1.5x faster, not
the default because its D1 is a little worse on the Mitsuba evaluation pairs (D1 noc 0.1653 / 0.2078 against
0.1652 / 0.2073, clean / stressed; pooled Middlebury 2001/2003 D1 0.0489 against 0.0488). **Which data chose it**: the real Middlebury 2001 pairs tsukuba and
venus and the Mitsuba tuning pairs p_000 of the scenes objects and cornell (at 256x256 and at the
quick run's 128x128), clean and radiometrically stressed; the score: the mean D1 of the two real pairs
plus the mean D1 of the eight Mitsuba ones,
over the cost's terms (census alone, + gradient, + intensity with weight 0.3, 0.5 or 1 and l_bt 0.04 or
0.1, BT radius 1 or 2), P1 in {0.05 ... 0.8}, P2 / P1 in {4, 8, 16}, the median, uniqueness and
border options. None of the pairs the tables report (Middlebury teddy and cones, Mitsuba
pairs other than p_000) took part. StereoConfig()'s own field defaults stay census + SGM-8 (census
units), the pipeline research.bench times in compact mode. A further search on the same tuning data (same
score: 0.1511 for the default) tried the census tolerance census_eps 0.01 / 0.02 / 0.04 (0.1514 / 0.1553 /
0.1548), lr_max_diff 2 (0.1501), P2 12.8 (0.1558), P1 0.4 (0.1636), and BT radius 3 / 4 / 5 (0.1448 /
0.1434 / 0.1422). The radius gains come from the 128-px Mitsuba pairs while tsukuba + venus get worse
at every step (mean D1 0.021 -> 0.022 / 0.025 / 0.027), and cornell at 256 px stays at 0.27 clean. So
the default was kept. Cornell's outliers lie on the slanted, textureless walls and ceiling (0.27-0.38 px
of disparity per pixel), where SGM's P1 favours fronto-parallel plateaus, and in the left band where
the LR check removes the wall and the row fill copies one value.

Patch features (for "corr", standing in for learned ones): each pixel's
(2r+1)^2 neighbourhood (replicated at the border), minus its mean, divided by
its norm (+ a small floor), as C = (2r+1)^2 channels. Their correlation is
then a scaled normalised cross-correlation.

Metrics, over an evaluation mask M of pixels with ground truth (KITTI 2015,
Menze & Geiger; Middlebury, Scharstein & Szeliski), with e = |d - d_gt|:
  * EPE = mean_M e; bad-k = fraction of M with e > k px (k = 1, 2, 3);
  * D1 = fraction of M with e > 3 px AND e > 5% of d_gt;
  * depth abs-rel = mean |Z - Z_gt| / Z_gt over the pixels of M whose
    estimate gives a valid depth (Z = f b / d, kernels.stereo.depth_from_disparity).
Images: `match` and `cost_volume` take uint8, uint16 or float images in [0, 1], grey (H, W) or
colour (H, W, 3), through research.images.to_unit_grey (uint8 / 255, uint16 / 65535, colour by
Rec. 601 luma, except "bt", which keeps colour, and "adcensus", whose gradient and intensity terms keep
colour while its census term reads the luma; a float image outside [0, 1] is refused).

Units of the penalties and thresholds, none of which depends on the stored image range (8 or 16
bits, or float), because every image is first normalised to [0, 1]:
  * SAD and BT costs are mean absolute intensity differences on that [0, 1] scale, so their P1, P2
    (and a soft-argmin temperature) are in [0, 1] intensity units: P1 = 0.02 is a mean difference
    of about 5 grey levels of 255;
  * census costs are Hamming distances (counts of differing bits, 0 to the window's bit count),
    so P1 = 8 means 8 differing comparisons, whatever the image range (census is also invariant to
    any monotonic change of intensity: gain, offset, gamma);
  * ZNCC costs are 1 - correlation in [0, 2] (unitless; invariant to gain and offset per window),
    and the ZNCC epsilon is a variance floor in [0, 1]-intensity^2 units;
  * "corr" costs are negated correlations of unit-norm patch features, in [-1, 1] (unitless);
  * "adcensus" costs are sums of terms in [0, 1) (unitless; at most 2 + bt_weight), so its P1, P2 are
    fractions of one term's range; its lambdas are in each term's units (module kernels.stereo.adcensus).
StereoConfig's field defaults (P1 = 8, P2 = 64) are census units.

Memory: every configuration holds float32 volumes (`peak_volume_bytes`: the cost and SGM's
aggregate, 8 bytes per cell), except SGM + winner-take-all on census costs with integer penalties,
at every size, on "adcensus" costs with `fast_compact` (FAST_DEFAULT_CONFIG) at every size, and on other
"adcensus" costs once float32 volumes would exceed FLOAT_VOLUME_BUDGET (1 GiB):
they run in compact mode (`uses_compact`: uint8 costs, a uint16 aggregate, 3 bytes per cell; census
gives the same results and is the faster path on the CPU, adcensus quantises its cost to steps of
1 / 110 and its penalties to that step).

Benchmark protocols (Middlebury, KITTI, ETH3D; `protocol_metrics`, `pool_protocol`) are described
at the end of this module.

Invalid estimates are first filled as KITTI's devkit does before evaluating
(`fill_invalid`): along each row, a gap takes the smaller (background)
disparity of its two valid ends, or the one valid end at a border. So every
method is scored on every pixel of M; `density` reports the fraction it
estimated itself.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from kernels import _arrays as A
from kernels import stereo
from research.images import unit_grey_pair, unit_pair
from research.io import linear_to_srgb

COSTS = ("sad", "zncc", "census", "bt", "adcensus", "corr")
AGGREGATIONS = ("none", "sgm4", "sgm8")
DISPARITY_METHODS = ("wta", "soft_argmin")
BAD_THRESHOLDS = (1.0, 2.0, 3.0)


def to_gray_u8(rgba: np.ndarray) -> np.ndarray:
    """Linear premultiplied RGB(A) -> 8-bit sRGB-encoded luminance (Rec. 709 weights), as a camera stores it."""
    rgb = np.asarray(rgba, dtype=np.float64)[..., :3]
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    return np.floor(np.clip(linear_to_srgb(lum), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def patch_features(img: np.ndarray, radius: int, floor: float = 1e-2) -> np.ndarray:
    """Zero-mean, unit-norm (2r+1)^2 patches as features (C, H, W) (see the module docstring)."""
    pad = np.pad(np.asarray(img, dtype=np.float32), radius, mode="edge")
    win = sliding_window_view(pad, (2 * radius + 1, 2 * radius + 1))  # (H, W, k, k)
    f = win.reshape(*img.shape, -1)
    f = f - f.mean(axis=-1, keepdims=True)
    f = f / (np.linalg.norm(f, axis=-1, keepdims=True) + floor)
    return np.ascontiguousarray(np.moveaxis(f, -1, 0))


@dataclass(frozen=True)
class StereoConfig:
    cost: str = "census"
    aggregation: str = "sgm8"
    p1: float = 8.0
    p2: float = 64.0
    radius: int = 2  # window radius of SAD / ZNCC / BT / patch features
    census_radii: tuple[int, int] = (3, 4)  # (ry, rx): a 7x9 window, 62 bits
    zncc_eps: float = 1e-4
    disparity: str = "wta"
    temperature: float = 1.0  # soft-argmin only
    uniqueness: float = 0.0
    lr_check: bool = True
    lr_max_diff: float = 1.0
    grad_cap: float = 0.25  # adcensus: the x-gradient clip, [0, 1] intensity units
    lambda_census: float = 30.0  # adcensus: bits
    lambda_grad: float = 0.04  # adcensus: units of the clipped gradient image G in [0, 1]
    bt_weight: float = 0.0  # adcensus: weight of the intensity BT term (0: none)
    lambda_bt: float = 0.04  # adcensus: [0, 1] intensity units
    census_eps: float = 0.0  # adcensus: census tolerance, bit [I(q) < I(p) - eps], [0, 1] intensity units
    border_invalid: bool = False
    median: int = 0  # 0: none; else an odd size >= 3
    fast_compact: bool = False  # adcensus + SGM: compact mode at every size, vector rho (module docstring: Memory)

    def __post_init__(self) -> None:
        for name, value, allowed in (("cost", self.cost, COSTS), ("aggregation", self.aggregation, AGGREGATIONS),
                                     ("disparity", self.disparity, DISPARITY_METHODS)):
            if value not in allowed:
                raise ValueError(f"{name}: expected one of {allowed}, got {value!r}")
        for name in ("p1", "p2", "zncc_eps", "temperature", "uniqueness", "lr_max_diff", "grad_cap", "lambda_census",
                     "lambda_grad", "bt_weight", "lambda_bt", "census_eps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
                raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
        if self.p2 < self.p1:
            raise ValueError(f"p2: expected p2 >= p1 = {self.p1}, got {self.p2}")
        if self.temperature <= 0:
            raise ValueError(f"temperature: expected a finite number > 0, got {self.temperature!r}")
        A.check_int("radius", self.radius, minimum=0)
        for name in ("grad_cap", "lambda_census", "lambda_grad", "lambda_bt"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: expected a finite number > 0, got {getattr(self, name)!r}")
        for name in ("border_invalid", "fast_compact"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name}: expected True or False, got {getattr(self, name)!r}")
        if isinstance(self.median, bool) or not isinstance(self.median, (int, np.integer)) or \
                not (self.median == 0 or (self.median >= 3 and self.median % 2 == 1)):
            raise ValueError(f"median: expected 0 (off) or an odd size >= 3, got {self.median!r}")

    @property
    def label(self) -> str:
        agg = {"none": "WTA", "sgm4": "SGM-4", "sgm8": "SGM-8"}[self.aggregation]
        cost = {"sad": "SAD", "zncc": "ZNCC", "census": "census", "bt": "BT", "adcensus": "census+grad",
                "corr": "corr (patch feat.)"}[self.cost]
        if self.cost == "adcensus" and self.bt_weight > 0:
            cost += "+BT"
        tail = " soft-argmin" if self.disparity == "soft_argmin" else ""
        post = [p for p, on in (("border", self.border_invalid), (f"median {self.median}", self.median)) if on]
        return f"{cost} + {agg}{tail}" + (f" ({', '.join(post)})" if post else "")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# drlab's default configuration (module docstring: which data chose it).
DEFAULT_CONFIG = StereoConfig(cost="adcensus", aggregation="sgm8", p1=0.8, p2=6.4, radius=2, census_radii=(3, 4),
                              grad_cap=0.25, lambda_census=30.0, lambda_grad=0.04, bt_weight=0.3, lambda_bt=0.04,
                              border_invalid=True, median=3)
# The same pipeline in compact mode at every size, with the vector rho (module docstring).
FAST_DEFAULT_CONFIG = replace(DEFAULT_CONFIG, fast_compact=True)


@dataclass
class StereoResult:
    disparity: np.ndarray  # (H, W) float32
    valid: np.ndarray  # (H, W) bool
    timings: dict[str, float]  # cost_s, aggregate_s, disparity_s, total_s


def cost_volume(left: np.ndarray, right: np.ndarray, dmin: int, dmax: int, cfg: StereoConfig,
                device: str = "cpu") -> Any:
    """The matching cost (H, W, D) of `cfg.cost`, as a wp.array on `device` (lower is better).

    `left`, `right`: uint8, uint16 or float in [0, 1], grey or colour (module docstring: Images).
    """
    import warp as wp

    if cfg.cost == "bt":
        _check_range_args(dmin, dmax)
        l_img, r_img = (wp.array(x, device=device) for x in unit_pair(left, right))
        return stereo.bt_cost(l_img, r_img, dmin, dmax, cfg.radius, device=device)
    if cfg.cost == "adcensus":
        _check_range_args(dmin, dmax)
        colour = unit_pair(left, right)
        grey = tuple(wp.array(x, device=device) for x in unit_grey_pair(left, right))
        l_img, r_img = (wp.array(x, device=device) for x in colour)
        levels = stereo.compact_levels(cfg.bt_weight) if uses_compact(cfg, *grey[0].shape, dmax - dmin) else 0
        vector_rho = bool(levels) and cfg.fast_compact and l_img.device.is_cpu
        return stereo.adcensus_cost(l_img, r_img, dmin, dmax, grey=grey if colour[0].ndim == 3 else None,
                                    census_radii=cfg.census_radii, radius=cfg.radius, grad_cap=cfg.grad_cap,
                                    lambda_census=cfg.lambda_census, lambda_grad=cfg.lambda_grad,
                                    bt_weight=cfg.bt_weight, lambda_bt=cfg.lambda_bt, census_eps=cfg.census_eps,
                                    levels=levels, vector_rho=vector_rho, device=device)
    left, right = unit_grey_pair(left, right)
    _check_range_args(dmin, dmax)
    if cfg.cost == "corr":
        fl, fr = (wp.array(patch_features(x, cfg.radius), device=device) for x in (left, right))
        corr = stereo.feature_correlation(fl, fr, dmin, dmax, device=device)
        return wp.array(-corr.numpy(), device=device)
    l_img, r_img = (wp.array(np.ascontiguousarray(x, dtype=np.float32), device=device) for x in (left, right))
    if cfg.cost == "sad":
        return stereo.sad_cost(l_img, r_img, dmin, dmax, cfg.radius, device=device)
    if cfg.cost == "zncc":
        return stereo.zncc_cost(l_img, r_img, dmin, dmax, cfg.radius, eps=cfg.zncc_eps, device=device)
    compact = uses_compact(cfg, *left.shape, dmax - dmin)
    return stereo.census_cost(l_img, r_img, dmin, dmax, *cfg.census_radii, compact=compact, device=device)


# Above this many bytes of float32 volumes, "adcensus" + SGM runs in compact mode (`uses_compact`).
FLOAT_VOLUME_BUDGET = 2**30


def compact_penalties(cfg: StereoConfig) -> tuple[int, int]:
    """P1, P2 of an "adcensus" configuration in units of its compact cost (kernels.stereo.adcensus: the uint8
    round(C q), q = compact_levels(bt_weight)): round(P q). DEFAULT_CONFIG: q = 110, 0.8 -> 88, 6.4 -> 704."""
    q = stereo.compact_levels(cfg.bt_weight)
    return int(round(cfg.p1 * q)), int(round(cfg.p2 * q))


def uses_compact(cfg: StereoConfig, height: int, width: int, disparities: int) -> bool:
    """Whether `match` runs `cfg` in kernels.stereo's compact mode: uint8 costs and a uint16 SGM aggregate
    (3 bytes per cell instead of float32's 8), for SGM + winner-take-all with D a multiple of 8 and P2
    within the uint8 volume's bound (kernels.stereo.sgm: P2 <= 7936, in cost units):
      * census with integer P1 and P2, at every size: the same results as the float32 pipeline, exactly,
        and on the CPU the faster path (compact SGM runs in int16 vectors, kernels.stereo.sweep);
      * "adcensus" with `fast_compact` (FAST_DEFAULT_CONFIG) at every size, the others once its float32 volumes would
        exceed FLOAT_VOLUME_BUDGET: its cost quantised to uint8
        with step 1 / q (q = compact_levels(bt_weight), 110 for DEFAULT_CONFIG: at most 0.0045 off,
        against terms in [0, 1)) and P1, P2 rounded to that step (`compact_penalties`); not
        bit-identical, D1 unchanged within noise (held-out teddy + cones D1 0.0774 either way); without `fast_compact` it is kept for
        sizes where memory runs out (Middlebury at half resolution, 1482x994x256). On the CPU `fast_compact`
        computes the cost with the vector rho (kernels.stereo.adcensus), a level off in rare cells."""
    if cfg.cost not in ("census", "adcensus") or cfg.aggregation == "none" or cfg.disparity != "wta" or \
            disparities % 8:
        return False
    if cfg.cost == "census":
        return cfg.p1 == int(cfg.p1) and cfg.p2 == int(cfg.p2) and cfg.p2 <= 7936
    return compact_penalties(cfg)[1] <= 7936 and (cfg.fast_compact or
                                                  8 * int(height) * int(width) * int(disparities) > FLOAT_VOLUME_BUDGET)


def peak_volume_bytes(cfg: StereoConfig, height: int, width: int, disparities: int) -> int:
    """The bytes of the (H, W, D) volumes `match` holds at once for `cfg` on the CPU: the cost volume and
    SGM's aggregate (plus SGM's padded copies when D is not a multiple of its vector width, 16 float32 or
    32 uint8 lanes), in float32 or compact mode (the adcensus kernel's band buffers, 2 (2 r + 2) W D values
    per band, are not counted)."""
    cells = int(height) * int(width) * int(disparities)
    if cfg.aggregation == "none":
        return 4 * cells
    if uses_compact(cfg, height, width, disparities):
        # uint8 costs + the uint16 aggregate padded to whole 32-lane vectors (+ the padded uint8 copy)
        padded = int(height) * int(width) * (-(-int(disparities) // 32) * 32)
        return cells + 2 * padded + (padded if padded != cells else 0)
    padded = int(height) * int(width) * (-(-int(disparities) // 16) * 16)
    return 4 * (2 * cells + (2 * padded if padded != cells else 0))


def _check_range_args(dmin: Any, dmax: Any) -> None:
    if isinstance(dmin, bool) or isinstance(dmax, bool) or not all(isinstance(d, (int, np.integer))
                                                                   for d in (dmin, dmax)):
        raise ValueError(f"dmin, dmax: expected integers, got {dmin!r} and {dmax!r}")
    if not dmin <= dmax:
        raise ValueError(f"dmax: expected dmax >= dmin = {dmin}, got {dmax}")


def disparity_from_cost(cost: Any, dmin: int, cfg: StereoConfig, device: str = "cpu") -> StereoResult:
    """Aggregate a cost volume (wp.array), then extract the disparity as `cfg` says; timed (no cost_s).
    A compact (uint8) "adcensus" volume takes `cfg`'s penalties in its units (`compact_penalties`)."""
    import warp as wp

    if cfg.cost == "adcensus" and cost.dtype == wp.uint8:
        p1, p2 = compact_penalties(cfg)
        cfg = replace(cfg, p1=float(p1), p2=float(p2))
    t0 = time.perf_counter()
    # SGM + winner-take-all: SGM, both views' winners and the left-right check in one call
    # (kernels.stereo.sgm_disparity, the same numbers as the separate calls below); aggregate_s covers it all.
    fused = cfg.aggregation != "none" and cfg.disparity == "wta"
    if fused:
        disp, valid = stereo.sgm_disparity(cost, dmin, cfg.p1, cfg.p2, int(cfg.aggregation[3:]),
                                           uniqueness=cfg.uniqueness,
                                           lr_max_diff=cfg.lr_max_diff if cfg.lr_check else None, device=device)
        wp.synchronize_device(device)
    elif cfg.aggregation != "none":
        cost = stereo.sgm(cost, cfg.p1, cfg.p2, paths=int(cfg.aggregation[3:]), device=device)
        wp.synchronize_device(device)
    t1 = time.perf_counter()
    if fused:
        pass
    elif cfg.disparity == "soft_argmin":
        disp = stereo.soft_argmin(cost, dmin, cfg.temperature, device=device)
        valid = wp.ones(disp.shape, dtype=wp.uint8, device=device)
        if cfg.lr_check:
            disp_r, valid_r = stereo.wta_right(cost, dmin, device=device)
    elif cfg.lr_check:  # both views' winners in one pass over the volume
        disp, valid, disp_r, valid_r = stereo.wta_left_right(cost, dmin, uniqueness=cfg.uniqueness, device=device)
    else:
        disp, valid = stereo.wta(cost, dmin, uniqueness=cfg.uniqueness, device=device)
    if cfg.lr_check and not fused:
        valid = stereo.left_right_check(disp, disp_r, cfg.lr_max_diff, valid_left=valid, valid_right=valid_r,
                                        device=device)
    disp_np, valid_np = disp.numpy().astype(np.float32), valid.numpy().astype(bool)
    disp_np, valid_np = post_process(disp_np, valid_np, dmin + int(cost.shape[2]), cfg)
    t2 = time.perf_counter()
    return StereoResult(disp_np, valid_np, {"aggregate_s": t1 - t0, "disparity_s": t2 - t1, "total_s": t2 - t0})


def post_process(disp: np.ndarray, valid: np.ndarray, dmax: int, cfg: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """`cfg`'s border invalidation and median filter (module docstring: Post-processing)."""
    H, W = valid.shape
    k = min(int(dmax) - 1, W)
    if cfg.border_invalid and k > 0:
        valid = valid.copy()
        if k < W:
            band = valid[:, k:]
            first = np.argmax(band, axis=1) + k
            d_b = np.where(band.any(axis=1), disp[np.arange(H), first], -np.inf)
            valid[:, :k] &= ~(np.arange(k)[None, :] < d_b[:, None] + 1.0)
        else:
            valid[:, :] = False
    if cfg.median == 3:  # kernels.stereo.post: the same fill and median, exactly, in one row pass and one pixel pass
        disp = np.asarray(stereo.fill_median3(np.ascontiguousarray(disp, dtype=np.float32), valid), dtype=np.float32)
    elif cfg.median:
        from scipy.ndimage import median_filter

        disp = median_filter(fill_invalid(disp, valid), size=cfg.median, mode="nearest").astype(np.float32)
    return disp, valid


def match(left: np.ndarray, right: np.ndarray, dmin: int, dmax: int, cfg: StereoConfig | None = None,
          device: str = "cpu") -> StereoResult:
    """Run the pipeline of `cfg` (None: DEFAULT_CONFIG) on one image pair; each phase is timed.

    `left`, `right`: uint8, uint16 or float in [0, 1], grey (H, W) or colour (H, W, 3), normalised
    by research.images.to_unit_grey; the penalties of `cfg` assume that [0, 1] range (module docstring).
    """
    import warp as wp

    cfg = DEFAULT_CONFIG if cfg is None else cfg
    t0 = time.perf_counter()
    cost = cost_volume(left, right, dmin, dmax, cfg, device)
    wp.synchronize_device(device)
    cost_s = time.perf_counter() - t0
    out = disparity_from_cost(cost, dmin, cfg, device)
    out.timings = {"cost_s": cost_s, **out.timings, "total_s": cost_s + out.timings["total_s"]}
    return out


# --------------------------------------------------------------------------- evaluation


def fill_invalid(disp: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """KITTI devkit's background interpolation along rows (module docstring); rows with no valid pixel get 0."""
    disp = np.asarray(disp, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    if disp.shape != valid.shape or disp.ndim != 2:
        raise ValueError(f"disp, valid: expected two (H, W) arrays of one shape, got {disp.shape} and {valid.shape}")
    H, W = disp.shape
    cols = np.broadcast_to(np.arange(W), (H, W))
    # Index of the nearest valid pixel to the left / right (-1 / W where there is none).
    left_idx = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    right_idx = np.minimum.accumulate(np.where(valid, cols, W)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(H)[:, None]
    left_val = np.where(left_idx >= 0, disp[rows, np.clip(left_idx, 0, W - 1)], np.inf)
    right_val = np.where(right_idx < W, disp[rows, np.clip(right_idx, 0, W - 1)], np.inf)
    filled = np.minimum(left_val, right_val)
    filled = np.where(np.isfinite(filled), filled, 0.0)
    return np.where(valid, disp, filled)


def disparity_metrics(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """EPE, bad-1/2/3 and D1 over `mask` (module docstring); `pred` must already be dense."""
    pred, gt, mask = np.asarray(pred, np.float64), np.asarray(gt, np.float64), np.asarray(mask, bool)
    if not (pred.shape == gt.shape == mask.shape):
        raise ValueError(f"pred, gt, mask: shapes differ ({pred.shape}, {gt.shape}, {mask.shape})")
    if not mask.any():
        raise ValueError("mask: selects no pixel")
    if not (np.all(np.isfinite(pred[mask])) and np.all(np.isfinite(gt[mask]))):
        raise ValueError("pred, gt: non-finite values inside the mask")
    err = np.abs(pred[mask] - gt[mask])
    out = {"epe": float(err.mean())}
    for k in BAD_THRESHOLDS:
        out[f"bad{k:g}"] = float(np.mean(err > k))
    out["d1"] = float(np.mean((err > 3.0) & (err > 0.05 * gt[mask])))
    out["pixels"] = int(mask.sum())
    return out


def depth_abs_rel(pred_disp: np.ndarray, gt_depth: np.ndarray, mask: np.ndarray, focal: float,
                  baseline: float) -> dict[str, float]:
    """Mean |Z - Z_gt| / Z_gt over mask pixels with a valid estimated depth, and their fraction of the mask."""
    depth, ok = stereo.depth_from_disparity(np.asarray(pred_disp, np.float64), focal, baseline)
    sel = np.asarray(mask, bool) & ok & (gt_depth > 0)
    rel = np.abs(depth[sel] - gt_depth[sel]) / gt_depth[sel]
    return {"abs_rel": float(rel.mean()) if sel.any() else float("nan"),
            "depth_valid_fraction": float(sel.sum() / max(int(np.sum(mask)), 1))}


def evaluate(disp: np.ndarray, valid: np.ndarray, gt: np.ndarray, masks: dict[str, np.ndarray],
             gt_depth: np.ndarray, focal: float, baseline: float) -> dict[str, dict[str, float]]:
    """Fill, then score over each named mask: {mask name: metrics + abs_rel + density}."""
    dense = fill_invalid(disp, valid)
    out = {}
    for name, m in masks.items():
        row = disparity_metrics(dense, gt, m)
        row.update(depth_abs_rel(dense, gt_depth, m, focal, baseline))
        row["density"] = float(np.mean(np.asarray(valid, bool)[m]))
        out[name] = row
    return out


# --------------------------------------------------------------------------- benchmark protocols
#
# Each benchmark's own measures, over masks at the resolution evaluated, on a dense estimate (invalid
# pixels filled by `fill_invalid` first, as above, for every benchmark alike), e = |d - d_gt|:
#   * Middlebury 2014/2021: bad-0.5, bad-1, bad-2, bad-4 (fraction of the mask with e > t px) and
#     avgerr (mean e), on the "nonocc" and "all" masks;
#   * ETH3D two-view: bad-1, bad-2 and avgerr on the same two masks;
#   * Middlebury 2001/2003 (tsukuba, venus, teddy, cones; no occlusion masks): bad-0.5/1/2/4, avgerr
#     (= EPE, the mean |e|) and D1 over the one mask "all" of every pixel with known ground truth;
#   * KITTI 2012/2015: D1 (e > 3 px AND e > 5 % of d_gt) over background, foreground and all pixels,
#     on "noc" (disp_noc) and "occ" (disp_occ); bg/fg only where an object map marks the foreground.
# `protocol_metrics` returns, per mask, each measure and the pixel count it is a fraction or mean of,
# so that `pool_protocol` can pool pairs exactly: over pixels for KITTI (its devkit sums error and
# pixel counts over images), and as the mean over images for Middlebury and ETH3D (their tables
# average per-image scores; here with equal weights). A subset with no pixel gives NaN.

PROTOCOLS = {
    "middlebury": {"masks": ("nonocc", "all"), "thresholds": (0.5, 1.0, 2.0, 4.0)},
    "eth3d": {"masks": ("nonocc", "all"), "thresholds": (1.0, 2.0)},
    "kitti": {"masks": ("noc", "occ"), "thresholds": ()},
    "middlebury2003": {"masks": ("all",), "thresholds": (0.5, 1.0, 2.0, 4.0)},
}


def _checked_inputs(pred: np.ndarray, gt: np.ndarray, *masks: np.ndarray) -> tuple[np.ndarray, ...]:
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    masks = tuple(np.asarray(m, bool) for m in masks)
    if pred.ndim != 2 or any(x.shape != pred.shape for x in (gt, *masks)):
        raise ValueError(f"pred, gt, masks: expected (H, W) arrays of one shape, got "
                         f"{[x.shape for x in (pred, gt, *masks)]}")
    sel = np.logical_or.reduce(masks) if masks else np.ones(pred.shape, bool)
    if not (np.all(np.isfinite(pred[sel])) and np.all(np.isfinite(gt[sel]))):
        raise ValueError("pred, gt: non-finite values inside the mask (fill the estimate first)")
    return (pred, gt, *masks)


def bad_pixel_metrics(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray,
                      thresholds: tuple[float, ...]) -> dict[str, float]:
    """bad-t for each t (fraction of `mask` with |pred - gt| > t px), avgerr (mean error) and the pixel count."""
    pred, gt, mask = _checked_inputs(pred, gt, mask)
    err = np.abs(pred[mask] - gt[mask])
    n = int(err.size)
    out = {f"bad{t:g}": (float(np.mean(err > t)) if n else float("nan")) for t in thresholds}
    out["avgerr"] = float(err.mean()) if n else float("nan")
    out["pixels"] = n
    return out


def d1_outliers(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """KITTI's outlier map: |pred - gt| > 3 px AND > 5 % of gt."""
    err = np.abs(np.asarray(pred, np.float64) - np.asarray(gt, np.float64))
    return (err > 3.0) & (err > 0.05 * np.abs(np.asarray(gt, np.float64)))


def kitti_d1(pred: np.ndarray, gt: np.ndarray, noc: np.ndarray, occ: np.ndarray,
             foreground: np.ndarray | None = None) -> dict[str, dict[str, float]]:
    """D1-bg / D1-fg / D1-all on the noc and occ masks ({"noc": {...}, "occ": {...}}); bg/fg need `foreground`."""
    pred, gt, noc, occ = _checked_inputs(pred, gt, noc, occ)
    fg = None if foreground is None else np.asarray(foreground, bool)
    if fg is not None and fg.shape != pred.shape:
        raise ValueError(f"foreground: expected shape {pred.shape}, got {fg.shape}")
    out = np.zeros(pred.shape, bool)
    sel = noc | occ
    out[sel] = d1_outliers(pred[sel], gt[sel])
    res = {}
    for name, m in (("noc", noc), ("occ", occ)):
        parts = {"all": m} if fg is None else {"bg": m & ~fg, "fg": m & fg, "all": m}
        row: dict[str, float] = {}
        for part, pm in parts.items():
            n = int(pm.sum())
            row[f"d1_{part}"] = float(out[pm].mean()) if n else float("nan")
            row[f"pixels_{part}"] = n
        row["pixels"] = row["pixels_all"]
        res[name] = row
    return res


def protocol_metrics(protocol: str, disp: np.ndarray, valid: np.ndarray, gt: np.ndarray, noc: np.ndarray,
                     all_mask: np.ndarray, foreground: np.ndarray | None = None) -> dict[str, dict[str, float]]:
    """One pair's scores under a benchmark `protocol` (block comment above), after the KITTI fill.

    `noc`, `all_mask`: the non-occluded and the all-ground-truth masks (KITTI: disp_noc, disp_occ).
    Each mask's row also has `density`, the fraction of it the method estimated itself.
    """
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol: expected one of {tuple(PROTOCOLS)}, got {protocol!r}")
    dense = fill_invalid(disp, valid)
    valid = np.asarray(valid, bool)
    names = PROTOCOLS[protocol]["masks"]
    masks = (all_mask,) if protocol == "middlebury2003" else (noc, all_mask)
    if protocol == "kitti":
        out = kitti_d1(dense, gt, noc, all_mask, foreground)
    else:
        out = {name: bad_pixel_metrics(dense, gt, m, PROTOCOLS[protocol]["thresholds"])
               for name, m in zip(names, masks)}
    if protocol == "middlebury2003":
        m = np.asarray(all_mask, bool)
        out["all"]["d1"] = float(d1_outliers(dense[m], gt[m]).mean()) if m.any() else float("nan")
    for name, m in zip(names, masks):
        m = np.asarray(m, bool)
        out[name]["density"] = float(valid[m].mean()) if m.any() else float("nan")
    return out


def pool_protocol(protocol: str, rows: list[dict[str, dict[str, float]]]) -> dict[str, dict[str, float]]:
    """Pairs' `protocol_metrics` pooled as the benchmark does (block comment above); NaN rows are skipped."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol: expected one of {tuple(PROTOCOLS)}, got {protocol!r}")
    if not rows:
        raise ValueError("rows: expected the scores of at least one pair")
    out: dict[str, dict[str, float]] = {}
    for name in PROTOCOLS[protocol]["masks"]:
        keys = [k for k in rows[0][name] if not k.startswith("pixels")]
        pooled: dict[str, float] = {}
        for k in keys:
            vals = np.array([r[name][k] for r in rows], dtype=np.float64)
            if protocol == "kitti":
                part = k[3:] if k.startswith("d1_") else "all"
                w = np.array([r[name][f"pixels_{part}"] for r in rows], dtype=np.float64)
            else:
                w = np.array([1.0 if r[name]["pixels"] > 0 else 0.0 for r in rows])
            ok = np.isfinite(vals) & (w > 0)
            pooled[k] = float(np.sum(w[ok] * vals[ok]) / np.sum(w[ok])) if ok.any() else float("nan")
        pooled["pixels"] = int(sum(r[name]["pixels"] for r in rows))
        out[name] = pooled
    return out
