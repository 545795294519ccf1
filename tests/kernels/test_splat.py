"""kernels/splat.py against a plain NumPy reference, finite differences, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from kernels import splat as ks
from research.checks import splat as cs
from research.gradcheck import assert_gradcheck

PARAMS = cs.PARAMS

# --------------------------------------------------------------------------- NumPy reference


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def sh_basis_ref(d: np.ndarray) -> np.ndarray:
    """Real SH up to degree 3 in the 3DGS convention, for unit directions d (..., 3) -> (..., 16)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    c0, c1 = 0.28209479177387814, 0.4886025119029199
    c2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396]
    c3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
          1.445305721320277, -0.5900435899266435]
    return np.stack([
        np.full_like(x, c0),
        -c1 * y, c1 * z, -c1 * x,
        c2[0] * x * y, c2[1] * y * z, c2[2] * (2 * z * z - x * x - y * y), c2[3] * x * z, c2[4] * (x * x - y * y),
        c3[0] * y * (3 * x * x - y * y), c3[1] * x * y * z, c3[2] * y * (4 * z * z - x * x - y * y),
        c3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y), c3[4] * x * (4 * z * z - x * x - y * y),
        c3[5] * z * (x * x - y * y), c3[6] * x * (x * x - 3 * y * y),
    ], axis=-1)


def project_ref(params: dict, cam: ks.SplatCamera, sh_degree: int | None = None, antialiased: bool = False) -> dict:
    means, log_scales, quats = params["means"], params["log_scales"], params["quats"]
    logits, sh = params["opacity_logits"], params["sh"]
    n = len(means)
    deg = int(round(math.sqrt(sh.shape[1]))) - 1 if sh_degree is None else sh_degree
    fx, fy, cx, cy, near, far = cam.params()
    Rw, tw = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
    centre = -Rw.T @ tw
    out = {"means2d": np.zeros((n, 2)), "conics": np.zeros((n, 3)), "depths": np.zeros(n),
           "radii": np.zeros(n, dtype=np.int64), "colors": np.zeros((n, 3)), "opacities": np.zeros(n)}
    for i in range(n):
        x, y, z = Rw @ means[i] + tw
        if z < near or z > far:
            continue
        R = quat_to_rotmat(quats[i])
        S = np.diag(np.exp(log_scales[i]))
        sigma_cam = Rw @ (R @ S @ S.T @ R.T) @ Rw.T
        lim_x = (cx / fx + 0.3 * cam.width / fx, (cam.width - cx) / fx + 0.3 * cam.width / fx)
        lim_y = (cy / fy + 0.3 * cam.height / fy, (cam.height - cy) / fy + 0.3 * cam.height / fy)
        xc = z * np.clip(x / z, -lim_x[0], lim_x[1])
        yc = z * np.clip(y / z, -lim_y[0], lim_y[1])
        J = np.array([[fx / z, 0.0, -fx * xc / z**2], [0.0, fy / z, -fy * yc / z**2]])
        cov = J @ sigma_cam @ J.T
        cov_dilated = cov + 0.3 * np.eye(2)
        det = np.linalg.det(cov_dilated)
        if det <= 0:
            continue
        half_trace = 0.5 * np.trace(cov_dilated)
        lam_max = half_trace + math.sqrt(max(0.01, half_trace**2 - det))
        radius = math.ceil(3.0 * math.sqrt(lam_max))
        u, v = fx * x / z + cx, fy * y / z + cy
        if u + radius <= 0 or u - radius >= cam.width or v + radius <= 0 or v - radius >= cam.height:
            continue
        conic = np.linalg.inv(cov_dilated)
        direction = (means[i] - centre) / np.linalg.norm(means[i] - centre)
        basis = sh_basis_ref(direction)[: (deg + 1) ** 2]
        opacity = 1.0 / (1.0 + math.exp(-logits[i]))
        if antialiased:
            opacity *= math.sqrt(max(0.0, np.linalg.det(cov) / det))
        out["means2d"][i] = u, v
        out["conics"][i] = conic[0, 0], conic[0, 1], conic[1, 1]
        out["depths"][i] = z
        out["radii"][i] = radius
        out["colors"][i] = np.maximum(basis @ sh[i, : len(basis)] + 0.5, 0.0)
        out["opacities"][i] = opacity
    return out


