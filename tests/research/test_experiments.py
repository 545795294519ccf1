"""The experiment contract (research.experiment) and every registered experiment's smoke run.

Each experiment runs in its own process, as `drlab run` starts it (`python -m experiments.<name>`),
with --smoke: tiny sizes, seconds each. The results folder must hold metrics.json and table.md with
the run's provenance, and numbers that make sense for that experiment.
"""

from __future__ import annotations

import importlib
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from research import experiment
from research.registry import EXPERIMENTS, REPO_ROOT, family_modules
from tests.wheel_build import build_wheel, can_build_wheels

SHARED_OPTIONS = ("--quick", "--smoke", "--device", "--out", "--seed", "--data", "--no-progress")


def _env() -> dict[str, str]:
    """Import this checkout's code in child processes, whatever the current directory."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


def _run(args: list[str], cwd: Path | str = REPO_ROOT, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=cwd, env=_env(), capture_output=True, text=True,
                          timeout=timeout)


# --------------------------------------------------------------------------- smoke runs


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def _check_datasets(m):
    assert set(m["scenes"]) == {"objects", "spheres", "cornell"}
    for s in m["scenes"].values():
        assert s["aov"]["pixel_err_max"] < 1e-2  # the stored cameras agree with Mitsuba's own positions
        assert 0.5 < s["stereo"]["noc_fraction"] <= 1.0 and 0.5 < s["flow"]["valid_fraction"] <= 1.0


def _check_kalman(m):
    for method in m["methods"].values():
        assert method["smoother_rmse"]["mean"] < m["observation_rmse"]["mean"]
    assert m["methods"]["cv_white_accel"]["filter_rmse"]["mean"] < m["observation_rmse"]["mean"]


def _check_mot(m):
    assert set(m["trackers"]) >= {"sort", "bytetrack", "bytetrack_app"}
    for t in m["trackers"].values():
        assert -1.0 <= t["mota"] <= 1.0 and 0.0 <= t["idf1"] <= 1.0 and t["fps"] > 0


def _check_lucas_kanade(m):
    # The task itself is the same at every size: the pyramid recovers the 5 px motion.
    assert abs(m["runs"]["kernels.lucas_kanade pyramidal, 3 levels x 10 steps"]["mean_u_valid"] - 5.0) < 0.1


def _check_raft(m):
    scene = m["per_scene"]["objects"]
    assert all(_finite(v["epe"]) and v["epe"] >= 0 for v in scene.values())
    assert scene["CorrFlow (L=4, r=4)"]["epe"] < scene["zero flow"]["epe"]
    c2f = "C2F correlation flow (default)"
    assert scene[c2f]["epe"] < scene["zero flow"]["epe"]
    for condition in ("clean", "stressed"):
        assert m["radiometric"][condition][c2f]["epe"] < m["radiometric"][condition]["zero flow"]["epe"]
    photo = m["real_texture"]["methods"]
    assert photo[c2f]["epe"] < photo["zero flow"]["epe"] and photo[c2f]["epe"] < photo["OpenCV Farneback"]["epe"]
    assert m["cell"]["levels"] == 4 and m["cell"]["radius"] == 4 and len(m["ablation"]) == 16


def _check_stereo(m):
    for r in m["methods"].values():
        assert 0.0 <= r["pooled"]["d1"] <= 1.0 and 0.0 < r["pooled"]["density"] <= 1.0
        assert 0.0 <= r["pooled_stressed"]["d1"] <= 1.0 and 0.0 <= r["tuning_d1_stressed"] <= 1.0
    assert m["best_drlab"] in m["methods"] and m["robust_drlab"] in m["methods"]
    assert "OpenCV StereoSGBM" in m["methods"]
    # drlab's default runs as it is (research.stereo.matching.DEFAULT_CONFIG), never picked as the grid's best or robust one.
    from research.stereo.matching import DEFAULT_CONFIG

    default = m["methods"][m["default_drlab"]]
    assert default["family"] == "drlab-default" and default["params"]["cost"] == DEFAULT_CONFIG.cost
    assert default["params"]["p1"] == DEFAULT_CONFIG.p1 and default["params"]["median"] == DEFAULT_CONFIG.median
    assert m["default_drlab"] not in (m["best_drlab"], m["robust_drlab"])


def _check_splats(m):
    assert m["ply_roundtrip_identical"] is True
    assert _finite(m["test_psnr"]) and m["test_psnr"] > 5 and m["gaussians"] > 0 and m["render_fps"] > 0


def _check_nerf(m):
    assert set(m["fields"]) == {"grid", "hashgrid", "pe_mlp"}
    for f in m["fields"].values():
        assert _finite(f["eval"]["mean"]["psnr"]) and f["eval"]["mean"]["psnr"] > 5 and f["params"] > 0
    assert m["noise_floor"]["psnr_between_two_renders"] > 5


def _check_volume(m):
    assert m["max_abs_err"]["warp_float64"] <= m["agreement_tol"]
    assert m["max_abs_err"]["warp_float32"] < 1e-3
    # the timed render_dense and the general path: one image bit for bit on the CPU
    for v in m["render_dense_vs_general_path"].values():
        assert v["bitwise_equal"] and v["max_abs_diff"] == 0.0


def _check_performance(m):
    assert {r["bench"].split(".")[0] for r in m["rows"]} == set(family_modules("bench"))
    assert all(r["threads"] >= 1 and r["cpu"] for r in m["rows"])
    assert m["targets"] and all(t["status"].startswith("n/a") for t in m["targets"])  # smoke sizes


def _check_sfm_poses(m):
    assert m["registered"] >= m["total"] // 2 and m["registered"] <= m["total"]
    # smoke (48 views at 4 spp) measured 48/48, 1.8 deg median, 2% of the scene radius
    assert m["pose_errors"]["rotation_deg_median"] < 10.0 and m["translation_median_pct"] < 15.0
    assert _finite(m["splats"]["sfm_poses"]["psnr"]) and _finite(m["splats"]["gt_poses"]["psnr"])


def _check_real_photos(m):
    # smoke: the synthetic 16-view capture in the Middlebury format (seed 3) measured 16/16, 0.66 deg median,
    # 0.9% of the scene radius, focal -0.2%
    assert m["registered"] >= m["images"] // 2 and m["registered"] <= m["images"]
    assert m["pose_errors"]["rotation_deg_median"] < 10.0 and m["centre_error_median_pct"] < 15.0
    assert abs(m["focal_error_pct"]) < 10.0
    for fit in ("calibrated", "sfm"):
        assert _finite(m["splats"][fit]["psnr"]) and m["splats"][fit]["psnr"] > 5


def _check_oracle(m):
    assert m["worst_float64_rel"] <= 1e-10  # drlab conforms to its Dr.Jit oracle in float64
    for case in m["cases"].values():
        assert case["float32"]["fwd_rel"] < 1e-3  # float32 rounding, not a different formula


def _check_pose_refinement(m):
    assert set(m["runs"]) == {"gt", "noisy", "refined", "refined_rgbd"}  # refined_rgbd: default depth weight
    for r in m["runs"].values():
        assert _finite(r["test_psnr"]) and r["test_psnr"] > 3
    # ground-truth poses are never moved; 1e-5 deg, not 1e-6: arccos of a rotation trace 1 ulp below 3
    # is already 1.2e-6 deg, and the Sim(3) alignment's SVD rounds at that level
    assert m["runs"]["gt"]["errors"]["rot_max_deg"] < 1e-5
    assert abs(m["errors_before_unaligned"]["rot_mean_deg"] - m["perturbation"]["rot_deg"]) < 1e-6
    assert m["model"] == "splats" and m["joint"]["refine_poses"] and m["refined_length"] == 1  # the default model
    assert m["joint"]["iterations"] == m["iterations"] and m["refine_passes"] == 1
    for run in ("refined", "refined_rgbd"):  # the poses moved
        assert m["runs"][run]["errors"]["rot_max_deg"] != m["errors_before"]["rot_max_deg"]
    assert m["depth_weight_rgbd"] > 0 and m["runs"]["refined"]["final_loss"] != m["runs"]["refined_rgbd"]["final_loss"]
    # the test views' poses optimised against each fixed model (test-time pose optimisation)
    assert all(np.isfinite(r["test_psnr_tto"]) and r["test_psnr_tto"] > 3 for r in m["runs"].values())


def _check_feature_vo(m):
    assert m["frames"] == 60 and not m["tracking_failures"] and m["keyframes"] >= 10
    # smoke (60 frames at 128 px, 4 spp, seed 3) measured 1.92% -> 1.71% of the path, 2 loops (frame 59 -> 0, 1)
    before, after = m["before_loop_closure"], m["after_loop_closure"]
    assert before["ate_pct_of_path"] < 6.0 and after["ate_pct_of_path"] <= before["ate_pct_of_path"] + 1e-9
    assert m["loops"] and m["pose_graph"]["cost_after"] < m["pose_graph"]["cost_before"]
    ba = m["bundle_adjustments"]  # robust (Huber) cost, so the plain RMS is compared on average
    assert ba and np.mean([b["rms_after_px"] for b in ba]) < np.mean([b["rms_before_px"] for b in ba])


def _check_slam(m):
    assert m["frames"] == 8 and m["path_length"] > 0 and m["fps"] > 0 and m["splats"] > 0
    assert _finite(m["ate"]["rmse"])
    assert m["ate"]["pct_of_path"] == pytest.approx(100 * m["ate"]["rmse"] / m["path_length"])
    assert _finite(m["held_out"]["psnr"]) and m["held_out"]["psnr"] > 5 and len(m["per_frame"]) == 8


def _check_lens_distortion(m):
    assert [(r["lens"], r["route"]) for r in m["rows"]] == [("opencv", r) for r in ("lens", "undistorted", "ignored")]
    assert all(_finite(r[f"{es}_psnr"]) and r[f"{es}_psnr"] > 5 for r in m["rows"]
               for es in ("distorted", "undistorted", "pinhole", "wide"))
    assert m["lenses"]["opencv"]["undistorted_invalid_pixels"] == 0  # barrel: OpenCV finds a source for every pixel


def _check_time_budget(m):
    runs = m["runs"]
    assert [r["iterations"] for r in runs if r["method"] == "splats"] == [10, 30]
    assert [r["scale"] for r in runs if r["method"] == "hashgrid"] == [0.5, 1.0]
    assert all(_finite(r["psnr"]) and r["psnr"] > 5 and r["wall_s"] > 0 and r["cpu_s"] > 0 for r in runs)
    for row, budget in zip(m["budget_table"], m["budgets_min"]):  # the best run that fits in each budget
        for method in ("splats", "hashgrid"):
            fit = [r["psnr"] for r in runs if r["method"] == method and r["wall_s"] <= 60 * budget]
            assert row[method].startswith(f"{max(fit):.2f} (") if fit else row[method].startswith("-")


def _check_surface_recon(m):
    rows = m["results"]
    assert {"gt/drlab", "splats/drlab", "field/drlab"} <= set(rows)
    for r in rows.values():
        assert r["faces"] > 0 and _finite(r["chamfer"]) and 0 <= r["normal_consistency"] <= 1
        assert all(0 <= t["fscore"] <= 1 for t in r["per_threshold"]) and r["views"] > 0
    assert all(rows[f"{s}/drlab"]["ply"]["round_trip_identical"] for s in ("gt", "splats", "field"))
    if m["open3d"] is not None:  # the same algorithm on the same voxels: the same mesh size
        assert rows["gt/open3d"]["faces"] == rows["gt/drlab"]["faces"]


def _check_splat_densification(m):
    base, equal_n, equal_t = (m["models"][k] for k in ("3DGS", "MCMC, equal count", "MCMC, equal time"))
    assert m["cap"] == base["splats"] and equal_n["iterations"] == base["iterations"]
    assert equal_n["strategy"] == equal_t["strategy"] == "mcmc" and base["strategy"] == "3dgs"
    assert all(f["splats"] <= m["cap"] and _finite(f["psnr"]) and f["cpu_seconds"] > 0 for f in (equal_n, equal_t))
    abs_n, abs_t = m["models"]["AbsGS, equal count"], m["models"]["AbsGS, equal time"]
    assert abs_n["iterations"] == base["iterations"] and m["absgrad_threshold"]["value"] == 0.0008
    for f in (abs_n, abs_t):
        assert f["strategy"] == "3dgs" and f["train"]["densify"]["absgrad"] and f["splats"] <= m["cap"]
        assert f["train"]["densify"]["grad_threshold"] == 0.0008 and _finite(f["psnr"]) and f["cpu_seconds"] > 0
    assert not base["train"]["densify"]["absgrad"]


def _check_splat_geometry(m):
    rows, models = m["rows"], m["models"]
    assert set(rows) == {f"{k}, {d}" for k in ("3DGS", "3DGS + L_n") for d in ("expected", "median")}
    for r in rows.values():
        assert r["absrel"] >= 0 and r["rmse"] >= 0 and 0 <= r["normal_mean_deg"] <= 180 and r["pixels"] > 0
    assert models["3DGS"]["train"]["normal_weight"] == 0 and models["3DGS + L_n"]["train"]["normal_weight"] == 0.05
    assert all(_finite(f["psnr"]) for f in models.values())
    # the operator on the true depth is far better than chance (90 degrees)
    assert m["operator_floor"]["normal_median_deg"] < 30


def _check_lidar(m):
    methods = m["methods"]
    assert m["frames"] == 5 and m["returns_per_scan"] > 1000 and len(methods) == 4 + (m["kiss_icp"] is not None)
    assert all(_finite(r["ate_rmse"]) and r["ms_per_scan"] > 0 for r in methods.values())
    # smoke (seed 0) measured 0.020 m for point-to-plane scan-to-map, 0.13-0.18 m for point-to-point
    assert methods["drlab point-to-plane, scan-to-map"]["ate_rmse"] < 0.05
    pairs = m["single_registrations"]
    if pairs["open3d"] is not None:  # the same objective, run to convergence: the same pose
        assert all(e["rot_deg"] < 1e-4 for r in pairs["methods"].values()
                   for e in r["diff_to_other_library_converged"] if e["drlab_converged"])


def _check_pointnet(m):
    assert set(m["methods"]) == {"d2_pca_knn", "pointnet", "pointnet_sa"} and m["chance"] == pytest.approx(1 / 9)
    assert all(0.0 <= r["test_accuracy"] <= 1.0 for r in m["methods"].values())
    for k in ("pointnet", "pointnet_sa"):
        assert m["methods"][k]["params"] > 0 and len(m["methods"][k]["train_loss"]) == 2
    # the plain Warp MLP gives a permuted cloud's logits to the bit (research/pointnet/model.py)
    assert m["permutation"]["pointnet"]["warp_backend"]["bit_equal"]
    assert m["permutation"]["pointnet_sa"]["warp_backend"]["bit_equal"]


def _check_splat_antialiasing(m):
    assert m["scales"] == [0.25, 0.5, 1.0, 2.0]
    models = m["models"]
    assert list(models) == ["3DGS", "2D Mip filter", "3D filter", "Mip-Splatting (3D + 2D)"]
    assert [r["model"]["filter_3d"] for r in models.values()] == [0.0, 0.0, 0.2, 0.2]
    for r in models.values():
        scores = r["per_scale"]
        assert list(scores) == ["0.25x", "0.5x", "1x", "2x"] and r["splats"] > 0 and r["train_seconds"] > 0
        assert all(_finite(s["psnr"]) and s["psnr"] > 5 and 0 <= s["ssim"] <= 1 for s in scores.values())
        assert r["mean_psnr"] == pytest.approx(sum(s["psnr"] for s in scores.values()) / 4)



def _check_splat_appearance(m):
    assert m["models"] == ["none", "affine", "bilateral"] and len(m["sets"]) == 2
    for s in m["sets"].values():
        assert len(s["responses"]) == s["train_views"] and s["test_views"] >= 1
        rows = s["models"]
        assert rows["none"]["gain_vs_exposure_corr"] is None
        for r in rows.values():
            assert _finite(r["psnr"]) and r["psnr"] > 5 and 0 <= r["ssim"] <= 1 and r["splats"] > 0
            # the best affine fit of the render can only lower the squared error in linear RGB; on sRGB after
            # clipping it may differ slightly, never by much
            assert r["psnr_corrected"] > r["psnr"] - 1.0

def _check_unbounded_fields(m):
    scene = m["scenes"]["backdrop"]
    assert set(scene["methods"]) == {"baseline", "contracted"} and 0.3 < scene["background_fraction"] < 1.0
    for r in scene["methods"].values():
        mean = r["mean"]
        assert all(_finite(mean[k]) for k in ("psnr", "ssim", "bg_psnr", "bg_ssim", "fg_psnr", "fg_ssim"))
        assert r["train_s"] > 0
        assert mean["psnr"] > 3 and -1 <= mean["ssim"] <= 1 and r["params"] > 0
    assert scene["methods"]["contracted"]["config"]["n_main"] == 8 and "fern" not in m["scenes"]


CHECKS = {"performance": _check_performance, "datasets": _check_datasets, "kalman_tracking": _check_kalman,
          "mot_tracking": _check_mot, "lucas_kanade": _check_lucas_kanade, "raft_flow": _check_raft,
          "stereo_depth": _check_stereo, "fit_splats": _check_splats, "fit_nerf": _check_nerf,
          "volume_render_spheres": _check_volume, "sfm_poses": _check_sfm_poses, "real_photos": _check_real_photos,
          "oracle_conformance": _check_oracle, "splat_densification": _check_splat_densification,
          "splat_geometry": _check_splat_geometry,
          "pose_refinement": _check_pose_refinement, "feature_vo": _check_feature_vo,
          "lidar_odometry": _check_lidar,
          "splat_slam": _check_slam, "time_budget": _check_time_budget, "lens_distortion": _check_lens_distortion,
          "surface_recon": _check_surface_recon, "pointnet_classify": _check_pointnet,
          "splat_antialiasing": _check_splat_antialiasing, "splat_appearance": _check_splat_appearance,
          "unbounded_fields": _check_unbounded_fields}


def test_every_registered_experiment_has_a_smoke_check():
    assert set(CHECKS) == set(EXPERIMENTS)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    """One dataset cache for every smoke run (several experiments share a configuration)."""
    return tmp_path_factory.mktemp("data")


@pytest.mark.timeout(240)
@pytest.mark.parametrize("name", list(EXPERIMENTS))
def test_smoke_run(name, tmp_path, data_dir):
    out = tmp_path / "out"
    extra = (["--ply", str(tmp_path / "model.ply")] if name == "fit_splats"
             else ["--ply-dir", str(tmp_path / "meshes")] if name == "surface_recon" else [])
    t0 = time.perf_counter()
    r = _run(["-m", f"experiments.{name}", "--smoke", "--no-progress", "--out", str(out), "--data", str(data_dir),
              "--seed", "3", *extra])
    seconds = time.perf_counter() - t0
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert (out / "table.md").read_text().strip()
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["experiment"] == name and doc["seed"] == 3 and doc["device"] == "cpu"
    assert doc["config"]["smoke"] is True and doc["wall_time_s"] > 0
    assert {"commit"} <= set(doc["source"]) and doc["versions"]["numpy"] and doc["host"]["cpus"] >= 1
    assert not list(tmp_path.glob("out.partial-*")) and not list(tmp_path.glob("out.old-*"))
    assert not [p for p in out.iterdir() if ".tmp" in p.name], "a temporary file was left in the results"
    CHECKS[name](doc["metrics"])
    print(f"{name} --smoke: {seconds:.1f} s")


@pytest.mark.parametrize("name", ["splat_geometry", "splat_appearance", "fit_splats", "lens_distortion", "real_photos"])
def test_bad_iterations_are_refused_in_one_line_before_any_work(name, tmp_path):
    r = _run(["-m", f"experiments.{name}", "--smoke", "--no-progress", "--iterations", "0", "--out",
              str(tmp_path / "out"), "--data", str(tmp_path / "data")])
    assert r.returncode != 0
    assert r.stderr.strip().splitlines()[-1].endswith("--iterations: expected an integer >= 1, got 0"), r.stderr
    assert not (tmp_path / "data").exists() and not (tmp_path / "out").exists()


@pytest.mark.timeout(240)
def test_fit_splats_gsplat_mode_is_recorded(tmp_path, data_dir):
    """`fit_splats --mode gsplat` trains and evaluates with gsplat's conventions and says so in the table."""
    out = tmp_path / "out"
    r = _run(["-m", "experiments.fit_splats", "--smoke", "--no-progress", "--out", str(out), "--data", str(data_dir),
              "--ply", str(tmp_path / "model.ply"), "--mode", "gsplat"])
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["metrics"]["mode"] == "gsplat" and doc["config"]["train"]["mode"] == "gsplat"
    assert doc["metrics"]["method"].endswith("gsplat conventions") and "follow gsplat" in (out / "table.md").read_text()


