"""Kalman filtering of the circular trajectory of the Video and 3D Vision textbook chapter.

The chapter's coding task: a point goes once round a circle (50 steps,
radius 10, centre (20, 20)), observed with isotropic Gaussian noise of
sigma 2. Compared over many noise draws:

  textbook   its filter as written: constant velocity (CV), Q = 0.01 I, R = 4 I,
             x0 = [z_0, 0, 0], P0 = 10 I, and a prediction before the first update;
  CV, Q = 0.01 I, diffuse prior     the same model, properly initialised;
  CV, Q = q I                       the textbook's Q structure with its scale tuned;
  CV, white-noise acceleration      Q from a continuous white-noise acceleration of density q;
  CA, white-noise jerk              constant-acceleration model, density q;
each with its Rauch-Tung-Striebel smoother. q is tuned by maximising the
innovation log-likelihood of held-out trajectories (random centre, phase and
direction, disjoint noise draws), never on the evaluation draws.

Errors: RMSE = sqrt(mean_k |x_k - x_true_k|^2) per trajectory, then mean and std
over trajectories; error reduction = 1 - RMSE_filter / RMSE_observations per
trajectory. The filter is linear in the measurements, so its error splits
exactly into a deterministic part (the filter run on noise-free measurements:
the lag) and a zero-mean noise part.

Writes results/kalman_tracking/: metrics.json, table.md, trajectory.png.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from research.experiment import Context, Experiment
from research.results import finish_figure, markdown_table
from research.tracking import kalman
from research.tracking.synthetic import circular_trajectory

EXPERIMENT = "kalman_tracking"
N_STEPS, RADIUS, CENTRE, SIGMA = 50, 10.0, (20.0, 20.0), 2.0
TEXTBOOK_Q, TEXTBOOK_P0 = 0.01, 10.0


def add_options(p) -> None:
    p.add_argument("--trials", type=int, default=None,
                   help="evaluation noise draws (default 2000; quick 200; smoke 20)")
    p.add_argument("--tune-trials", type=int, default=None,
                   help="held-out tuning trajectories (default 500; quick 100; smoke 10)")


# -- models -----------------------------------------------------------------
def textbook_model(q: float = TEXTBOOK_Q) -> kalman.LinearGaussianModel:
    """The snippet's matrices: CV with F = [[I, I], [0, I]], Q = q I (4x4), R = 4 I."""
    cv = kalman.constant_velocity(ndim=2, q=1.0, r=SIGMA**2)
    return kalman.LinearGaussianModel(F=cv.F, H=cv.H, Q=q * np.eye(4), R=cv.R)


def textbook_prior(zs: np.ndarray, model: kalman.LinearGaussianModel) -> tuple[np.ndarray, np.ndarray]:
    """The snippet starts from x = [z_0, 0, 0], P = 10 I, and *predicts* before the
    first update, i.e. its prior at step 0 is (F x, F P F^T + Q) with x = [z_0, 0, 0]."""
    x0 = np.zeros((zs.shape[0], 4))
    x0[:, :2] = zs[:, 0]
    x0 = x0 @ model.F.T
    P0 = model.F @ (TEXTBOOK_P0 * np.eye(4)) @ model.F.T + model.Q
    return x0, P0


def diffuse(zs: np.ndarray, model: kalman.LinearGaussianModel) -> tuple[np.ndarray, np.ndarray]:
    x0 = np.zeros((zs.shape[0], model.state_dim))
    x0[:, :2] = zs[:, 0]
    return x0, 1e6 * np.eye(model.state_dim)


MODELS: dict[str, Callable[[float], kalman.LinearGaussianModel]] = {
    "cv_scaled_identity": textbook_model,
    "cv_white_accel": lambda q: kalman.constant_velocity(2, q=q, r=SIGMA**2),
    "ca_white_jerk": lambda q: kalman.constant_acceleration(2, q=q, r=SIGMA**2),
}


# -- data -------------------------------------------------------------------
def eval_measurements(seed: int, trials: int) -> tuple[np.ndarray, np.ndarray]:
    truth = circular_trajectory(N_STEPS, RADIUS, CENTRE)
    noise = np.random.default_rng([seed, 0]).normal(0.0, SIGMA, (trials, N_STEPS, 2))
    return truth, truth[None] + noise


