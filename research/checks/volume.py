"""Finite-difference checks (float64) of every hand-written backward pass in kernels.volume.

Registered for `drlab gradcheck volume`; tests/kernels/test_volume_*.py run the same functions
over more seeds. Inputs are random and kept away from the kinks of the functions checked:
  * compositing: a ray that terminates early does so with T far below the threshold (one
    very dense sample), so a step of 1e-6 cannot move the termination point;
  * spheres: points at least 0.05 away from every sphere surface (the max(0, .) kink) and with a
    total density far above the 1e-6 colour-normalisation switch;
  * grids / hash grids: gradients with respect to the values, which enter linearly (the cell
    boundaries are kinks only in the points, which are constants here);
  * MLPs: every ReLU pre-activation at least RELU_MARGIN away from 0 (inputs are redrawn until so).
Sample positions and view directions are constants in the parameter checks; the camera checks at the end
differentiate them (kernels.volume.field_points, kernels.volume.rays) with the sample distances held fixed.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
import warp as wp

from kernels.volume import (GridField, HashGridField, PEMLPField, SphereField, composite_backward, composite_forward,
                            render_backward, render_rays)
from kernels.volume.render import optical_depth_sum
from kernels.volume.field import Field
from research.gradcheck import GradcheckResult, check_vjp, register_check

RELU_MARGIN = 1e-4
SPARSITY_WEIGHT = 0.3
BOX = np.array([[-1.0, -0.8, -0.6], [1.0, 0.9, 0.7]])


# --------------------------------------------------------------------------- compositing

def composite_inputs(seed: int) -> dict[str, Any]:
    """Packed rays of 0..9 samples, per-ray backgrounds, one ray that terminates early."""
    rng = np.random.default_rng(seed)
    counts = np.array([5, 0, 9, 1, 7, 4, 8])
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    n = int(offsets[-1])
    sigma = rng.uniform(0.05, 3.0, n)
    sigma[offsets[4] + 3] = 200.0  # T drops from O(0.1) to ~1e-50 << 1e-4: ray 4 stops after this sample
    return {
        "sigma": sigma,
        "rgb": rng.uniform(0.0, 1.0, (n, 3)),
        "delta": rng.uniform(0.05, 0.4, n),
        "z": np.sort(rng.uniform(1.0, 5.0, n)),
        "ray_offsets": offsets,
        "background": rng.uniform(0.0, 1.0, (len(counts), 3)),
    }


def _composite_f(t_threshold: float) -> Callable:
    def f(sigma, rgb, delta, z, ray_offsets, background):
        r = composite_forward(sigma, rgb, delta, z, ray_offsets, background, t_threshold)
        return {"rgb": r.rgb, "depth": r.depth, "opacity": r.opacity}  # NumPy in, NumPy out
    return f


def _composite_vjp(t_threshold: float) -> Callable:
    def vjp(inp, cot):
        args = (inp["sigma"], inp["rgb"], inp["delta"], inp["z"], inp["ray_offsets"])
        r = composite_forward(*args, inp["background"], t_threshold)
        gs, gr = composite_backward(*args, r, cot["rgb"], cot["depth"], cot["opacity"], inp["background"])
        return {"sigma": gs, "rgb": gr}
    return vjp


def check_composite(seeds=(0, 1), t_threshold: float = 1e-4) -> list[GradcheckResult]:
    results = []
    for seed in seeds:
        inputs = composite_inputs(seed)
        results += check_vjp(_composite_f(t_threshold), _composite_vjp(t_threshold), inputs, wrt=["sigma", "rgb"],
                             seed=seed, name="volume.composite")
    return results


# --------------------------------------------------------------------------- fields

def _field_check(make: Callable[[dict[str, np.ndarray]], Field], params: dict[str, np.ndarray], points: np.ndarray,
                 dirs: np.ndarray | None, name: str, seed: int) -> list[GradcheckResult]:
    def f(**kw):
        out = make(kw).forward(points, dirs)
        return {"sigma": out.sigma, "rgb": out.rgb}  # NumPy points, NumPy outputs

    def vjp(inp, cot):
        field = make(inp)
        out = field.forward(points, dirs)
        return {k: v.numpy() for k, v in field.backward(points, dirs, out, cot["sigma"], cot["rgb"]).items()}

    return check_vjp(f, vjp, params, seed=seed, name=name)


def sphere_points(rng: np.random.Generator, field: SphereField, n: int) -> np.ndarray:
    """Points in front of the Video and 3D Vision chapter's spheres (SphereField.textbook), >= 0.05 from
    every surface."""
    P = field.params_numpy()
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = rng.uniform([-1.8, -1.2, 2.8], [2.2, 1.2, 5.8])
        dist = np.linalg.norm(p - P["centers"], axis=1)
        if np.all(np.abs(dist - P["radii"]) > 0.05):
            pts.append(p)
    return np.array(pts)


def check_spheres(seeds=(0, 1)) -> list[GradcheckResult]:
    results = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        base = SphereField.textbook(wp.float64)
        params = {k: v + rng.normal(0.0, 0.05, v.shape) for k, v in base.params_numpy().items()}
        points = sphere_points(rng, base, 24)
        make = lambda p: SphereField(p["centers"], p["radii"], p["colors"], p["sharpness"], dtype=wp.float64)  # noqa: E731
        results += _field_check(make, params, points, None, "volume.field.spheres", seed)
    return results


def check_grid(seeds=(0, 1), sh_degree: int | None = None, activation: str = "softplus") -> list[GradcheckResult]:
    results = []
    name = f"volume.field.grid_{'rgb' if sh_degree is None else f'sh{sh_degree}'}_{activation}"
    for seed in seeds:
        rng = np.random.default_rng(seed)
        field = GridField(BOX, (3, 4, 5), sh_degree=sh_degree, density_bias=0.2, density_scale=1.7,
                          density_activation=activation, dtype=wp.float64)
        params = {"density": rng.normal(0.0, 1.0, field.params["density"].shape),
                  "color": rng.normal(0.0, 1.0, field.params["color"].shape)}
        points = rng.uniform(BOX[0], BOX[1], (24, 3))
        dirs = None
        if sh_degree is not None:
            dirs = rng.normal(size=(24, 3))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)

        def make(p, field=field):
            field.set_params(p)
            return field
        results += _field_check(make, params, points, dirs, name, seed)
    return results


def relu_margin(field: Field, points: np.ndarray) -> float:
    """min |z| over the hidden pre-activations of a neural field's MLP at `points`."""
    out = field.forward(points)
    pre = out.cache["mlp"].pre[:-1]
    return float(min(np.abs(z.numpy()).min() for z in pre)) if pre else np.inf


