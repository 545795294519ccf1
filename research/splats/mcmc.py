"""MCMC densification of the splats: "3D Gaussian Splatting as Markov Chain Monte Carlo" (Kheradmand et al. 2024).

The splats are treated as samples of a distribution; instead of 3DGS's clone / split / prune, every
`refine_every` iterations in (refine_start, refine_stop):

  * RELOCATION: the dead splats (opacity o <= min_opacity) are moved onto live ones drawn with
    probability proportional to opacity (with replacement). A live splat drawn N - 1 times
    becomes N copies of itself (itself and the dead splats moved onto it) whose opacity and scale
    are corrected so that the N copies render like the one splat they replace (the paper's eq. 9):

        o_new = 1 - (1 - o_old)^(1/N),
        s_new = o_old / D_N(o_new) * s_old,
        D_N(o) = sum_{i=1}^{N} sum_{k=0}^{i-1} C(i-1, k) (-1)^k o^(k+1) / sqrt(k+1)

    (scales s are the square roots of the covariance's eigenvalues, so Sigma_new = (o_old / D_N)^2 Sigma_old).
    The first condition makes N copies composite to o_old at the centre: 1 - (1 - o_new)^N = o_old. The
    second makes the line integral of the composited alpha 1 - (1 - o_new g(x))^N equal that of o_old g(x),
    g a Gaussian profile: expanding the power binomially, the j-th term integrates to C(N, j) (-1)^(j-1)
    o_new^j s_new sqrt(2 pi / j), and sum_{i=1}^{N} C(i-1, k) = C(N, k+1) turns the double sum into
    D_N(o) = sum_{j=1}^{N} C(N, j) (-1)^(j-1) o^j / sqrt(j), the form evaluated here (float64).
    N is clamped to [1, N_MAX] as gsplat does (its binomial table has 51 rows); o_new to
    [min_opacity, 1 - float32 eps].
  * GROWTH: min(cap_max, int(grow_rate * n)) - n new splats are added the same way (sources drawn by
    opacity over all splats, each source and its copies corrected as above), up to the hard cap.
  * ADAM STATE: the moments of the relocated sources and of the rows they were copied into are zeroed
    (gsplat zeroes the sources only and leaves the dead rows' stale moments; zeroing both is the
    "moved splats get a fresh state" of the paper's code); added rows start with zero moments.

Every iteration the means get NOISE (the SGLD term of the paper, gsplat's inject_noise_to_position):

    mu <- mu + lr_means * noise_lr * sigmoid(k ((1 - o) - t)) * Sigma eps,   eps ~ N(0, I),  k = 100, t = 0.995,

Sigma = R diag(s^2) R^T the splat's covariance; the sigmoid is ~1 for nearly transparent splats and
~0 (e^-50 at o = 0.5) for opaque ones, so only splats about to die explore.

The loss gets the paper's L1 REGULARISERS, as gsplat writes them (means over the splats):

    L_reg = opacity_reg * mean_i o_i + scale_reg * mean_{i,j} s_ij,   o = sigmoid(logit), s = exp(log_scale),

with gradients opacity_reg o (1 - o) / n by logit and scale_reg s / (3 n) by log-scale, added to the
rendered loss's gradients before the Adam step. There is no opacity reset and no pruning.

Defaults are gsplat's MCMCStrategy and simple_trainer "mcmc" config (cap_max, noise_lr 5e5, refine
500..25000 every 100, min_opacity 0.005, grow rate 1.05, both regularisers 0.01; its initial
opacity 0.5 and scale x 0.1 are INIT_OPACITY and INIT_SCALE_FACTOR, applied by the caller). None was
tuned here: they are gsplat's values for 30k iterations, and the iteration numbers are scaled to the
run as research.splats.densify.Schedule.scaled scales 3DGS's (with its floor on the interval).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kernels.optim import Adam
from research.splats.densify import MIN_DENSIFY_INTERVAL, REFERENCE_ITERATIONS, _quat_to_rotmats
from research.splats.model import GaussianModel

N_MAX = 51  # gsplat's binomial table: copies per source are clamped to this
NOISE_K = 100.0  # the noise gate's steepness and threshold (paper and gsplat)
NOISE_T = 0.995
INIT_OPACITY = 0.5  # gsplat's simple_trainer "mcmc" config: init_opa 0.5, init_scale 0.1 (times the kNN scale)
INIT_SCALE_FACTOR = 0.1
_F32_EPS = float(np.finfo(np.float32).eps)


@dataclass(frozen=True)
class MCMCConfig:
    cap_max: int = 1_000_000
    noise_lr: float = 5e5
    refine_start_iter: int = 500  # at 30k iterations; scaled to the run (MCMCSchedule)
    refine_stop_iter: int = 25_000
    refine_every: int = 100
    min_opacity: float = 0.005
    grow_rate: float = 1.05
    opacity_reg: float = 0.01
    scale_reg: float = 0.01

    def __post_init__(self) -> None:
        if not (isinstance(self.cap_max, (int, np.integer)) and self.cap_max >= 1):
            raise ValueError(f"cap_max: expected an integer >= 1, got {self.cap_max!r}")
        for name in ("noise_lr", "opacity_reg", "scale_reg"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: expected a value >= 0, got {getattr(self, name)}")
        if not 0 < self.min_opacity < 1:
            raise ValueError(f"min_opacity: expected a value in (0, 1), got {self.min_opacity}")
        if not self.grow_rate >= 1:
            raise ValueError(f"grow_rate: expected a value >= 1, got {self.grow_rate}")
        if not 0 <= self.refine_start_iter < self.refine_stop_iter or self.refine_every < 1:
            raise ValueError("refine_start_iter, refine_stop_iter, refine_every: expected 0 <= start < stop and "
                             f"every >= 1, got {self.refine_start_iter}, {self.refine_stop_iter}, {self.refine_every}")


@dataclass(frozen=True)
class MCMCSchedule:
    start: int
    stop: int
    every: int

    @classmethod
    def scaled(cls, iterations: int, cfg: MCMCConfig) -> "MCMCSchedule":
        """cfg's iteration numbers (given for REFERENCE_ITERATIONS) times iterations / 30000, as
        densify.Schedule.scaled: at least 1, the interval at least MIN_DENSIFY_INTERVAL."""
        if iterations < 1:
            raise ValueError(f"iterations: expected a positive integer, got {iterations}")
        s = iterations / REFERENCE_ITERATIONS

        def at(x: float) -> int:
            return max(1, round(x * s))

        return cls(at(cfg.refine_start_iter), at(cfg.refine_stop_iter),
                   max(at(cfg.refine_every), MIN_DENSIFY_INTERVAL))

    def refine_now(self, iteration: int) -> bool:
        """After `iteration` iterations (1-based)."""
        return self.start < iteration < self.stop and iteration % self.every == 0


def binomial_denominator(opacity: np.ndarray, n: np.ndarray) -> np.ndarray:
    """D_N(o) = sum_{j=1}^{N} C(N, j) (-1)^(j-1) o^j / sqrt(j) (module docstring), float64, per element."""
    o = np.asarray(opacity, dtype=np.float64)
    n = np.asarray(n)
    j = np.arange(1, int(n.max(initial=1)) + 1)
    comb = np.array([[math.comb(int(m), int(jj)) for jj in j] for m in range(int(n.max(initial=1)) + 1)],
                    dtype=np.float64)  # comb[N, j-1] = C(N, j), zero for j > N
    terms = comb[n] * (-1.0) ** (j - 1) * o[..., None] ** j / np.sqrt(j)
    return terms.sum(axis=-1)


def relocation(opacity: np.ndarray, scales: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The opacity (K,) and scales (K, 3) of each of n (K,) copies replacing a splat of `opacity` and
    `scales` (the paper's eq. 9, module docstring); float64. n must be in [1, N_MAX]."""
    o = np.asarray(opacity, dtype=np.float64)
    s = np.asarray(scales, dtype=np.float64)
    n = np.asarray(n)
    if o.ndim != 1 or s.shape != (len(o), 3) or n.shape != o.shape:
        raise ValueError(f"opacity, scales, n: expected shapes (K,), (K, 3), (K,), got {o.shape}, {s.shape}, {n.shape}")
    if not np.issubdtype(n.dtype, np.integer) or np.any(n < 1) or np.any(n > N_MAX):
        raise ValueError(f"n: expected integers in [1, {N_MAX}]")
    if np.any(~(o > 0)) or np.any(~(o <= 1)) or np.any(~(s > 0)):
        raise ValueError("opacity, scales: expected opacities in (0, 1] and positive scales")
    o_new = -np.expm1(np.log1p(-o) / n)  # 1 - (1 - o)^(1/n), accurate for small o
    return o_new, (o / binomial_denominator(o_new, n))[:, None] * s


