"""Registries: kernel families and experiments, and where results and data go by default.

Everything is registered by *name and module*, not by import, so that
`drlab --help` stays fast and a broken optional module cannot break the CLI.

* FAMILIES: name -> Family, the one table that `drlab gradcheck`, `drlab bench` and the
  oracle_conformance experiment read. A family names, as module paths, each part it has (all optional):

    kernels       its Warp kernels and entry points (`kernels.<family>`);
    reference     its plain NumPy forward (`kernels.reference.<family>`), which the tests import;
    checks        a module whose import registers its float64 gradient checks with
                  `research.gradcheck.register_check`, named "<family>.<what>";
    oracle_cases  a module holding `SIZES` (mode -> size keys) and `CASES` (research.oracles.cases.Case:
                  drlab against its Dr.Jit oracle, research/oracles);
    bench         a module exposing `cases(device: str, quick: bool, tiny: bool = False)`, an iterator
                  of JSON-ready dicts (see research/bench/__init__.py).

  `register_family` adds one (in the order below: the order of `drlab bench`, of the oracle table and
  of `drlab list`'s checks); `family_modules(part)` lists the families that have a part.
  `temporary_families()` drops whatever was registered inside it (tests register a toy family so).
* EXPERIMENTS: name -> ExperimentSpec. Each is the module `experiments.<name>`
  (research.experiment's contract: `main(argv) -> int`, the shared options
  `--quick --smoke --device --out --seed --data --no-progress` and its own). The
  CLI runs it in a fresh process, `python -m experiments.<name>` (research never
  imports experiments).

Default folders: in a checkout (this package beside pyproject.toml and experiments/), results go to
`<checkout>/results/<name>` (quick runs: `<checkout>/build/results-quick/<name>`, smoke runs:
`<checkout>/build/results-smoke/<name>`) and datasets to `<checkout>/data`; installed from a wheel
(no checkout), the same paths under the current directory: `./results/<name>`, `./data`, ...
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Iterator

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
    "lens_distortion",
    "Splats on a distorted Mitsuba image set: trained through the lens model (opencv, fisheye) vs OpenCV-undistorted "
    "images with a pinhole vs the distortion ignored; held-out PSNR/SSIM, the stated margin.",
    quick_budget_s=900,
)

register_experiment(
    "splat_antialiasing",
    "Splats trained at one resolution, scored at 1/4 to 2x: 3DGS's dilation against Mip-Splatting's 2D filter, "
    "3D filter and both, on Mitsuba renders box-averaged from 2x.",
    quick_budget_s=600,
)

register_experiment(
    "splat_appearance",
    "Per-image appearance for splats on training views whose exposure and colour vary (Mitsuba `objects` through the "
    "radiometric stress set; LLFF fern with a known per-image exposure): none vs per-image affine vs gsplat's "
    "bilateral grid; held-out PSNR/SSIM and colour-corrected PSNR.",
    quick_budget_s=600,
    needs_data="nerf_llff_data/fern",
)

register_experiment(
    "splat_densification",
    "Splat density control on Mitsuba `objects`: 3DGS's clone/split/prune vs 3DGS-MCMC's relocation (gsplat's "
    "defaults) at equal splat count and equal CPU time; PSNR/SSIM, splats, CPU and wall time.",
    quick_budget_s=600,
)

register_experiment(
    "splat_geometry",
    "Splat depth and normals on Mitsuba `objects` against the stored depth and normals: expected vs median depth, "
    "with and without 2DGS's depth-normal consistency loss (shortest-axis splat normals); AbsRel, RMSE, angles.",
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
    "unbounded_fields",
    "Unbounded scenes: the hash-grid field behind mip-NeRF 360's contraction with a proposal sampler vs the bounded "
    "box, on Mitsuba `backdrop` (distant panorama wall, sky) and LLFF fern: PSNR/SSIM on full images and background.",
    quick_budget_s=900,
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
    "Every kernel family with a Dr.Jit AD oracle against it (research/oracles) at full size: max abs/rel difference, "
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
    "pointnet_classify",
    "PointNet and one-level PointNet++ on Warp kernels vs a D2 + PCA k-NN baseline: test accuracy on synthetic "
    "posed, scaled, noisy shape clouds (9 classes), train time, confusion matrices.",
    quick_budget_s=300,
)

register_experiment(
    "feature_vo",
    "Classical RGB-D feature VO on the Mitsuba `objects` loop (splat_slam's sequence): ORB, essential matrix, "
    "PnP RANSAC, local BA with Warp Jacobians, loop closure by pose graph: ATE/RPE before and after, FPS.",
    quick_budget_s=300,
)

register_experiment(
    "lidar_odometry",
    "ICP odometry on Mitsuba-ray-cast 360-degree LiDAR scans: point-to-point / point-to-plane, scan-to-scan / "
    "scan-to-map vs KISS-ICP (ATE/RPE, ms per scan), and single scan pairs vs Open3D's ICP.",
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

register_experiment(
    "surface_recon",
    "TSDF fusion + marching cubes (Warp) of Mitsuba GT, splat and field depth maps on `objects`, beside Open3D's "
    "TSDF on the same depth maps: chamfer, F-score, normal consistency against the true shapes, fusion time.",
    quick_budget_s=300,
)

# --------------------------------------------------------------------------- kernel families


@dataclass(frozen=True)
class Family:
    """One kernel family: the module path of each part it has (None where it has none)."""

    name: str
    description: str
    kernels: str | None = None
    reference: str | None = None
    checks: str | None = None
    oracle_cases: str | None = None
    bench: str | None = None


# The parts a family may name, in Family's order.
PARTS = tuple(f.name for f in fields(Family) if f.name not in ("name", "description"))

FAMILIES: dict[str, Family] = {}


def register_family(name: str, description: str, *, kernels: str | None = None, reference: str | None = None,
                    checks: str | None = None, oracle_cases: str | None = None,
                    bench: str | None = None) -> Family:
    """Add a family to FAMILIES (by module names: nothing is imported here) and return it."""
    if not name.isidentifier():
        raise ValueError(f"family name: expected an identifier, got {name!r}")
    if name in FAMILIES:
        raise ValueError(f"family {name!r} registered twice")
    family = Family(name, description, kernels, reference, checks, oracle_cases, bench)
    FAMILIES[name] = family
    return family


def family_modules(part: str) -> dict[str, str]:
    """family name -> module of `part` ("checks", "bench", ...), for the families that have it, in order."""
    if part not in PARTS:
        raise ValueError(f"part: expected one of {', '.join(PARTS)}, got {part!r}")
    return {name: getattr(f, part) for name, f in FAMILIES.items() if getattr(f, part) is not None}


@contextlib.contextmanager
def temporary_families() -> Iterator[None]:
    """Families registered inside the block are unregistered at its end (FAMILIES as it was)."""
    saved = dict(FAMILIES)
    try:
        yield
    finally:
        FAMILIES.clear()
        FAMILIES.update(saved)


register_family("selftest", "the gradient checker's own check, on an analytic function with a known gradient",
                checks="research.checks.selftest")
register_family("launch", "race-free split launches of CPU kernels over several threads",
                kernels="kernels.launch", bench="research.bench.launch")
register_family("corr", "RAFT all-pairs correlation: volume, pyramid, lookups (stored and on the fly)",
                kernels="kernels.corr", reference="kernels.reference.corr", checks="research.checks.corr",
                oracle_cases="research.oracles.cases.corr", bench="research.bench.corr")
register_family("stereo", "stereo cost volumes, semi-global matching, disparity selection",
                kernels="kernels.stereo", reference="kernels.reference.stereo", checks="research.checks.stereo",
                oracle_cases="research.oracles.cases.stereo", bench="research.bench.stereo")
register_family("splat", "3D Gaussian splatting: projection, tile binning, rasteriser, camera gradients",
                kernels="kernels.splat", reference="kernels.reference.splat", checks="research.checks.splat",
                oracle_cases="research.oracles.cases.splat", bench="research.bench.splat")
register_family("ssim", "the SSIM map and its backward",
                kernels="kernels.ssim", reference="kernels.reference.ssim", checks="research.checks.ssim",
                oracle_cases="research.oracles.cases.ssim", bench="research.bench.ssim")
register_family("volume", "NeRF volume rendering: sampling, compositing, fields, camera gradients through rays",
                kernels="kernels.volume", reference="kernels.reference.volume", checks="research.checks.volume",
                oracle_cases="research.oracles.cases.volume", bench="research.bench.volume")
register_family("mip_filter", "Mip-Splatting's 3D smoothing filter of the splats (scales and opacity)",
                kernels="kernels.splat.filter3d", reference="kernels.reference.splat_filter3d",
                checks="research.checks.mip_filter", oracle_cases="research.oracles.cases.mip_filter")
register_family("appearance", "per-image appearance: a bilateral grid (or one affine) of 3x4 colour transforms, sliced",
                kernels="kernels.appearance", reference="kernels.reference.appearance",
                checks="research.checks.appearance", oracle_cases="research.oracles.cases.appearance")
register_family("unbounded", "unbounded scenes for the fields: mip-NeRF 360's contraction, s-space spacing, "
                "proposal weights, inverse-CDF resampling, interlevel loss",
                kernels="kernels.volume.proposal", reference="kernels.reference.volume_unbounded",
                checks="research.checks.unbounded", oracle_cases="research.oracles.cases.unbounded")
register_family("splat_geometry", "splat median and expected depth, shortest-axis and depth normals, depth-normal "
                "consistency loss", kernels="kernels.splat.depth", reference="kernels.reference.splat_geometry",
                checks="research.checks.splat_geometry", oracle_cases="research.oracles.cases.splat_geometry")
register_family("mcmc", "3DGS-MCMC densification: relocation's opacity/scale correction, position noise, regularisers",
                checks="research.checks.mcmc")
register_family("lens", "lens camera models (opencv, fisheye, orthographic): ray generator, splat projection",
                kernels="kernels.lens", reference="kernels.reference.lens", checks="research.checks.lens",
                oracle_cases="research.oracles.cases.lens")
register_family("ba", "bundle adjustment: reprojection residuals and their pose/point Jacobians",
                kernels="kernels.ba", reference="kernels.reference.ba", checks="research.checks.ba",
                oracle_cases="research.oracles.cases.ba")
register_family("slam", "the splat SLAM tracking and mapping losses (research/slam) through the splat renderer",
                checks="research.checks.slam")
register_family("points", "point clouds on a uniform hash grid: kNN, ball query, FPS, normals, chamfer distance",
                kernels="kernels.points", reference="kernels.reference.points", checks="research.checks.points",
                oracle_cases="research.oracles.cases.points", bench="research.bench.points")
register_family("tsdf", "TSDF fusion of depth maps and marching cubes (no gradient)",
                kernels="kernels.tsdf", reference="kernels.reference.tsdf", bench="research.bench.tsdf")
register_family("pointnet", "PointNet's max-pool, PointNet++'s grouping in local coordinates, the classifiers",
                kernels="kernels.pointnet", reference="kernels.reference.pointnet", checks="research.checks.pointnet",
                oracle_cases="research.oracles.cases.pointnet")
register_family("lucas_kanade", "Lucas-Kanade flow: structure tensor, pyramidal",
                kernels="kernels.lucas_kanade", reference="kernels.reference.lucas_kanade")
register_family("icp", "ICP: point-to-point/plane residuals, pose Jacobians, robust weights, normal equations",
                kernels="kernels.icp", reference="kernels.reference.icp", checks="research.checks.icp",
                oracle_cases="research.oracles.cases.icp")