def binned_tiles(m2, conic, opacity, radius, tiles_x, tiles_y, square: bool = False) -> list[int]:
    """Tiles met by the square mean2d +- radius and (unless `square`) by the bounding box of
    the ellipse d^T Q d <= 2 ln(255 o), outside which alpha < 1/255."""
    if radius <= 0:
        return []
    ex = ey = radius
    if not square:
        if 255 * opacity < 1:
            return []
        cov = np.linalg.inv([[conic[0], conic[1]], [conic[1], conic[2]]])
        k2 = 2 * math.log(255 * opacity)
        ex, ey = min(radius, math.sqrt(k2 * cov[0, 0])), min(radius, math.sqrt(k2 * cov[1, 1]))
    x0 = min(max(math.floor((m2[0] - ex) / 16), 0), tiles_x)
    x1 = min(max(math.ceil((m2[0] + ex) / 16), 0), tiles_x)
    y0 = min(max(math.floor((m2[1] - ey) / 16), 0), tiles_y)
    y1 = min(max(math.ceil((m2[1] + ey) / 16), 0), tiles_y)
    return [ty * tiles_x + tx for ty in range(y0, y1) for tx in range(x0, x1)]


def tile_lists_ref(m2, conics, opacities, radii, depths, width, height, square=False) -> dict[int, list[int]]:
    """Splats of every tile, front to back (stable in the splat index)."""
    tiles_x, tiles_y = (width + 15) // 16, (height + 15) // 16
    lists: dict[int, list[int]] = {t: [] for t in range(tiles_x * tiles_y)}
    for i in np.argsort(depths, kind="stable"):
        for t in binned_tiles(m2[i], conics[i], opacities[i], radii[i], tiles_x, tiles_y, square):
            lists[t].append(int(i))
    return lists


