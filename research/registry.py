"""Registries: experiments, gradient checks and benchmarks, and where results and data go by default.

Everything is registered by *name and module*, not by import, so that
`drlab --help` stays fast and a broken optional module cannot break the CLI.

* EXPERIMENTS: name -> ExperimentSpec. Each is the module `experiments.<name>`
  (research.experiment's contract: `main(argv) -> int`, the shared options
  `--quick --smoke --device --out --seed --data --no-progress` and its own). The
  CLI runs it in a fresh process, `python -m experiments.<name>` (research never
  imports experiments).
* GRADCHECK_MODULES: modules whose import registers gradient checks with
  `research.gradcheck.register_check`.
* BENCH_MODULES: family -> module exposing `cases(device: str, quick: bool, tiny: bool = False)`,
  an iterator of JSON-ready dicts (see research/bench/__init__.py).

Default folders: in a checkout (this package beside pyproject.toml and experiments/), results go to
`<checkout>/results/<name>` (quick runs: `<checkout>/build/results-quick/<name>`, smoke runs:
`<checkout>/build/results-smoke/<name>`) and datasets to `<checkout>/data`; installed from a wheel
(no checkout), the same paths under the current directory: `./results/<name>`, `./data`, ...
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

# The folder holding research/ and kernels/: a checkout's root, or site-packages when installed.
REPO_ROOT = Path(__file__).resolve().parent.parent


def in_checkout() -> bool:
    """Whether this code runs from a source checkout (else it was installed from a wheel)."""
    return (REPO_ROOT / "pyproject.toml").is_file() and (REPO_ROOT / "experiments").is_dir()


def base_dir() -> Path:
    """The root of default folders: the checkout, else the current directory."""
    return REPO_ROOT if in_checkout() else Path.cwd()


def results_dir(quick: bool = False, smoke: bool = False) -> Path:
    """Where `drlab run` / `drlab reproduce` put each experiment's folder by default."""
    if smoke:
        return base_dir() / "build" / "results-smoke"
    return base_dir() / ("build/results-quick" if quick else "results")


def default_out(name: str, quick: bool = False, smoke: bool = False) -> Path:
    return results_dir(quick, smoke) / name


def describe_default_out(name: str) -> str:
    return (f"results/{name}, with --quick build/results-quick/{name}, with --smoke build/results-smoke/{name}; "
            "in the checkout when run from one, else under the current directory")


def default_data_dir() -> Path:
    return base_dir() / "data"


def describe_default_data() -> str:
    return "data/ in the checkout when run from one, else ./data"


@dataclass(frozen=True)
class ExperimentSpec:
    name: str
    description: str
    # Budget for --quick mode on 2 CPU cores, seconds.
    quick_budget_s: float
    # The seed `drlab reproduce` (full mode) runs, where the reported run is not the experiment's own
    # default seed 0: one that none of its settings were picked on. None: the experiment's default.
    reproduce_seed: int | None = None
    # External data the experiment cannot run without (real photographs, not in the repository): a path
    # under the default data folder. `drlab reproduce` skips the experiment in one line when it is absent.
    needs_data: str | None = None

    @property
    def module(self) -> str:
        """The module to run with `python -m`."""
        return f"experiments.{self.name}"


EXPERIMENTS: dict[str, ExperimentSpec] = {}


def register_experiment(name: str, description: str, quick_budget_s: float, reproduce_seed: int | None = None,
                        needs_data: str | None = None) -> None:
    if name in EXPERIMENTS:
        raise ValueError(f"experiment {name!r} registered twice")
    EXPERIMENTS[name] = ExperimentSpec(name, description, quick_budget_s, reproduce_seed, needs_data)


def missing_data(name: str) -> str | None:
    """Why `drlab reproduce` cannot run `name` (its `needs_data` folder is absent), or None."""
    need = EXPERIMENTS[name].needs_data
    if need is None or (default_data_dir() / need).is_dir():
        return None
    return (f"its data folder {default_data_dir() / need} is absent (real photographs, not in the repository); "
            f"`drlab run {name} -- --data DIR` runs it on such a folder")


def reproduce_seed(name: str, quick: bool) -> int | None:
    """The --seed `drlab reproduce` passes to `name`: its reproduce_seed in full mode, else None (the
    experiment's own default; quick runs are checks of the defaults, not the reported figures)."""
    return None if quick else EXPERIMENTS[name].reproduce_seed


register_experiment(
    "datasets",
    "Mitsuba ground-truth datasets (multi-view, stereo, flow): render time and geometric consistency.",
    quick_budget_s=300,
)

register_experiment(
    "kalman_tracking",
    "Kalman filter and RTS smoother on the noisy circle of the Video and 3D Vision textbook chapter: textbook Q vs likelihood-tuned Q.",
    quick_budget_s=180,
)
register_experiment(
    "mot_tracking",
    "SORT vs ByteTrack vs ByteTrack+appearance on synthetic occlusion sequences (MOTA, IDF1, ID switches, FPS).",
    quick_budget_s=180,
)

