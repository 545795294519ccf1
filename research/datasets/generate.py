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
                                       f_NNN_flow.flo and f_NNN_valid.png (frame NNN -> NNN+1), flow.json;
                                       with flow_path "loop" the frames orbit once and return to the start
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

The configuration and its validation are in research/datasets/config.py; the folder handling
(`--out` checks, `.partial` state, the --force swap, the lock) in research/datasets/folders.py.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable

import numpy as np
from tqdm import tqdm

from research import atomic, io
from research.cameras import Camera, smooth_path
from research.poses.se3 import loop_path
from research.datasets.config import DatasetConfig, config_record
from research.datasets.folders import (PARTIAL_CONFIG, check_out, commit, config_diff, dataset_lock, notice,
                                      partial_config, partial_dir, partial_state, recover_swap)
from research.datasets.groundtruth import forward_flow, stereo_disparity, stereo_right_camera
from research.datasets.render import SceneRenderer
from research.datasets.scenes import SceneSpec, get_scene
from research.datasets.integrity import (GENERATOR, MANIFEST, VERIFIED, content_hash, file_sha256, read_manifest,
                                     verify, write_cache)
from research.results import host, versions

SPLITS = ("train", "val", "test")
# Bump whenever the generator would write different files for the same DatasetConfig (a change of
# pixel filter, integrator, scene or file layout). ensure() regenerates datasets of an older revision,
# so experiments never silently train on data the current code would not produce.
GENERATOR_REVISION = 2  # 2: box pixel filter for the RGB pass
VIEW_SUFFIXES = (".png", ".exr", "_depth.exr", "_normal.exr", "_mask.png")


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
        elevation = max(25.0, s.min_elevation_deg + 10.0) if s.hemisphere else 20.0
        if cfg.flow_path == "loop":
            poses = loop_path(cfg.flow_frames, s.radius, s.target, s.up, start_azimuth_deg=start,
                              elevation_deg=elevation)
        else:
            poses = smooth_path(cfg.flow_frames, s.radius, s.target, s.up, start_azimuth_deg=start,
                                sweep_deg=cfg.flow_step_deg * (cfg.flow_frames - 1), elevation_deg=elevation)
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
        doc = {
            "convention": "f_NNN_flow.flo maps frame NNN to NNN+1: (u, v) = (x right, y down) in pixels; "
                          "valid = surface visible in both frames (1% z-test)",
            "frames": [{"name": f"f_{k:03d}", **c.to_dict()} for k, c in enumerate(cams)],
        }
        if self.cfg.flow_path != "arc":  # the arc's flow.json stays as it was before paths had names
            doc["path"] = self.cfg.flow_path
        atomic.write_json(self.root / "flow" / "flow.json", doc)


def generate(cfg: DatasetConfig, out: str | Path, *, resume: bool = False, force: bool = False,
             show_progress: bool = True, ray: Any = None) -> Path:
    """Render the dataset described by `cfg` into `out` (see module docstring). Returns `out`.

    Every argument is checked before anything is created: a bad one raises ValueError naming the
    `drlab dataset` option. `force` replaces only a directory that holds a drlab dataset.

    `ray` (a research.sweep.RayOptions): render the views, stereo pairs and the flow sequence as Ray
    tasks (`drlab dataset --ray`). Each task rebuilds the plan from `cfg` (the generator is
    deterministic) and writes its files straight into `<out>.partial`, which must be on a path every
    node sees; no image travels through this process. This process then hashes the files and writes
    the manifest as a single-process render does, so the manifest's files and content hash are the
    same as a local render's on the same kind of machine (research.results.host).
    """
    cfg.validate()
    out = check_out(out, force=force)
    partial = partial_dir(out)
    cfg_dict = config_record(cfg)
    partial_state(partial, cfg_dict, resume, force)  # its errors too come before the lock file is created
    with dataset_lock(out):
        recover_swap(out)
        out = check_out(out, force=force)  # again, under the lock: another process may have finished it
        state = partial_state(partial, cfg_dict, resume, force)
        if state in ("unreadable", "force"):
            why = ("its configuration record is missing or unreadable" if state == "unreadable" else
                   "--force starts over (--resume would finish it)")
            notice(f"note: replacing {partial}: {why}")
            shutil.rmtree(partial)
        if partial.exists():
            atomic.sweep_temporary(partial)  # left by a killed run; nothing else writes here (we hold the lock)
        else:
            partial.mkdir(parents=True)
            atomic.write_json(partial / PARTIAL_CONFIG, cfg_dict)  # first, before any work
        _render(cfg, partial, show_progress, ray)
        commit(out, partial)
    return out


