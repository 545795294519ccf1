"""Photographs to a COLMAP model: `drlab sfm IMAGES_DIR --out DIR`, through pycolmap on the CPU.

Stages (each a pycolmap call; nothing of COLMAP is re-implemented here):

1. Feature extraction (`pycolmap.extract_features`, SIFT) of the images directly in IMAGES_DIR
   (.png, .jpg, .jpeg; sub-folders and other files are ignored), into a temporary database.
   Cameras: by default one camera per image of the estimated model `camera_model` (COLMAP's
   default SIMPLE_RADIAL); `shared_camera` gives every image one camera (COLMAP's single-camera
   mode: the images must have one size); `intrinsics` (fx, fy, cx, cy) gives one PINHOLE camera
   with those values, kept fixed in bundle adjustment (focal length, principal point and extra
   parameters are not refined).
2. Matching: `exhaustive` (every pair; best for unordered photos up to a few hundred) or
   `sequential` (each image with the next `overlap` images by name; for video frames and camera
   paths), both with COLMAP's geometric verification.
3. Incremental mapping (`pycolmap.incremental_mapping`); the model with most registered images is
   kept. Fewer than `min_registered` registered images (default: half of them, at least 3) is an
   error (SfmError, a ValueError: `drlab sfm` exits 2) saying how many registered of how many.
4. Undistortion (`pycolmap.undistort_images`): the images resampled to pinhole cameras (a PINHOLE or
   SIMPLE_PINHOLE model is copied unchanged). With `undistort=False` (`--no-undistort`) this stage only
   writes the model as estimated and copies the registered images as they are: research.datasets.colmap
   reads SIMPLE_RADIAL, RADIAL, OPENCV and OPENCV_FISHEYE cameras with their lens (kernels/lens.py), so
   the fits train on the photographs without resampling them.

Output, written into `<out>.partial-<pid>` and renamed to `<out>` only when complete (the results
folder protocol of research.experiment; an interrupted run leaves no `<out>`):

    <out>/images/        the undistorted registered images (as they are, without undistortion), under
                         their own names
    <out>/sparse/0/      cameras.bin, images.bin, points3D.bin (PINHOLE cameras; the estimated model
                         without undistortion), for load_colmap
    <out>/sfm.json       options, registered / total, the names left out, the cameras as estimated
                         (before undistortion), points, mean reprojection error, stage timings

Checked before any work (SfmError naming the argument): IMAGES_DIR missing, not a folder, or with
no images; images of different sizes with `shared_camera` or `intrinsics`; intrinsics outside the
image; `out` existing (unless `force` and it holds a previous sfm.json); bad option values.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterator

from research import atomic

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MATCHERS = ("exhaustive", "sequential")
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE")
SUMMARY = "sfm.json"


class SfmError(ValueError):
    """A bad input to `run_sfm`, or a reconstruction that registered too few images (one line)."""


@dataclass(frozen=True)
class SfmOptions:
    matcher: str = "exhaustive"
    overlap: int = 10  # sequential matching: pairs with the next `overlap` images
    shared_camera: bool = False
    camera_model: str = "SIMPLE_RADIAL"  # estimated model; ignored with `intrinsics` (PINHOLE)
    intrinsics: tuple[float, float, float, float] | None = None  # fx, fy, cx, cy: fixed PINHOLE
    min_registered: int | None = None  # None: max(3, ceil(half of the images))
    max_features: int = 8192  # SIFT features per image
    # -1: every core. COLMAP's multi-threaded matching and mapping are not reproducible: two runs on the
    # same images with the same seed gave camera poses up to 2.5 apart (48 views); with 1 thread they
    # were identical.
    threads: int = -1
    seed: int = 0  # the mapper's RANSAC and initial-pair draws
    undistort: bool = True  # False: keep the estimated (distorted) cameras and the original images

    def validate(self) -> None:
        if self.matcher not in MATCHERS:
            raise SfmError(f"--matcher: expected one of {', '.join(MATCHERS)}, got {self.matcher!r}")
        if self.camera_model not in CAMERA_MODELS:
            raise SfmError(f"--camera-model: expected one of {', '.join(CAMERA_MODELS)}, got {self.camera_model!r}")
        for name, v, lo in (("--overlap", self.overlap, 1), ("--max-features", self.max_features, 64),
                            ("--min-registered", self.min_registered, 2)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < lo):
                raise SfmError(f"{name}: expected an integer >= {lo}, got {v!r}")
        if isinstance(self.threads, bool) or not isinstance(self.threads, int) or not (self.threads == -1
                                                                                       or self.threads >= 1):
            raise SfmError(f"--threads: expected -1 (every core) or an integer >= 1, got {self.threads!r}")
        if not isinstance(self.undistort, bool):
            raise SfmError(f"undistort: expected True or False, got {self.undistort!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**31:
            raise SfmError(f"--seed: expected an integer in [0, 2^31), got {self.seed!r}")
        if self.intrinsics is not None:
            k = self.intrinsics
            if len(k) != 4 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in k) \
                    or k[0] <= 0 or k[1] <= 0:
                raise SfmError(f"--intrinsics: expected fx,fy,cx,cy (finite, fx and fy > 0), got {k!r}")

    def required(self, total: int) -> int:
        """How many registered images a reconstruction of `total` images needs."""
        return self.min_registered if self.min_registered is not None else max(3, math.ceil(total / 2))


@dataclass
class SfmResult:
    out: Path
    total: int
    registered: list[str]  # image names in the model, sorted
    unregistered: list[str]
    points: int
    mean_reprojection_error: float
    cameras: list[dict]  # as estimated (before any undistortion): {"id", "model", "width", "height", "params"}
    seconds: dict[str, float] = field(default_factory=dict)


def list_images(images_dir: str | Path, same_size: bool) -> tuple[list[Path], tuple[int, int]]:
    """The images directly in `images_dir`, sorted by name, and the first one's size (w, h).

    SfmError naming the folder or the image when the folder is missing or holds none, an image
    cannot be read, or (`same_size`) two images differ in size.
    """
    from research.datasets.loader import _image_size

    root = Path(images_dir)
    if not root.exists():
        raise SfmError(f"IMAGES_DIR: {root} does not exist")
    if not root.is_dir():
        raise SfmError(f"IMAGES_DIR: {root} is not a folder")
    files = sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise SfmError(f"IMAGES_DIR: {root} holds no images (expected {', '.join(IMAGE_SUFFIXES)} files directly "
                       "in it)")
    sizes = {}
    for f in files:
        try:
            sizes[f] = _image_size(f)
        except ValueError as e:
            raise SfmError(" ".join(str(e).split())) from None
    first = sizes[files[0]]
    if same_size:
        for f in files[1:]:
            if sizes[f] != first:
                raise SfmError(f"{f}: image is {sizes[f][0]}x{sizes[f][1]}, but {files[0].name} is {first[0]}x"
                               f"{first[1]} (one shared camera needs one image size)")
    return files, first


def check_out(out: str | Path, force: bool) -> Path:
    """`out` as an absolute path; SfmError when it exists (with `force`: unless it is a previous output)."""
    out = Path(out).absolute()
    if out.exists():
        if not out.is_dir():
            raise SfmError(f"--out: {out} is a file")
        if not force:
            raise SfmError(f"--out: {out} exists (choose another folder, or --force to replace a previous "
                           "`drlab sfm` output)")
        if any(out.iterdir()) and not (out / SUMMARY).is_file():
            raise SfmError(f"--out: {out} is not a `drlab sfm` output (no {SUMMARY}); --force replaces only those")
    if not out.parent.is_dir():
        raise SfmError(f"--out: the parent folder {out.parent} does not exist")
    return out


@contextlib.contextmanager
def quiet_colmap(verbose: bool) -> Iterator[None]:
    """COLMAP's own log (glog) at INFO when `verbose`, else silent (drlab raises its own errors); restored
    afterwards."""
    import pycolmap

    log = pycolmap.logging
    previous = (log.minloglevel, log.stderrthreshold)
    level = int(log.INFO if verbose else log.FATAL)
    log.minloglevel, log.stderrthreshold = level, level
    try:
        yield
    finally:
        log.minloglevel, log.stderrthreshold = previous


def _camera_record(cam) -> dict:
    return {"id": int(cam.camera_id), "model": cam.model.name, "width": int(cam.width), "height": int(cam.height),
            "params": [float(v) for v in cam.params]}


def run_sfm(images_dir: str | Path, out: str | Path, options: SfmOptions = SfmOptions(), *, force: bool = False,
            progress: bool = True, verbose: bool = False) -> SfmResult:
    """Reconstruct the images of `images_dir` into the COLMAP folder `out` (module docstring)."""
    import pycolmap
    from tqdm import tqdm

    options.validate()
    same_size = options.shared_camera or options.intrinsics is not None
    files, (w, h) = list_images(images_dir, same_size)
    if options.intrinsics is not None:
        fx, fy, cx, cy = options.intrinsics
        if not (0 < cx < w and 0 < cy < h):
            raise SfmError(f"--intrinsics: the principal point ({cx:g}, {cy:g}) is outside the {w}x{h} images")
    total = len(files)
    need = options.required(total)
    if need > total:
        raise SfmError(f"--min-registered: {need} exceeds the {total} images in {Path(images_dir)}")
    out = check_out(out, force)
    images_dir = Path(images_dir).absolute()
    names = [f.name for f in files]

    from research.experiment import clean_stale, commit_folder

    clean_stale(out)
    tmp = out.with_name(f"{out.name}.partial-{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    seconds: dict[str, float] = {}
    device = pycolmap.Device.cpu
    stages = tqdm(total=4, desc="drlab sfm", unit="stage", disable=not progress)
    try:
        with quiet_colmap(verbose):
            work = tmp / ".work"
            work.mkdir()
            db = work / "database.db"
            # 1. features
            stages.set_postfix_str(f"features ({total} images)")
            t0 = time.perf_counter()
            reader = pycolmap.ImageReaderOptions()
            if options.intrinsics is not None:
                reader.camera_model = "PINHOLE"
                reader.camera_params = ",".join(repr(float(v)) for v in options.intrinsics)
            else:
                reader.camera_model = options.camera_model
            extraction = pycolmap.FeatureExtractionOptions()
            extraction.num_threads = options.threads
            extraction.sift.max_num_features = options.max_features
            mode = pycolmap.CameraMode.SINGLE if same_size else pycolmap.CameraMode.PER_IMAGE
            pycolmap.extract_features(db, images_dir, image_names=names, camera_mode=mode, reader_options=reader,
                                      extraction_options=extraction, device=device)
            seconds["features"] = time.perf_counter() - t0
            stages.update()
            # 2. matching
            stages.set_postfix_str(f"{options.matcher} matching")
            t0 = time.perf_counter()
            matching = pycolmap.FeatureMatchingOptions()
            matching.num_threads = options.threads
            if options.matcher == "sequential":
                pairing = pycolmap.SequentialPairingOptions()
                pairing.overlap = options.overlap
                pairing.quadratic_overlap = False
                pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing, device=device)
            else:
                pycolmap.match_exhaustive(db, matching_options=matching, device=device)
            seconds["matching"] = time.perf_counter() - t0
            stages.update()
            # 3. incremental mapping
            stages.set_postfix_str("incremental mapping")
            t0 = time.perf_counter()
            mapping = pycolmap.IncrementalPipelineOptions()
            mapping.num_threads = options.threads
            mapping.random_seed = options.seed
            mapping.mapper.random_seed = options.seed
            if options.intrinsics is not None:
                mapping.ba_refine_focal_length = False
                mapping.ba_refine_principal_point = False
                mapping.ba_refine_extra_params = False
            bar = tqdm(total=total, desc="registered", unit="image", leave=False, disable=not progress)
            models = pycolmap.incremental_mapping(db, images_dir, work / "sparse", mapping,
                                                  next_image_callback=lambda: bar.update())
            bar.close()
            seconds["mapping"] = time.perf_counter() - t0
            rec = max(models.values(), key=lambda r: r.num_reg_images(), default=None)
            got = 0 if rec is None else rec.num_reg_images()
            if got < need:
                raise SfmError(f"IMAGES_DIR: only {got} of {total} images registered in {images_dir} (at least "
                               f"{need} needed; --min-registered): give more overlapping views, more texture or a "
                               "higher resolution, or try --matcher exhaustive / --shared-camera")
            stages.update()
            # 4. undistortion, or the estimated model and the images as they are
            stages.set_postfix_str("undistortion" if options.undistort else "model as estimated")
            t0 = time.perf_counter()
            (tmp / "sparse" / "0").mkdir(parents=True)
            if options.undistort:
                model_in = work / "model"
                model_in.mkdir()
                rec.write(str(model_in))
                undist = work / "undistorted"
                pycolmap.undistort_images(undist, model_in, images_dir, output_type="COLMAP",
                                          num_threads=options.threads)
                for f in (undist / "sparse").iterdir():
                    if f.is_file():
                        os.replace(f, tmp / "sparse" / "0" / f.name)
                os.replace(undist / "images", tmp / "images")
                seconds["undistortion"] = time.perf_counter() - t0
            else:
                rec.write(str(tmp / "sparse" / "0"))
                (tmp / "images").mkdir()
                for im in rec.images.values():
                    if im.has_pose:
                        shutil.copyfile(images_dir / im.name, tmp / "images" / im.name)
                seconds["model"] = time.perf_counter() - t0
            stages.update()
        registered = sorted(im.name for im in rec.images.values() if im.has_pose)
        result = SfmResult(out, total, registered, sorted(set(names) - set(registered)), rec.num_points3D(),
                           float(rec.compute_mean_reprojection_error()),
                           [_camera_record(c) for c in rec.cameras.values()], seconds)
        shutil.rmtree(work)
        summary = {"images_dir": str(images_dir), "options": asdict(options), "pycolmap": pycolmap.__version__,
                   **{k: v for k, v in asdict(result).items() if k != "out"}}
        atomic.write_json(tmp / SUMMARY, summary)
    except BaseException:
        stages.close()
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    stages.close()
    commit_folder(tmp, out)
    return result


def parse_intrinsics(text: str) -> tuple[float, float, float, float]:
    """`fx,fy,cx,cy` (the --intrinsics option) as four floats; SfmError naming the option otherwise."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise SfmError(f"--intrinsics: expected four numbers fx,fy,cx,cy (pixels), got {text!r}")
    return values  # type: ignore[return-value]


def describe(result: SfmResult) -> str:
    """The one-paragraph summary `drlab sfm` prints."""
    cams = ", ".join(f"{c['model']} {c['width']}x{c['height']} [{', '.join(f'{v:.4g}' for v in c['params'])}]"
                     for c in result.cameras[:3]) + (" ..." if len(result.cameras) > 3 else "")
    t = sum(result.seconds.values())
    return (f"registered {len(result.registered)} of {result.total} images; {result.points} points, mean "
            f"reprojection error {result.mean_reprojection_error:.3f} px; camera(s) as estimated: {cams}; "
            f"{t:.1f} s; wrote {result.out} (images/, sparse/0/, {SUMMARY})")

