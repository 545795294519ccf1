"""Render a few 3D Gaussians with the splatting kernels, then take one gradient step.

Run from the repository root:  python docs/examples/render_splats.py

Five Gaussians (degree-0 spherical harmonics, i.e. one colour each) sit in front of a camera at
the origin that looks down +z (OpenCV axes: x right, y down). `render` projects, bins and
rasterises them; `render_backward` gives the gradient of a loss on the image with respect to
every splat parameter. One small step against that gradient must lower the loss.
"""

from __future__ import annotations

import numpy as np

from kernels.splat import SplatCamera, gaussian_inputs, render, render_backward
from research.warp_runtime import init_warp

SH_C0 = 0.28209479177387814  # Y_00, the constant real spherical harmonic: colour = SH_C0 f + 1/2


def to_numpy(x):
    """Entry points hand back the input's kind (NumPy in, NumPy out); this accepts a wp.array too."""
    return np.asarray(x.numpy() if hasattr(x, "numpy") else x)


def scene(dtype=np.float64):
    """Means, log-scales, quaternions (w, x, y, z), opacity logits and SH coefficients (N, 1, 3)."""
    means = np.array([[0.0, 0.0, 4.0], [-0.8, -0.4, 5.0], [0.9, 0.5, 4.5], [0.3, -0.9, 6.0], [-0.5, 0.8, 3.5]])
    log_scales = np.log(np.array([[0.5, 0.3, 0.3], [0.4, 0.4, 0.2], [0.3, 0.6, 0.3], [0.8, 0.3, 0.3],
                                  [0.2, 0.2, 0.2]]))
    quats = np.array([[1.0, 0.0, 0.0, 0.0], [0.9, 0.0, 0.0, 0.4], [0.8, 0.3, 0.0, 0.2], [0.7, 0.0, 0.7, 0.0],
                      [1.0, 0.2, 0.2, 0.0]])
    opacity_logits = np.array([2.0, 1.0, 1.5, 3.0, 0.5])
    colours = np.array([[0.9, 0.2, 0.1], [0.1, 0.8, 0.2], [0.2, 0.3, 0.9], [0.9, 0.9, 0.2], [0.8, 0.3, 0.8]])
    sh = ((colours - 0.5) / SH_C0)[:, None, :]
    return [a.astype(dtype) for a in (means, log_scales, quats, opacity_logits, sh)]


def main() -> None:
    init_warp()  # keep Warp's start-up banner off stdout
    width = height = 64
    camera = SplatCamera(viewmat=np.eye(4), K=np.array([[60.0, 0.0, 32.0], [0.0, 60.0, 32.0], [0.0, 0.0, 1.0]]),
                         width=width, height=height)
    params = scene()
    result = render(gaussian_inputs(*params), camera)
    rgb, alpha, depth = to_numpy(result.rgb), to_numpy(result.alpha), to_numpy(result.depth)
    print(f"rendered {width}x{height}: rgb {rgb.shape}, {int((alpha > 0.5).sum())} pixels more than half covered")
    print(f"mean colour {np.round(rgb.reshape(-1, 3).mean(axis=0), 4)}, "
          f"alpha in [{alpha.min():.3f}, {alpha.max():.3f}]")
    centre = (height // 2, width // 2)
    # `depth` is the alpha-weighted sum of z-depths; dividing by alpha gives the expected z-depth.
    print(f"expected z-depth at the centre pixel: {depth[centre] / alpha[centre]:.4f}")

    # Loss: squared distance of the image to a flat grey; its image gradient is 2 (rgb - target).
    target = np.full_like(rgb, 0.5)
    loss = float(((rgb - target) ** 2).sum())
    grads = render_backward(gaussian_inputs(*params), result, 2.0 * (rgb - target))
    names = ("means", "log_scales", "quats", "opacity_logits", "sh")
    for name in names:
        print(f"|dL/d{name}| = {np.linalg.norm(to_numpy(grads[name])):.4f}")

    step = 1e-3
    stepped = [p - step * to_numpy(grads[n]) for p, n in zip(params, names)]
    new_rgb = to_numpy(render(gaussian_inputs(*stepped), camera).rgb)
    new_loss = float(((new_rgb - target) ** 2).sum())
    print(f"loss {loss:.4f} -> {new_loss:.4f} after one gradient step of {step}")
    if not new_loss < loss:
        raise SystemExit("the gradient step did not lower the loss")
    print("gradient step lowered the loss")


if __name__ == "__main__":
    main()
