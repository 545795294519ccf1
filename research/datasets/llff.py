"""LLFF forward-facing captures (`poses_bounds.npy` and images_N/), read as NeRF's `load_llff_data`.

Layout (LLFF, Mildenhall et al. 2019; the NeRF release's nerf_llff_data/<scene>):

    poses_bounds.npy      float (N, 17): one row per image, in the order of the sorted image names
    images/  images_4/  images_8/     the photographs at full size and at 1/4, 1/8 (PNG or JPEG)

A row is a 3x5 matrix, row-major (15 numbers), then the image's near and far z-depth bounds. The
matrix is [R | t | hwf]: R's columns are the camera's (down, right, back) axes in the world, t its
centre, hwf = (height, width, focal) of the full-size images (images/), one camera for all. NeRF
reorders the columns to (right, up, back), the OpenGL camera frame, research.cameras'
`transform_matrix` convention: c2w_gl = [r1, -r0, r2, t]; drlab's OpenCV camera-to-world is then
c2w_gl diag(1, -1, -1, 1) (research.cameras.Camera.from_nerf). LLFF's (down, right, back) frame is
right-handed, so R is checked as it is stored by kernels/rotation.py's one check (max |R^T R - I|
<= 1e-5, det R > 0); a matrix that fails it is refused naming the file, the row and the image.

Images: the files of images_N (N = `factor`; images/ for 1) with a .png, .jpg or .jpeg name (any
case), sorted by name, as NeRF lists them; their count must equal the number of rows. Intrinsics
as NeRF's loader: focal f / N, the principal point at the image centre (w/2, h/2), square pixels;
each image must be the full size over N to within a pixel (LLFF's minified folders are rounded).
(NeRF's own ray generator puts pixel i at x = (i - W/2) / f, half a pixel off the pixel-centre
convention of research.cameras, where the centre of pixel i is i + 1/2; drlab keeps the centre.)

World frame: NeRF's. The translations and bounds are scaled by 1 / (0.75 min(bounds)) (bd_factor
0.75: the nearest bound becomes 1/0.75, so the NDC near plane at depth 1 lies in front of all the
content), then every pose is expressed relative to the mean pose (`recenter_poses`: the mean
centre, the normalised sum of the back axes and the sum of the up axes): the cameras sit near the
origin looking down -z with +y up. Both are similarity transforms of the whole capture, so images,
and with them PSNR and SSIM, are unchanged by them; they matter only because NDC (and so the fields'
box) is defined in this frame. Like NeRF, the mean pose is taken over all images (it uses no pixel).

Protocol ("llff", NeRF's for its real forward-facing scenes): every 8th image by name is a test view
(llffhold 8: index % 8 == 0; fern: images 0, 8, 16 of 20), the rest train; images_8 unless `factor`
says otherwise (504x378 for fern); opaque photographs, no background; PSNR and SSIM on sRGB in
[0, 1] (research.metrics). NeRF also reports LPIPS; drlab does not compute it.

Geometry for the models: `Dataset.ndc` (research.nerf.ndc.NDC: near 1, the first camera's focal and
size, NeRF's `ndc_rays` arguments) puts the radiance fields in NDC, inside `NDC.bbox_for` the
cameras; `Dataset.near_far` holds each view's scaled bounds, and `Dataset.bbox` is the world box of
the training frusta between them. LLFF gives no SfM points (`Dataset.points` is None); fit_splats
then starts from points sampled in those frusta.

Errors (DatasetError, one line naming the file or folder, before any pixel is read): a missing
poses_bounds.npy or images_N folder (the folders present are named), an array that is not (N, 17)
finite numbers, a count mismatch between poses and images, a rotation that is not one, bounds that
are not 0 < near < far, an hwf that is not positive or not one for all rows, an image whose size is
not the full size over N.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kernels.rotation import checked_rotation
from research.cameras import Camera
from research.datasets import external
from research.datasets.integrity import DatasetError
from research.datasets.loader import Dataset, Protocol, Split, View, _image_size

POSES_BOUNDS = "poses_bounds.npy"
LLFFHOLD = external.LLFFHOLD
BD_FACTOR = 0.75
DEFAULT_FACTOR = 8
NDC_NEAR = 1.0
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def llff_protocol(factor: int, width: int, height: int) -> Protocol:
    return external.llffhold_protocol("llff", "LLFF protocol (NeRF)", factor, width, height, "LPIPS not computed; ")


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _viewmatrix(z: np.ndarray, up: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """NeRF's `viewmatrix`: a (right, up, back) camera-to-world 3x4 with back axis z and up near `up`."""
    vec2 = _normalize(z)
    vec0 = _normalize(np.cross(up, vec2))
    vec1 = _normalize(np.cross(vec2, vec0))
    return np.stack([vec0, vec1, vec2, pos], axis=1)


