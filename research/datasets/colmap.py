"""COLMAP sparse models and the Mip-NeRF 360 layout, read through pycolmap.

Layout (Mip-NeRF 360; `colmap image_undistorter` writes the same without the images_N folders):

    images/  images_2/  images_4/  images_8/     the photographs, the same names at 1/N size
    sparse/0/{cameras,images,points3D}.{bin,txt} the model (sparse/ itself is accepted too)

The model is read by pycolmap (binary or text; no COLMAP file is parsed here). Cameras are read as
they are, lens included (research.cameras.Camera.lens, kernels/lens.py), so a distorted model needs
no undistortion step: the splat projection and the ray generator take the lens.

    COLMAP model     params                                 drlab camera
    SIMPLE_PINHOLE   f, cx, cy                              pinhole
    PINHOLE          fx, fy, cx, cy                         pinhole
    SIMPLE_RADIAL    f, cx, cy, k                           opencv (k1 = k)
    RADIAL           f, cx, cy, k1, k2                      opencv (k1, k2)
    OPENCV           fx, fy, cx, cy, k1, k2, p1, p2         opencv (k1, k2, p1, p2; k3 = 0)
    OPENCV_FISHEYE   fx, fy, cx, cy, k1, k2, k3, k4         fisheye (k1, k2, k3, k4)
    SIMPLE_RADIAL_FISHEYE  f, cx, cy, k                     fisheye (k1 = k)
    RADIAL_FISHEYE   f, cx, cy, k1, k2                      fisheye (k1, k2)
    SIMPLE_FISHEYE   f, cx, cy                              fisheye (no coefficients)
    FISHEYE          fx, fy, cx, cy                         fisheye (no coefficients)

COLMAP's formulas for these are OpenCV's (tests hold kernels/reference/lens.py to pycolmap's
img_from_cam / cam_from_img); its other fisheyes are the same equidistant model
theta_d = theta (1 + k1 theta^2 + k2 theta^4 + ...) with fewer terms (the radial two as nerfstudio
reads them; SIMPLE_FISHEYE and FISHEYE, pycolmap 3.12 on, with none).
SIMPLE_RADIAL, RADIAL and OPENCV with every coefficient exactly 0 are pinholes (no lens is attached,
so they take the pinhole path as before); a fisheye stays one at 0. Any other model (FULL_OPENCV's
rational terms, FOV, the thin-prism fisheyes) is refused by name.

Poses: COLMAP stores world-to-camera (cam_from_world: x_cam = R x_world + t) in the OpenCV camera
frame (+x right, +y down, +z forward), drlab's own, so the OpenCV camera-to-world is its inverse,
c2w = [[R^T, -R^T t], [0, 1]] (`c2w_from_colmap`, `colmap_from_c2w`). COLMAP's pixel (0, 0) has its
centre at (0.5, 0.5), as in research.cameras, so K is taken as it is.

Protocol ("mipnerf360", as the 3DGS paper evaluates Mip-NeRF 360): the images sorted by name, every
8th (index % 8 == 0) is a test view (llffhold 8), the rest train; images from images_N, with N 4
for the outdoor scenes (bicycle, flowers, garden, stump, treehill) and 2 for the indoor ones
(room, counter, kitchen, bonsai), else 1 (images/), unless `factor` says otherwise. K is scaled by
each image's actual size over the camera's (images_N sizes are rounded). Photographs are opaque:
no background compositing.

Scene bound: the box of the SfM points between their 1st and 99th percentiles per axis (far,
sparse points of the background stretch a min/max box), padded by 5%; the cameras' bound when
the model has fewer than 8 points. `Dataset.points` / `point_colors` carry every SfM point and its
sRGB colour, for 3DGS's initialisation.

Errors (DatasetError, one line naming the file): sparse/0 missing, a model pycolmap cannot read
(an unknown camera model is named), an unsupported camera model, an images_N folder
missing, an image listed but absent, an image whose size does not match its camera.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kernels.lens import Lens
from research.cameras import Camera, check_pose
from research.datasets import external
from research.datasets.integrity import DatasetError
from research.datasets.loader import Dataset, Protocol, Split, View, _image_size

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
FISHEYE_MODELS = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "SIMPLE_FISHEYE", "FISHEYE")
LENS_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV") + FISHEYE_MODELS
MIPNERF360_OUTDOOR = ("bicycle", "flowers", "garden", "stump", "treehill")
MIPNERF360_INDOOR = ("room", "counter", "kitchen", "bonsai")
LLFFHOLD = external.LLFFHOLD
_MODEL_FILES = ("cameras", "images", "points3D")


def default_factor(scene: str) -> int:
    """The 3DGS paper's resolution for a Mip-NeRF 360 scene: images_4 outdoors, images_2 indoors, else 1."""
    return 4 if scene in MIPNERF360_OUTDOOR else 2 if scene in MIPNERF360_INDOOR else 1


