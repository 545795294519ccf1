#!/usr/bin/env python3
"""drlab's kernels against their second oracle, Dr.Jit's AD (research/oracles), at full size.

Every kernel family's forward is written again in Dr.Jit (LLVM backend, its own reverse-mode AD)
from the equations in the kernel modules' docstrings; the splat chain follows the original 3DGS
code. For random inputs, each case compares drlab's forward and its hand-written backward (the VJP
for a random cotangent) with the oracle's, in float64 and in float32 (drlab float32 against the
oracle float32, and against the oracle float64), at the sizes the kernels run at:

  * ssim          a 256x256x3 image pair (map, d/dx, d/dy);
  * stereo        SAD (r 2) and ZNCC (r 3) volumes 256x256x64; feature correlation 32 channels,
                  256x256x64 (volume, d features); soft-argmin over a 256x256x64 volume (disparity,
                  d cost);
  * corr          a RAFT pyramid at 46x62 (1/8 of 368x496), 64 channels, 4 levels, radius 4:
                  dense (volume, pyramid, lookup) and on-the-fly paths (lookup, d f1, d f2, d coords);
  * volume        a dense grid of 64^3 vertices with SH degree 2 colour at 65,536 points (sigma,
                  rgb, d density, d colour); a hash-grid field (16 levels, 2^19 entries, finest level
                  128^3, MLP 32-64-64-4) at 65,536 points (sigma, rgb, d of every parameter); the
                  renderer's camera gradients: 128x128 pixel rays x 64 fixed samples through a 32^3
                  grid with SH degree 2 colour, early termination at T < 0.01 (rgb, depth, opacity,
                  d pose xi (6) and d intrinsics (4), kernels/volume/rays.py);
  * splat         3,000 Gaussians (SH degree 3) rendered at 256x256 in the default ("3dgs") mode
                  (rgb, alpha, depth, d means, log-scales, quaternions, opacity logits, SH, background,
                  and the camera's pose (6) and intrinsics (4)).
  * points        the chamfer distance of two 4,096-point clouds (value, d x, d y; kernels/points/chamfer.py),
                  the oracle by brute force over all pairs.

Differences are normwise: max |drlab - oracle| over all outputs of a kind, and that divided by the
oracle's largest value of the same outputs (the "rel" columns). Times: one call each (the oracle's
includes Dr.Jit's tracing and, on the first run on a machine, its LLVM compilation; drlab's kernels
are loaded from Warp's cache after a warm-up call).

Writes results/oracle_conformance/{table.md, metrics.json, figure.png}.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from research.experiment import Context, Experiment
from research.results import markdown_table, save_figure

# Sizes per mode: full (the default), quick and smoke.
SIZES = {
    "full": dict(img=256, disp=64, feat=32, corr=(64, 46, 62, 4, 4), grid=64, points=65536, hash_log2=19,
                 hash_max=128, splats=3000, splat_px=256, ray_px=128, ray_samples=64, ray_grid=32),
    "quick": dict(img=128, disp=32, feat=16, corr=(32, 23, 31, 3, 3), grid=32, points=8192, hash_log2=16,
                  hash_max=64, splats=600, splat_px=128, ray_px=64, ray_samples=32, ray_grid=16),
    "smoke": dict(img=24, disp=8, feat=4, corr=(4, 8, 10, 2, 1), grid=6, points=200, hash_log2=10, hash_max=16,
                  splats=30, splat_px=32, ray_px=8, ray_samples=8, ray_grid=4),
}


class _Rounded:
    """A NumPy generator whose draws are float64 arrays holding float32 values, so that the float64 and
    float32 runs of a case see the same inputs and one float64 oracle run serves both comparisons."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def uniform(self, *args, **kwargs) -> np.ndarray:
        return np.asarray(self.rng.uniform(*args, **kwargs)).astype(np.float32).astype(np.float64)

    def normal(self, *args, **kwargs) -> np.ndarray:
        return np.asarray(self.rng.normal(*args, **kwargs)).astype(np.float32).astype(np.float64)


