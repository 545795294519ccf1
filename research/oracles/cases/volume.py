"""Radiance fields and the volume renderer's camera gradients against their Dr.Jit oracles
(research/oracles/volume.py, rays.py): a dense grid with SH degree 2 colour (sigma, rgb, d density,
d colour); a hash-grid field + MLP (sigma, rgb, d of every parameter); pixel rays x fixed samples
through a grid with early termination (rgb, depth, opacity, d pose xi (6) and d intrinsics (4),
kernels/volume/rays.py).

Cases of the oracle_conformance experiment (research.oracles.cases describes the contract).
"""

from __future__ import annotations

import numpy as np

from research.oracles.cases import Case, Rounded

# Sizes per mode: grid, vertices per side; points, field queries; hash_log2, hash_max, the hash table's
# size and finest level; ray_px, ray_samples, ray_grid, the camera case's pixels per side, samples and grid.
SIZES = {
    "full": dict(grid=64, points=65536, hash_log2=19, hash_max=128, ray_px=128, ray_samples=64, ray_grid=32),
    "quick": dict(grid=32, points=8192, hash_log2=16, hash_max=64, ray_px=64, ray_samples=32, ray_grid=16),
    "smoke": dict(grid=6, points=200, hash_log2=10, hash_max=16, ray_px=8, ray_samples=8, ray_grid=4),
}


BBOX = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def case_grid(dt, S, seed):
    import warp as wp

    from kernels.volume import GridField
    from research.oracles.volume import grid_field_oracle

    rng = Rounded(seed)
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

    rng = Rounded(seed)
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

    rng = Rounded(seed)
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


CASES = [
    Case("dense grid field", case_grid),
    Case("hash grid + MLP field", case_hashgrid),
    Case("volume render camera gradients (pose, intrinsics)", case_volume_camera),
]