def _render(cfg: DatasetConfig, partial: Path, show_progress: bool, ray: Any = None) -> None:
    """Every file of the dataset, then manifest.json (and the verification cache), inside `partial`."""
    w = _Writer(cfg, partial)
    plan = w.multiview_plan()
    stereo_plan = w.stereo_plan() if cfg.stereo else []
    flow_cams = w.flow_cameras() if cfg.flow else []
    total = len(plan) + len(stereo_plan) + len(flow_cams)
    ray_variant = None
    if ray is not None:  # the tasks render every file; the loop below then finds them all and renders nothing
        ray_variant = _render_on_ray(cfg, partial, len(plan), len(stereo_plan), bool(flow_cams), ray, show_progress)
    with tqdm(total=total, desc=f"dataset {cfg.scene}", unit="view",
              disable=not show_progress or ray is not None) as bar:
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

    skip = {MANIFEST, PARTIAL_CONFIG, VERIFIED}
    files = {p.relative_to(partial).as_posix(): file_sha256(p)
             for p in sorted(partial.rglob("*")) if p.is_file() and p.relative_to(partial).as_posix() not in skip}
    variant = w._renderer.variant if w._renderer is not None else ray_variant or _recorded_variant(partial)
    atomic.write_json(partial / MANIFEST, {
        "generator": GENERATOR,
        "generator_revision": GENERATOR_REVISION,
        "config": config_record(cfg),
        "seed": cfg.seed,
        "scene": w.scene_info(),
        "mitsuba_variant": variant,
        "versions": versions(),
        "host": host(),
        "content_hash": content_hash(files),
        "files": files,
    })
    write_cache(partial, (partial / MANIFEST).read_bytes(), files)


_WORKER_WRITERS: dict[tuple[str, str], _Writer] = {}


def render_item(cfg_dict: dict[str, Any], partial: str, kind: str, index: int) -> str | None:
    """One Ray task of `drlab dataset --ray`: multi-view view `index`, stereo pair `index` or ("flow") the
    whole flow sequence (its frames share geometry), written into `partial`; the Mitsuba variant used.

    The writer (and its Mitsuba scene) is kept per worker process, so a worker's later tasks reuse it.
    """
    key = (json.dumps(cfg_dict, sort_keys=True), partial)
    w = _WORKER_WRITERS.get(key)
    if w is None:
        _WORKER_WRITERS.clear()
        w = _WORKER_WRITERS[key] = _Writer(DatasetConfig(**cfg_dict), Path(partial))
    if kind == "view":
        stem, _, cam, seed = w.multiview_plan()[index]
        w.render_view(stem, cam, seed)
    elif kind == "stereo":
        w.render_stereo_pair(*w.stereo_plan()[index])
    elif kind == "flow":
        w.render_flow(w.flow_cameras(), lambda: None)
    else:
        raise ValueError(f"unknown render task kind {kind!r}")
    return w._renderer.variant if w._renderer is not None else None


def _render_on_ray(cfg: DatasetConfig, partial: Path, views: int, pairs: int, flow: bool, opts: Any,
                   show_progress: bool) -> str | None:
    """Render every item as a Ray task (1 CPU each, worker deaths retried twice); the Mitsuba variant used."""
    from research.sweep import ray_session

    items = [("view", k) for k in range(views)] + [("stereo", k) for k in range(pairs)] + ([("flow", 0)] if flow else [])
    cfg_dict = config_record(cfg)
    variants = set()
    with ray_session(opts) as ray:
        task = ray.remote(render_item).options(num_cpus=1, max_retries=2, retry_exceptions=False)
        pending = [task.remote(cfg_dict, str(partial.absolute()), kind, k) for kind, k in items]
        with tqdm(total=len(items), desc=f"dataset {cfg.scene} (ray)", unit="task", disable=not show_progress) as bar:
            try:
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    variants.add(ray.get(done[0]))
                    bar.update()
            except BaseException:
                for ref in pending:
                    ray.cancel(ref, force=True)
                raise
    variants.discard(None)
    if len(variants) > 1:
        raise RuntimeError(f"the Ray workers rendered with different Mitsuba variants {sorted(variants)}; the "
                           "dataset would mix them")
    return variants.pop() if variants else None


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
    return (isinstance(recorded, dict) and recorded.get("config") == config_record(cfg)
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
        recover_swap(out)
        if _matches(out, cfg):
            verify(out)
            return out
        partial = partial_dir(out)
        recorded = partial_config(partial) if partial.is_dir() else None
        resume = recorded == config_record(cfg)
        if partial.exists() and not resume:
            why = "its configuration record is missing or unreadable" if recorded is None else \
                f"it was started with a different configuration ({config_diff(recorded, config_record(cfg))})"
            notice(f"note: replacing {partial}: {why}")
            shutil.rmtree(partial)
        return generate(cfg, out, resume=resume, force=out.exists(), show_progress=show_progress)
