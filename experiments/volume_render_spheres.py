#!/usr/bin/env python3
"""The volume-rendering exercise of the Video and 3D Vision textbook chapter: three soft spheres, Warp vs NumPy.

Scene and camera exactly as the textbook states them: spheres red (0,0,4) r 0.8, green
(1.5,0.5,5) r 0.6, blue (-1,-0.5,3.5) r 0.5, all with sigma 5; a 64x64 image, focal 60, the camera
at the origin looking down +z, 64 samples on t in [1, 6] (linspace, last delta 1e-3), density
exp(-max(0, |p-c| - r) sigma) sigma, colour weighted by density.

Renders, all from the same rays and samples:
  * numpy_loop   a plain NumPy port of the textbook's render_ray (loops over pixels, samples and
                 spheres, as the snippet does; research/nerf/textbook.py) -- the reference;
  * numpy_vec    the same formula vectorised over rays and samples;
  * warp         kernels.volume in float64 and float32: SphereField.render_dense, which places the
                 samples, evaluates the spheres and composites per ray (the timed render), and the
                 general path (dense_samples, SphereField.forward, the compositing kernel), untimed,
                 which on the CPU gives the same image bit for bit.
The float64 Warp image must agree with the loop port to 1e-5, and on the CPU the two Warp paths
must give identical images (the script fails otherwise).
A fourth image renders the same scene through research.nerf.render_image with the project's
camera convention (OpenCV, pixel centres at +0.5, 64 midpoint strata on [1, 6]) with its
z-depth and opacity maps; the textbook's frame (y up, z forward) is the mirror image of a real
camera, so that image is flipped vertically relative to the textbook's.

Writes results/volume_render_spheres/{table.md, metrics.json, spheres.png, figure.png}.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from research.experiment import Context, Experiment
from research.results import finish_figure, image_panel, markdown_table

AGREEMENT_TOL = 1e-5


def run(ctx: Context) -> int:
    import warp as wp

    from kernels.volume import SphereField, render_samples
    from kernels.volume.sampling import dense_samples
    from research import io
    from research.bench import time_median
    from research.cameras import Camera
    from research.nerf import textbook as tb
    from research.nerf.render import render_image

    repeats = 3 if ctx.quick else 5
    # A smoke run renders the same view at 16x16 (the loop port takes seconds at 64x64).
    h, w = (16, 16) if ctx.smoke else (tb.IMG_H, tb.IMG_W)
    focal = tb.FOCAL * w / tb.IMG_W
    origins, dirs = tb.textbook_rays(h, w, focal)
    t, delta = tb.textbook_t_delta()
    n_rays = origins.shape[0]

    t0 = time.perf_counter()
    ref = tb.render_image_loop(h, w, focal)
    loop_s = time.perf_counter() - t0
    vec_img = tb.render_image_vectorized(h, w, focal)
    vec_s = time_median(lambda: tb.render_image_vectorized(h, w, focal), repeats=repeats)

    def inputs(np_t):
        # t and delta are the same on every ray: one row each, broadcast to (R, S) without a copy
        # (render_dense reads the row in place; the same values as tiling it)
        return (origins.astype(np_t), dirs.astype(np_t), np.broadcast_to(t.astype(np_t), (n_rays, t.shape[0])),
                np.broadcast_to(delta.astype(np_t), (n_rays, delta.shape[0])))

    def warp_render(np_t, wp_t):
        field = SphereField.textbook(wp_t, device=ctx.device)

        def run():
            # SphereField.render_dense: samples, field and compositing per ray, the fused forward of
            # render_samples on dense_samples
            rgb, _, _ = field.render_dense(*inputs(np_t), background=(0.0, 0.0, 0.0), t_threshold=0.0)
            return rgb

        img = run()
        # The general path (packed samples, the field's forward, the compositing kernel), untimed: on
        # the CPU the same image bit for bit (kernels.volume.spheres), elsewhere to float rounding.
        general = render_samples(field, dense_samples(*inputs(np_t), device=ctx.device), background=(0.0, 0.0, 0.0),
                                 t_threshold=0.0, keep_factor=False).rgb.numpy()
        diff = {"bitwise_equal": bool(general.tobytes() == img.tobytes()),
                "max_abs_diff": float(np.abs(general.astype(np.float64) - img).max())}
        secs = time_median(run, repeats=repeats, sync=lambda: wp.synchronize_device(ctx.device))
        return img.reshape(h, w, 3).astype(np.float64), secs, diff

    warp64, warp64_s, general64 = warp_render(np.float64, wp.float64)
    warp32, warp32_s, general32 = warp_render(np.float32, wp.float32)
    vs_general = {"warp_float64": general64, "warp_float32": general32}
    err = {name: float(np.abs(img - ref).max()) for name, img in
           (("numpy_vec", vec_img), ("warp_float64", warp64), ("warp_float32", warp32))}

    # The project's camera convention, with z-depth and opacity.
    K = np.array([[focal, 0.0, w / 2], [0.0, focal, h / 2], [0.0, 0.0, 1.0]])
    cam = Camera(K, np.eye(4), w, h)
    field64 = SphereField.textbook(wp.float64, device=ctx.device)
    big_box = np.array([[-10.0, -10.0, 0.0], [10.0, 10.0, 10.0]])
    cv = render_image(cam, field64, big_box, near=tb.T_NEAR, far=tb.T_FAR, n_samples=tb.N_SAMPLES, t_threshold=0.0)

    io.write_png_u8(ctx.out / "spheres.png", np.floor(np.clip(warp64, 0, 1) * 255 + 0.5).astype(np.uint8))
    figure(ref, warp64, cv, ctx.out / "figure.png")

    rows = [
        ["NumPy port of the textbook loop (reference)", "float64", loop_s, "0"],
        ["NumPy, vectorised over rays and samples", "float64", vec_s, f"{err['numpy_vec']:.1e}"],
        ["Warp kernels (kernels.volume)", "float64", warp64_s, f"{err['warp_float64']:.1e}"],
        ["Warp kernels (kernels.volume)", "float32", warp32_s, f"{err['warp_float32']:.1e}"],
    ]
    table = (f"Textbook task: {h}x{w}, focal {focal:g}, 64 samples on t in [1, 6], 3 soft spheres (sigma 5), "
             f"{n_rays * tb.N_SAMPLES} samples; device `{ctx.device}`. Times: "
             f"median of {repeats} for NumPy-vectorised and Warp (after a warm-up), "
             "one run for the loop port. Error: max |pixel - reference| over all pixels and channels "
             "(unclipped).\n\n"
             + markdown_table(["renderer", "dtype", "seconds", "max abs err vs reference"], rows, floatfmt=".4f")
             + f"\nWarp float64 agrees with the NumPy port to {err['warp_float64']:.1e} "
             f"(required: {AGREEMENT_TOL:g}). Speed-up of Warp float64 over the loop port: "
             f"{loop_s / warp64_s:.0f}x; over vectorised NumPy: {vec_s / warp64_s:.1f}x.\n"
             "\nThe Warp renders run SphereField.render_dense (samples, field and compositing per ray). The general "
             "path (dense_samples, the field's forward, the compositing kernel) renders the same image"
             + ("" if all(v["bitwise_equal"] for v in vs_general.values()) else " to float rounding")
             + ": max |difference| " + ", ".join(f"{k} {v['max_abs_diff']:.1e}" for k, v in vs_general.items())
             + ".\n"
             f"\nThe OpenCV-convention render (pixel centres, y down) has mean opacity {cv.opacity.mean():.3f} and "
             f"z-depth range [{cv.depth[cv.opacity > 0.5].min():.3f}, {cv.depth[cv.opacity > 0.5].max():.3f}] "
             "where opacity > 0.5.\n")
    metrics = {"numpy_loop_s": loop_s, "numpy_vectorized_s": vec_s, "warp_float64_s": warp64_s,
               "warp_float32_s": warp32_s, "max_abs_err": err, "agreement_tol": AGREEMENT_TOL,
               "render_dense_vs_general_path": vs_general,
               "image_min": float(ref.min()), "image_max": float(ref.max()),
               "opencv_render": {"mean_opacity": float(cv.opacity.mean()), "n_samples": cv.n_samples}}
    config = {"height": h, "width": w, "focal": focal,
              "n_samples": tb.N_SAMPLES, "t_near": tb.T_NEAR, "t_far": tb.T_FAR, "repeats": repeats}
    ctx.write_results(config=config, metrics=metrics, table_md=table)
    if not err["warp_float64"] <= AGREEMENT_TOL:
        print(f"FAIL: Warp float64 differs from the NumPy port by {err['warp_float64']:.3g}", file=sys.stderr)
        return 1
    if wp.get_device(ctx.device).is_cpu and not all(v["bitwise_equal"] for v in vs_general.values()):
        print(f"FAIL: render_dense and the general path differ on the CPU: {vs_general}", file=sys.stderr)
        return 1
    return 0


def figure(ref: np.ndarray, warp64: np.ndarray, cv, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 5, figsize=(16, 3.4))
    panels = [(np.clip(ref, 0, 1), "NumPy port of the textbook"), (np.clip(warp64, 0, 1), "Warp (float64)"),
              (np.abs(warp64 - ref).max(axis=2), "|Warp - NumPy| (max over RGB)"),
              (np.clip(cv.rgb, 0, 1), "OpenCV camera (y down)"),
              (np.ma.masked_where(cv.opacity < 0.5, cv.depth), "expected z-depth")]
    for ax, (img, title) in zip(axes, panels):
        image_panel(fig, ax, img, title, colorbar=np.ndim(img) == 2, cmap=None if np.ndim(img) == 3 else "viridis")
    finish_figure(fig, path)


main = Experiment("volume_render_spheres", __doc__, run, seed_help="unused: the task is deterministic; recorded",
                  sizes="Quick: a median of 3 timed runs per renderer instead of 5 (the images are the same); "
                        "smoke: the same view at 16x16.").script(__name__)