def _diff(pairs: list[tuple[Any, Any]]) -> tuple[float, float]:
    """(max |a - b|, that / max |b|) over the pairs (drlab, oracle)."""
    d = max(float(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)))) for a, b in pairs)
    s = max(float(np.max(np.abs(np.asarray(b, np.float64)))) for _, b in pairs)
    return d, d / s if s > 0 else d


def _timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


# --------------------------------------------------------------------------- cases
# Each case(dtype, sizes, seed) returns (size text, drlab (fwd list, vjp list), oracle (fwd, vjp), times).


def case_ssim(dt, S, seed):
    from kernels import ssim as kssim
    from research.oracles.ssim import ssim_oracle

    rng = _Rounded(seed)
    shape = (S["img"], S["img"], 3)
    y = rng.uniform(0, 1, shape)
    x = np.clip(y + rng.normal(0, 0.1, shape), 0, 1)
    g = rng.normal(size=shape)

    def drlab(t):
        st = kssim.ssim_map(x.astype(t), y.astype(t))
        return [st.map], list(kssim.ssim_map_backward(st, g.astype(t)))

    def oracle(t):
        m, (gx, gy) = ssim_oracle(x.astype(dt).astype(t), y.astype(dt).astype(t), g.astype(dt).astype(t))
        return [m], [gx, gy]

    return f"{shape[0]}x{shape[1]}x3", drlab, oracle


def case_window_cost(kind):
    def case(dt, S, seed):
        from kernels import stereo as kst
        from research.oracles.stereo import window_cost_oracle

        rng = _Rounded(seed)
        n, D = S["img"], S["disp"]
        left = rng.uniform(0, 1, (n, n))
        right = np.roll(left, -5, axis=1) + rng.normal(0, 0.05, (n, n))
        r = 2 if kind == "sad" else 3
        fn = kst.sad_cost if kind == "sad" else kst.zncc_cost

        def drlab(t):
            return [fn(left.astype(t), right.astype(t), 0, D, r)], []

        def oracle(t):
            return [window_cost_oracle(left.astype(dt).astype(t), right.astype(dt).astype(t), 0, D, r, kind)], []

        return f"{n}x{n}x{D}, r {r}", drlab, oracle
    return case


def case_feature_corr(dt, S, seed):
    from kernels import stereo as kst
    from research.oracles.stereo import feature_correlation_oracle

    rng = _Rounded(seed)
    n, D, C = S["img"], S["disp"], S["feat"]
    fl, fr, g = rng.normal(size=(C, n, n)), rng.normal(size=(C, n, n)), rng.normal(size=(n, n, D))

    def drlab(t):
        b = kst.feature_correlation_backward(fl.astype(t), fr.astype(t), g.astype(t), -2)
        return [kst.feature_correlation(fl.astype(t), fr.astype(t), -2, D - 2)], [b["feat_left"], b["feat_right"]]

    def oracle(t):
        c, (a, b) = feature_correlation_oracle(*(v.astype(dt).astype(t) for v in (fl, fr)), -2, D - 2,
                                               g.astype(dt).astype(t))
        return [c], [a, b]

    return f"C {C}, {n}x{n}x{D}", drlab, oracle


def case_soft_argmin(dt, S, seed):
    from kernels import stereo as kst
    from research.oracles.stereo import soft_argmin_oracle

    rng = _Rounded(seed)
    n, D = S["img"], S["disp"]
    cost, g = rng.uniform(0, 3, (n, n, D)), rng.normal(size=(n, n))

    def drlab(t):
        return [kst.soft_argmin(cost.astype(t), -1, 0.5)], [kst.soft_argmin_backward(cost.astype(t), -1, g.astype(t),
                                                                                       0.5)["cost"]]

    def oracle(t):
        d, gc = soft_argmin_oracle(cost.astype(dt).astype(t), -1, g.astype(dt).astype(t), 0.5)
        return [d], [gc]

    return f"{n}x{n}x{D}, T 0.5", drlab, oracle