def c2w_from_colmap(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """OpenCV camera-to-world (4x4) from COLMAP's cam_from_world rotation R (3x3) and translation t (3,)."""
    M = np.eye(4)
    M[:3, :3] = R.T
    M[:3, 3] = -R.T @ np.asarray(t, dtype=np.float64)
    return check_pose("cam_from_world", M)


def colmap_from_c2w(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's cam_from_world (R, t) from an OpenCV camera-to-world."""
    c2w = check_pose("c2w", c2w)
    R = c2w[:3, :3].T
    return R, -R @ c2w[:3, 3]


def model_dir(root: Path) -> Path:
    """sparse/0, else sparse/ when it holds the model; DatasetError naming sparse/0 when neither does."""
    for d in (root / "sparse" / "0", root / "sparse"):
        if d.is_dir() and any((d / f"cameras{ext}").is_file() for ext in (".bin", ".txt")):
            return d
    raise DatasetError(f"{root / 'sparse' / '0'}: missing (expected a COLMAP sparse model: cameras, images and "
                       "points3D as .bin or .txt)")


def _model_file(d: Path, stem: str) -> Path:
    for ext in (".bin", ".txt"):
        if (d / f"{stem}{ext}").is_file():
            return d / f"{stem}{ext}"
    return d / f"{stem}.bin"


def read_model(d: Path):
    """The pycolmap.Reconstruction in `d`; DatasetError naming the file on failure."""
    import pycolmap

    for stem in _MODEL_FILES:
        if not any((d / f"{stem}{ext}").is_file() for ext in (".bin", ".txt")):
            raise DatasetError(f"{d / (stem + '.bin')}: missing (nor {stem}.txt) in the COLMAP model")
    try:
        return pycolmap.Reconstruction(str(d))
    except (ValueError, RuntimeError) as e:
        msg = " ".join(str(e).split())
        cams = _model_file(d, "cameras")
        if "camera model" in msg.lower() and cams.suffix == ".txt":
            known = set(pycolmap.CameraModelId.__members__)
            for line in cams.read_text().splitlines():
                fields = line.split()
                if fields and not line.startswith("#") and len(fields) > 1 and fields[1] not in known:
                    raise DatasetError(f"{cams}: camera {fields[0]}: unknown camera model {fields[1]!r}") from None
        raise DatasetError(f"{_failing_file(d, msg)}: pycolmap cannot read the model ({msg})") from None


# Words of pycolmap's messages that tell which file of a model it failed on (its messages name none):
# an image line (its pose, its POINTS2D, a camera it names that does not exist), a 3D point, a camera.
_FAILURE_WORDS = (("images", ("image_id", "cam_from_world", "line_stream2", "point3d_id_signed", "rig with id")),
                  ("points3D", ("point3d", "track")), ("cameras", ("camera",)), ("images", ("image",)))


def _failing_file(d: Path, msg: str) -> Path:
    """The model file that pycolmap's message `msg` is about, else the model folder."""
    low = msg.lower()
    for stem, words in _FAILURE_WORDS:
        if any(w in low for w in words):
            return _model_file(d, stem)
    return d


def camera_model(camera, cams_file: Path) -> tuple[np.ndarray, Lens | None]:
    """(K, lens) of a pycolmap camera (module docstring's table; lens None for a pinhole), else
    DatasetError naming the model."""
    name = camera.model.name
    p = np.asarray(camera.params, dtype=np.float64)
    if name in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE",
                "SIMPLE_FISHEYE"):
        f, cx, cy, dist = p[0], p[1], p[2], p[3:]
        fx = fy = f
    elif name in ("PINHOLE", "OPENCV", "OPENCV_FISHEYE", "FISHEYE"):
        fx, fy, cx, cy, dist = p[0], p[1], p[2], p[3], p[4:]
    else:
        raise DatasetError(f"{cams_file}: camera {camera.camera_id}: camera model {name} is not supported "
                           f"(expected one of {', '.join(PINHOLE_MODELS + LENS_MODELS)})")
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    if name in FISHEYE_MODELS:
        return K, Lens("fisheye", tuple(dist))
    if len(dist) and np.any(dist != 0.0):
        return K, Lens("opencv", tuple(dist))
    return K, None


def mipnerf360_protocol(factor: int, width: int, height: int) -> Protocol:
    return external.llffhold_protocol("mipnerf360", "Mip-NeRF 360 protocol (3DGS)", factor, width, height)


def _points_bound(points: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(points, 1.0, axis=0), np.percentile(points, 99.0, axis=0)
    pad = 0.05 * np.maximum(hi - lo, 1e-6 * max(1.0, float(np.abs(points).max())))
    return np.array([lo - pad, hi + pad])


def load_colmap(path: str | Path, factor: int | None = None) -> Dataset:
    """Read a COLMAP / Mip-NeRF 360 folder (module docstring) as a research.datasets Dataset.

    `factor`: read images_<factor> (1: images/); None: `default_factor` of the folder's name.
    Headers, cameras and sizes are checked here; pixels are read by `Dataset.load_split`.
    """
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such dataset folder")
    scene = root.resolve().name
    factor = default_factor(scene) if factor is None else external.check_factor(factor)
    d = model_dir(root)
    rec = read_model(d)
    cams_file, images_file = _model_file(d, "cameras"), _model_file(d, "images")
    folder = external.image_folder(root, factor)
    models = {cid: camera_model(cam, cams_file) for cid, cam in rec.cameras.items()}
    entries = []
    for image in sorted(rec.images.values(), key=lambda im: im.name):
        if not image.has_pose:
            continue
        img_path = folder / image.name
        if not img_path.is_file():
            raise DatasetError(f"{images_file}: image {image.name!r} is listed but {img_path} is missing")
        cam = rec.cameras[image.camera_id]
        w, h = _image_size(img_path)
        ew, eh = cam.width / factor, cam.height / factor
        if abs(w - ew) > 1.0 or abs(h - eh) > 1.0:
            raise DatasetError(f"{img_path}: image is {w}x{h}, but camera {image.camera_id} ({cam.width}x"
                               f"{cam.height}) at 1/{factor} expects about {ew:g}x{eh:g}")
        pose = image.cam_from_world()
        M = pose.matrix()
        S = np.diag([w / cam.width, h / cam.height, 1.0])
        try:
            K, lens = models[image.camera_id]
            camera = Camera(S @ K, c2w_from_colmap(M[:, :3], M[:, 3]), w, h, lens)
        except ValueError as e:
            raise DatasetError(f"{images_file}: image {image.name!r}: {e}") from None
        entries.append((image.name, img_path, camera))
    if len(entries) < 2:
        raise DatasetError(f"{images_file}: {len(entries)} registered image(s); the protocol needs at least 2")
    sizes = {(c.width, c.height) for _, _, c in entries}
    views, files = [], {}
    for i, (name, img_path, camera) in enumerate(entries):
        split = "test" if i % LLFFHOLD == 0 else "train"
        views.append(View(name, split, camera, root))
        files[name] = img_path
    cams = [c for _, _, c in entries]

    pts = np.array([p.xyz for p in rec.points3D.values()], dtype=np.float64).reshape(-1, 3)
    cols = np.array([p.color for p in rec.points3D.values()], dtype=np.float64).reshape(-1, 3) / 255.0
    bbox = _points_bound(pts) if len(pts) >= 8 else external.bound_from_cameras(cams)
    width, height = cams[0].width, cams[0].height
    if len(sizes) > 1:
        width, height = max(sizes)

    def load_views(selected: list[View]) -> Split:
        images = external.read_views(selected, files)
        if len({im.shape for im in images}) > 1:
            raise DatasetError(f"{folder}: the {len(selected)} images of a split must have one size to be "
                               f"stacked, got {sorted({im.shape[1::-1] for im in images})}")
        return external.split_from_srgb([v.camera for v in selected], images, [str(files[v.name]) for v in selected])

    model_files = [f for f in d.iterdir() if f.is_file()]
    manifest = {"format": "colmap", "content_hash": external.content_hash(root, model_files + list(files.values())),
                "factor": factor, "root": str(root), "model": str(d), "points": len(pts)}
    return Dataset(root, manifest, views, bbox, external.up_from_cameras(cams), format="colmap", scene=scene,
                   protocol=mipnerf360_protocol(factor, width, height), points=pts if len(pts) else None,
                   point_colors=cols if len(pts) else None, split_loader=load_views)