def tuning_measurements(seed: int, trials: int) -> np.ndarray:
    """Held-out circles: same radius and length, random centre, phase and direction."""
    rng = np.random.default_rng([seed, 1])
    out = np.empty((trials, N_STEPS, 2))
    for i in range(trials):
        truth = circular_trajectory(
            N_STEPS, RADIUS, tuple(rng.uniform(0, 40, 2)), rng.uniform(0, 2 * np.pi), rng.choice([-1.0, 1.0])
        )
        out[i] = truth + rng.normal(0.0, SIGMA, (N_STEPS, 2))
    return out


# -- tuning -----------------------------------------------------------------
def heldout_loglik(make: Callable[[float], kalman.LinearGaussianModel], q: float, zs: np.ndarray) -> float:
    """Mean innovation log-likelihood per trajectory, from step 3 on (the first
    steps only initialise the state from the diffuse prior)."""
    model = make(q)
    res = kalman.kalman_filter(zs, model, *diffuse(zs, model))
    return float(res.loglik[:, 3:].sum(axis=1).mean())


def tune_q(make: Callable[[float], kalman.LinearGaussianModel], zs: np.ndarray) -> tuple[float, float]:
    """argmax_q of the held-out log-likelihood, searched over log10 q in [-5, 2]."""
    opt = minimize_scalar(
        lambda lq: -heldout_loglik(make, 10.0**lq, zs), bounds=(-5.0, 2.0), method="bounded", options={"xatol": 1e-3}
    )
    return float(10.0**opt.x), float(-opt.fun)


# -- evaluation -------------------------------------------------------------
def rmse(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-trajectory RMSE of positions: est (B, T, 2), truth (T, 2) -> (B,)."""
    return np.sqrt(np.mean(np.sum((est - truth) ** 2, axis=-1), axis=-1))


def mean_euclid(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The snippet's error measure (which it prints as "RMSE"): mean Euclidean distance."""
    return np.mean(np.linalg.norm(est - truth, axis=-1), axis=-1)


def run_method(model, prior, zs, truth) -> dict[str, np.ndarray]:
    res = kalman.kalman_filter(zs, model, *prior(zs, model))
    xs, _ = kalman.rts_smoother(res, model.F)
    clean = np.broadcast_to(truth, zs[:1].shape)
    res0 = kalman.kalman_filter(clean, model, *prior(clean, model))
    return {
        "filter": res.x_filt[..., :2],
        "smoother": xs[..., :2],
        "lag_filter": res0.x_filt[0, :, :2] - truth,
        "lag_smoother": kalman.rts_smoother(res0, model.F)[0][0, :, :2] - truth,
    }


def steady_gain(model: kalman.LinearGaussianModel, iters: int = 2000) -> np.ndarray:
    """Steady-state Kalman gain (by iterating the Riccati recursion)."""
    P = np.eye(model.state_dim)
    K = np.zeros((model.state_dim, model.meas_dim))
    for _ in range(iters):
        P = model.F @ P @ model.F.T + model.Q
        S = model.H @ P @ model.H.T + model.R
        K = np.linalg.solve(S, model.H @ P).T
        P = (np.eye(model.state_dim) - K @ model.H) @ P
    return K


def summary(x: np.ndarray) -> dict[str, float]:
    return {"mean": float(np.mean(x)), "std": float(np.std(x))}


def make_figure(truth, zs, outs, curve, q_hat, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5.2))
    ax = axes[0]
    ax.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="ground truth")
    ax.scatter(zs[0, :, 0], zs[0, :, 1], s=14, c="#e74c3c", alpha=0.6, label="observations")
    ax.plot(*outs["textbook"]["filter"][0].T, color="#7f8c8d", lw=1.8, label="textbook filter")
    ax.plot(*outs["cv_white_accel"]["filter"][0].T, color="#3498db", lw=1.8, label="tuned CV filter")
    ax.plot(*outs["cv_white_accel"]["smoother"][0].T, color="#27ae60", lw=1.8, label="tuned CV + RTS smoother")
    ax.set_aspect("equal")
    ax.set_title("trajectory (evaluation draw 0)")
    ax.legend(fontsize=8, loc="center")
    ax.grid(alpha=0.3)

    ax = axes[1]
    steps = np.arange(truth.shape[0])
    ax.plot(steps, np.sqrt(np.mean(np.sum((zs - truth) ** 2, -1), 0)), color="#e74c3c", label="observations")
    for key, style, label in [
        ("textbook", dict(color="#7f8c8d"), "textbook filter"),
        ("cv_white_accel", dict(color="#3498db"), "tuned CV filter"),
    ]:
        err = outs[key]["filter"] - truth
        ax.plot(steps, np.sqrt(np.mean(np.sum(err**2, -1), 0)), label=label, **style)
        lag = np.linalg.norm(outs[key]["lag_filter"], axis=-1)
        ax.plot(steps, lag, ls="--", label=f"{label}: lag (no noise)", **style)
    err = outs["cv_white_accel"]["smoother"] - truth
    ax.plot(steps, np.sqrt(np.mean(np.sum(err**2, -1), 0)), color="#27ae60", label="tuned CV + RTS")
    ax.set_xlabel("step")
    ax.set_ylabel("RMS position error over draws")
    ax.set_title("error per step")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)
    ax.grid(alpha=0.3)

    ax = axes[2]
    qs, ll, err_f = curve
    ax.semilogx(qs, ll, color="#8e44ad")
    ax.axvline(q_hat, color="#8e44ad", ls=":")
    ax.set_xlabel("q (CV, white-noise acceleration density)")
    ax.set_ylabel("held-out log-likelihood per trajectory", color="#8e44ad")
    ax2 = ax.twinx()
    ax2.semilogx(qs, err_f, color="#3498db")
    ax2.set_ylabel("evaluation filter RMSE", color="#3498db")
    ax.set_title(f"tuning q by innovation likelihood (dotted: ML q = {q_hat:.3g})")
    ax.grid(alpha=0.3)
    finish_figure(fig, path)


