"""Registries that later issues extend: experiments, gradient checks and benchmarks.

Everything is registered by *name and location*, not by import, so that
`drlab --help` stays fast and a broken optional module cannot break the CLI.

* EXPERIMENTS: name -> ExperimentSpec. Each is a standalone script
  `experiments/<name>.py` accepting `--quick --device --out --seed`. The CLI
  runs it in a fresh process (research never imports experiments/).
* GRADCHECK_MODULES: modules whose import registers gradient checks with
  `research.gradcheck.register_check`.
* BENCH_MODULES: family -> module exposing `cases(device: str, quick: bool)`,
  an iterator of JSON-ready dicts (see research/bench/__init__.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
EXPERIMENTS_DIR = REPO_ROOT / "experiments"
RESULTS_DIR = REPO_ROOT / "results"


@dataclass(frozen=True)
class ExperimentSpec:
    name: str
    description: str
    # Budget for --quick mode on 2 CPU cores, seconds (stated by the issue).
    quick_budget_s: float

    @property
    def script(self) -> Path:
        return EXPERIMENTS_DIR / f"{self.name}.py"


EXPERIMENTS: dict[str, ExperimentSpec] = {}


def register_experiment(name: str, description: str, quick_budget_s: float) -> None:
    if name in EXPERIMENTS:
        raise ValueError(f"experiment {name!r} registered twice")
    EXPERIMENTS[name] = ExperimentSpec(name, description, quick_budget_s)


register_experiment(
    "datasets",
    "Mitsuba ground-truth datasets (multi-view, stereo, flow): render time and geometric consistency.",
    quick_budget_s=300,
)

register_experiment(
    "kalman_tracking",
    "Kalman filter and RTS smoother on the textbook's noisy circle: textbook Q vs likelihood-tuned Q.",
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

# Modules that register gradient checks when imported.
GRADCHECK_MODULES: list[str] = [
    "research.checks.selftest",
    "research.checks.corr",
    "research.checks.stereo",
    "research.checks.splat",
    "research.checks.ssim",
    "research.checks.volume",
]

# Benchmark families.
BENCH_MODULES: dict[str, str] = {
    "launch": "research.bench.launch",
    "corr": "research.bench.corr",
    "stereo": "research.bench.stereo",
    "splat": "research.bench.splat",
    "volume": "research.bench.volume",
}
