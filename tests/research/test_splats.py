"""research/splats: model, PLY files, Adam, loss, densification, training, comparison table."""

from __future__ import annotations

import inspect
import math
import subprocess
import sys
import warnings

import numpy as np
import pytest
import warp as wp

from kernels import splat as ks
from research.cameras import Camera, look_at
from research.gradcheck import assert_gradcheck, check_vjp
from research.splats import densify, loss, model as sm, optim, ply, train as st
from tests.research.splat_fixtures import moved_copy, ring_cameras, training_scene


def random_model(n: int, seed: int = 0) -> sm.GaussianModel:
    rng = np.random.default_rng(seed)
    return sm.GaussianModel(means=rng.normal(size=(n, 3)), log_scales=rng.uniform(-4, -1, (n, 3)),
                            quats=rng.normal(size=(n, 4)), opacity_logits=rng.normal(size=n),
                            sh_dc=rng.normal(size=(n, 1, 3)), sh_rest=rng.normal(size=(n, 15, 3)))


# --------------------------------------------------------------------------- model and PLY


def test_model_validates_shapes_and_values():
    m = random_model(3)
    with pytest.raises(ValueError, match="sh_rest: expected shape"):
        sm.GaussianModel(**{**m.arrays(), "sh_rest": np.zeros((3, 8, 3))})
    with pytest.raises(ValueError, match="means: contains NaN"):
        sm.GaussianModel(**{**m.arrays(), "means": np.full((3, 3), np.nan)})


def test_ply_round_trip(tmp_path):
    m = random_model(25)
    path = ply.save_ply(tmp_path / "a.ply", m)
    back = ply.load_ply(path)
    for k, v in m.arrays().items():
        np.testing.assert_array_equal(getattr(back, k), v, err_msg=k)
    header = path.read_bytes().split(b"end_header\n")[0].decode().splitlines()
    props = [line.split()[2] for line in header if line.startswith("property")]
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert props[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert path.stat().st_size == len("\n".join(header)) + len("end_header\n") + 25 * 62 * 4 + 1


def test_ply_f_rest_is_channel_major(tmp_path):
    m = random_model(1)
    m.sh_rest[0] = np.arange(45, dtype=np.float32).reshape(15, 3)  # coefficient k, channel c -> 3k + c
    raw = ply.to_bytes(m)
    body = np.frombuffer(raw.split(b"end_header\n", 1)[1], dtype="<f4")
    f_rest = body[9:54]
    for c in range(3):
        for k in range(15):
            assert f_rest[c * 15 + k] == 3 * k + c


def write_ply(path, props: dict, *, text: bool = False, byte_order: str = "<", extra_elements=()) -> None:
    """A PLY file written with plyfile: `props` maps name -> array (its dtype is the property type)."""
    from plyfile import PlyData, PlyElement

    n = len(next(iter(props.values())))
    data = np.zeros(n, dtype=[(k, np.asarray(v).dtype.str.replace(">", "<")) for k, v in props.items()])
    for k, v in props.items():
        data[k] = v
    elements = [PlyElement.describe(data, "vertex")] + list(extra_elements)
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))


def layout_props(m: sm.GaussianModel, n_rest: int = 15, normals: bool = True, dtype=np.float32) -> dict:
    """The 3DGS vertex properties of `m` (the first `n_rest` SH coefficients per channel)."""
    rest = m.sh_rest[:, :n_rest].transpose(0, 2, 1).reshape(m.n, -1)
    props = {a: m.means[:, i] for i, a in enumerate("xyz")}
    if normals:
        props.update({k: np.zeros(m.n, np.float32) for k in ("nx", "ny", "nz")})
    props.update({f"f_dc_{c}": m.sh_dc[:, 0, c] for c in range(3)})
    props.update({f"f_rest_{i}": rest[:, i] for i in range(rest.shape[1])})
    props["opacity"] = m.opacity_logits
    props.update({f"scale_{i}": m.log_scales[:, i] for i in range(3)})
    props.update({f"rot_{i}": m.quats[:, i] for i in range(4)})
    return {k: np.asarray(v, dtype=dtype) for k, v in props.items()}


def assert_same_model(a: sm.GaussianModel, b: sm.GaussianModel) -> None:
    for k, v in a.arrays().items():
        np.testing.assert_array_equal(getattr(b, k), v, err_msg=k)