def run(ctx: Context) -> int:
    args = ctx.args
    trials = args.trials or (20 if ctx.smoke else 200 if ctx.quick else 2000)
    tune_trials = args.tune_trials or (10 if ctx.smoke else 100 if ctx.quick else 500)
    truth, zs = eval_measurements(ctx.seed, trials)
    z_tune = tuning_measurements(ctx.seed, tune_trials)

    methods: dict[str, tuple[str, kalman.LinearGaussianModel, Callable, float]] = {
        "textbook": ("textbook: CV, Q = q I, textbook init", textbook_model(), textbook_prior, TEXTBOOK_Q),
        "textbook_diffuse": ("CV, Q = q I, diffuse prior", textbook_model(), diffuse, TEXTBOOK_Q),
    }
    tuned = {}
    for key in ctx.tqdm(MODELS, desc="tuning q", disable=None):
        q_hat, ll = tune_q(MODELS[key], z_tune)
        tuned[key] = {"q": q_hat, "heldout_loglik": ll}
    labels = {
        "cv_scaled_identity": "CV, Q = q I (tuned)",
        "cv_white_accel": "CV, white-noise accel. (tuned)",
        "ca_white_jerk": "CA, white-noise jerk (tuned)",
    }
    for key, make in MODELS.items():
        methods[key] = (labels[key], make(tuned[key]["q"]), diffuse, tuned[key]["q"])
    tuned["textbook_heldout_loglik"] = heldout_loglik(MODELS["cv_scaled_identity"], TEXTBOOK_Q, z_tune)

    obs_rmse = rmse(zs, truth)
    obs_me = mean_euclid(zs, truth)
    outs, metrics = {}, {}
    for key, (label, model, prior, q) in ctx.tqdm(methods.items(), desc="methods", disable=None):
        out = run_method(model, prior, zs, truth)
        outs[key] = out
        f_rmse, s_rmse = rmse(out["filter"], truth), rmse(out["smoother"], truth)
        metrics[key] = {
            "label": label,
            "q": q,
            "filter_rmse": summary(f_rmse),
            "filter_reduction": summary(1.0 - f_rmse / obs_rmse),
            "smoother_rmse": summary(s_rmse),
            "smoother_reduction": summary(1.0 - s_rmse / obs_rmse),
            "filter_lag_rms": float(np.sqrt(np.mean(np.sum(out["lag_filter"] ** 2, -1)))),
            "smoother_lag_rms": float(np.sqrt(np.mean(np.sum(out["lag_smoother"] ** 2, -1)))),
            "filter_noise_rms": summary(rmse(out["filter"] - out["lag_filter"], truth)),
            "filter_mean_euclid": summary(mean_euclid(out["filter"], truth)),
        }
    gain = steady_gain(textbook_model())
    speed = RADIUS * 2 * np.pi / (N_STEPS - 1)
    explain = {
        "speed_per_step": speed,
        "centripetal_accel_per_step2": speed**2 / RADIUS,
        "textbook_steady_gain_alpha": float(gain[0, 0]),
        "textbook_steady_gain_beta": float(gain[2, 0]),
        "observation_mean_euclid": summary(obs_me),
    }

    # Held-out likelihood and evaluation RMSE along q for the CV white-noise-acceleration model.
    qs = np.logspace(-3, 1, 25)
    ll_curve = [heldout_loglik(MODELS["cv_white_accel"], q, z_tune) for q in qs]
    err_curve = []
    for q in qs:
        m = MODELS["cv_white_accel"](q)
        err_curve.append(float(rmse(kalman.kalman_filter(zs, m, *diffuse(zs, m)).x_filt[..., :2], truth).mean()))

    make_figure(truth, zs, outs, (qs, ll_curve, err_curve), tuned["cv_white_accel"]["q"], ctx.out / "trajectory.png")

    table = table_markdown(metrics, obs_rmse, explain, tuned, trials, tune_trials)
    all_metrics = {
        "trials": trials,
        "tune_trials": tune_trials,
        "observation_rmse": summary(obs_rmse),
        "methods": metrics,
        "tuning": tuned,
        "diagnosis": explain,
        "q_sweep": {"q": qs.tolist(), "heldout_loglik": ll_curve, "eval_filter_rmse": err_curve},
    }
    config = {
        "n_steps": N_STEPS,
        "radius": RADIUS,
        "centre": list(CENTRE),
        "sigma": SIGMA,
        "trials": trials,
        "tune_trials": tune_trials,
        "textbook": {"Q": "0.01 I", "R": "4 I", "P0": "10 I", "x0": "[z0, 0, 0]"},
        "diffuse_prior_var": 1e6,
    }
    ctx.write_results(config=config, metrics=all_metrics, table_md=table)
    return 0