# --------------------------------------------------------------------------- options and help


@pytest.mark.parametrize("name", list(EXPERIMENTS))
def test_help_via_python_m_documents_every_shared_option(name):
    r = _run(["-m", f"experiments.{name}", "--help"], timeout=120)
    assert r.returncode == 0, r.stderr
    for opt in SHARED_OPTIONS:
        assert opt in r.stdout, f"{name}: --help does not document {opt}"


def test_script_by_path_runs_without_path_hacks(tmp_path):
    # `python experiments/<name>.py` imports the installed packages; PYTHONPATH stands in for the install here.
    r = _run([str(REPO_ROOT / "experiments" / "stereo_depth.py"), "--help"], cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "--smoke" in r.stdout and "stereo_depth" in r.stdout
    for path in (REPO_ROOT / "experiments").glob("*.py"):
        assert "sys.path" not in path.read_text(), f"{path.name} manipulates sys.path"


def test_every_experiment_module_exposes_main():
    for spec in EXPERIMENTS.values():
        module = importlib.import_module(spec.module)
        assert callable(module.main), spec.name


def test_bad_device_is_a_usage_error_naming_the_option(tmp_path):
    r = _run(["-m", "experiments.lucas_kanade", "--device", "tpu", "--out", str(tmp_path / "o")], timeout=120)
    assert r.returncode == 2 and "--device" in r.stderr and "'tpu'" in r.stderr
    assert not (tmp_path / "o").exists()


def test_cuda_is_refused_clearly_when_warp_sees_none():
    import warp as wp

    from research.warp_runtime import init_warp

    init_warp()
    if wp.is_cuda_available():
        assert experiment.resolve_device("cuda").startswith("cuda")
    else:
        with pytest.raises(ValueError, match="--device cuda: Warp sees no CUDA device"):
            experiment.resolve_device("cuda")
    assert experiment.resolve_device("cpu") == "cpu"


# --------------------------------------------------------------------------- results folder


def _write_run(folder: Path, tag: str) -> None:
    (folder / "metrics.json").write_text(json.dumps({"run": tag}))
    (folder / "table.md").write_text(f"| {tag} |\n")


def test_a_run_that_raises_leaves_the_previous_folder_intact(tmp_path):
    out = tmp_path / "res"
    with experiment.results_folder(out) as tmp:
        _write_run(tmp, "first")
    assert json.loads((out / "metrics.json").read_text()) == {"run": "first"}

    def body(ctx):
        (ctx.out / "figure.png").write_bytes(b"new figure")
        raise RuntimeError("killed in the middle")

    exp = experiment.Experiment("dummy", "a test experiment", body, sizes="-", warp=False)
    with pytest.raises(RuntimeError, match="killed in the middle"):
        exp.main(["--out", str(out)])
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "table.md"]
    assert json.loads((out / "metrics.json").read_text()) == {"run": "first"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]