def neural_field(kind: str, seed: int, backend: str | None = None) -> Field:
    """A small float64 neural field with non-degenerate parameters (hash table entries O(1)); `backend` None:
    the MLP's default for the device (kernels.volume.mlp)."""
    if kind == "hashgrid":
        # Levels 2, 4, 8 with a 64-entry table: level 0 dense, levels 1-2 hashed (collisions included).
        return HashGridField(BOX, n_levels=3, n_features=2, log2_table_size=6, base_resolution=2, max_resolution=8,
                             hidden=(8, 8), density_bias=-0.5, table_init_scale=1.0, seed=seed, dtype=wp.float64,
                             backend=backend)
    if kind == "pe_mlp":
        return PEMLPField(BOX, n_freqs=2, hidden=(8, 8), density_bias=-0.5, seed=seed, dtype=wp.float64,
                          backend=backend)
    raise ValueError(f"kind: unknown neural field {kind!r}")


def _margin_points(field: Field, rng: np.random.Generator, n: int) -> np.ndarray:
    for _ in range(50):
        points = rng.uniform(BOX[0], BOX[1], (n, 3))
        if relu_margin(field, points) > RELU_MARGIN:
            return points
    raise RuntimeError("could not draw points away from the ReLU kinks")


def check_neural(kind: str, seeds=(0, 1), backend: str | None = None) -> list[GradcheckResult]:
    results = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        field = neural_field(kind, seed, backend)
        params = field.params_numpy()
        points = _margin_points(field, rng, 16)

        def make(p, field=field):
            field.set_params(p)
            return field
        results += _field_check(make, params, points, None, f"volume.field.{kind}", seed)
    return results