def table_markdown(metrics, obs_rmse, explain, tuned, trials, tune_trials) -> str:
    def pm(s: dict, scale: float = 1.0, fmt: str = ".3f") -> str:
        return f"{s['mean'] * scale:{fmt}} ± {s['std'] * scale:{fmt}}"

    rows = []
    for key, m in metrics.items():
        rows.append(
            [
                m["label"],
                f"{m['q']:.3g}",
                pm({"mean": obs_rmse.mean(), "std": obs_rmse.std()}),
                pm(m["filter_rmse"]),
                pm(m["filter_reduction"], 100, ".1f") + " %",
                f"{m['filter_lag_rms']:.2f}",
                pm(m["smoother_rmse"]),
                pm(m["smoother_reduction"], 100, ".1f") + " %",
            ]
        )
    headers = [
        "method",
        "q",
        "obs RMSE",
        "filter RMSE",
        "filter reduction",
        "filter lag RMS",
        "RTS RMSE",
        "RTS reduction",
    ]
    tb = metrics["textbook"]
    cv = metrics["cv_white_accel"]
    ca = metrics["ca_white_jerk"]
    text = [
        "# Kalman filtering of the textbook's circle",
        "",
        f"Circle of {N_STEPS} steps, radius {RADIUS:g}, centre {CENTRE}, measurement noise sigma {SIGMA:g}. "
        f"Mean ± std over {trials} noise draws; q tuned by maximum held-out innovation likelihood on "
        f"{tune_trials} other circles (random centre, phase, direction). RMSE = sqrt(mean |error|^2) per "
        "trajectory; reduction = 1 - RMSE_est / RMSE_obs per trajectory. Lag RMS: the error of the same "
        "estimator on noise-free measurements (the estimators are linear, so error = lag + noise part).",
        "",
        markdown_table(headers, rows),
        "## Why the textbook's filter gives no gain, and the fix",
        "",
        f"The snippet reports observation \"RMSE\" 2.25 and filter 2.26 for one draw. Over {trials} draws its "
        f"filter is hardly better by the snippet's own measure, the mean Euclidean error (which it prints "
        f"under the name RMSE): {explain['observation_mean_euclid']['mean']:.2f} for the observations, "
        f"{tb['filter_mean_euclid']['mean']:.2f} for the filter "
        f"({100 * (1 - tb['filter_mean_euclid']['mean'] / explain['observation_mean_euclid']['mean']):.1f} %). "
        f"By true RMSE the gain is "
        f"{100 * tb['filter_reduction']['mean']:.1f} % ({obs_rmse.mean():.2f} → {tb['filter_rmse']['mean']:.2f}), "
        f"smaller than its spread between draws ({100 * tb['filter_reduction']['std']:.1f} %).",
        "",
        f"1. **Process noise far too small for the motion (the main cause).** The point moves "
        f"{explain['speed_per_step']:.2f} units per step round a circle of radius {RADIUS:g}, so its velocity "
        f"turns by {360 / (N_STEPS - 1):.1f}° each step: a centripetal acceleration of "
        f"{explain['centripetal_accel_per_step2']:.3f} units/step². Q = 0.01 I tells the constant-velocity "
        f"filter that the velocity hardly changes, so its gain is small (steady state α = "
        f"{explain['textbook_steady_gain_alpha']:.2f} on position, β = {explain['textbook_steady_gain_beta']:.3f} "
        f"on velocity) and it cuts the chord instead of following the curve. On noise-free measurements "
        f"it is off by {tb['filter_lag_rms']:.2f} RMS (lag), while it shrinks the noise part to "
        f"{tb['filter_noise_rms']['mean']:.2f}; together sqrt(lag² + noise²) ≈ the observation error, "
        f"hence no gain.",
        "2. **Initialisation.** The snippet starts with zero velocity (the true speed is "
        f"{explain['speed_per_step']:.2f}) and predicts before its first update, so z_0 enters a prior centred on "
        f"z_0 and then again as a measurement, counted twice. A diffuse prior (next row) changes little: "
        f"filter RMSE {metrics['textbook_diffuse']['filter_rmse']['mean']:.3f} instead of "
        f"{tb['filter_rmse']['mean']:.3f}; the lag from Q dominates.",
        "3. **Measurement.** The printed \"RMSE\" is a mean distance, and one draw (2.25 vs 2.26) is within "
        f"the spread between draws (std of the observation error {explain['observation_mean_euclid']['std']:.2f}).",
        "",
        f"**Fix:** choose the process noise from data. Maximising the held-out innovation log-likelihood gives "
        f"q = {cv['q']:.3g} for the CV model with white-noise acceleration (Q = q [[1/3, 1/2], [1/2, 1]] per "
        f"axis) and Q = {metrics['cv_scaled_identity']['q']:.3g} I for the textbook's Q structure (the "
        f"textbook's 0.01 has held-out log-likelihood {tuned['textbook_heldout_loglik']:.1f} per trajectory vs "
        f"{tuned['cv_scaled_identity']['heldout_loglik']:.1f} at the optimum). The tuned CV filter lowers the RMSE by "
        f"{100 * cv['filter_reduction']['mean']:.1f} %, and its RTS smoother, which uses future measurements "
        f"too (offline), by {100 * cv['smoother_reduction']['mean']:.1f} %. "
        f"The tuned CA model filters {'worse' if ca['filter_rmse']['mean'] > cv['filter_rmse']['mean'] else 'better'} "
        f"than CV ({100 * ca['filter_reduction']['mean']:.1f} % vs {100 * cv['filter_reduction']['mean']:.1f} %): "
        "on a circle the acceleration rotates, so it is no more constant than the velocity, and the extra "
        "state costs variance. Its smoother, which can fit the acceleration from both sides, reaches "
        f"{100 * ca['smoother_reduction']['mean']:.1f} %. Smoothing also rescues the textbook's model "
        f"({100 * tb['smoother_reduction']['mean']:.1f} %): the backward pass lags the other way, and the "
        f"lag RMS drops from {tb['filter_lag_rms']:.2f} to {tb['smoother_lag_rms']:.2f}. "
        "The likelihood optimum of q sits close to the RMSE optimum (trajectory.png, right), so tuning on "
        "held-out data needs no ground truth.",
        "",
    ]
    return "\n".join(text)


main = Experiment(EXPERIMENT, __doc__, run, add_options, warp=False, seed_help="seed of all noise draws",
                  sizes="Quick: 200 evaluation draws and 100 tuning trajectories (a few seconds); smoke: 20 and "
                        "10.").script(__name__)
