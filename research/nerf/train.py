"""Fitting a radiance field to posed images: random ray batches, MSE, Adam, occupancy grid.

Per iteration (instant-ngp's recipe, Mueller et al. 2022, on the CPU):
  1. draw `batch_rays` pixels uniformly from all training views (seeded);
  2. draw a random background colour b per ray, composite the target over it,
     target = rgb_premultiplied + (1 - alpha) b, and render the ray over the same b -- the field
     must then explain alpha with its opacity (NeRF-synthetic practice);
  3. ray-march with a fixed step, jittered, skipping unoccupied cells (kernels.volume.sample_rays);
     during a warm-up of `occupancy_start` iterations nothing is skipped and the step is coarser,
     so that surfaces form before cells can be declared empty (a cell declared empty gets no
     samples, hence no gradient, and would stay empty);
  4. loss = mean((C - target)^2) (+ an optional sparsity penalty `sigma_l1` * mean over rays of the
     optical depth sum_k sigma_k delta_k, against floating fog); dL/dC = 2 (C - target) / (3 B);
     backward through compositing and the field (kernels.volume.render_backward); one Adam step
     (kernels.optim.Adam);
  5. every `occupancy_every` iterations, update the occupancy grid from the field's density
     (EMA-max, threshold; kernels.volume.OccupancyGrid).
Voxel grids also take a total-variation penalty (Plenoxels) with weights `tv_weight` on the mean
squared neighbour difference, and are fitted coarse to fine (`upsample_grid`, as DVGO and
Plenoxels do): a coarse grid sees many rays per vertex and converges in few iterations.
Images are fitted in sRGB (the PNGs of the dataset: straight-alpha sRGB, then premultiplied),
since the field's colour is a sigmoid in [0, 1].

Validation: the ray bank is checked once (finite values), and the first iteration runs with the
kernels' value checks on; the iterations after it run inside `kernels._arrays.value_checks(False)`
(their inputs are slices of the checked bank and the loop's own outputs), so only shape and dtype
checks remain in the loop.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field as dc_field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from kernels import _arrays as A
from kernels.optim import Adam
from kernels.volume import Field, GridField, OccupancyGrid, Workspace, render_backward, render_rays
from kernels.volume.grid import add_tv_grad
from research.cameras import Camera
from research.metrics import srgb_targets
from research.nerf.render import camera_rays


@dataclass
class TrainConfig:
    iters: int = 2000
    batch_rays: int = 4096
    lr: dict[str, float] | float = 1e-2
    betas: tuple[float, float] = (0.9, 0.99)
    adam_eps: float = 1e-15
    step: float = 0.02  # ray-marching stratum length (world units)
    t_threshold: float = 1e-4
    occupancy_res: tuple[int, int, int] = (64, 64, 16)
    occupancy_every: int = 16
    occupancy_start: int = 64  # no skipping (and a coarser step) before this iteration
    warmup_step_factor: float = 2.0  # step multiplier before occupancy_start
    occupancy_decay: float = 0.95
    occupancy_threshold: float = 0.01
    lr_decay_from: float = 0.6  # fraction of iters after which the learning rate decays
    lr_decay_to: float = 0.1  # ... linearly (in log space) down to this factor at the end
    random_background: bool = True
    tv_weight: dict[str, float] = dc_field(default_factory=dict)  # grid fields: weight of mean TV per parameter
    sigma_l1: float = 0.0  # weight of the sparsity penalty mean_rays sum_k sigma_k delta_k
    seed: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class RayBank:
    """Every training pixel as a ray: origins, unit dirs, z_scale, and its `srgb_targets` RGBA."""

    origins: np.ndarray
    dirs: np.ndarray
    z_scale: np.ndarray
    rgba: np.ndarray

    @classmethod
    def from_views(cls, cameras: list[Camera], rgba_linear: np.ndarray, dtype: Any = np.float32,
                   ndc: Any = None) -> "RayBank":
        """`ndc` (research.nerf.ndc.NDC): the rays in NDC (forward-facing data; research.nerf.render)."""
        rays = [camera_rays(c, dtype, ndc) for c in cameras]
        target = srgb_targets(rgba_linear).reshape(-1, 4)
        return cls(np.concatenate([r[0] for r in rays]), np.concatenate([r[1] for r in rays]),
                   np.concatenate([r[2] for r in rays]), target)

    def __len__(self) -> int:
        return self.origins.shape[0]


@dataclass
class TrainLog:
    losses: list[float]
    samples_per_ray: list[float]
    occupied_fraction: list[float]
    seconds: float


def _lr_factor(cfg: Any, it: int) -> float:
    start = int(cfg.lr_decay_from * cfg.iters)
    if it < start or cfg.iters <= start:
        return 1.0
    return float(cfg.lr_decay_to ** ((it - start) / (cfg.iters - start)))


def optimiser_step(opt: Adam, field: Any, grads: dict[str, Any], cfg: Any, it: int, base_lr: dict[str, float]) -> None:
    """One step of iteration `it` (cfg: TrainConfig or research.poses.refine_volume's JointConfig): a
    voxel grid's TV gradients (cfg.tv_weight per parameter, over the vertex count) added into
    `grads`, the learning rates decayed from cfg.lr_decay_from of cfg.iters down to cfg.lr_decay_to
    at the end, then the optimiser's step."""
    if isinstance(field, GridField):
        nv = field.params["density"].shape[0]
        for name, w in cfg.tv_weight.items():
            add_tv_grad(field.params[name], field.resolution, w / nv, grads[name])
    f = _lr_factor(cfg, it)
    opt.lr = {k: v * f for k, v in base_lr.items()}
    opt.step(grads)


def upsample_grid(field: GridField, resolution: tuple[int, int, int]) -> GridField:
    """The same field on a finer vertex grid: every parameter trilinearly resampled (vertex-aligned)."""
    from scipy.ndimage import map_coordinates

    new = GridField(field.bbox, resolution, field.sh_degree, field.density_bias, field.density_scale,
                    field.density_activation, dtype=field.dtype, device=field.device)
    nx, ny, nz = field.resolution
    mx, my, mz = new.resolution
    coords = np.stack(np.meshgrid(np.linspace(0, nz - 1, mz), np.linspace(0, ny - 1, my), np.linspace(0, nx - 1, mx),
                                  indexing="ij")).reshape(3, -1)
    values = {}
    for name, arr in field.params.items():
        a = arr.numpy().astype(np.float64).reshape(nz, ny, nx, -1)
        out = np.stack([map_coordinates(a[..., c], coords, order=1, mode="nearest") for c in range(a.shape[-1])], -1)
        values[name] = out.reshape(new.params[name].shape).astype(a.dtype)
    new.set_params(values)
    return new


def train(field: Field, bank: RayBank, bbox: np.ndarray, cfg: TrainConfig, occupancy: OccupancyGrid,
          progress: bool = True, desc: str = "train") -> TrainLog:
    """Fit `field` to `bank` in place (module docstring); returns the loss curve and the time taken.

    NumPy's BLAS (the MLP fields' matrix products) runs on one thread while training. Its products
    here are small (batch x 64 x 64), and OpenBLAS's threads wait for each other: beside two busy
    processes, 150 hash-grid iterations took 311 s with its default 2 threads and 48 s with 1; on
    an idle machine 34 s and 31 s. Results stay deterministic, but the rounding differs from two
    threads' (the full fit_nerf PE-MLP went from 26.70 to 26.58 dB). Rendering outside training
    keeps the default, where 2 threads help the large forward products.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _train(field, bank, bbox, cfg, occupancy, progress, desc)


def _train(field: Field, bank: RayBank, bbox: np.ndarray, cfg: TrainConfig, occupancy: OccupancyGrid,
           progress: bool, desc: str) -> TrainLog:
    for name in ("origins", "dirs", "z_scale", "rgba"):
        A.check_finite(f"bank.{name}", getattr(bank, name))
    rng = np.random.default_rng(cfg.seed)
    np_t = A.NP_OF_WP[field.dtype]
    opt = Adam(field.params, cfg.lr, cfg.betas, cfg.adam_eps)
    base_lr = dict(opt.lr)
    losses, spr, occ = [], [], []
    t0 = time.perf_counter()
    workspace = Workspace(field.device)  # compositing buffers, reused by every iteration
    bar = tqdm(range(cfg.iters), desc=desc, disable=not progress, mininterval=2.0)
    for it in bar:
        with A.value_checks(it == 0):  # one validated iteration (module docstring)
            warm = it < cfg.occupancy_start
            if not warm and (it - cfg.occupancy_start) % cfg.occupancy_every == 0:
                occupancy.update_from(field.density, seed=cfg.seed * 1_000_003 + it, dtype=field.dtype)
            idx = rng.integers(0, len(bank), cfg.batch_rays)
            bg = rng.uniform(0.0, 1.0, (cfg.batch_rays, 3)) if cfg.random_background else np.zeros((cfg.batch_rays, 3))
            # Over a random background the target is blended in sRGB space: exact where alpha is 0 or 1,
            # an approximation on the few partially covered edge pixels (the field renders in sRGB).
            target = bank.rgba[idx, :3] + (1.0 - bank.rgba[idx, 3:]) * bg
            res = render_rays(field, bank.origins[idx], bank.dirs[idx], bbox,
                              step=cfg.step * (cfg.warmup_step_factor if warm else 1.0), z_scale=bank.z_scale[idx],
                              occupancy=None if warm else occupancy, jitter=True, seed=cfg.seed * 1_000_003 + it,
                              background=bg.astype(np_t), t_threshold=cfg.t_threshold, workspace=workspace)
            diff = res.rgb.numpy().astype(np.float64) - target  # res.rgb: a workspace view
            loss = float(np.mean(diff**2))
            grads = render_backward(field, res, (2.0 * diff / diff.size).astype(np_t),
                                    sigma_l1=cfg.sigma_l1 / cfg.batch_rays, workspace=workspace)
            optimiser_step(opt, field, grads, cfg, it, base_lr)
            losses.append(loss)
            spr.append(res.samples.n_samples / cfg.batch_rays)
            if it % 50 == 0:
                occ.append(occupancy.occupied_fraction())
                bar.set_postfix(loss=f"{loss:.4f}", spr=f"{spr[-1]:.1f}", occ=f"{occ[-1]:.3f}")
    occupancy.update_from(field.density, seed=cfg.seed * 1_000_003 + cfg.iters, dtype=field.dtype)
    return TrainLog(losses, spr, occ, time.perf_counter() - t0)
