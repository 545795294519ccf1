"""Writing a ground-truth dataset directory from a built-in Mitsuba scene.

Layout of `<out>/`:

    {train,val,test}/r_NNN.png         sRGB 8-bit, straight alpha
    {train,val,test}/r_NNN.exr         linear premultiplied RGBA, float32
    {train,val,test}/r_NNN_depth.exr   z-depth, float32 (0 = no surface)
    {train,val,test}/r_NNN_normal.exr  world shading normal, float32
    {train,val,test}/r_NNN_mask.png    255 where the pixel-centre ray hits a surface
    transforms_{train,val,test}.json   NeRF-synthetic (+ nerfstudio keys), OpenGL poses
    cameras.json                       OpenCV K and camera-to-world for every view
    stereo/ (with --stereo)            p_NNN_{left,right}.{png,exr}, p_NNN_left_depth.exr,
                                       p_NNN_disp.pfm, p_NNN_noc.png, p_NNN_mask.png, stereo.json
    flow/   (with --flow)              f_NNN.{png,exr}, f_NNN_depth.exr, f_NNN_mask.png,
                                       f_NNN_flow.flo and f_NNN_valid.png (frame NNN -> NNN+1), flow.json
    manifest.json                      config, Mitsuba variant, versions, seed, SHA-256 of every file
    .drlab-verified.json               research.datasets.integrity's cache (sizes and times); not content

Safety:
* Every argument is validated (ValueError naming the `drlab dataset` option) before any file or
  folder is created.
* Everything is written into `<out>.partial/`, each file atomically; its configuration is recorded
  there first (`.drlab-partial.json`), and the directory is renamed to `<out>` only after
  manifest.json is written. A killed run therefore never leaves a directory that looks complete,
  and `resume=True` finishes a partial one (a view counts as done when all its files exist; its
  configuration must match the recorded one). A `.partial` whose record is missing or unreadable
  is replaced with a one-line notice. Temporary files of a killed run are swept before rendering.
* `force=True` replaces only a directory holding a manifest.json written by drlab's generator, and
  only once the new dataset is complete; it also starts over from a `.partial` (with a notice)
  unless `resume=True`.
* The run holds an fcntl lock on `<out>.lock`, so two processes never write the same dataset;
  `ensure` holds it too, so a second process waits and reuses the first one's data.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import shutil
import sys
import threading
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from tqdm import tqdm

from research import atomic, io
from research.cameras import Camera, smooth_path
from research.datasets.groundtruth import forward_flow, stereo_disparity, stereo_right_camera
from research.datasets.render import SceneRenderer
from research.datasets.scenes import SceneSpec, get_scene
from research.datasets.integrity import (GENERATOR, MANIFEST, VERIFIED, content_hash, file_sha256, read_manifest,
                                     verify, write_cache)
from research.results import host, versions

SPLITS = ("train", "val", "test")
_PARTIAL_CONFIG = ".drlab-partial.json"
# Bump whenever the generator would write different files for the same DatasetConfig (a change of
# pixel filter, integrator, scene or file layout). ensure() regenerates datasets of an older revision,
# so experiments never silently train on data the current code would not produce.
GENERATOR_REVISION = 2  # 2: box pixel filter for the RGB pass
VIEW_SUFFIXES = (".png", ".exr", "_depth.exr", "_normal.exr", "_mask.png")


@dataclass(frozen=True)
class DatasetConfig:
    scene: str
    views: int = 100
    res: int = 256
    spp: int = 64
    seed: int = 0
    val_fraction: float = 0.1
    test_fraction: float = 0.1
    stereo: bool = False
    stereo_pairs: int = 10
    baseline: float | None = None  # default: 8% of the scene's camera distance
    flow: bool = False
    flow_frames: int = 12
    flow_step_deg: float = 1.5  # camera azimuth step between consecutive flow frames

    def validate(self) -> None:
        """Raise ValueError naming the `drlab dataset` option (or the field, for those without one)."""
        from research.datasets.scenes import SCENES

        if not isinstance(self.scene, str) or self.scene not in SCENES:
            raise ValueError(f"--scene: expected one of {', '.join(SCENES)}, got {self.scene!r}")
        for name in ("views", "res", "spp", "stereo_pairs", "flow_frames"):
            v = getattr(self, name)
            if not _is_int(v) or v <= 0:
                raise ValueError(f"{_OPTION[name]}: expected a positive integer, got {v!r}")
        if self.views < 3:
            raise ValueError(f"--views: expected at least 3 (one per split), got {self.views}")
        if self.res > MAX_RES:
            raise ValueError(f"--res: expected at most {MAX_RES} pixels, got {self.res}")
        if not _is_int(self.seed) or not 0 <= self.seed < 2**63:
            raise ValueError(f"--seed: expected an integer in [0, 2**63), got {self.seed!r}")
        for name in ("stereo", "flow"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{_OPTION[name]}: expected True or False, got {getattr(self, name)!r}")
        if self.flow and self.flow_frames < 2:
            raise ValueError(f"--flow-frames: expected at least 2, got {self.flow_frames}")
        for name in ("val_fraction", "test_fraction"):
            v = getattr(self, name)
            if not _is_real(v) or not 0.0 < v < 0.5:
                raise ValueError(f"{name}: expected a value in (0, 0.5), got {v!r}")
        if max(1, round(self.views * self.val_fraction)) + max(1, round(self.views * self.test_fraction)) >= self.views:
            raise ValueError(f"--views: {self.views} views leave no training view after the val and test splits")
        if not _is_real(self.flow_step_deg) or not 0.0 < self.flow_step_deg <= 90.0:
            raise ValueError(f"flow_step_deg: expected a camera step in (0, 90] degrees, got {self.flow_step_deg!r}")
        if self.baseline is not None:
            spec = SCENES[self.scene]
            limit = max_baseline(spec)
            if not _is_real(self.baseline) or not 0.0 < self.baseline <= limit:
                raise ValueError(f"--baseline: expected a finite distance in (0, {limit:.4g}] for scene {self.scene} "
                                 f"(a wider baseline moves the scene out of the right view), got {self.baseline!r}")


# `drlab dataset` options of the DatasetConfig fields that have one.
_OPTION = {"views": "--views", "res": "--res", "spp": "--spp", "stereo_pairs": "--stereo-pairs",
           "flow_frames": "--flow-frames", "stereo": "--stereo", "flow": "--flow"}
MAX_RES = 8192


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_real(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)


def max_baseline(spec: SceneSpec) -> float:
    """The widest stereo baseline that keeps the scene's target inside the right view.

    Cameras sit `spec.radius` from the target, looking at it; moving the right camera by b along
    its x axis shifts the target by b / radius * (focal length) pixels, and it leaves the image at
    b = radius * tan(fov_x / 2). Half of that keeps the target in the right view's central half.
    """
    return 0.5 * spec.radius * math.tan(math.radians(spec.fov_x_deg) / 2)


def split_assignment(n: int, val_fraction: float, test_fraction: float, seed: int) -> list[str]:
    """A seeded random split of n views; val and test get at least one view each."""
    n_val = max(1, round(n * val_fraction))
    n_test = max(1, round(n * test_fraction))
    labels = ["test"] * n_test + ["val"] * n_val + ["train"] * (n - n_val - n_test)
    order = np.random.default_rng([seed, 1]).permutation(n)
    out = [""] * n
    for label, idx in zip(labels, order):
        out[idx] = label
    return out


def _view_seed(seed: int, stream: int, index: int) -> int:
    """Independent, reproducible render seeds for every image (fits in 31 bits)."""
    return int(np.random.default_rng([seed, stream, index]).integers(0, 2**31 - 1))


class _Writer:
    def __init__(self, cfg: DatasetConfig, root: Path):
        self.cfg = cfg
        self.root = root
        self.spec: SceneSpec = get_scene(cfg.scene)
        self._renderer: SceneRenderer | None = None

    @property
    def renderer(self) -> SceneRenderer:
        # Created lazily so a fully resumed run needs no Mitsuba at all.
        if self._renderer is None:
            self._renderer = SceneRenderer(self.spec, spp=self.cfg.spp)
        return self._renderer

    def camera(self, c2w: np.ndarray) -> Camera:
        return Camera.from_fov(self.spec.fov_x_deg, self.cfg.res, self.cfg.res, c2w)

    def exists(self, stem: str, suffixes: tuple[str, ...]) -> bool:
        return all((self.root / f"{stem}{s}").exists() for s in suffixes)

    def write_color(self, stem: str, rgba: np.ndarray) -> None:
        io.write_exr(self.root / f"{stem}.exr", rgba)
        io.write_png(self.root / f"{stem}.png", rgba)

    def write_geometry(self, stem: str, depth: np.ndarray, mask: np.ndarray, normal: np.ndarray | None) -> None:
        io.write_exr(self.root / f"{stem}_depth.exr", depth.astype(np.float32))
        if normal is not None:
            io.write_exr(self.root / f"{stem}_normal.exr", normal.astype(np.float32), ["X", "Y", "Z"])
        io.write_png_u8(self.root / f"{stem}_mask.png", (mask * 255).astype(np.uint8))

    # ---------------------------------------------------------------- multi-view
    def multiview_plan(self) -> list[tuple[str, str, Camera, int]]:
        cfg = self.cfg
        poses = self.spec.view_poses(cfg.views, cfg.seed)
        labels = split_assignment(cfg.views, cfg.val_fraction, cfg.test_fraction, cfg.seed)
        counters = {s: 0 for s in SPLITS}
        plan = []
        for k, (pose, split) in enumerate(zip(poses, labels)):
            stem = f"{split}/r_{counters[split]:03d}"
            counters[split] += 1
            plan.append((stem, split, self.camera(pose), _view_seed(cfg.seed, 0, k)))
        return plan

    def render_view(self, stem: str, cam: Camera, seed: int) -> None:
        if self.exists(stem, VIEW_SUFFIXES):
            return
        rgba = self.renderer.render_rgba(cam, seed)
        g = self.renderer.render_geometry(cam)
        self.write_geometry(stem, g.depth, g.mask, g.normal)
        self.write_color(stem, rgba)

    def write_multiview_metadata(self, plan: list[tuple[str, str, Camera, int]]) -> None:
        cam0 = plan[0][2]
        for split in SPLITS:
            frames = [{"file_path": f"{stem}.png", "depth_file_path": f"{stem}_depth.exr",
                       "mask_path": f"{stem}_mask.png", "transform_matrix": cam.to_nerf().tolist()}
                      for stem, s, cam, _ in plan if s == split]
            atomic.write_json(self.root / f"transforms_{split}.json", {
                "camera_angle_x": math.radians(cam0.fov_x_deg),
                "fl_x": cam0.fx, "fl_y": cam0.fy, "cx": cam0.cx, "cy": cam0.cy,
                "w": cam0.width, "h": cam0.height,
                "camera_model": "OPENCV", "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
                "frames": frames,
            })
        atomic.write_json(self.root / "cameras.json", {
            "convention": "opencv: x right, y down, z forward; c2w is camera-to-world; pixel centres at +0.5",
            "scene": self.scene_info(),
            "views": [{"name": stem, "split": split, **cam.to_dict()} for stem, split, cam, _ in plan],
        })

    def scene_info(self) -> dict[str, Any]:
        s = self.spec
        return {"name": s.name, "bbox_min": list(s.bbox_min), "bbox_max": list(s.bbox_max), "up": list(s.up),
                "near_clip": s.near_clip}

    # ---------------------------------------------------------------- stereo
    def baseline(self) -> float:
        return self.cfg.baseline if self.cfg.baseline is not None else 0.08 * self.spec.radius

    def stereo_plan(self) -> list[tuple[str, Camera, Camera, int]]:
        b = self.baseline()
        poses = self.spec.view_poses(self.cfg.stereo_pairs, self.cfg.seed + 7919)
        plan = []
        for k, pose in enumerate(poses):
            left = self.camera(pose)
            plan.append((f"stereo/p_{k:03d}", left, stereo_right_camera(left, b), k))
        return plan

    def render_stereo_pair(self, stem: str, left: Camera, right: Camera, k: int) -> None:
        suffixes = ("_left.png", "_left.exr", "_right.png", "_right.exr", "_left_depth.exr", "_disp.pfm",
                    "_noc.png", "_mask.png")
        if self.exists(stem, suffixes):
            return
        gl = self.renderer.render_geometry(left)
        gr = self.renderer.render_geometry(right)
        disp, noc = stereo_disparity(left, self.baseline(), gl.depth, gl.mask, gr.depth, gr.mask)
        self.write_color(f"{stem}_left", self.renderer.render_rgba(left, _view_seed(self.cfg.seed, 1, k)))
        self.write_color(f"{stem}_right", self.renderer.render_rgba(right, _view_seed(self.cfg.seed, 2, k)))
        io.write_exr(self.root / f"{stem}_left_depth.exr", gl.depth.astype(np.float32))
        io.write_pfm(self.root / f"{stem}_disp.pfm", disp.astype(np.float32))
        io.write_png_u8(self.root / f"{stem}_noc.png", (noc * 255).astype(np.uint8))
        io.write_png_u8(self.root / f"{stem}_mask.png", (gl.mask * 255).astype(np.uint8))

    def write_stereo_metadata(self, plan: list[tuple[str, Camera, Camera, int]]) -> None:
        left0 = plan[0][1]
        atomic.write_json(self.root / "stereo" / "stereo.json", {
            "baseline": self.baseline(), "fx": left0.fx, "fy": left0.fy,
            "convention": "rectified; right = left + baseline along OpenCV x; left (x, y) <-> right (x - d, y); "
                          "d = fx * baseline / Z; noc = visible in both views (1% z-test); mask = surface hit",
            "pairs": [{"name": Path(stem).name, "left": l.to_dict(), "right": r.to_dict()} for stem, l, r, _ in plan],
        })

    # ---------------------------------------------------------------- flow
    def flow_cameras(self) -> list[Camera]:
        s, cfg = self.spec, self.cfg
        start = float(np.random.default_rng([cfg.seed, 3]).uniform(0.0, 360.0))
        poses = smooth_path(cfg.flow_frames, s.radius, s.target, s.up, start_azimuth_deg=start,
                            sweep_deg=cfg.flow_step_deg * (cfg.flow_frames - 1),
                            elevation_deg=max(25.0, s.min_elevation_deg + 10.0) if s.hemisphere else 20.0)
        return [self.camera(p) for p in poses]

    def render_flow(self, cams: list[Camera], progress: Callable[[], None]) -> None:
        geometry: dict[int, Any] = {}

        def geom(k: int):
            if k not in geometry:
                geometry[k] = self.renderer.render_geometry(cams[k])
            return geometry[k]

        for k, cam in enumerate(cams):
            stem = f"flow/f_{k:03d}"
            last = k == len(cams) - 1
            need = (".png", ".exr", "_depth.exr", "_mask.png") + (() if last else ("_flow.flo", "_valid.png"))
            if not self.exists(stem, need):
                g1 = geom(k)
                if not last:
                    g2 = geom(k + 1)
                    flow, valid = forward_flow(cam, g1.depth, g1.mask, cams[k + 1], g2.depth, g2.mask)
                    io.write_flo(self.root / f"{stem}_flow.flo", flow.astype(np.float32))
                    io.write_png_u8(self.root / f"{stem}_valid.png", (valid * 255).astype(np.uint8))
                self.write_geometry(stem, g1.depth, g1.mask, None)
                self.write_color(stem, self.renderer.render_rgba(cam, _view_seed(self.cfg.seed, 3, k)))
            geometry.pop(k - 1, None)
            progress()
        atomic.write_json(self.root / "flow" / "flow.json", {
            "convention": "f_NNN_flow.flo maps frame NNN to NNN+1: (u, v) = (x right, y down) in pixels; "
                          "valid = surface visible in both frames (1% z-test)",
            "frames": [{"name": f"f_{k:03d}", **c.to_dict()} for k, c in enumerate(cams)],
        })


def generate(cfg: DatasetConfig, out: str | Path, *, resume: bool = False, force: bool = False,
             show_progress: bool = True) -> Path:
    """Render the dataset described by `cfg` into `out` (see module docstring). Returns `out`.

    Every argument is checked before anything is created: a bad one raises ValueError naming the
    `drlab dataset` option. `force` replaces only a directory that holds a drlab dataset.
    """
    cfg.validate()
    out = check_out(out, force=force)
    partial = partial_dir(out)
    cfg_dict = asdict(cfg)
    _partial_state(partial, cfg_dict, resume, force)  # its errors too come before the lock file is created
    with dataset_lock(out):
        _recover_swap(out)
        out = check_out(out, force=force)  # again, under the lock: another process may have finished it
        state = _partial_state(partial, cfg_dict, resume, force)
        if state in ("unreadable", "force"):
            why = ("its configuration record is missing or unreadable" if state == "unreadable" else
                   "--force starts over (--resume would finish it)")
            notice(f"note: replacing {partial}: {why}")
            shutil.rmtree(partial)
        if partial.exists():
            atomic.sweep_temporary(partial)  # left by a killed run; nothing else writes here (we hold the lock)
        else:
            partial.mkdir(parents=True)
            atomic.write_json(partial / _PARTIAL_CONFIG, cfg_dict)  # first, before any work
        _render(cfg, partial, show_progress)
        _commit(out, partial)
    return out


def _render(cfg: DatasetConfig, partial: Path, show_progress: bool) -> None:
    """Every file of the dataset, then manifest.json (and the verification cache), inside `partial`."""
    w = _Writer(cfg, partial)
    plan = w.multiview_plan()
    stereo_plan = w.stereo_plan() if cfg.stereo else []
    flow_cams = w.flow_cameras() if cfg.flow else []
    total = len(plan) + len(stereo_plan) + len(flow_cams)
    with tqdm(total=total, desc=f"dataset {cfg.scene}", unit="view", disable=not show_progress) as bar:
        for stem, _, cam, seed in plan:
            w.render_view(stem, cam, seed)
            bar.update()
        w.write_multiview_metadata(plan)
        for item in stereo_plan:
            w.render_stereo_pair(*item)
            bar.update()
        if stereo_plan:
            w.write_stereo_metadata(stereo_plan)
        if flow_cams:
            w.render_flow(flow_cams, bar.update)

    skip = {MANIFEST, _PARTIAL_CONFIG, VERIFIED}
    files = {p.relative_to(partial).as_posix(): file_sha256(p)
             for p in sorted(partial.rglob("*")) if p.is_file() and p.relative_to(partial).as_posix() not in skip}
    variant = w._renderer.variant if w._renderer is not None else _recorded_variant(partial)
    atomic.write_json(partial / MANIFEST, {
        "generator": GENERATOR,
        "generator_revision": GENERATOR_REVISION,
        "config": asdict(cfg),
        "seed": cfg.seed,
        "scene": w.scene_info(),
        "mitsuba_variant": variant,
        "versions": versions(),
        "host": host(),
        "content_hash": content_hash(files),
        "files": files,
    })
    write_cache(partial, (partial / MANIFEST).read_bytes(), files)


def _commit(out: Path, partial: Path) -> None:
    """Rename the finished `partial` to `out`; with --force the old dataset is renamed aside first.

    A kill between the renames leaves `<out>.drlab-old`, which the next run puts back or deletes
    (`_recover_swap`); the finished `.partial` still holds its manifest, so `--force --resume`
    completes it without rendering (plain `--force` starts over).
    """
    (partial / _PARTIAL_CONFIG).unlink(missing_ok=True)  # the manifest records the configuration from here on
    if out.is_dir() and not out.is_symlink() and not any(out.iterdir()):
        out.rmdir()
    if out.exists() or out.is_symlink():
        old = _old_dir(out)
        os.replace(out, old)
        os.replace(partial, out)
        if old.is_symlink():  # --out was a link to a dataset: drop the link, keep what it pointed to
            old.unlink()
        else:
            shutil.rmtree(old)
    else:
        os.replace(partial, out)


def _partial_state(partial: Path, cfg_dict: dict[str, Any], resume: bool, force: bool) -> str:
    """"none", "resume", "unreadable" or "force" (the last two: replace it); ValueError when the user must decide."""
    if not partial.exists():
        return "none"
    recorded = _partial_config(partial)
    if recorded is None:
        return "unreadable"
    if force and not resume:
        return "force"
    if not resume:
        raise ValueError(f"--resume: an interrupted run left {partial}; pass --resume to finish it, or delete that "
                         "folder")
    if recorded != cfg_dict:
        raise ValueError(f"--resume: {partial} was started with a different configuration "
                         f"({_config_diff(recorded, cfg_dict)}); delete that folder or rerun with its settings")
    return "resume"


def partial_dir(out: Path) -> Path:
    return out.with_name(out.name + ".partial")


def _old_dir(out: Path) -> Path:
    return out.with_name(out.name + ".drlab-old")


def notice(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _holds_dataset(path: Path) -> bool:
    """Whether `path` is a directory with a manifest.json written by drlab's generator."""
    try:
        m = json.loads((path / MANIFEST).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(m, dict) and m.get("generator") == GENERATOR


def _partial_config(partial: Path) -> dict[str, Any] | None:
    """The configuration a `.partial` folder was started with; None when missing or unreadable.

    A run killed after writing its manifest (but before the final rename) has already removed the
    configuration record; the manifest's copy counts then.
    """
    for name, key in ((_PARTIAL_CONFIG, None), (MANIFEST, "config")):
        try:
            doc = json.loads((partial / name).read_text())
        except (OSError, ValueError):
            continue
        doc = doc.get(key) if key and isinstance(doc, dict) else doc
        if isinstance(doc, dict) and set(doc) == set(asdict(DatasetConfig("spheres"))):
            return doc
    return None


def _config_diff(recorded: dict[str, Any], wanted: dict[str, Any]) -> str:
    diff = [f"{k} {recorded.get(k)!r} there, {v!r} now" for k, v in wanted.items() if recorded.get(k) != v]
    return "; ".join(diff) or "same settings"


def check_out(out: str | Path, *, force: bool) -> Path:
    """`--out` checked before anything is created: a directory path whose parent can be written, not a
    file, and (unless empty) replaced only with `force` and only when it holds a drlab dataset."""
    if not isinstance(out, (str, os.PathLike)) or not str(out).strip():
        raise ValueError(f"--out: expected a directory path, got {out!r}")
    out = Path(out)
    if out.name in ("", ".", ".."):
        raise ValueError(f"--out: expected a path that names the dataset directory, got {str(out)!r}")
    if out.name.endswith(".partial") or out.name.endswith(".drlab-old") or out.name.endswith(".lock"):
        raise ValueError(f"--out: names ending in .partial, .drlab-old or .lock are drlab's own, got {out.name!r}")
    if (out.exists() or out.is_symlink()) and not out.is_dir():
        raise ValueError(f"--out: {out} is a file (or a broken link); expected a dataset directory")
    partial = partial_dir(out)
    if (partial.exists() or partial.is_symlink()) and not partial.is_dir():
        raise ValueError(f"--out: {partial} is a file, and drlab keeps the unfinished dataset there; move it away")
    anc = out.absolute().parent
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ValueError(f"--out: {anc} is a file, so {out} cannot be created")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise ValueError(f"--out: cannot create {out}: no write permission in {anc}")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise ValueError(f"--out: {out} already exists; pass --force to replace it (only a drlab dataset is "
                             "replaced)")
        if not _holds_dataset(out):
            raise ValueError(f"--out: {out} does not hold a drlab dataset (no manifest.json written by drlab "
                             "dataset); --force replaces only datasets, so nothing was touched")
    return out


def _recover_swap(out: Path) -> None:
    """Finish what a run killed during the --force swap left: put the old dataset back or delete it."""
    old = _old_dir(out)
    if not old.is_dir() or not _holds_dataset(old):
        return
    if out.exists():
        shutil.rmtree(old)
    else:
        os.replace(old, out)
        notice(f"note: restored {out} from {old}, left by a run killed while replacing it")


_locks = threading.local()


@contextlib.contextmanager
def dataset_lock(out: Path):
    """An exclusive fcntl.flock on `<out>.lock` (kept beside the dataset), re-entrant within a thread.

    Another process preparing the same dataset waits here (with a one-line notice) and then sees the
    finished dataset. The lock file stays: deleting it would let a third process lock a new file.
    """
    path = out.absolute().with_name(out.name + ".lock")
    held = _locks.__dict__.setdefault("held", {})
    key = str(path)
    if held.get(key):
        held[key] += 1
        try:
            yield
        finally:
            held[key] -= 1
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            notice(f"note: waiting for another process preparing {out} (lock {path})")
            fcntl.flock(fd, fcntl.LOCK_EX)
        held[key] = 1
        try:
            yield
        finally:
            held.pop(key, None)
    finally:
        os.close(fd)  # releases the lock


def _recorded_variant(root: Path) -> str:
    """A resumed run that rendered nothing new: the variant is unknown to this process."""
    from research.mitsuba_env import select_variant

    return select_variant()


CACHE_ROOT_HELP = ("cache root: the dataset lives in <data>/<scene and config> (research.datasets.cache_dir), "
                   "rendered if missing and shared with every experiment that asks for the same configuration")


def cache_dir(cfg: DatasetConfig, root: str | Path) -> Path:
    """A directory under `root` named by the configuration, so experiments that ask for the same data share it.

    Only the fields that differ from DatasetConfig's defaults (besides the scene) appear in the name.
    """
    defaults = asdict(DatasetConfig(cfg.scene))
    parts = [cfg.scene] + [f"{k}{'' if v is True else v}" for k, v in asdict(cfg).items()
                           if k != "scene" and v != defaults[k] and v is not False]
    return Path(root) / "-".join(parts)


def provenance(path: str | Path) -> dict[str, Any]:
    """What an experiment should record about a dataset it used: directory name, generator
    revision, content hash and the host that rendered it (from its manifest).

    The dataset is verified first (research.datasets.integrity), so the content hash recorded is one
    the files on disk were just checked against. The content hash identifies the pixels; the
    revision and host explain why two runs of the same configuration can differ.
    """
    root = Path(path)
    digest = verify(root)
    m, _ = read_manifest(root)
    return {"name": root.name, "generator_revision": m.get("generator_revision"),
            "content_hash": digest, "host": m.get("host")}


def _matches(out: Path, cfg: DatasetConfig) -> bool:
    try:
        recorded = json.loads((out / MANIFEST).read_text())
    except (OSError, ValueError):
        return False
    return (isinstance(recorded, dict) and recorded.get("config") == asdict(cfg)
            and recorded.get("generator_revision") == GENERATOR_REVISION)


def ensure(cfg: DatasetConfig, out: str | Path, show_progress: bool = True) -> Path:
    """Return `out` if it holds a finished dataset with exactly this configuration, else (re)generate it.

    Holds `dataset_lock(out)` throughout, so a second process preparing the same data waits and then
    reuses it. A dataset that is reused is verified against its manifest (DatasetError naming a
    changed or missing file: tampered data is never reused, nor silently replaced). A dataset written
    by an older generator revision, or with another configuration, is regenerated. An interrupted run
    of the same configuration is resumed; a `.partial` of another configuration, or whose record is
    unreadable, is replaced with a one-line notice.
    """
    cfg.validate()
    out = check_out(out, force=True)
    with dataset_lock(out):
        _recover_swap(out)
        if _matches(out, cfg):
            verify(out)
            return out
        partial = partial_dir(out)
        recorded = _partial_config(partial) if partial.is_dir() else None
        resume = recorded == asdict(cfg)
        if partial.exists() and not resume:
            why = "its configuration record is missing or unreadable" if recorded is None else \
                f"it was started with a different configuration ({_config_diff(recorded, asdict(cfg))})"
            notice(f"note: replacing {partial}: {why}")
            shutil.rmtree(partial)
        return generate(cfg, out, resume=resume, force=out.exists(), show_progress=show_progress)