def check_tv(seeds=(0, 1)) -> list[GradcheckResult]:
    """The grid's total-variation regulariser: add_tv_grad against FD of the NumPy total variation."""
    from kernels.reference.volume import total_variation
    from kernels.volume.grid import add_tv_grad

    results = []
    res = (3, 4, 5)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        inputs = {"density": rng.normal(size=60), "color": rng.normal(size=(60, 3))}

        def f(density, color):
            return np.array(0.7 * (total_variation(density, res) + total_variation(color, res)))

        def vjp(inp, cot):
            out = {}
            for k in ("density", "color"):
                g = wp.zeros(inp[k].shape, dtype=wp.float64)
                add_tv_grad(wp.array(inp[k], dtype=wp.float64), res, 0.7 * float(cot), g)
                out[k] = g.numpy()
            return out

        results += check_vjp(f, vjp, inputs, seed=seed, name="volume.grid_tv")
    return results


# --------------------------------------------------------------------------- end to end

def render_setup(kind: str, seed: int) -> tuple[Field, np.ndarray, np.ndarray, np.ndarray]:
    """A field and rays (origins, unit dirs, z_scale) crossing BOX from a camera-like fan."""
    rng = np.random.default_rng(seed)
    if kind == "grid":
        field = GridField(BOX, (4, 4, 4), sh_degree=1, density_bias=0.0, dtype=wp.float64)
        field.set_params({"density": rng.normal(0.5, 1.0, field.params["density"].shape),
                          "color": rng.normal(0.0, 1.0, field.params["color"].shape)})
    else:
        field = neural_field(kind, seed)
    n_rays = 6
    origins = np.tile([0.1, -0.05, -3.0], (n_rays, 1)) + rng.normal(0.0, 0.05, (n_rays, 3))
    targets = rng.uniform(BOX[0] * 0.8, BOX[1] * 0.8, (n_rays, 3))
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return field, origins, dirs, dirs[:, 2].copy()


def check_render(kind: str, seeds=(0, 1)) -> list[GradcheckResult]:
    """Pixel colour, depth and opacity of a few rays (and the sparsity penalty, weight SPARSITY_WEIGHT)
    with respect to every field parameter.

    For neural fields a seed whose samples put a ReLU pre-activation within RELU_MARGIN of 0 is
    replaced by seed + 100 (then + 200, ...), so that every requested seed yields a check.
    """
    results = []
    for seed in seeds:
        for attempt in range(10):
            s = seed + 100 * attempt
            field, origins, dirs, z_scale = render_setup(kind, s)
            opts = dict(n_samples=12, z_scale=z_scale, jitter=True, seed=s, background=(0.3, 0.2, 0.1),
                        t_threshold=0.0)
            if kind == "grid":
                break
            pts = render_rays(field, origins, dirs, BOX, **opts).samples.points.numpy()
            if relu_margin(field, pts) > RELU_MARGIN:
                break
        else:
            raise RuntimeError(f"volume.render.{kind}: no seed away from the ReLU kinks")

        def f(field=field, origins=origins, dirs=dirs, opts=opts, **kw):
            field.set_params(kw)
            r = render_rays(field, origins, dirs, BOX, **opts)
            return {"rgb": r.rgb, "depth": r.depth, "opacity": r.opacity,
                    "sparsity": np.array(SPARSITY_WEIGHT * optical_depth_sum(r))}

        def vjp(inp, cot, field=field, origins=origins, dirs=dirs, opts=opts):
            field.set_params(inp)
            r = render_rays(field, origins, dirs, BOX, **opts)
            grads = render_backward(field, r, cot["rgb"], cot["depth"], cot["opacity"],
                                    sigma_l1=SPARSITY_WEIGHT * float(cot["sparsity"]))
            return {k: v.numpy() for k, v in grads.items()}

        results += check_vjp(f, vjp, field.params_numpy(), seed=s, name=f"volume.render.{kind}")
    return results