def rasterize_ref(m2, conics, colors, opacities, depths, radii, width, height, background):
    """3DGS's rasteriser: each pixel blends the splats whose square mean2d +- radius meets its tile.

    (The kernel bins by a smaller box that only leaves out pixels with alpha < 1/255,
    so it must give the same image.)"""
    lists = tile_lists_ref(m2, conics, opacities, radii, depths, width, height, square=True)
    tiles_x = (width + 15) // 16
    rgb, alpha, depth = np.zeros((height, width, 3)), np.zeros((height, width)), np.zeros((height, width))
    for py in range(height):
        for px in range(width):
            T, C, D = 1.0, np.zeros(3), 0.0
            for i in lists[(py // 16) * tiles_x + px // 16]:
                d = m2[i] - (px + 0.5, py + 0.5)
                Q = np.array([[conics[i, 0], conics[i, 1]], [conics[i, 1], conics[i, 2]]])
                power = -0.5 * d @ Q @ d
                if power > 0:
                    continue
                a = min(0.99, opacities[i] * math.exp(power))
                if a < 1.0 / 255.0:
                    continue
                if T * (1 - a) < 1e-4:
                    break
                C += colors[i] * a * T
                D += depths[i] * a * T
                T *= 1 - a
            rgb[py, px] = C + T * background
            alpha[py, px] = 1 - T
            depth[py, px] = D
    return rgb, alpha, depth


def as_dtype(params: dict, dtype) -> dict:
    return {k: v.astype(dtype) for k, v in params.items()}


# --------------------------------------------------------------------------- forward vs reference

TOL = {np.float32: dict(rtol=2e-4, atol=2e-5), np.float64: dict(rtol=1e-10, atol=1e-11)}


def test_sh_basis_is_orthonormal():
    # Gauss-Legendre in cos(theta) x uniform phi integrates degree <= 6 products exactly.
    ct, wt = np.polynomial.legendre.leggauss(12)
    phi = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    C, P = np.meshgrid(ct, phi, indexing="ij")
    st = np.sqrt(1 - C**2)
    d = np.stack([st * np.cos(P), st * np.sin(P), C], axis=-1)
    w = (wt[:, None] * np.full_like(P, 2 * np.pi / len(phi)))[..., None]
    Y = sh_basis_ref(d)
    gram = np.einsum("ijk,ijl->kl", Y * w, Y)
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("antialiased", [False, True])
def test_project_matches_reference(dtype, antialiased):
    scene = cs.smooth_scene(5, antialiased=antialiased, off_frustum=True)
    params = as_dtype(scene.params, dtype)
    ref = project_ref({k: v.astype(np.float64) for k, v in params.items()}, scene.camera, antialiased=antialiased)
    g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    p = ks.project(g, scene.camera, antialiased=antialiased)
    np.testing.assert_array_equal(p.radii.numpy(), ref["radii"])
    assert (ref["radii"] > 0).sum() >= 10
    for key in ("means2d", "conics", "depths", "colors", "opacities"):
        got = getattr(p, key).numpy()
        assert got.dtype == dtype
        np.testing.assert_allclose(got, ref[key], **TOL[dtype], err_msg=key)


def test_project_sh_degree_and_culling():
    rng = np.random.default_rng(3)
    scene = cs.random_scene(rng)
    params = dict(scene.params)
    params["means"] = params["means"].copy()
    R, t = scene.camera.viewmat[:3, :3], scene.camera.viewmat[:3, 3]
    params["means"][0] = R.T @ (np.array([0.0, 0.0, -1.0]) - t)  # behind the camera
    params["means"][1] = R.T @ (np.array([0.0, 0.0, 0.005]) - t)  # in front, but nearer than near = 0.01
    params["means"][2] = R.T @ (np.array([40.0, 0.0, 4.0]) - t)  # far right of the image
    for deg in (0, 1, 2):
        ref = project_ref(params, scene.camera, sh_degree=deg)
        p = ks.project(ks.gaussian_inputs(*(params[k] for k in PARAMS)), scene.camera, sh_degree=deg)
        assert list(p.radii.numpy()[:3]) == [0, 0, 0]
        np.testing.assert_array_equal(p.radii.numpy(), ref["radii"])
        np.testing.assert_allclose(p.colors.numpy(), ref["colors"], rtol=1e-10, atol=1e-12)
        np.testing.assert_array_equal(p.conics.numpy()[:3], 0.0)


def test_tile_binning_matches_reference():
    scene = cs.smooth_scene(6)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    p = ks.project(g, scene.camera)
    W, H = scene.camera.width, scene.camera.height
    tiles = ks.bin_tiles(ks.splats_2d(p.means2d, p.conics, p.colors, p.opacities, p.depths, p.radii), W, H)
    ref = tile_lists_ref(p.means2d.numpy(), p.conics.numpy(), p.opacities.numpy(), p.radii.numpy(),
                         p.depths.numpy(), W, H)
    ranges, gid = tiles.ranges.numpy(), tiles.sorted_gid.numpy()
    assert tiles.n_entries == sum(len(v) for v in ref.values())
    assert sum(len(v) > 1 for v in ref.values()) >= 4  # splats overlap on several tiles
    for t, members in ref.items():
        assert list(gid[ranges[t, 0]:ranges[t, 1]]) == members, f"tile {t}"


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_rasterize_matches_reference(dtype):
    scene = cs.smooth_scene(7, require_events=True)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    p = ks.project(g, scene.camera)
    W, H = scene.camera.width, scene.camera.height
    inputs = [getattr(p, k).numpy() for k in ("means2d", "conics", "colors", "opacities", "depths")]
    ref = rasterize_ref(*inputs, p.radii.numpy(), W, H, scene.background)
    s = ks.splats_2d(*(a.astype(dtype) for a in inputs), p.radii.numpy())
    r, _ = ks.rasterize(s, W, H, scene.background.astype(dtype))
    for got, want in zip((r.rgb, r.alpha, r.depth), ref):
        assert got.numpy().dtype == dtype
        np.testing.assert_allclose(got.numpy(), want, **TOL[dtype])
    assert ref[1].max() > 0.999  # some pixels reached the T < 1e-4 stop


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("antialiased", [False, True])
def test_render_matches_reference(dtype, antialiased):
    scene = cs.smooth_scene(8, antialiased=antialiased)
    params = as_dtype(scene.params, dtype)
    p64 = {k: v.astype(np.float64) for k, v in params.items()}
    proj = project_ref(p64, scene.camera, antialiased=antialiased)
    ref = rasterize_ref(proj["means2d"], proj["conics"], proj["colors"], proj["opacities"], proj["depths"],
                        proj["radii"], scene.camera.width, scene.camera.height, scene.background)
    r = ks.render(ks.gaussian_inputs(*(params[k] for k in PARAMS)), scene.camera, scene.background.astype(dtype),
                  antialiased=antialiased)
    for got, want in zip((r.rgb, r.alpha, r.depth), ref):
        np.testing.assert_allclose(got.numpy(), want, **TOL[dtype])


# --------------------------------------------------------------------------- gradients (float64 FD)


def test_project_gradients():
    assert_gradcheck(cs.project_checks())


def test_rasterize_gradients():
    assert_gradcheck(cs.rasterize_checks())


def test_render_gradients():
    assert_gradcheck(cs.render_checks())


def test_backward_independent_of_thread_count(monkeypatch):
    rng = np.random.default_rng(11)
    scene = cs.random_scene(rng, n=60, width=96, height=80)
    g = ks.gaussian_inputs(*(scene.params[k] for k in PARAMS))
    cot = rng.normal(size=(80, 96, 3))
    grads = []
    for threads in ("1", "2", "3"):
        monkeypatch.setenv("DRLAB_THREADS", threads)
        r = ks.render(g, scene.camera, scene.background)
        grads.append({k: v.numpy() for k, v in ks.render_backward(g, r, cot).items()})
    for other in grads[1:]:
        for k in grads[0]:
            np.testing.assert_array_equal(other[k], grads[0][k], err_msg=k)


# --------------------------------------------------------------------------- empty scenes and bad input


def _camera() -> ks.SplatCamera:
    view = np.eye(4)
    view[2, 3] = 4.0
    return ks.SplatCamera(view, np.array([[40.0, 0, 16], [0, 40.0, 12], [0, 0, 1]]), 32, 24)


def _params(n: int, rng=None) -> dict:
    rng = rng or np.random.default_rng(0)
    return {"means": rng.uniform(-0.3, 0.3, (n, 3)), "log_scales": rng.uniform(-2.5, -1.5, (n, 3)),
            "quats": rng.normal(size=(n, 4)), "opacity_logits": rng.normal(size=n),
            "sh": rng.normal(0, 0.2, (n, 16, 3))}


@pytest.mark.parametrize("case", ["empty", "all_culled"])
def test_empty_image_has_zero_gradients(case):
    params = _params(0 if case == "empty" else 5)
    if case == "all_culled":
        params["means"][:, 2] = -10.0  # every splat behind the camera
    cam = _camera()
    bg = np.array([0.2, 0.4, 0.6])
    g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
    r = ks.render(g, cam, bg)
    np.testing.assert_array_equal(r.rgb.numpy(), np.broadcast_to(bg, (24, 32, 3)))
    np.testing.assert_array_equal(r.alpha.numpy(), 0.0)
    np.testing.assert_array_equal(r.depth.numpy(), 0.0)
    grads = ks.render_backward(g, r, np.ones((24, 32, 3)), np.ones((24, 32)), np.ones((24, 32)))
    for k in PARAMS:
        assert grads[k].shape == params[k].shape
        np.testing.assert_array_equal(grads[k].numpy(), 0.0)
    np.testing.assert_array_equal(grads["background"].numpy(), 24 * 32)


def test_tiny_scales_stay_finite():
    params = _params(6)
    params["log_scales"][:] = -40.0  # splats far below a pixel: the dilation keeps them finite
    for aa in (False, True):
        g = ks.gaussian_inputs(*(params[k] for k in PARAMS))
        r = ks.render(g, _camera(), antialiased=aa)
        grads = ks.render_backward(g, r, np.ones((24, 32, 3)))
        assert np.all(np.isfinite(r.rgb.numpy()))
        assert all(np.all(np.isfinite(v.numpy())) for v in grads.values())


def _bad(**changes) -> dict:
    p = _params(4)
    p.update(changes)
    return p


@pytest.mark.parametrize("params, match", [
    (_bad(means=np.zeros((4, 2))), "means: expected shape"),
    (_bad(log_scales=np.zeros((3, 3))), "log_scales: expected shape"),
    (_bad(quats=np.zeros((4, 3))), "quats: expected shape"),
    (_bad(opacity_logits=np.zeros((4, 1))), "opacity_logits: expected shape"),
    (_bad(sh=np.zeros((4, 5, 3))), "sh: expected"),
    (_bad(sh=np.zeros((4, 16))), "sh: expected shape"),
    (_bad(means=np.zeros((4, 3), dtype=np.int64)), "means: expected float32 or float64"),
    (_bad(log_scales=np.zeros((4, 3), dtype=np.float32)), "log_scales: expected dtype float64"),
    (_bad(means=np.full((4, 3), np.nan)), "means: contains NaN"),
    (_bad(sh=np.full((4, 16, 3), np.inf)), "sh: contains NaN"),
    (_bad(quats=np.zeros((4, 4))), "quats: quaternion 0 has zero norm"),
    (_bad(log_scales=np.full((4, 3), -np.inf)), "log_scales: contains NaN or infinite"),
    (_bad(log_scales=np.full((4, 3), 200.0)), "log_scales: "),
])
def test_bad_gaussians(params, match):
    with pytest.raises(ValueError, match=match):
        ks.gaussian_inputs(*(params[k] for k in PARAMS))


def test_warp_array_inputs():
    p = _params(4)
    means = wp.array(p["means"], dtype=wp.float64, device="cpu")
    g = ks.gaussian_inputs(means, *(p[k] for k in PARAMS[1:]))
    assert g.means is means
    with pytest.raises(ValueError, match="log_scales: expected dtype float64"):
        ks.gaussian_inputs(means, *(p[k].astype(np.float32) for k in PARAMS[1:]))


def test_bad_camera_and_options():
    K = np.array([[40.0, 0, 16], [0, 40.0, 12], [0, 0, 1]])
    with pytest.raises(ValueError, match="viewmat"):
        ks.SplatCamera(np.diag([1.0, 1.0, -1.0, 1.0]), K, 32, 24)  # a reflection
    with pytest.raises(ValueError, match="K: expected"):
        ks.SplatCamera(np.eye(4), np.array([[40.0, 1.0, 16], [0, 40.0, 12], [0, 0, 1]]), 32, 24)
    with pytest.raises(ValueError, match="width"):
        ks.SplatCamera(np.eye(4), K, 0, 24)
    with pytest.raises(ValueError, match="near, far"):
        ks.SplatCamera(np.eye(4), K, 32, 24, near=-1.0)
    g = ks.gaussian_inputs(*(_params(4)[k] for k in PARAMS))
    with pytest.raises(ValueError, match="sh_degree"):
        ks.render(g, _camera(), sh_degree=4)
    with pytest.raises(ValueError, match="background: expected shape"):
        ks.render(g, _camera(), np.zeros(4))
    with pytest.raises(ValueError, match="camera: expected a SplatCamera"):
        ks.render(g, "cam")
    r = ks.render(g, _camera())
    with pytest.raises(ValueError, match="grad_rgb: expected shape"):
        ks.render_backward(g, r, np.ones((24, 32)))
    with pytest.raises(ValueError, match="grad_alpha: contains NaN"):
        ks.render_backward(g, r, np.ones((24, 32, 3)), np.full((24, 32), np.nan))


def test_bad_splats_2d():
    n = 3
    args = dict(means2d=np.zeros((n, 2)), conics=np.tile([1.0, 0.0, 1.0], (n, 1)), colors=np.zeros((n, 3)),
                opacities=np.full(n, 0.5), depths=np.ones(n), radii=np.full(n, 3))
    ks.splats_2d(**args)
    for key, value, match in [("conics", np.tile([1.0, 2.0, 1.0], (n, 1)), "positive definite"),
                              ("opacities", np.full(n, 1.5), "opacities: expected values in"),
                              ("radii", np.full(n, -1), "radii"),
                              ("radii", np.full(n, 1.0), "radii"),
                              ("depths", np.ones(n + 1), "depths: expected shape")]:
        with pytest.raises(ValueError, match=match):
            ks.splats_2d(**dict(args, **{key: value}))
    with pytest.raises(ValueError, match="height"):
        ks.rasterize(ks.splats_2d(**args), 16, 0)