def test_out_must_be_a_results_folder_since_it_is_replaced_whole(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    (home / "notes.txt").write_text("not results")
    r = _run(["-m", "experiments.kalman_tracking", "--smoke", "--out", str(home)], timeout=120)
    assert r.returncode == 2 and "--out" in r.stderr and "no metrics.json" in r.stderr
    assert [p.name for p in home.iterdir()] == ["notes.txt"]
    with pytest.raises(ValueError, match="neither empty nor an experiment's results folder"):
        with experiment.results_folder(home):
            pass


def test_a_finished_run_replaces_the_folder_whole(tmp_path):
    out = tmp_path / "res"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    (out / "stale.png").write_bytes(b"from an older run")

    def body(ctx):
        ctx.write_results(config={}, metrics={"value": 1.5}, table_md="| x |\n")
        ctx.after_commit(lambda: f"after commit: {(ctx.final_out / 'metrics.json').is_file()}")

    assert experiment.Experiment("dummy", None, body, sizes="-", warp=False).main(["--out", str(out),
                                                                                   "--seed", "4"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "table.md"]
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["metrics"] == {"value": 1.5} and doc["seed"] == 4 and doc["experiment"] == "dummy"
    assert doc["config"] == {"quick": False}  # recorded by the Context for every experiment
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]


def test_script_runs_only_as_main_and_the_table_is_printed(tmp_path, monkeypatch, capsys):
    def body(ctx):
        ctx.write_results(config={}, metrics={}, table_md="| printed |\n", compare=True)  # smoke: no comparison
        return 3

    exp = experiment.Experiment("dummy", None, body, sizes="-", warp=False)
    assert exp.script("experiments.dummy") == exp.main  # imported: nothing runs
    assert not (tmp_path / "res").exists()
    monkeypatch.setattr(sys, "argv", ["dummy", "--smoke", "--out", str(tmp_path / "res")])
    with pytest.raises(SystemExit) as e:
        exp.script("__main__")
    assert e.value.code == 3 and (tmp_path / "res" / "metrics.json").is_file()
    out = capsys.readouterr().out
    assert "| printed |" in out and "comparison" not in out


_SLOW_EXPERIMENT = textwrap.dedent("""
    import sys, time
    from research.experiment import Experiment

    def body(ctx):
        (ctx.out / "disparity_maps.png").write_bytes(b"new figure")
        print("figure written", flush=True)
        time.sleep(60)
        ctx.write_results(config={}, metrics={}, table_md="| new |\\n")

    sys.exit(Experiment("slow", None, body, sizes="-", warp=False).main())
""")


def test_sigkill_mid_run_leaves_the_previous_folder_and_the_next_run_cleans_up(tmp_path):
    out = tmp_path / "res"
    out.mkdir()
    _write_run(out, "old")
    script = tmp_path / "slow.py"
    script.write_text(_SLOW_EXPERIMENT)
    proc = subprocess.Popen([sys.executable, str(script), "--out", str(out)], env=_env(), stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == "figure written"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    proc.stdout.close()
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "table.md"]
    assert json.loads((out / "metrics.json").read_text()) == {"run": "old"}
    partial = tmp_path / f"res.partial-{proc.pid}"
    assert (partial / "disparity_maps.png").is_file()  # the killed run's files stay out of res/

    with experiment.results_folder(out) as tmp:  # the next run into res/ removes the dead run's folder
        _write_run(tmp, "new")
    assert not partial.exists()
    assert json.loads((out / "metrics.json").read_text()) == {"run": "new"}


def test_sigterm_cleans_the_temporary_folder(tmp_path):
    out = tmp_path / "res"
    script = tmp_path / "slow.py"
    script.write_text(_SLOW_EXPERIMENT)
    proc = subprocess.Popen([sys.executable, str(script), "--out", str(out)], env=_env(), stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "figure written"
    proc.terminate()
    assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    proc.stdout.close()
    assert list(tmp_path.iterdir()) == [script]


def test_stale_old_folder_of_a_dead_run_is_put_back(tmp_path):
    out = tmp_path / "res"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    old = tmp_path / f"res.old-{dead}"  # killed between its two renames: res/ moved aside, new one not in
    old.mkdir()
    _write_run(old, "previous")
    assert experiment.clean_stale(out) == []
    assert json.loads((out / "metrics.json").read_text()) == {"run": "previous"} and not old.exists()


# --------------------------------------------------------------------------- CLI and packaging


def test_drlab_run_passes_options_after_double_dash(tmp_path):
    out = tmp_path / "kt"
    if sys.version_info >= (3, 11):  # a folder named `experiments` where drlab runs must not shadow the package
        (tmp_path / "experiments").mkdir()
        (tmp_path / "experiments" / "__init__.py").write_text("raise ImportError('the wrong experiments')\n")
    r = _run(["-m", "research.cli", "run", "kalman_tracking", "--seed", "2", "--out", "kt", "--",
              "--smoke", "--trials", "7", "--no-progress"], cwd=tmp_path, timeout=240)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "-m experiments.kalman_tracking" in r.stdout
    doc = json.loads((out / "metrics.json").read_text())  # --out is relative to the caller's directory
    assert doc["metrics"]["trials"] == 7 and doc["seed"] == 2 and doc["config"]["smoke"] is True


def test_drlab_run_reports_an_experiment_option_error():
    r = _run(["-m", "research.cli", "run", "kalman_tracking", "--", "--no-such-option"], timeout=120)
    assert r.returncode == 2 and "--no-such-option" in r.stderr


@pytest.mark.timeout(240)
@pytest.mark.skipif(not can_build_wheels(), reason="no bdist_wheel here (setuptools < 70.1 without `wheel`; "
                                                    "`make setup` installs it with the dev extras)")
def test_wheel_contains_experiments_and_drlab_run_works_from_it(tmp_path):
    wheel = build_wheel(REPO_ROOT, ("research", "kernels", "experiments"), tmp_path)
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        assert "experiments/__init__.py" in names
        for spec in EXPERIMENTS.values():
            assert f"experiments/{spec.name}.py" in names
        assert not [n for n in names if n.startswith("tests/")]
        z.extractall(tmp_path / "site")
    # As after `pip install` from the wheel: no checkout, so results go under the current directory.
    work = tmp_path / "work"
    work.mkdir()
    env = dict(os.environ, PYTHONPATH=str(tmp_path / "site"))
    r = subprocess.run([sys.executable, "-m", "research.cli", "run", "kalman_tracking", "--", "--smoke",
                        "--no-progress"], cwd=work, env=env, capture_output=True, text=True, timeout=200)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert (work / "results" / "kalman_tracking" / "metrics.json").is_file()


# --------------------------------------------------------------------------- bench families


@pytest.mark.timeout(240)
@pytest.mark.parametrize("family", list(family_modules("bench")))
def test_bench_family_tiny_cases(family):
    module = importlib.import_module(family_modules("bench")[family])
    t0 = time.perf_counter()
    rows = list(module.cases("cpu", quick=True, tiny=True))
    seconds = time.perf_counter() - t0
    assert rows, f"{family}: no cases"
    for row in rows:
        assert str(row["bench"]).startswith(family + "."), row
        assert row["device"] == "cpu" and row["threads"] >= 1
        timings = {k: v for k, v in row.items() if k.endswith("_s")}
        assert any(isinstance(v, float) and v > 0 for v in timings.values()), row
    print(f"bench {family} tiny: {seconds:.2f} s")


@pytest.mark.parametrize("argv, message", [
    (["--splat-iterations", "0"], "--splat-iterations: expected positive values, got [0]"),
    (["--budgets", "10", "-5"], "--budgets: expected positive values, got [10.0, -5.0]"),
    (["--splat-iterations", "--fields"], "--splat-iterations and --fields are both empty: nothing to run"),
])
def test_time_budget_refuses_bad_schedules_in_one_line(tmp_path, argv, message):
    r = _run(["-m", "experiments.time_budget", "--smoke", "--no-progress", "--out", str(tmp_path / "out"),
              "--data", str(tmp_path / "data"), *argv])
    assert r.returncode == 2 and message in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "data").exists()  # refused before any dataset is rendered
