"""The volume-rendering exercise of the Video and 3D Vision textbook chapter (exercise 3), ported to NumPy.

A faithful, unvectorised port of its `render_ray` (loops over pixels, samples and spheres, as the
JAX snippet does), kept as the reference the Warp kernels are compared with. The snippet's own
conventions are kept on purpose, and noted here because they differ from the project's:

* rays: direction ((j - W/2) / f, -(i - H/2) / f, 1), normalised -- pixel corners rather than
  centres (no +0.5), and image y pointing up with z forward: a left-handed frame, the mirror image
  of any real camera (research.cameras uses OpenCV, y down, centres at +0.5);
* samples: t = linspace(t_near, t_far, S) with delta_k = t_{k+1} - t_k and a LAST delta of 1e-3
  (not the remaining stratum), no jitter, no background;
* colour: density-weighted sphere colours, divided by the density where it exceeds 1e-6;
* the image is clipped to [0, 1] afterwards (the port returns the unclipped values too).
"""

from __future__ import annotations

import numpy as np

from kernels.volume.spheres import TEXTBOOK_SPHERES

IMG_H = IMG_W = 64
FOCAL = 60.0
N_SAMPLES = 64
T_NEAR, T_FAR = 1.0, 6.0
LAST_DELTA = 1e-3


def textbook_rays(h: int = IMG_H, w: int = IMG_W, focal: float = FOCAL) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions (h*w, 3), row-major over (i, j), as the snippet builds them."""
    dirs = np.empty((h, w, 3))
    for i in range(h):
        for j in range(w):
            d = np.array([(j - w / 2) / focal, -(i - h / 2) / focal, 1.0])
            dirs[i, j] = d / np.linalg.norm(d)
    return np.zeros((h * w, 3)), dirs.reshape(-1, 3)


def textbook_t_delta(n_samples: int = N_SAMPLES, t_near: float = T_NEAR, t_far: float = T_FAR
                     ) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(t_near, t_far, n_samples)
    return t, np.concatenate([np.diff(t), [LAST_DELTA]])


def render_ray(origin: np.ndarray, direction: np.ndarray, spheres=TEXTBOOK_SPHERES, n_samples: int = N_SAMPLES,
               t_near: float = T_NEAR, t_far: float = T_FAR) -> np.ndarray:
    """The snippet's render_ray, line by line, in NumPy float64."""
    t_vals, deltas = textbook_t_delta(n_samples, t_near, t_far)
    colour = np.zeros(3)
    transmittance = 1.0
    for i in range(n_samples):
        point = origin + t_vals[i] * direction
        density = 0.0
        point_colour = np.zeros(3)
        for center, radius, col, sigma in spheres:
            dist = np.linalg.norm(point - np.asarray(center))
            d = np.exp(-np.maximum(0, dist - radius) * sigma) * sigma
            density += d
            point_colour += d * np.asarray(col)
        point_colour = np.where(density > 1e-6, point_colour / density, point_colour)
        alpha = 1.0 - np.exp(-density * deltas[i])
        colour += transmittance * alpha * point_colour
        transmittance *= 1.0 - alpha
    return colour


def render_image_loop(h: int = IMG_H, w: int = IMG_W, focal: float = FOCAL) -> np.ndarray:
    """The snippet's image loop (unclipped), (h, w, 3)."""
    origins, dirs = textbook_rays(h, w, focal)
    out = np.empty((h * w, 3))
    for r in range(h * w):
        out[r] = render_ray(origins[r], dirs[r])
    return out.reshape(h, w, 3)


def render_image_vectorized(h: int = IMG_H, w: int = IMG_W, focal: float = FOCAL) -> np.ndarray:
    """The same formula vectorised over rays and samples in NumPy (unclipped), (h, w, 3)."""
    origins, dirs = textbook_rays(h, w, focal)
    t, delta = textbook_t_delta()
    pts = origins[:, None, :] + t[None, :, None] * dirs[:, None, :]  # (R, S, 3)
    density = np.zeros(pts.shape[:2])
    colour = np.zeros(pts.shape)
    for center, radius, col, sigma in TEXTBOOK_SPHERES:
        dist = np.linalg.norm(pts - np.asarray(center), axis=-1)
        d = np.exp(-np.maximum(0, dist - radius) * sigma) * sigma
        density += d
        colour += d[..., None] * np.asarray(col)
    colour = np.where((density > 1e-6)[..., None], colour / np.maximum(density, 1e-300)[..., None], colour)
    alpha = 1.0 - np.exp(-density * delta)
    trans = np.cumprod(np.concatenate([np.ones((alpha.shape[0], 1)), 1.0 - alpha[:, :-1]], axis=1), axis=1)
    return ((trans * alpha)[..., None] * colour).sum(axis=1).reshape(h, w, 3)
