"""Finite-difference checks (float64) of the bilateral-grid slice (kernels/appearance.py) and of the
grid's total-variation loss (research/splats/appearance.py).

Registered for `drlab gradcheck appearance`. The slice is checked with respect to the grid and the
rendered image, for gsplat's grid shape scaled down (3 x 4 x 5), a grid with one node on some axes and
the 1 x 1 x 1 per-image affine transform. Inputs: grids at the identity plus N(0, 0.2) noise, colours
in [0.05, 0.95] (so the luminance is inside (0, 1), where z has a gradient; a step of 1e-6 crosses a
kink of the trilinear interpolation, an integer z, with probability about 1e-5 per pixel, and the
seeds below were run and cross none), an image size that is not a multiple of the grid's.
"""

from __future__ import annotations

import numpy as np

from kernels.appearance import bilateral_slice, bilateral_slice_backward, identity_grid
from research.gradcheck import GradcheckResult, check_vjp, register_check
from research.splats.appearance import total_variation

SHAPES = ((3, 4, 5), (4, 1, 3), (1, 1, 1))


def check_slice(seed: int, shape: tuple[int, int, int], size: tuple[int, int] = (7, 9)) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    grid = identity_grid(shape, np.float64) + rng.normal(0.0, 0.2, (*shape, 12))
    rgb = rng.uniform(0.05, 0.95, (*size, 3))

    def f(grid, rgb):
        return bilateral_slice(grid, rgb)

    def vjp(inp, cot):
        return bilateral_slice_backward(inp["grid"], inp["rgb"], cot)

    return check_vjp(f, vjp, {"grid": grid, "rgb": rgb}, seed=seed,
                     name=f"appearance.slice[{'x'.join(map(str, shape))}, seed={seed}]")


def check_tv(seed: int, shape: tuple[int, ...] = (3, 3, 4, 5, 12)) -> list[GradcheckResult]:
    rng = np.random.default_rng(seed)
    grids = rng.normal(size=shape)
    return check_vjp(lambda grids: np.array(total_variation(grids)[0]),
                     lambda inp, cot: {"grids": float(cot) * total_variation(inp["grids"])[1]},
                     {"grids": grids}, seed=seed, name=f"appearance.tv[seed={seed}]")


@register_check("appearance.slice")
def slice_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for shape in SHAPES for r in check_slice(seed, shape)]


@register_check("appearance.tv")
def tv_checks() -> list[GradcheckResult]:
    return [r for seed in (0, 1) for r in check_tv(seed)]