def case_corr(path):
    def case(dt, S, seed):
        from kernels import corr
        from research.oracles.corr import lookup_oracle

        C, H, W, L, r = S["corr"]
        rng = _Rounded(seed)
        f1, f2 = rng.normal(size=(C, H, W)), rng.normal(size=(C, H, W))
        coords = np.stack([rng.uniform(-4, W + 4, (H, W)), rng.uniform(-4, H + 4, (H, W))])
        g = rng.normal(size=(L * (2 * r + 1) ** 2, H, W))

        def drlab(t):
            a, b, c, gg = (v.astype(t) for v in (f1, f2, coords, g))
            if path == "dense":
                pyr = corr.correlation_pyramid(corr.correlation_volume(a, b), L)
                out = corr.lookup(pyr, c, r)
                lb = corr.lookup_backward(pyr, c, r, gg)
                fg = corr.correlation_volume_backward(a, b, next(iter(corr.correlation_pyramid_backward(
                    lb["pyramid"]).values())))
                return [out], [fg["f1"], fg["f2"], lb["coords"]]
            fp = corr.pool_features(b, L)
            out = corr.lookup_onthefly(a, fp, c, r)
            bk = corr.lookup_onthefly_backward(a, fp, c, r, gg)
            f2g = next(iter(corr.pool_features_backward(bk["f2_pyramid"]).values()))
            return [out], [bk["f1"], f2g, bk["coords"]]

        def oracle(t):
            out, gr = lookup_oracle(*(v.astype(dt).astype(t) for v in (f1, f2, coords)), L, r, g.astype(dt).astype(t))
            return [out], [gr["f1"], gr["f2"], gr["coords"]]

        return f"{H}x{W}, C {C}, {L} levels, r {r}", drlab, oracle
    return case