def recenter(c2w_gl: np.ndarray) -> np.ndarray:
    """NeRF's `recenter_poses`: (N, 4, 4) OpenGL camera-to-world expressed relative to their mean pose
    (`poses_avg`: the mean centre, the sum of the back axes, the sum of the up axes)."""
    avg = np.eye(4)
    avg[:3] = _viewmatrix(c2w_gl[:, :3, 2].sum(0), c2w_gl[:, :3, 1].sum(0), c2w_gl[:, :3, 3].mean(0))
    return np.linalg.inv(avg) @ c2w_gl


def read_poses_bounds(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(c2w_gl (N, 4, 4) as stored, bounds (N, 2), hwf (3,)) from poses_bounds.npy, every row checked."""
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as e:
        raise DatasetError(f"{path}: not a NumPy .npy array ({' '.join(str(e).split())})") from None
    if arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] < 1 or not np.issubdtype(arr.dtype, np.number):
        raise DatasetError(f"{path}: expected an (N, 17) array (a 3x5 pose and near, far per image), got "
                           f"shape {arr.shape} of {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        row = int(np.nonzero(~np.all(np.isfinite(arr), axis=1))[0][0])
        raise DatasetError(f"{path}: row {row} holds a non-finite value")
    poses = arr[:, :15].reshape(-1, 3, 5)
    bounds = arr[:, 15:]
    hwf = poses[:, :, 4]
    if np.any(hwf <= 0) or np.any(np.abs(hwf - hwf[0]) > 1e-9 * np.abs(hwf[0])):
        raise DatasetError(f"{path}: the hwf column (height, width, focal) must be one positive camera for every "
                           f"row, got {np.unique(hwf, axis=0).tolist()[:3]}")
    if np.any(bounds[:, 0] <= 0) or np.any(bounds[:, 1] <= bounds[:, 0]):
        row = int(np.nonzero((bounds[:, 0] <= 0) | (bounds[:, 1] <= bounds[:, 0]))[0][0])
        raise DatasetError(f"{path}: row {row}: bounds must satisfy 0 < near < far, got {bounds[row].tolist()}")
    c2w = np.tile(np.eye(4), (len(arr), 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2] = poses[:, :, 1], -poses[:, :, 0], poses[:, :, 2]
    c2w[:, :3, 3] = poses[:, :, 3]
    return c2w, bounds, hwf[0]


def faces_one_way(path: Path) -> bool:
    """Whether poses_bounds.npy's cameras form a forward-facing capture: no two viewing axes more than
    90 degrees apart. Mip-NeRF 360's scenes ship a poses_bounds.npy too, for cameras all around the
    object (facing cameras on opposite sides look about 180 degrees apart, less twice their elevation),
    beside their COLMAP model; `formats.detect_format` reads those as COLMAP. An unreadable file counts
    as forward-facing (load_llff then names its fault)."""
    try:
        c2w_gl, _, _ = read_poses_bounds(path)
    except DatasetError:
        return True
    view = c2w_gl[:, :3, 2]  # the back axes: their pairwise angles are the viewing axes'
    view = view / np.linalg.norm(view, axis=1, keepdims=True)
    return bool(np.min(view @ view.T) > 0.0)


def _check_rotations(path: Path, c2w_gl: np.ndarray, names: list[str]) -> None:
    for i, name in enumerate(names):
        R_llff = np.stack([-c2w_gl[i, :3, 1], c2w_gl[i, :3, 0], c2w_gl[i, :3, 2]], axis=1)  # (down, right, back)
        try:
            checked_rotation("R", R_llff)
        except ValueError as e:
            raise DatasetError(f"{path}: row {i} ({name}): the 3x3 pose part is not a rotation ({e})") from None


def _frusta_box(cameras: list[Camera], near_far: np.ndarray) -> np.ndarray:
    """The world box of each camera's frustum between its near and far z-depth bounds."""
    pts = []
    for c, (n, f) in zip(cameras, near_far):
        corners = np.array([[0.0, 0.0], [c.width, 0.0], [0.0, c.height], [c.width, c.height]])
        d = c.camera_directions(corners[:, 0], corners[:, 1]) @ c.R.T  # z-depth 1 along each
        pts += [c.center + n * d, c.center + f * d]
    pts = np.concatenate(pts)
    return np.array([pts.min(axis=0), pts.max(axis=0)])


def load_llff(path: str | Path, factor: int | None = None) -> Dataset:
    """Read an LLFF folder (module docstring) as a research.datasets Dataset.

    `factor`: read images_<factor> (1: images/); None: 8, the NeRF protocol's. Every check that needs
    no pixels runs here; pixels are read by `Dataset.load_split`.
    """
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such dataset folder")
    factor = DEFAULT_FACTOR if factor is None else external.check_factor(factor)
    pb = root / POSES_BOUNDS
    if not pb.is_file():
        raise DatasetError(f"{pb}: missing (an LLFF folder has {POSES_BOUNDS} and images_N/)")
    c2w_raw, bounds, (H, W, focal) = read_poses_bounds(pb)
    folder = external.image_folder(root, factor)
    names = sorted(p.name for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if len(names) != len(c2w_raw):
        raise DatasetError(f"{folder}: {len(names)} images, but {pb} holds {len(c2w_raw)} poses (one row per "
                           "image, in the order of the sorted names)")
    _check_rotations(pb, c2w_raw, names)

    scale = 1.0 / (bounds.min() * BD_FACTOR)  # NeRF: sc = 1 / (bds.min() * bd_factor), then recentre
    c2w = c2w_raw.copy()
    c2w[:, :3, 3] *= scale
    near_far = bounds * scale
    c2w = recenter(c2w)

    f = focal / factor
    cams, files = [], []
    for i, name in enumerate(names):
        img = folder / name
        w, h = _image_size(img)
        if abs(w - W / factor) > 1.0 or abs(h - H / factor) > 1.0:
            raise DatasetError(f"{img}: image is {w}x{h}, but {pb}'s camera ({W:g}x{H:g}) at 1/{factor} expects "
                               f"about {W / factor:g}x{H / factor:g}")
        try:
            cams.append(Camera.from_nerf(c2w[i], w, h, fl_x=f, fl_y=f, cx=w / 2.0, cy=h / 2.0))
        except ValueError as e:
            raise DatasetError(f"{pb}: row {i} ({name}): {e}") from None
        files.append(img)
    if len(cams) < 2:
        raise DatasetError(f"{pb}: {len(cams)} image(s); the protocol needs at least 2")
    if len({(c.width, c.height) for c in cams}) > 1:
        raise DatasetError(f"{folder}: the images differ in size ({sorted({(c.width, c.height) for c in cams})}); "
                           "LLFF has one camera")
    views = [View(name, "test" if i % LLFFHOLD == 0 else "train", cam, root)
             for i, (name, cam) in enumerate(zip(names, cams))]
    by_name = dict(zip(names, files))
    train = [i for i, v in enumerate(views) if v.split == "train"]

    from research.nerf.ndc import NDC

    ndc = NDC.of_camera(cams[0], NDC_NEAR)

    def load_views(selected: list[View]) -> Split:
        return external.load_split(selected, by_name)

    manifest = {"format": "llff", "content_hash": external.content_hash(root, [pb, *files]), "factor": factor,
                "root": str(root), "scale": scale, "bd_factor": BD_FACTOR, "ndc_near": NDC_NEAR}
    return Dataset(root, manifest, views, _frusta_box([cams[i] for i in train], near_far[train]),
                   external.up_from_cameras(cams), format="llff", scene=root.resolve().name,
                   protocol=llff_protocol(factor, cams[0].width, cams[0].height), split_loader=load_views,
                   ndc=ndc, near_far=near_far)
