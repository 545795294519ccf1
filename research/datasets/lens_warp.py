"""Distorted images from pinhole renders, and their undistortion with OpenCV.

A pinhole render (intrinsics K_r, W_r x H_r) is warped into the image of a camera with a lens model
(kernels/lens.py) and intrinsics K_d at the same pose: each output pixel centre (u, v) is unprojected
through the lens (kernels.volume.lens_rays) to its camera-frame ray e, which the pinhole sees at
K_r (e_x / e_z, e_y / e_z, 1); cv2.remap samples the render there (bilinear). With `supersample` s
the warp runs at s times the output size and is then box-averaged down (cv2.INTER_AREA), so each
output pixel averages s^2 samples of its footprint instead of one bilinear tap. The exact model is
the lens itself: no approximation other than the resampling.

`lens_intrinsics` picks K_d: square pixels, the principal point at the image centre, and the largest
focal length scale c (K_d's focal = c f_r scaled to the output size, c >= 1 in steps of 0.005) such
that every output pixel's ray falls inside the render with a one-pixel margin, so no output pixel
is invented.

`undistort` is the usual route (COLMAP's image_undistorter, 3DGS's loader): the distorted images
remapped by OpenCV (cv2.initUndistortRectifyMap, or cv2.fisheye.initUndistortRectifyMap) to a
pinhole of the same K_d. OpenCV's pixel centres are at integer coordinates, drlab's at i + 1/2
(research/cameras.py), so the matrices handed to OpenCV have cx - 1/2, cy - 1/2.
"""

from __future__ import annotations

import numpy as np

from kernels.lens import Lens


def _cv_K(K: np.ndarray) -> np.ndarray:
    """K in OpenCV's pixel convention (pixel centres at integers)."""
    out = np.array(K, dtype=np.float64)
    out[0, 2] -= 0.5
    out[1, 2] -= 0.5
    return out


def _rays(lens: Lens, K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit rays (H, W, 3) of every pixel centre through `lens` and K, and their validity."""
    from kernels.volume.lens_rays import lens_rays
    from kernels.volume.rays import pixel_centers

    px = pixel_centers(width, height)
    _, d, _, valid = lens_rays(np.eye(4), [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], lens, px, device="cpu")
    return d.reshape(height, width, 3), valid.reshape(height, width)


def source_coordinates(lens: Lens, K_d: np.ndarray, size: tuple[int, int], K_r: np.ndarray) -> np.ndarray:
    """(H, W, 2) continuous pinhole-render coordinates (drlab's convention) seen by each output pixel."""
    d, valid = _rays(lens, K_d, *size)
    if not valid.all() or np.any(d[..., 2] <= 0):
        raise ValueError("lens: some output pixels are outside the lens's domain or look backwards")
    w = d[..., :2] / d[..., 2:3]
    return np.stack([K_r[0, 0] * w[..., 0] + K_r[0, 2], K_r[1, 1] * w[..., 1] + K_r[1, 2]], axis=-1)


def lens_intrinsics(lens: Lens, K_r: np.ndarray, render_size: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    """K_d of the module docstring for an output image of `size` (W, H)."""
    (Wr, Hr), (W, H) = render_size, size
    scale = W / Wr
    for i in range(400):
        c = 1.0 + 0.005 * i
        K = np.array([[c * K_r[0, 0] * scale, 0.0, W / 2.0], [0.0, c * K_r[0, 0] * scale, H / 2.0], [0.0, 0.0, 1.0]])
        try:
            xy = source_coordinates(lens, K, size, K_r)
        except ValueError:
            continue
        if xy[..., 0].min() >= 1.0 and xy[..., 0].max() <= Wr - 1.0 and xy[..., 1].min() >= 1.0 \
                and xy[..., 1].max() <= Hr - 1.0:
            return K
    raise ValueError("lens: no focal scale up to 3 keeps the distorted image inside the render")


def warp_to_lens(images: np.ndarray, K_r: np.ndarray, lens: Lens, K_d: np.ndarray, size: tuple[int, int],
                 supersample: int = 2) -> np.ndarray:
    """(N, H, W, C) float32 images of the lens camera (K_d, `size`) from pinhole renders (N, H_r, W_r, C)."""
    import cv2

    W, H = size
    s = int(supersample)
    Ks = np.diag([s, s, 1.0]) @ K_d
    xy = source_coordinates(lens, Ks, (W * s, H * s), K_r) - 0.5  # OpenCV's pixel centres
    mx, my = xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32)
    out = []
    for img in np.asarray(images, dtype=np.float32):
        big = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        small = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA) if s > 1 else big
        out.append(small.reshape(H, W, -1))
    return np.stack(out).astype(np.float32)


def undistort(images: np.ndarray, lens: Lens, K_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pinhole images (N, H, W, C) of the same K_d, valid (H, W)): OpenCV's undistortion (module docstring);
    pixels whose source falls outside the distorted image are 0 and invalid."""
    import cv2

    n, H, W = images.shape[:3]
    Kc = _cv_K(K_d)
    if lens.model == "fisheye":
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(Kc, np.array(lens.coeffs), np.eye(3), Kc, (W, H), cv2.CV_32FC1)
    elif lens.model == "opencv":
        m1, m2 = cv2.initUndistortRectifyMap(Kc, np.array(lens.coeffs), None, Kc, (W, H), cv2.CV_32FC1)
    else:
        raise ValueError(f"lens: OpenCV undistorts opencv and fisheye models, got {lens.model!r}")
    valid = (m1 >= -0.5) & (m1 <= W - 0.5) & (m2 >= -0.5) & (m2 <= H - 0.5)
    out = np.stack([cv2.remap(np.asarray(img, dtype=np.float32), m1, m2, cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0).reshape(H, W, -1) for img in images])
    return out, valid