# --------------------------------------------------------------------------- registry


def _with(check: Callable[..., list[GradcheckResult]], **kwargs: Any) -> Callable[[], list[GradcheckResult]]:
    """`check(**kwargs)` as the zero-argument function a registered check is."""
    def run() -> list[GradcheckResult]:
        return check(**kwargs)

    return run


for _name, _check, _kwargs in [
        ("volume.composite", check_composite, {}), ("volume.field.spheres", check_spheres, {}),
        ("volume.field.grid_rgb", check_grid, {"sh_degree": None, "activation": "softplus"}),
        ("volume.field.grid_sh2", check_grid, {"sh_degree": 2, "activation": "exp"}),
        ("volume.grid_tv", check_tv, {}),
        ("volume.field.hashgrid", check_neural, {"kind": "hashgrid"}),
        ("volume.field.pe_mlp", check_neural, {"kind": "pe_mlp"}),
        ("volume.render.grid", check_render, {"kind": "grid"}),
        ("volume.render.hashgrid", check_render, {"kind": "hashgrid"}),
        ("volume.render.pe_mlp", check_render, {"kind": "pe_mlp"})]:
    register_check(_name)(_with(_check, **_kwargs))


# --------------------------------------------------------------------------- camera gradients

def camera_setup(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(w2c (4, 4), intrinsics (4,), pixels (P, 2)): a random camera about 3 units in front of BOX
    looking at it, with fx != fy and an off-centre principal point, and random pixels of a 24x20 image."""
    from research.cameras import look_at

    rng = np.random.default_rng(seed)
    eye = rng.normal(0.0, 0.3, 3) + np.array([0.2, -0.3, -3.0])
    c2w = look_at(eye, rng.normal(0.0, 0.1, 3), up=(0.0, -1.0, 0.0))
    intrinsics = np.array([rng.uniform(40.0, 48.0), rng.uniform(38.0, 46.0), rng.uniform(10.0, 14.0),
                           rng.uniform(8.0, 12.0)])
    pixels = rng.uniform([2.0, 2.0], [22.0, 18.0], (8, 2))
    return np.linalg.inv(c2w), intrinsics, pixels


def check_camera_rays(seeds=(0, 1)) -> list[GradcheckResult]:
    """Origins, directions and z_scale of kernels.volume.camera_rays with respect to the left se(3)
    perturbation xi of world-to-camera (checked at xi = 0 of a random pose) and (fx, fy, cx, cy)."""
    from kernels.volume.rays import camera_rays, camera_rays_backward
    from research.poses.se3 import se3_exp

    results = []
    for seed in seeds:
        w2c, intrinsics, pixels = camera_setup(seed)

        def f(xi, intrinsics, w2c=w2c, pixels=pixels):
            o, d, z = camera_rays(se3_exp(xi) @ w2c, intrinsics, pixels)
            return {"origins": o, "dirs": d, "z_scale": z}

        def vjp(inp, cot, w2c=w2c, pixels=pixels):
            g = camera_rays_backward(se3_exp(inp["xi"]) @ w2c, inp["intrinsics"], pixels, cot["origins"],
                                     cot["dirs"], cot["z_scale"])
            return {"xi": g.xi, "intrinsics": g.intrinsics}

        results += check_vjp(f, vjp, {"xi": np.zeros(6), "intrinsics": intrinsics}, seed=seed,
                             name="volume.camera_rays")
    return results


def ndc_setup(seed: int) -> tuple[np.ndarray, np.ndarray, float, tuple[float, float], tuple[float, float]]:
    """(origins (R, 3), dirs (R, 3), near, (fx, fy), (W, H)): forward-facing rays as LLFF's recentred
    cameras give them (origins near the world origin, directions down -z within a 60-degree cone; the
    near plane at z = -1 as NeRF's after its bd_factor rescaling), with fx != fy."""
    rng = np.random.default_rng(seed)
    origins = rng.normal(0.0, 0.2, (8, 3))
    dirs = np.column_stack([rng.uniform(-0.5, 0.5, (8, 2)), -np.ones(8)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return origins, dirs, 1.0, (rng.uniform(380.0, 420.0), rng.uniform(380.0, 420.0)), (504.0, 378.0)


def check_ndc_rays(seeds=(0, 1, 2)) -> list[GradcheckResult]:
    """NDC origins and directions of kernels.volume.ndc_rays (NeRF's d' and the unit u') with respect to
    the world origins and directions."""
    from kernels.volume.rays import ndc_rays, ndc_rays_backward

    results = []
    for seed in seeds:
        origins, dirs, near, focal, size = ndc_setup(seed)
        for normalize in (False, True):
            def f(origins, dirs, normalize=normalize, near=near, focal=focal, size=size):
                o, d = ndc_rays(origins, dirs, near, focal, size, normalize=normalize)
                return {"origins": o, "dirs": d}

            def vjp(inp, cot, normalize=normalize, near=near, focal=focal, size=size):
                go, gd = ndc_rays_backward(inp["origins"], inp["dirs"], near, focal, size, cot["origins"],
                                           cot["dirs"], normalize=normalize)
                return {"origins": go, "dirs": gd}

            results += check_vjp(f, vjp, {"origins": origins, "dirs": dirs}, seed=seed,
                                 name="volume.ndc_rays" + (".unit" if normalize else ""))
    return results


def camera_field(kind: str, seed: int) -> Field:
    """A float64 field filling BOX: soft spheres, or a grid with RGB or degree-2 SH colour."""
    rng = np.random.default_rng(seed)
    if kind == "spheres":
        return SphereField(rng.uniform(BOX[0] * 0.6, BOX[1] * 0.6, (3, 3)), rng.uniform(0.2, 0.4, 3),
                           rng.uniform(0.1, 0.9, (3, 3)), rng.uniform(2.0, 4.0, 3), dtype=wp.float64)
    field = GridField(BOX, (4, 5, 4), sh_degree=None if kind == "grid_rgb" else 2, density_bias=0.0,
                      dtype=wp.float64)
    field.set_params({"density": rng.normal(0.3, 1.0, field.params["density"].shape),
                      "color": rng.normal(0.0, 1.0, field.params["color"].shape)})
    return field


def check_field_points(kind: str, seeds=(0, 1)) -> list[GradcheckResult]:
    """sigma and rgb of a field with respect to its points (and view directions for SH colour):
    kernels.volume.field_points.field_point_backward, points away from the kinks."""
    from kernels.volume.field_points import field_point_backward

    results = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        field = camera_field(kind, seed)
        for _ in range(50):
            points = rng.uniform(BOX[0] * 0.95, BOX[1] * 0.95, (24, 3))
            if _away_from_kinks(field, points):
                break
        else:
            raise RuntimeError(f"volume.field_points.{kind}: no points away from the kinks")
        dirs = rng.normal(size=(24, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)

        def f(points, dirs, field=field):
            out = field.forward(points, dirs)
            return {"sigma": out.sigma, "rgb": out.rgb}

        def vjp(inp, cot, field=field):
            out = field.forward(inp["points"], inp["dirs"])
            g_p, g_d = field_point_backward(field, inp["points"], inp["dirs"], out, cot["sigma"], cot["rgb"])
            return {"points": g_p, "dirs": g_d}

        results += check_vjp(f, vjp, {"points": points, "dirs": dirs}, seed=seed,
                             name=f"volume.field_points.{kind}")
    return results


def check_render_camera(kind: str, seeds=(0, 1)) -> list[GradcheckResult]:
    """Rendered colour, expected depth and opacity of pixel rays through `kind` with respect to the pose
    perturbation xi (at 0) and the intrinsics: kernels.volume.rays.render_backward_camera.

    The sample distances t and intervals are held fixed (the module's convention): they are drawn
    once, jittered, from the unperturbed rays, and the function renders o + t d at those t. Sample
    points are kept at least 1e-3 (in cells) from the grid's cell faces and 1e-3 from the sphere
    surfaces (the kinks); a seed that puts one closer is replaced by seed + 100 (then + 200, ...).
    """
    from kernels.volume.rays import camera_rays, render_backward_camera
    from kernels.volume.sampling import dense_samples, sample_rays
    from kernels.volume import render_samples
    from research.poses.se3 import se3_exp

    results = []
    for seed in seeds:
        for attempt in range(10):
            s = seed + 100 * attempt
            field = camera_field(kind, s)
            w2c, intrinsics, pixels = camera_setup(s)
            o, d, zs = camera_rays(w2c, intrinsics, pixels)
            smp = sample_rays(o, d, BOX, n_samples=10, jitter=True, seed=s)
            counts = np.diff(smp.ray_offsets)
            if counts.min() != counts.max() or counts[0] == 0:
                continue  # every ray crosses the box: a dense (R, S) layout
            t = smp.t.reshape(len(o), -1)
            delta = smp.delta.reshape(len(o), -1)
            if _away_from_kinks(field, smp.points):
                break
        else:
            raise RuntimeError(f"volume.render.camera_{kind}: no seed away from the kinks")

        def render(xi, intr, field=field, w2c=w2c, pixels=pixels, t=t, delta=delta):
            W = se3_exp(xi) @ w2c
            o, d, zs = camera_rays(W, intr, pixels)
            return W, render_samples(field, dense_samples(o, d, t, delta, zs), background=(0.3, 0.2, 0.1),
                                     t_threshold=0.0)

        def f(xi, intrinsics, render=render):
            r = render(xi, intrinsics)[1]
            return {"rgb": r.rgb.numpy(), "depth": r.depth.numpy(), "opacity": r.opacity.numpy()}

        def vjp(inp, cot, render=render, field=field, pixels=pixels):
            W, r = render(inp["xi"], inp["intrinsics"])
            g = render_backward_camera(field, r, W, inp["intrinsics"], pixels, cot["rgb"], cot["depth"],
                                       cot["opacity"])
            return {"xi": g.xi, "intrinsics": g.intrinsics}

        results += check_vjp(f, vjp, {"xi": np.zeros(6), "intrinsics": intrinsics}, seed=s,
                             name=f"volume.render.camera_{kind}")
    return results


def _away_from_kinks(field: Field, points: np.ndarray) -> bool:
    """Whether no point is within 1e-3 cells of a grid cell face or 1e-3 of a sphere surface."""
    if isinstance(field, SphereField):
        P = field.params_numpy()
        dist = np.linalg.norm(points[:, None, :] - P["centers"][None], axis=2)
        return bool(np.all(np.abs(dist - P["radii"][None]) > 1e-3))
    res = np.array(field.resolution)
    u = (points - field.bbox[0]) / (field.bbox[1] - field.bbox[0]) * (res - 1)
    return bool(np.all(np.abs(u - np.round(u)) > 1e-3))


for _name, _check, _kwargs in [
        ("volume.camera_rays", check_camera_rays, {}),
        ("volume.ndc_rays", check_ndc_rays, {}),
        ("volume.field_points.spheres", check_field_points, {"kind": "spheres"}),
        ("volume.field_points.grid_rgb", check_field_points, {"kind": "grid_rgb"}),
        ("volume.field_points.grid_sh2", check_field_points, {"kind": "grid_sh2"}),
        ("volume.render.camera_spheres", check_render_camera, {"kind": "spheres"}),
        ("volume.render.camera_grid_rgb", check_render_camera, {"kind": "grid_rgb"}),
        ("volume.render.camera_grid_sh2", check_render_camera, {"kind": "grid_sh2"})]:
    register_check(_name)(_with(_check, **_kwargs))
