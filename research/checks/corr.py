"""Gradient checks of kernels.corr: volume, pyramid, dense lookup, feature pooling, on-the-fly lookup.

Inputs are random and non-degenerate: standard-normal features and volumes, and
lookup coordinates spread past every border (so zero-padded taps are exercised).
Bilinear sampling is piecewise linear: its derivative jumps where a sample
position crosses a tap, i.e. where x / 2^l - 1/2 is an integer for some level l.
Over all levels those positions have x mod 1 in {0, 0.5}, so every coordinate
here keeps its fractional part in [0.1, 0.4] or [0.6, 0.9], far from the kinks
compared with the finite-difference step (1e-6).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from kernels import corr
from research.gradcheck import GradcheckResult, check_vjp, register_check

SEEDS = (0, 1, 2)
# (C, H, W), levels, radius of the checks: small, but with odd sizes (floors in the pooling) and 3 levels.
SHAPE = (3, 8, 11)
LEVELS = 3
RADIUS = 2


def smooth_coords(rng: np.random.Generator, height: int, width: int, margin: float = 3.0) -> np.ndarray:
    """(2, H, W) positions in [-margin, W + margin] x [-margin, H + margin], fractional parts off the kinks."""
    def axis(extent: int) -> np.ndarray:
        whole = rng.integers(-int(margin), extent + int(margin), (height, width)).astype(np.float64)
        frac = rng.uniform(0.1, 0.4, (height, width)) + 0.5 * rng.integers(0, 2, (height, width))
        return whole + frac

    return np.stack([axis(width), axis(height)])


def _random_levels(rng: np.random.Generator, prefix: str, lead: tuple[int, ...], height: int, width: int,
                   levels: int) -> dict[str, np.ndarray]:
    """Standard-normal pyramid levels {prefix0: (*lead, H_0, W_0), prefix1: ...}, drawn in level order."""
    return {f"{prefix}{lvl}": rng.standard_normal((*lead, hl, wl))
            for lvl, (hl, wl) in enumerate(corr.level_shapes(height, width, levels))}


def check_volume(seed: int, shape: tuple[int, int, int] = SHAPE, backend: str | None = None) -> list[GradcheckResult]:
    """V = f1 . f2 / sqrt(C), against f1 and f2, with the product's `backend` (None: the device's default)."""
    rng = np.random.default_rng(seed)
    inputs = {"f1": rng.standard_normal(shape), "f2": rng.standard_normal(shape)}

    def forward(f1: np.ndarray, f2: np.ndarray) -> np.ndarray:
        return corr.correlation_volume(f1, f2, backend=backend)

    def vjp(x: dict[str, np.ndarray], cot: np.ndarray) -> dict[str, np.ndarray]:
        return corr.correlation_volume_backward(x["f1"], x["f2"], cot, backend=backend)

    name = "corr.volume" if backend is None else f"corr.volume_{backend}"
    return check_vjp(forward, vjp, inputs, seed=seed, name=name)


def check_volume_warp(seed: int) -> list[GradcheckResult]:
    """`check_volume` with the blocked Warp product (the CPU's default is BLAS)."""
    return check_volume(seed, backend="warp")


def _check_pooling(seed: int, name: str, arg: str, shape: tuple[int, ...], forward: Callable[..., list],
                   backward: Callable[[list], dict]) -> list[GradcheckResult]:
    """Every level of a pooled pyramid `forward(x)` against a standard-normal x of `shape`, whose gradient is
    backward(cotangents)[arg]."""
    x = np.random.default_rng(seed).standard_normal(shape)

    def f(**x_in: np.ndarray) -> tuple[np.ndarray, ...]:
        return tuple(forward(x_in[arg]))

    def vjp(x_in: dict[str, np.ndarray], cot: tuple[np.ndarray, ...]) -> dict[str, np.ndarray]:
        return backward(list(cot))

    return check_vjp(f, vjp, {arg: x}, seed=seed, name=name)


def check_pyramid(seed: int, height: int = 9, width: int = 10, levels: int = LEVELS) -> list[GradcheckResult]:
    """2x2 average pooling over frame 2's dimensions, every level's output against V^0."""
    return _check_pooling(seed, "corr.pyramid", "volume", (height, width, height, width),
                          lambda v: corr.correlation_pyramid(v, levels), corr.correlation_pyramid_backward)


def check_lookup(seed: int, shape: tuple[int, int, int] = SHAPE, levels: int = LEVELS,
                 radius: int = RADIUS) -> list[GradcheckResult]:
    """Dense lookup (4), against every pyramid level and the coordinates."""
    rng = np.random.default_rng(seed)
    _, height, width = shape
    pyramid = _random_levels(rng, "level", (height, width), height, width, levels)
    inputs = {**pyramid, "coords": smooth_coords(rng, height, width)}
    names = list(pyramid)

    def f(coords: np.ndarray, **levels_in: np.ndarray) -> np.ndarray:
        return corr.lookup([levels_in[n] for n in names], coords, radius)

    def vjp(x: dict[str, np.ndarray], cot: np.ndarray) -> dict[str, np.ndarray]:
        grads = corr.lookup_backward([x[n] for n in names], x["coords"], radius, cot)
        return {**dict(zip(names, grads["pyramid"])), "coords": grads["coords"]}

    return check_vjp(f, vjp, inputs, seed=seed, name="corr.lookup")


def _chain_inputs(seed: int, shape: tuple[int, int, int]) -> dict[str, np.ndarray]:
    """The inputs of a whole lookup path: features f1, f2 (C, H, W) and coordinates (2, H, W)."""
    rng = np.random.default_rng(seed)
    _, height, width = shape
    return {"f1": rng.standard_normal(shape), "f2": rng.standard_normal(shape),
            "coords": smooth_coords(rng, height, width)}


def check_dense_chain(seed: int, shape: tuple[int, int, int] = SHAPE, levels: int = LEVELS,
                      radius: int = RADIUS) -> list[GradcheckResult]:
    """lookup(pyramid(volume(f1, f2)), coords), the whole dense path, against f1, f2 and the coordinates."""
    inputs = _chain_inputs(seed, shape)

    def f(f1: np.ndarray, f2: np.ndarray, coords: np.ndarray) -> np.ndarray:
        return corr.lookup(corr.correlation_pyramid(corr.correlation_volume(f1, f2), levels), coords, radius)

    def vjp(x: dict[str, np.ndarray], cot: np.ndarray) -> dict[str, np.ndarray]:
        pyramid = corr.correlation_pyramid(corr.correlation_volume(x["f1"], x["f2"]), levels)
        grads = corr.lookup_backward(pyramid, x["coords"], radius, cot)
        grad_volume = corr.correlation_pyramid_backward(grads["pyramid"])["volume"]
        return {**corr.correlation_volume_backward(x["f1"], x["f2"], grad_volume), "coords": grads["coords"]}

    return check_vjp(f, vjp, inputs, seed=seed, name="corr.dense_chain")


def check_pool_features(seed: int, shape: tuple[int, int, int] = (2, 9, 10),
                        levels: int = LEVELS) -> list[GradcheckResult]:
    """P^l(f2) for every level, against f2."""
    return _check_pooling(seed, "corr.pool_features", "f2", shape, lambda v: corr.pool_features(v, levels),
                          corr.pool_features_backward)


def check_lookup_onthefly(seed: int, shape: tuple[int, int, int] = SHAPE, levels: int = LEVELS,
                          radius: int = RADIUS) -> list[GradcheckResult]:
    """On-the-fly lookup, against f1, every pooled f2 level and the coordinates."""
    rng = np.random.default_rng(seed)
    channels, height, width = shape
    f1 = rng.standard_normal(shape)
    f2_levels = _random_levels(rng, "f2_level", (channels,), height, width, levels)
    inputs = {"f1": f1, **f2_levels, "coords": smooth_coords(rng, height, width)}
    names = list(f2_levels)

    def f(f1: np.ndarray, coords: np.ndarray, **f2_levels: np.ndarray) -> np.ndarray:
        return corr.lookup_onthefly(f1, [f2_levels[n] for n in names], coords, radius)

    def vjp(x: dict[str, np.ndarray], cot: np.ndarray) -> dict[str, np.ndarray]:
        grads = corr.lookup_onthefly_backward(x["f1"], [x[n] for n in names], x["coords"], radius, cot)
        return {"f1": grads["f1"], **dict(zip(names, grads["f2_pyramid"])), "coords": grads["coords"]}

    return check_vjp(f, vjp, inputs, seed=seed, name="corr.lookup_onthefly")


def check_onthefly_chain(seed: int, shape: tuple[int, int, int] = SHAPE, levels: int = LEVELS,
                         radius: int = RADIUS) -> list[GradcheckResult]:
    """lookup_onthefly(f1, pool_features(f2), coords), against f1, f2 and the coordinates."""
    inputs = _chain_inputs(seed, shape)

    def f(f1: np.ndarray, f2: np.ndarray, coords: np.ndarray) -> np.ndarray:
        return corr.lookup_onthefly(f1, corr.pool_features(f2, levels), coords, radius)

    def vjp(x: dict[str, np.ndarray], cot: np.ndarray) -> dict[str, np.ndarray]:
        grads = corr.lookup_onthefly_backward(x["f1"], corr.pool_features(x["f2"], levels), x["coords"],
                                              radius, cot)
        return {"f1": grads["f1"], **corr.pool_features_backward(grads["f2_pyramid"]), "coords": grads["coords"]}

    return check_vjp(f, vjp, inputs, seed=seed, name="corr.onthefly_chain")


def radius_of(seed: int) -> int:
    """The lookup radius the checks use with `seed`: 1, 2, 3 in turn."""
    return (1, 2, 3)[seed % 3]


def _over_seeds(check: Callable[..., list[GradcheckResult]], vary_radius: bool) -> Callable[[], list[GradcheckResult]]:
    """`check` run for every seed in SEEDS (with the seed's radius when `vary_radius`)."""
    def run() -> list[GradcheckResult]:
        return [r for seed in SEEDS
                for r in (check(seed, radius=radius_of(seed)) if vary_radius else check(seed))]

    return run


for _name, _check, _vary in [("corr.volume", check_volume, False), ("corr.volume_warp", check_volume_warp, False),
                             ("corr.pyramid", check_pyramid, False),
                             ("corr.lookup", check_lookup, True), ("corr.dense_chain", check_dense_chain, False),
                             ("corr.pool_features", check_pool_features, False),
                             ("corr.lookup_onthefly", check_lookup_onthefly, True),
                             ("corr.onthefly_chain", check_onthefly_chain, False)]:
    register_check(_name)(_over_seeds(_check, _vary))