def test_ply_reference_file_round_trips_byte_identical(tmp_path):
    """A file as the 3DGS code writes it (plyfile, float32, native little endian) -> model -> file."""
    m = random_model(9, seed=4)
    write_ply(tmp_path / "ref.ply", layout_props(m), byte_order="=")
    back = ply.load_ply(tmp_path / "ref.ply")
    assert_same_model(m, back)
    assert ply.to_bytes(back) == (tmp_path / "ref.ply").read_bytes()
    assert ply.save_ply(tmp_path / "again.ply", back).read_bytes() == (tmp_path / "ref.ply").read_bytes()


@pytest.mark.parametrize("fmt", ["ascii", "big_endian", "no_normals", "float64", "float64_big_endian",
                                 "extra_property", "extra_element"])
def test_ply_reads_other_writers_files(tmp_path, fmt):
    from plyfile import PlyElement

    m = random_model(6, seed=5)
    props = layout_props(m, normals=fmt != "no_normals", dtype=np.float64 if "float64" in fmt else np.float32)
    kw = {}
    if fmt == "ascii":
        kw["text"] = True
    if "big_endian" in fmt:
        kw["byte_order"] = ">"
    if fmt == "extra_property":
        props["red"] = np.arange(6, dtype=np.uint8)
    if fmt == "extra_element":
        face = np.array([([0, 1, 2],), ([2, 3, 4],)], dtype=[("vertex_indices", "O")])
        kw["extra_elements"] = [PlyElement.describe(face, "face")]
    write_ply(tmp_path / f"{fmt}.ply", props, **kw)
    if fmt.startswith("extra"):
        with pytest.warns(ply.PlyNote, match="red|face") as rec:
            back = ply.load_ply(tmp_path / f"{fmt}.ply")
        assert len(rec) == 1 and "\n" not in str(rec[0].message)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            back = ply.load_ply(tmp_path / f"{fmt}.ply")
    # ASCII stores shortest round-trip decimals of the float32 values, so every format is exact.
    assert_same_model(m, back)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply_sh_degree_from_the_f_rest_count(tmp_path, degree):
    m = random_model(5, seed=degree)
    k = (degree + 1) ** 2 - 1
    write_ply(tmp_path / "d.ply", layout_props(m, n_rest=k))
    back = ply.load_ply(tmp_path / "d.ply")
    np.testing.assert_array_equal(back.sh_rest[:, :k], m.sh_rest[:, :k])
    np.testing.assert_array_equal(back.sh_rest[:, k:], 0.0)
    np.testing.assert_array_equal(back.sh_dc, m.sh_dc)


def test_ply_has_no_hand_written_parser():
    src = inspect.getsource(ply)
    assert "plyfile" in src and "end_header" not in src and "frombuffer" not in src


def test_from_points_follows_3dgs_init():
    rng = np.random.default_rng(0)
    pts, cols = rng.uniform(-1, 1, (50, 3)), rng.uniform(0, 1, (50, 3))
    m = sm.from_points(pts, cols)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    d3 = np.sort(d, axis=1)[:, 1:4]
    np.testing.assert_allclose(np.exp(m.log_scales), np.sqrt((d3**2).mean(1))[:, None].repeat(3, 1), rtol=1e-5)
    np.testing.assert_allclose(ks.SH_C0 * m.sh_dc[:, 0] + 0.5, cols, atol=1e-6)
    np.testing.assert_allclose(m.opacities, 0.1, rtol=1e-5)
    assert np.all(m.quats == [1, 0, 0, 0]) and np.all(m.sh_rest == 0)
    with pytest.raises(ValueError, match="colors: expected shape"):
        sm.from_points(pts, cols[:3])