def _corrected_copies(model: GaussianModel, sources: np.ndarray, min_opacity: float) -> None:
    """Give every row in `sources` (with repeats) the corrected opacity and scale of its
    (repeat count + 1) copies, in place (gsplat's relocate / sample_add)."""
    counts = np.bincount(sources, minlength=model.n)[sources] + 1
    o_old = np.minimum(_sigmoid(model.opacity_logits[sources]), 1.0 - _F32_EPS)  # as float32 sees it (<= 1 - eps)
    o_new, s_new = relocation(o_old,
                              np.exp(model.log_scales[sources].astype(np.float64)), np.minimum(counts, N_MAX))
    o_new = np.clip(o_new, min_opacity, 1.0 - _F32_EPS)
    model.opacity_logits[sources] = np.log(o_new / (1.0 - o_new)).astype(np.float32)
    model.log_scales[sources] = np.log(s_new).astype(np.float32)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, dtype=np.float64)))  # no overflow for large |x|


def _sample_by_opacity(opacity: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    p = np.asarray(opacity, dtype=np.float64)
    return rng.choice(len(p), size=k, replace=True, p=p / p.sum())


def relocate_dead(model: GaussianModel, adam: Adam, cfg: MCMCConfig, rng: np.random.Generator) -> int:
    """Move the dead splats onto live ones (module docstring), in place; returns how many moved."""
    opac = _sigmoid(model.opacity_logits)
    dead = np.flatnonzero(opac <= cfg.min_opacity)
    alive = np.flatnonzero(opac > cfg.min_opacity)
    if len(dead) == 0 or len(alive) == 0:
        return 0
    sources = alive[_sample_by_opacity(opac[alive], len(dead), rng)]
    _corrected_copies(model, sources, cfg.min_opacity)
    for name, arr in model.arrays().items():
        arr[dead] = arr[sources]
    adam.reset_rows(np.concatenate([sources, dead]))
    return len(dead)


def add_new(model: GaussianModel, adam: Adam, cfg: MCMCConfig,
            rng: np.random.Generator) -> tuple[GaussianModel, int]:
    """Grow to min(cap_max, int(grow_rate n)) splats by copying sources drawn by opacity (module
    docstring); returns the new model (adam extended to match) and the number added."""
    n_new = max(0, min(cfg.cap_max, int(cfg.grow_rate * model.n)) - model.n)
    if n_new == 0:
        return model, 0
    sources = _sample_by_opacity(_sigmoid(model.opacity_logits), n_new, rng)
    _corrected_copies(model, sources, cfg.min_opacity)
    adam.append(n_new)
    return model.append(model.select(sources)), n_new


def covariances(log_scales: np.ndarray, quats: np.ndarray) -> np.ndarray:
    """Sigma = R diag(exp(2 log_scales)) R^T (N, 3, 3), R from the normalised quaternions (w, x, y, z), float64."""
    R = _quat_to_rotmats(np.asarray(quats, dtype=np.float64))
    s2 = np.exp(2.0 * np.asarray(log_scales, dtype=np.float64))
    return np.einsum("nij,nj,nkj->nik", R, s2, R)


def noise_gate(opacity: np.ndarray) -> np.ndarray:
    """sigmoid(k ((1 - o) - t)), k = 100, t = 0.995 (gsplat's op_sigmoid(1 - opacities))."""
    return 0.5 * (1.0 + np.tanh(0.5 * NOISE_K * ((1.0 - np.asarray(opacity, dtype=np.float64)) - NOISE_T)))


def position_noise(model: GaussianModel, lr_means: float, noise_lr: float,
                   rng: np.random.Generator) -> np.ndarray:
    """The noise step (N, 3) float64 added to the means (module docstring)."""
    eps = rng.standard_normal((model.n, 3)) * (noise_gate(_sigmoid(model.opacity_logits)) * lr_means * noise_lr)[:, None]
    return np.einsum("nij,nj->ni", covariances(model.log_scales, model.quats), eps)


def inject_noise(model: GaussianModel, lr_means: float, noise_lr: float, rng: np.random.Generator) -> None:
    model.means += position_noise(model, lr_means, noise_lr, rng).astype(np.float32)


def regularizer(opacity_logits: np.ndarray, log_scales: np.ndarray, opacity_reg: float,
                scale_reg: float) -> tuple[float, np.ndarray, np.ndarray]:
    """L_reg (module docstring) and its gradients by the opacity logits (N,) and log-scales (N, 3)."""
    logits = np.asarray(opacity_logits)
    ls = np.asarray(log_scales)
    n = len(logits)
    if logits.ndim != 1 or ls.shape != (n, 3) or n == 0:
        raise ValueError(f"opacity_logits, log_scales: expected shapes (N > 0,), (N, 3), got {logits.shape}, "
                         f"{ls.shape}")
    o = _sigmoid(logits)
    s = np.exp(ls)
    loss = opacity_reg * o.mean() + scale_reg * s.mean()
    return float(loss), (opacity_reg / n) * o * (1.0 - o), (scale_reg / (3 * n)) * s


def refine(model: GaussianModel, adam: Adam, cfg: MCMCConfig,
           rng: np.random.Generator) -> tuple[GaussianModel, dict[str, int]]:
    """One refinement step: relocate the dead, then grow towards the cap (gsplat's order)."""
    moved = relocate_dead(model, adam, cfg, rng)
    model, added = add_new(model, adam, cfg, rng)
    return model, {"relocated": moved, "added": added}
