"""Composite samples along rays (NeRF's volume-rendering quadrature) and differentiate it.

Run from the repository root:  python docs/examples/composite_rays.py

Four rays cross a fuzzy ball of density; each ray carries 32 samples, packed one ray after the
other (`ray_offsets` says where each ray's samples start). `composite_forward` computes, per ray,

    alpha_k = 1 - exp(-sigma_k delta_k),  T_k = prod_{j<k} (1 - alpha_j),  w_k = T_k alpha_k,
    colour = sum_k w_k c_k + T_N b,  depth = sum_k w_k z_k,  opacity = 1 - T_N,

which this script recomputes in NumPy for comparison. `composite_backward` returns the gradients
of <g_C, colour> + <g_D, depth> + <g_A, opacity> with respect to every sample's density and
colour; one density gradient is checked against a central finite difference.
"""

from __future__ import annotations

import numpy as np

from kernels.volume import composite_backward, composite_forward
from research.warp_runtime import init_warp

N_RAYS, N_SAMPLES = 4, 32


def to_numpy(x):
    """Entry points hand back the input's kind (NumPy in, NumPy out); this accepts a wp.array too."""
    return np.asarray(x.numpy() if hasattr(x, "numpy") else x)


def rays():
    """Packed samples of 4 rays through a Gaussian ball of density centred at depth 2."""
    z = np.tile(np.linspace(0.5, 3.5, N_SAMPLES), N_RAYS)  # sample depths along each ray
    delta = np.full(z.shape, 3.0 / N_SAMPLES)  # interval lengths
    miss = np.repeat([0.0, 0.2, 0.4, 0.8], N_SAMPLES)  # distance of each ray from the ball's centre
    sigma = 6.0 * np.exp(-((z - 2.0) ** 2 + miss ** 2) / 0.1)
    rgb = np.stack([0.5 + 0.4 * np.sin(3 * z), 0.5 + 0.4 * np.cos(2 * z), 0.3 + 0.0 * z], axis=1)
    offsets = np.arange(N_RAYS + 1, dtype=np.int32) * N_SAMPLES
    return sigma, rgb, delta, z, offsets


def numpy_composite(sigma, rgb, delta, z, offsets, background):
    """The same quadrature, one ray at a time, without early termination."""
    out = []
    for r in range(len(offsets) - 1):
        s = slice(offsets[r], offsets[r + 1])
        alpha = 1.0 - np.exp(-sigma[s] * delta[s])
        T = np.concatenate([[1.0], np.cumprod(1.0 - alpha)])
        w = T[:-1] * alpha
        out.append((w @ rgb[s] + T[-1] * background, w @ z[s], 1.0 - T[-1]))
    return [np.array(x) for x in zip(*out)]


def main() -> None:
    init_warp()  # keep Warp's start-up banner off stdout
    background = np.array([1.0, 1.0, 1.0])
    sigma, rgb, delta, z, offsets = rays()
    # t_threshold=0 turns early ray termination off, so the NumPy loop above is exact.
    res = composite_forward(sigma, rgb, delta, z, offsets, background=background, t_threshold=0.0)
    colour, depth, opacity = to_numpy(res.rgb), to_numpy(res.depth), to_numpy(res.opacity)
    for r in range(N_RAYS):
        print(f"ray {r}: colour {np.round(colour[r], 4)}  opacity {opacity[r]:.4f}  "
              f"expected depth {depth[r] / opacity[r]:.4f}")
    ref = numpy_composite(sigma, rgb, delta, z, offsets, background)
    err = max(np.abs(a - b).max() for a, b in zip((colour, depth, opacity), ref))
    print(f"max |Warp - NumPy| over colour, depth, opacity: {err:.2e}")
    if not err < 1e-12:
        raise SystemExit("the Warp forward disagrees with the NumPy quadrature")

    # Gradient of the summed red channel (g_C = (1, 0, 0) on every ray) with respect to sigma.
    grad_colour = np.zeros((N_RAYS, 3))
    grad_colour[:, 0] = 1.0
    # composite_backward returns the pair (d sigma (N,), d rgb (N, 3)).
    grads = composite_backward(sigma, rgb, delta, z, offsets, res, grad_rgb=grad_colour, background=background)
    d_sigma, d_rgb = (to_numpy(g) for g in grads)
    k = int(np.argmax(np.abs(d_sigma)))
    eps = 1e-6
    red = []
    for sign in (1.0, -1.0):
        s2 = sigma.copy()
        s2[k] += sign * eps
        red.append(to_numpy(composite_forward(s2, rgb, delta, z, offsets, background=background,
                                              t_threshold=0.0).rgb)[:, 0].sum())
    fd = (red[0] - red[1]) / (2 * eps)
    print(f"d(sum of red)/d sigma[{k}]: backward {d_sigma[k]:.8f}, finite difference {fd:.8f}")
    print(f"d(sum of red)/d rgb: the sample weights w_k, which sum to the opacities: "
          f"{np.round(d_rgb[:, 0].reshape(N_RAYS, N_SAMPLES).sum(axis=1), 4)}")
    if not abs(d_sigma[k] - fd) <= 1e-6 * max(1.0, abs(fd)):
        raise SystemExit("the backward disagrees with the finite difference")
    print("backward matches the finite difference")


if __name__ == "__main__":
    main()