def test_points_from_depth_and_random_points():
    cam = Camera.from_fov(60.0, 8, 6, look_at([0, 0, 3], [0, 0, 0], up=[0, 1, 0]))
    depth = np.full((1, 6, 8), 2.0)
    depth[0, 0, 0] = 0.0
    rgba = np.zeros((1, 6, 8, 4), np.float32)
    rgba[..., :3] = 0.25
    rgba[..., 3] = 0.5
    pts, cols = sm.points_from_depth([cam], rgba, depth, 100, 0)
    assert len(pts) == 47
    np.testing.assert_allclose(cam.world_to_camera(pts)[:, 2], 2.0, atol=1e-12)
    np.testing.assert_allclose(cols, 0.5)
    pts, _ = sm.points_from_depth([cam], rgba, depth, 10, 0)
    assert len(pts) == 10
    box = np.array([[0, 1, 2], [1, 2, 4.0]])
    pts, cols = sm.random_points(box, 200, 1)
    assert np.all(pts >= box[0]) and np.all(pts <= box[1]) and cols.shape == (200, 3)


def test_points_from_sfm_decodes_srgb_and_keeps_a_subset_in_order():
    from research.io import srgb_to_linear

    pts = np.arange(30.0).reshape(10, 3)
    srgb = np.linspace(0.0, 1.0, 30).reshape(10, 3)
    same, cols = sm.points_from_sfm(pts, srgb, 10, 0)
    assert same is pts
    np.testing.assert_array_equal(cols, srgb_to_linear(srgb))
    kept, kept_cols = sm.points_from_sfm(pts, srgb, 4, 0)
    rows = (kept[:, 0] // 3).astype(int)
    assert len(kept) == 4 and np.all(np.diff(rows) > 0)
    np.testing.assert_array_equal(kept_cols, srgb_to_linear(srgb)[rows])


# --------------------------------------------------------------------------- Adam and schedules


def test_adam_matches_pytorch_formula():
    m = random_model(5)
    lrs = {k: 0.01 * (i + 1) for i, k in enumerate(m.names())}
    adam = optim.make_adam(m, lrs)
    assert (adam.b1, adam.b2, adam.eps) == (0.9, 0.999, 1e-15)  # 3DGS's settings
    rng = np.random.default_rng(1)
    ref = {k: v.astype(np.float64).copy() for k, v in m.arrays().items()}
    mom = {k: np.zeros_like(v) for k, v in ref.items()}
    vel = {k: np.zeros_like(v) for k, v in ref.items()}
    for t in (1, 2, 3):
        grads = {k: rng.normal(size=v.shape).astype(np.float32) for k, v in m.arrays().items()}
        adam.step(grads, params=m.arrays())
        for k in ref:
            g = grads[k].astype(np.float64)
            mom[k] = 0.9 * mom[k] + 0.1 * g
            vel[k] = 0.999 * vel[k] + 0.001 * g * g
            m_hat, v_hat = mom[k] / (1 - 0.9**t), vel[k] / (1 - 0.999**t)
            ref[k] -= lrs[k] * m_hat / (np.sqrt(v_hat) + 1e-15)
    for k in ref:
        np.testing.assert_allclose(getattr(m, k), ref[k], rtol=1e-5, atol=1e-6, err_msg=k)
    adam.select(np.array([True, False, True, True, False]))
    adam.append(2)
    assert adam.m["means"].shape == (5, 3) and np.all(adam.m["means"][3:] == 0)
    adam.reset("opacity_logits")
    assert np.all(adam.v["opacity_logits"] == 0)
    with pytest.raises(ValueError, match="lr: expected one rate per parameter"):
        optim.make_adam(m, {"means": 1.0})


def test_expon_lr_and_schedule():
    assert optim.expon_lr(0, 1e-3, 1e-5, 100) == pytest.approx(1e-3)
    assert optim.expon_lr(50, 1e-3, 1e-5, 100) == pytest.approx(1e-4)
    assert optim.expon_lr(500, 1e-3, 1e-5, 100) == pytest.approx(1e-5)
    full = densify.Schedule.scaled(30_000)
    assert (full.densify_from, full.densify_until, full.densify_interval, full.reset_interval,
            full.sh_interval) == (500, 15_000, 100, 3_000, 1_000)
    short = densify.Schedule.scaled(3_000)
    assert (short.densify_from, short.densify_until, short.densify_interval, short.reset_interval,
            short.sh_interval) == (50, 1_500, 50, 500, 100)
    assert [short.sh_degree(i) for i in (0, 99, 100, 250, 300, 9999)] == [0, 0, 1, 2, 3, 3]
    assert short.densify_now(100) and not short.densify_now(125) and not short.densify_now(1500)
    assert short.reset_now(1000) and not short.reset_now(1500)


# --------------------------------------------------------------------------- loss


def test_l1_dssim_gradient():
    rng = np.random.default_rng(0)
    target = rng.uniform(0, 1, (12, 14, 3))
    offset = rng.choice([-1.0, 1.0], target.shape) * rng.uniform(0.02, 0.1, target.shape)  # |diff| > 0.02

    def f(pred):
        return np.array(loss.l1_dssim(pred, target)[0])

    def vjp(inputs, cot):
        return {"pred": float(cot) * loss.l1_dssim(inputs["pred"], target)[1]}

    assert_gradcheck(check_vjp(f, vjp, {"pred": target + offset}, name="splats.l1_dssim"))
    value, _, parts = loss.l1_dssim(target + offset, target)
    assert value == pytest.approx(0.8 * np.abs(offset).mean() + 0.2 * (1 - parts["ssim"]))
    with pytest.raises(ValueError, match="lambda_dssim"):
        loss.l1_dssim(target, target, lambda_dssim=1.5)


# --------------------------------------------------------------------------- densification


def test_stats_use_ndc_gradients():
    stats = densify.DensifyStats(3)
    stats.add(np.array([[1.0, 0.0], [0.0, 2.0], [5.0, 5.0]]), np.array([3, 4, 0]), width=100, height=50)
    stats.add(np.array([[3.0, 0.0], [0.0, 0.0], [5.0, 5.0]]), np.array([5, 0, 0]), width=100, height=50)
    np.testing.assert_allclose(stats.mean_grad(), [100.0, 50.0, 0.0])
    np.testing.assert_array_equal(stats.max_radii, [5, 4, 0])


def _densify_case():
    m = random_model(6, seed=3)
    m.log_scales[:] = np.log(0.001)
    m.log_scales[1] = np.log([0.5, 0.2, 0.1])  # big: split
    m.opacity_logits[:] = 2.0
    m.opacity_logits[2] = -8.0  # opacity 3e-4: pruned
    stats = densify.DensifyStats(6)
    stats.grad_sum[:] = [1e-3, 1e-3, 0, 0, 5e-3, 1e-5]  # 0, 1, 4 over the threshold
    stats.count[:] = 1
    return m, stats


def test_densify_clone_split_prune():
    m, stats = _densify_case()
    adam = optim.make_adam(m, {k: 1.0 for k in m.names()})
    for k in adam.m:
        adam.m[k][:] = 1.0
    new, counts = densify.densify_and_prune(m, adam, stats, extent=1.0, cfg=densify.DensifyConfig(),
                                            rng=np.random.default_rng(0), prune_screen=False)
    assert counts == {"cloned": 2, "split": 1, "pruned": 1}
    assert new.n == 6 + 2 + 2 - 1 - 1
    kept = [0, 3, 4, 5]
    np.testing.assert_array_equal(new.means[:4], m.means[kept])
    np.testing.assert_array_equal(new.means[4:6], m.means[[0, 4]])  # the clones
    np.testing.assert_allclose(np.exp(new.log_scales[6:]), np.exp(m.log_scales[[1, 1]]) / 1.6, rtol=1e-6)
    offsets = new.means[6:] - m.means[1]
    assert np.all(np.linalg.norm(offsets, axis=1) < 2.0) and not np.allclose(offsets, 0)
    assert adam.m["means"].shape == (8, 3)
    np.testing.assert_array_equal(adam.m["means"][:4], 1.0)
    np.testing.assert_array_equal(adam.m["means"][4:], 0.0)


def test_densify_cap_and_screen_prune():
    m, stats = _densify_case()
    adam = optim.make_adam(m, {k: 1.0 for k in m.names()})
    new, counts = densify.densify_and_prune(m, adam, stats, 1.0, densify.DensifyConfig(max_gaussians=7),
                                            np.random.default_rng(0), prune_screen=False)
    assert counts["cloned"] + counts["split"] == 1 and counts["cloned"] == 1  # only the largest gradient (4)
    m, stats = _densify_case()
    stats.grad_sum[:] = 0
    stats.max_radii[3] = 25.0
    adam = optim.make_adam(m, {k: 1.0 for k in m.names()})
    new, counts = densify.densify_and_prune(m, adam, stats, 1.0, densify.DensifyConfig(),
                                            np.random.default_rng(0), prune_screen=True)
    # splat 2: opacity; 3: screen size; 1: world size 0.5 > 0.1 * extent
    assert counts["pruned"] == 3 and new.n == 3


def test_reset_opacity():
    m = random_model(4)
    m.opacity_logits[:] = [-6.0, 0.0, 3.0, -4.0]
    adam = optim.make_adam(m, {k: 1.0 for k in m.names()})
    adam.v["opacity_logits"][:] = 1.0
    densify.reset_opacity(m, adam)
    np.testing.assert_allclose(m.opacities, [1 / (1 + math.exp(6)), 0.01, 0.01, 0.01], rtol=1e-5)
    assert np.all(adam.v["opacity_logits"] == 0)


# --------------------------------------------------------------------------- training


def test_training_reduces_the_loss():
    truth = random_model(40, seed=5)
    truth.means *= 0.4
    truth.sh_rest[:] = 0.0
    cams, images = training_scene(truth)
    start = moved_copy(truth, np.random.default_rng(0), 0.1)
    start.sh_dc[:] = 0.0
    cfg = st.TrainConfig(iterations=60, max_sh_degree=1, log_every=10)
    result = st.train(start, cams, images, extent=sm.scene_extent(cams), cfg=cfg, progress=False)
    assert result.history[-1]["loss"] < 0.8 * result.history[0]["loss"]
    before = st.evaluate(start, cams, images, 0).psnr
    after = st.evaluate(result.model, cams, images, result.sh_degree).psnr
    assert after > before + 2.0
    assert st.render_fps(result.model, cams[:2], result.sh_degree, device=result.device) > 0
    with pytest.raises(ValueError, match="images: expected"):
        st.train(start, cams, images[:3], 1.0, cfg, progress=False)


# --------------------------------------------------------------------------- comparison and CLI


def test_experiment_help():
    out = subprocess.run([sys.executable, "experiments/fit_splats.py", "--help"], capture_output=True, text=True,
                         check=True, cwd=str(__import__("research.registry", fromlist=["REPO_ROOT"]).REPO_ROOT))
    assert "--quick" in out.stdout and "--seed" in out.stdout and "PSNR" in out.stdout


def test_every_stage_runs_on_the_training_device(monkeypatch, tmp_path):
    """Training, evaluation, the FPS timing and the PLY check render on the device training used.

    A stand-in for a GPU: the CPU device object itself is passed, and the functions that put the
    model's arrays on a device (GaussianModel.inputs) and resolve the kernels' device
    (kernels.splat.gaussian_inputs) record the device argument they are given. A stage that
    forgets the device passes a default ("cpu" or None) instead of this object.
    """
    device = wp.get_device("cpu")
    seen = []
    real_inputs, real_gaussians = sm.GaussianModel.inputs, ks.gaussian_inputs

    def model_inputs(self, device=None):
        seen.append(device)
        return real_inputs(self, device)

    def gaussian_inputs(*arrays, device=None):
        seen.append(device)
        return real_gaussians(*arrays, device=device)

    monkeypatch.setattr(sm.GaussianModel, "inputs", model_inputs)
    monkeypatch.setattr(ks, "gaussian_inputs", gaussian_inputs)
    cams = ring_cameras(16, (0.0, 2.0, 4.0))
    truth = random_model(10, seed=5)
    truth.means *= 0.4
    truth.log_scales[:] = np.log(0.2)
    images = np.stack([sm.render(truth, c, sh_degree=0, device=device).rgb.numpy() for c in cams])
    stages = {}
    for stage, run in [
        ("train", lambda: st.train(truth, cams, images, 1.0, st.TrainConfig(iterations=2, log_every=1),
                                   progress=False, device=device)),
        ("evaluate", lambda: st.evaluate(truth, cams, images, 0, device=device)),
        ("render_fps", lambda: st.render_fps(truth, cams[:1], 0, device=device)),
        ("ply", lambda: st.ply_round_trip_identical(tmp_path / "m.ply", truth, cams[0], 3, device=device)),
    ]:
        seen.clear()
        out = run()
        stages[stage] = list(seen)
        if stage == "train":
            assert out.device is device
        if stage == "ply":
            assert out is True
    for stage, devices in stages.items():
        assert devices and all(d is device for d in devices), (stage, devices)