register_experiment(
    "lucas_kanade",
    "The textbook's Lucas-Kanade task (square moved 5 px): its axis bug, single-scale and pyramidal LK.",
    quick_budget_s=300,
)
register_experiment(
    "raft_flow",
    "Weight-free RAFT-style flow from correlation lookups on Mitsuba flow pairs: EPE/F1, levels x radius, baselines.",
    quick_budget_s=300,
)
register_experiment(
    "stereo_depth",
    "Stereo matching on Mitsuba rectified pairs: SAD/ZNCC/census/correlation x WTA/SGM-4/SGM-8 vs OpenCV SGBM/BM.",
    quick_budget_s=300,
)

register_experiment(
    "fit_splats",
    "3D Gaussian splatting fitted on the CPU (Warp kernels, hand-written backward) to Mitsuba `objects`: "
    "test PSNR/SSIM, splats, train time, render FPS, PLY size.",
    quick_budget_s=600,
)

register_experiment(
    "time_budget",
    "PSNR against training time on the official lego at 1/4: splats and the hash-grid field at longer and "
    "longer schedules, wall and CPU time, the best fit in 10, 30 and 60 minutes.",
    quick_budget_s=600,
    needs_data="nerf_synthetic/lego",
)

register_experiment(
    "volume_render_spheres",
    "The textbook's three soft spheres (64x64, focal 60, 64 samples): Warp volume rendering vs a NumPy port.",
    quick_budget_s=120,
)
register_experiment(
    "fit_nerf",
    "Voxel grid, hash grid + MLP and PE-MLP radiance fields fitted to Mitsuba `objects`: test PSNR/SSIM, "
    "depth MAE, train and render seconds.",
    quick_budget_s=600,
)
register_experiment(
    "sfm_poses",
    "`drlab sfm` (pycolmap) on bare renders of Mitsuba `objects`: registered views, pose error after Sim(3) "
    "alignment, and splats on SfM vs ground-truth poses.",
    quick_budget_s=300,
)

register_experiment(
    "real_photos",
    "Middlebury templeRing photographs with calibrated cameras: `drlab sfm` against the calibration (registered "
    "views, rotation, camera-centre and focal error after Sim(3)) and splats on held-out views with the calibrated "
    "and the SfM cameras.",
    quick_budget_s=600,
    needs_data="middlebury_mview/templeRing",
)

register_experiment(
    "performance",
    "drlab's kernels vs PyTorch / OpenCV / NumPy on the same CPU (drlab bench --compare): times, ratios, targets.",
    quick_budget_s=600,
)

register_experiment(
    "oracle_conformance",
    "Every kernel family against its Dr.Jit AD oracle (research/oracles) at full size: max abs/rel difference, "
    "forward and VJP, float32 and float64, with timings.",
    quick_budget_s=300,
)

register_experiment(
    "pose_refinement",
    "BARF-style pose refinement: Gaussian splats (default; or a voxel grid) and the training poses (perturbed "
    "5 degrees, 5% of the radius) fitted jointly from the renderer's camera gradients, RGB and RGB-D: pose errors "
    "before/after, test PSNR vs fixed and ground-truth poses.",
    quick_budget_s=600,
)

register_experiment(
    "feature_vo",
    "Classical RGB-D feature VO on the Mitsuba `objects` loop (splat_slam's sequence): ORB, essential matrix, "
    "PnP RANSAC, local BA with Warp Jacobians, loop closure by pose graph: ATE/RPE before and after, FPS.",
    quick_budget_s=300,
)

register_experiment(
    "splat_slam",
    "RGB-D SLAM with a Gaussian-splat map (SplaTAM-style) on a Mitsuba loop sequence: ATE/RPE (% of path), "
    "frames/s, tracking failures, held-out PSNR of the map.",
    quick_budget_s=600,
    # its tracking rates were picked on the first 10 frames of the seed-0 sequence (research/slam)
    reproduce_seed=1,
)

# Modules that register gradient checks when imported.
GRADCHECK_MODULES: list[str] = [
    "research.checks.selftest",
    "research.checks.corr",
    "research.checks.stereo",
    "research.checks.splat",
    "research.checks.ssim",
    "research.checks.volume",
    "research.checks.ba",
    "research.checks.slam",
    "research.checks.points",
]

# Benchmark families.
BENCH_MODULES: dict[str, str] = {
    "launch": "research.bench.launch",
    "corr": "research.bench.corr",
    "stereo": "research.bench.stereo",
    "splat": "research.bench.splat",
    "volume": "research.bench.volume",
    "points": "research.bench.points",
}