BBOX = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def case_grid(dt, S, seed):
    import warp as wp

    from kernels.volume import GridField
    from research.oracles.volume import grid_field_oracle

    rng = _Rounded(seed)
    res = (S["grid"],) * 3
    nv, N = S["grid"] ** 3, S["points"]
    density, color = rng.normal(size=nv), rng.normal(size=(nv, 27))
    pts = rng.uniform(-1.05, 1.05, (N, 3))
    d = rng.normal(size=(N, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    gs, gr = rng.normal(size=N), rng.normal(size=(N, 3))

    def drlab(t):
        f = GridField(BBOX, res, sh_degree=2, density_bias=-1.0, density_scale=3.0,
                      dtype=wp.float32 if t == np.float32 else wp.float64)
        f.set_params({"density": density.astype(t), "color": color.astype(t)})
        out = f.forward(pts.astype(t), d.astype(t))
        gg = f.backward(pts.astype(t), d.astype(t), out, gs.astype(t), gr.astype(t))
        return [out.sigma, out.rgb], [gg["density"].numpy(), gg["color"].numpy()]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        (s, rgb), g = grid_field_oracle(c(pts), c(d), c(density), c(color), BBOX, res, 2, -1.0, 3.0, "softplus",
                                         c(gs), c(gr))
        return [s, rgb], [g["density"], g["color"]]

    return f"{S['grid']}^3 vertices, SH 2, {N} points", drlab, oracle


def case_hashgrid(dt, S, seed):
    import warp as wp

    from kernels.volume import HashGridField
    from research.oracles.volume import hashgrid_field_oracle

    rng = _Rounded(seed)
    N = S["points"]
    pts = rng.uniform(-1.02, 1.02, (N, 3))
    gs, gr = rng.normal(size=N), rng.normal(size=(N, 3))
    kw = dict(n_levels=16, n_features=2, log2_table_size=S["hash_log2"], base_resolution=16,
              max_resolution=S["hash_max"], hidden=(64, 64), density_bias=-1.0)
    proto = HashGridField(BBOX, **kw, dtype=wp.float64)
    params = {k: v.numpy() for k, v in proto.params.items()}
    params["table"] = rng.uniform(-1, 1, params["table"].shape)

    def drlab(t):
        f = HashGridField(BBOX, **kw, dtype=wp.float32 if t == np.float32 else wp.float64)
        f.set_params({k: v.astype(t) for k, v in params.items()})
        out = f.forward(pts.astype(t))
        gg = f.backward(pts.astype(t), None, out, gs.astype(t), gr.astype(t))
        return [out.sigma, out.rgb], [gg[k].numpy() for k in sorted(gg)]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        (s, rgb), g = hashgrid_field_oracle(c(pts), {k: c(v) for k, v in params.items()}, BBOX,
                                            proto.encoding.resolutions, proto.encoding.table_size, proto.sizes,
                                            -1.0, "exp", c(gs), c(gr))
        return [s, rgb], [g[k] for k in sorted(g)]

    return (f"16 levels, 2^{S['hash_log2']} entries, finest {S['hash_max']}^3, MLP {'-'.join(map(str, proto.sizes))},"
            f" {N} points"), drlab, oracle


def case_volume_camera(dt, S, seed):
    import warp as wp

    from kernels.volume import GridField, render_samples
    from kernels.volume.rays import camera_rays, pixel_centers, render_backward_camera
    from kernels.volume.sampling import dense_samples
    from research.cameras import look_at
    from research.oracles.rays import render_camera_oracle

    rng = _Rounded(seed)
    px, n_s, res = S["ray_px"], S["ray_samples"], (S["ray_grid"],) * 3
    nv, P = S["ray_grid"] ** 3, S["ray_px"] ** 2
    w2c = np.linalg.inv(look_at(np.array([0.3, -0.4, -4.0]) + rng.normal(0.0, 0.2, 3), rng.normal(0.0, 0.1, 3),
                                up=(0.0, -1.0, 0.0)))
    K = np.array([2.2 * px, 2.1 * px, px / 2 + 0.7, px / 2 - 0.4])
    density, color = rng.normal(0.3, 1.0, nv), rng.normal(size=(nv, 27))
    # Fixed samples from 2.5 to 5.5 (the box [-1, 1]^3 lies within) jittered per ray; outside it the field is 0.
    t = 2.5 + 3.0 * (np.arange(n_s) + rng.uniform(0.0, 1.0, (P, n_s))) / n_s
    delta = np.full((P, n_s), 3.0 / n_s)
    cot = (rng.normal(size=(P, 3)), rng.normal(size=P), rng.normal(size=P))
    pixels = pixel_centers(px, px)
    bg, thr = (0.3, 0.5, 0.7), 0.01

    def drlab(t_):
        f = GridField(BBOX, res, sh_degree=2, density_bias=0.0, density_scale=2.0,
                      dtype=wp.float32 if t_ == np.float32 else wp.float64)
        f.set_params({"density": density.astype(t_), "color": color.astype(t_)})
        o, d, z = camera_rays(w2c, K, pixels.astype(t_))
        r = render_samples(f, dense_samples(o, d, t.astype(t_), delta.astype(t_), z), background=bg, t_threshold=thr)
        g = render_backward_camera(f, r, w2c, K, pixels.astype(t_), *(c.astype(t_) for c in cot))
        return [r.rgb.numpy(), r.depth.numpy(), r.opacity.numpy()], [g.xi, g.intrinsics]

    def oracle(t_):
        c = lambda v: v.astype(dt).astype(t_)  # noqa: E731
        field = dict(kind="grid", bbox=BBOX, resolution=res, sh_degree=2, density=c(density), color=c(color),
                     density_bias=0.0, density_scale=2.0, activation="softplus")
        (rgb, depth, opacity), g = render_camera_oracle(field, w2c, K, c(pixels), c(t), c(delta), bg, thr,
                                                        *(c(v) for v in cot))
        return [rgb, depth, opacity], [g["xi"], g["intrinsics"]]

    return f"{px}x{px} rays x {n_s} samples, {S['ray_grid']}^3 grid SH 2", drlab, oracle


def case_splat(dt, S, seed):
    from kernels import splat as ks
    from research.oracles.splat import render_oracle

    rng = _Rounded(seed)
    N, px = S["splats"], S["splat_px"]
    f = 0.86 * px
    K = np.array([[f, 0.0, px / 2 + 0.3], [0.0, f, px / 2 - 0.4], [0.0, 0.0, 1.0]])
    view = np.eye(4)
    view[:3, 3] = [0.02, -0.01, 4.0]
    cam = ks.SplatCamera(view, K, px, px)
    means = np.column_stack([rng.uniform(-2.4, 2.4, N), rng.uniform(-2.4, 2.4, N), rng.uniform(-1.0, 1.0, N)])
    log_scales = rng.uniform(-4.2, -2.8, (N, 3)) + np.log(256 / px) * (px < 256)
    quats, logits = rng.normal(size=(N, 4)), rng.uniform(-2.0, 3.0, N)
    sh = rng.normal(0.0, 0.15, (N, 16, 3))
    sh[:, 0, :] = (rng.uniform(0.2, 0.8, (N, 3)) - 0.5) / ks.SH_C0
    bg = np.array([0.3, 0.5, 0.7])
    cot = (rng.normal(size=(px, px, 3)), rng.normal(size=(px, px)), rng.normal(size=(px, px)))
    names = ("means", "log_scales", "quats", "opacity_logits", "sh")
    params = (means, log_scales, quats, logits, sh)

    def drlab(t):
        g = ks.gaussian_inputs(*(v.astype(t) for v in params))
        res = ks.render(g, cam, bg.astype(t))
        gg = ks.render_backward(g, res, *(c.astype(t) for c in cot), want_camera=True)
        return [res.rgb, res.alpha, res.depth], [gg[k] for k in (*names, "background", "pose", "intrinsics")]

    def oracle(t):
        c = lambda v: v.astype(dt).astype(t)  # noqa: E731
        img, gg, _ = render_oracle(*(c(v) for v in params), view, K, px, px, cam.near, cam.far, c(bg),
                                   *(c(v) for v in cot), want_camera=True)
        return list(img), [gg[k] for k in (*names, "background", "pose", "intrinsics")]

    return f"{N} Gaussians, {px}x{px}, SH 3", drlab, oracle


def case_chamfer(dt, S, seed):
    from kernels import points as kp
    from research.oracles.points import chamfer_oracle

    rng = _Rounded(seed)
    n = max(S["points"] // 16, 16)  # the oracle visits all n x n pairs
    x, y = rng.normal(size=(n, 3)), rng.normal(0.3, 0.8, (n, 3))
    g = float(rng.normal(size=1)[0])

    def drlab(t):
        res = kp.chamfer_distance(x.astype(t), y.astype(t))
        grads = kp.chamfer_backward(x.astype(t), y.astype(t), res, g)
        return [np.array([res.value])], [grads["x"], grads["y"]]

    def oracle(t):
        value, (gx, gy) = chamfer_oracle(x.astype(dt).astype(t), y.astype(dt).astype(t), g)
        return [np.array([value])], [gx, gy]

    return f"{n} x {n} points", drlab, oracle


CASES = [
    ("ssim", "SSIM map", case_ssim),
    ("stereo", "SAD volume", case_window_cost("sad")),
    ("stereo", "ZNCC volume", case_window_cost("zncc")),
    ("stereo", "feature correlation", case_feature_corr),
    ("stereo", "soft-argmin", case_soft_argmin),
    ("corr", "RAFT lookup, dense", case_corr("dense")),
    ("corr", "RAFT lookup, on the fly", case_corr("onthefly")),
    ("volume", "dense grid field", case_grid),
    ("volume", "hash grid + MLP field", case_hashgrid),
    ("volume", "volume render camera gradients (pose, intrinsics)", case_volume_camera),
    ("splat", "3DGS render (projection, SH, raster, depth, camera)", case_splat),
    ("points", "chamfer distance (both clouds' gradients)", case_chamfer),
]


def run(ctx: Context) -> int:
    S = SIZES[ctx.mode]
    rows, metrics = [], {}
    for family, name, case in ctx.tqdm(CASES, desc="oracle cases"):
        # The inputs hold float32 values (_Rounded): float64 compares drlab and the oracle in float64;
        # float32 both in float32; "float32 vs oracle64" drlab's float32 result with the float64 oracle.
        _, warm, _ = case(np.float64, SIZES["smoke"], ctx.seed)
        warm(np.float64)  # warm-up at the smoke size: Warp's kernels load once per dtype
        warm(np.float32)
        size, drlab, oracle = case(np.float64, S, ctx.seed)
        entry: dict[str, Any] = {"family": family, "size": size}
        d64, t_d64 = _timed(lambda: drlab(np.float64))
        o64, t_o64 = _timed(lambda: oracle(np.float64))
        d32, t_d32 = _timed(lambda: drlab(np.float32))
        o32, t_o32 = _timed(lambda: oracle(np.float32))
        for label, dl, orc, td, to in (("float64", d64, o64, t_d64, t_o64), ("float32", d32, o32, t_d32, t_o32),
                                        ("float32 vs oracle64", d32, o64, None, None)):
            fwd = _diff(list(zip(dl[0], orc[0])))
            vjp = _diff(list(zip(dl[1], orc[1]))) if dl[1] else (float("nan"), float("nan"))
            entry[label] = {"fwd_abs": fwd[0], "fwd_rel": fwd[1], "vjp_abs": vjp[0], "vjp_rel": vjp[1],
                            "drlab_s": td, "oracle_s": to}
            rows.append([family, name, size, label, fwd[0], fwd[1], "-" if not dl[1] else vjp[0],
                         "-" if not dl[1] else vjp[1], "-" if td is None else f"{td:.2f}",
                         "-" if to is None else f"{to:.2f}"])
        metrics[name] = entry
    worst64 = max(max(e["float64"]["fwd_rel"], np.nan_to_num(e["float64"]["vjp_rel"])) for e in metrics.values())
    table = ("Every kernel family against its Dr.Jit oracle (research/oracles), normwise: abs = max |drlab - "
             "oracle| over the outputs, rel = abs / max |oracle|; fwd = forward outputs, VJP = every input's "
             "vector-Jacobian product for one random cotangent. `float32` compares drlab and the oracle both "
             "in float32; `float32 vs oracle64` drlab's float32 result against the float64 oracle on the same "
             f"inputs. Times: one call each, in seconds, on `{ctx.device}` (the oracle's include Dr.Jit's "
             "tracing and compilation). Seed " + str(ctx.seed) + ".\n\n"
             + markdown_table(["family", "case", "size", "precision", "fwd abs", "fwd rel", "VJP abs", "VJP rel",
                               "drlab s", "oracle s"], rows, floatfmt=".2e")
             + f"\nLargest float64 relative difference: {worst64:.1e} (the conformance target is 1e-10).\n")
    figure(metrics, ctx.out / "figure.png")
    ctx.write_results(config={"mode": ctx.mode, "sizes": {k: list(v) if isinstance(v, tuple) else v
                                                          for k, v in S.items()}},
                      metrics={"cases": metrics, "worst_float64_rel": worst64}, table_md=table, device="cpu")
    return 0


def figure(metrics: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(metrics)
    series = [("float64", "fwd_rel", "float64 forward"), ("float64", "vjp_rel", "float64 VJP"),
              ("float32", "fwd_rel", "float32 forward"), ("float32", "vjp_rel", "float32 VJP")]
    fig, ax = plt.subplots(figsize=(11, 4.2))
    width = 0.2
    x = np.arange(len(names))
    for i, (prec, key, label) in enumerate(series):
        vals = [metrics[n][prec][key] for n in names]
        vals = [v if np.isfinite(v) and v > 0 else np.nan for v in vals]
        ax.bar(x + (i - 1.5) * width, vals, width, label=label)
    ax.axhline(1e-10, color="k", lw=0.8, ls="--", label="1e-10")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=25, ha="right", fontsize=8)
    ax.set_ylabel("max |drlab - oracle| / max |oracle|")
    ax.set_title("drlab vs its Dr.Jit AD oracle")
    ax.legend(fontsize=8, ncol=5)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


main = Experiment("oracle_conformance", __doc__, run, warp=False,
                  seed_help="seed of the random inputs",
                  sizes="Full (default): the sizes listed above, a few minutes on 2 cores. Quick: a quarter of "
                        "the pixels, a third of the points. Smoke: tiny sizes, seconds.").script(__name__)
