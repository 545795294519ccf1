"""Synthetic tracking data with ground truth.

1. `circular_trajectory`: the Kalman task of the Video and 3D Vision textbook chapter,
   a point on a circle.

2. `make_sequence`: a multi-object video. Rectangular "people" (two-tone:
   a top and a bottom colour) move in a W x H frame with varied dynamics
   (constant velocity, constant turn, weaving, stop-and-go, random
   acceleration), bounce off the frame edges, change size slowly, and occlude
   each other by depth order; static pillars (full-height bars, at least
   80 px apart) occlude everything. Every object stays in the frame for the
   whole sequence. Ground truth per frame: amodal boxes, ids and visibility
   (fraction of the box's pixels that show the object, from the label map).

   The detector is simulated from the ground truth, with the failure modes of
   a real detector:
   * missed: never when visibility < min_visibility; otherwise detected with
     probability p_detect * clip((v - min_visibility) / (full_visibility - min_visibility), 0, 1);
   * score = sigmoid(score_slope (v - score_mid) + N(0, score_noise^2)): partly
     occluded objects get low confidence (the effect ByteTrack exploits);
   * box: pulled toward the bounding box of the visible pixels by
     visible_pull (1 - v), then jittered with centre noise
     box_noise (1 + occluded_noise (1 - v)) [w, h] and log-normal size noise;
   * false positives: Poisson(fp_rate) random boxes per frame with
     Beta(fp_beta) scores, plus n_clutter fixed background spots that fire with
     probability clutter_rate per frame (a poster or a reflection that
     looks like a person) with low scores.

   Frames are rendered on demand by `Sequence.render(t)` (uint8 RGB: a muted
   textured background, the objects with a slow per-object brightness
   change, the pillars, and zero-mean uniform pixel noise), so that
   appearance embeddings are computed from pixels, not from hidden labels.
   The clutter spots are not drawn: their crops show background.

All randomness comes from the seed.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage


def circular_trajectory(
    n_steps: int = 50,
    radius: float = 10.0,
    centre: tuple[float, float] = (20.0, 20.0),
    phase: float = 0.0,
    direction: float = 1.0,
) -> np.ndarray:
    """The chapter's trajectory: n_steps points of one turn, angles linspace(0, 2 pi)."""
    t = np.linspace(0.0, 2.0 * np.pi, n_steps)
    a = phase + direction * t
    return np.stack([radius * np.cos(a) + centre[0], radius * np.sin(a) + centre[1]], axis=1)


@dataclass(frozen=True)
class SceneConfig:
    width: int = 640
    height: int = 360
    n_objects: int = 10
    n_frames: int = 300
    width_range: tuple[float, float] = (26.0, 56.0)
    aspect_range: tuple[float, float] = (1.3, 2.6)  # height / width
    speed_range: tuple[float, float] = (0.8, 3.5)  # pixels per frame
    n_pillars: int = 2
    pillar_width_range: tuple[float, float] = (22.0, 40.0)
    pixel_noise: float = 6.0  # std of the per-pixel noise, in 0..255 units
    dynamics: tuple[str, ...] = ("constant_velocity", "turning", "weaving", "stop_and_go", "random_accel")


@dataclass(frozen=True)
class DetectorConfig:
    min_visibility: float = 0.15
    full_visibility: float = 0.5
    p_detect: float = 0.95
    score_mid: float = 0.6
    score_slope: float = 10.0
    score_noise: float = 0.6
    box_noise: float = 0.04
    occluded_noise: float = 2.0
    size_noise: float = 0.05
    visible_pull: float = 0.5
    fp_rate: float = 0.5
    fp_beta: tuple[float, float] = (1.3, 4.0)
    n_clutter: int = 2
    clutter_rate: float = 0.35
    clutter_beta: tuple[float, float] = (2.0, 5.0)


@dataclass
class Sequence:
    """A generated sequence. Per-frame lists have length n_frames."""

    config: SceneConfig
    seed: int
    gt_ids: list[np.ndarray]  # (N,) int
    gt_boxes: list[np.ndarray]  # (N, 4) xyxy, amodal
    gt_visibility: list[np.ndarray]  # (N,) in [0, 1]
    dets: list[np.ndarray]  # (K, 5) [x1, y1, x2, y2, score]
    det_gt: list[np.ndarray]  # (K,) GT id of each detection, -1 for a false positive
    dynamics: list[str]  # dynamics kind of each object
    colours: np.ndarray  # (N, 2, 3) top and bottom colour, RGB in [0, 1]
    brightness: np.ndarray  # (n_frames, N) lighting factor
    pillars: list[tuple[int, int]]  # column spans [c0, c1)
    background: np.ndarray = field(repr=False)  # (H, W, 3) float32 in [0, 1]

    @property
    def n_frames(self) -> int:
        return len(self.gt_ids)

    def gt_frames(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return list(zip(self.gt_ids, self.gt_boxes))

    def render(self, t: int) -> np.ndarray:
        """Frame t as uint8 RGB (H, W, 3): background, objects far to near, pillars, noise."""
        cfg = self.config
        img = self.background.copy()
        for k in range(len(self.gt_ids[t])):  # gt order is far to near (painter's order)
            r0, r1, c0, c1 = _pixel_span(self.gt_boxes[t][k], cfg.width, cfg.height)
            split = r0 + int(round(0.45 * (r1 - r0)))
            obj = int(self.gt_ids[t][k])
            light = self.brightness[t, obj]
            img[r0:split, c0:c1] = self.colours[obj, 0] * light
            img[split:r1, c0:c1] = self.colours[obj, 1] * light
        for c0, c1 in self.pillars:
            img[:, c0:c1] = _PILLAR_RGB
        # Zero-mean uniform pixel noise with std pixel_noise (uniform: cheaper to draw than normal).
        rng = np.random.default_rng([self.seed, 7, t])
        noise = rng.random(img.shape, dtype=np.float32)
        noise -= np.float32(0.5)
        noise *= np.float32(np.sqrt(12.0) * cfg.pixel_noise / 255.0)
        img += noise
        np.clip(img, 0.0, 1.0, out=img)
        img *= np.float32(255.0)
        img += np.float32(0.5)
        return img.astype(np.uint8)


_PILLAR_RGB = np.array([0.42, 0.40, 0.38], dtype=np.float32)


def _pixel_span(box: np.ndarray, width: int, height: int) -> tuple[int, int, int, int]:
    """Rows [r0, r1) and columns [c0, c1) of the pixels whose centres lie in the box."""
    c0 = int(np.clip(np.ceil(box[0] - 0.5), 0, width))
    c1 = int(np.clip(np.ceil(box[2] - 0.5), 0, width))
    r0 = int(np.clip(np.ceil(box[1] - 0.5), 0, height))
    r1 = int(np.clip(np.ceil(box[3] - 0.5), 0, height))
    return r0, r1, c0, c1


def _random_colour(rng: np.random.Generator) -> np.ndarray:
    h = rng.uniform()
    s = rng.uniform(0.45, 0.95)
    v = rng.uniform(0.45, 0.95)
    return np.array(colorsys.hsv_to_rgb(h, s, v), dtype=np.float32)


def _simulate_centres(cfg: SceneConfig, sizes: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, list[str]]:
    """Centre trajectories (T, N, 2) with bouncing at the frame edges."""
    T, N = cfg.n_frames, cfg.n_objects
    kinds = [cfg.dynamics[i % len(cfg.dynamics)] for i in rng.permutation(N)]
    centres = np.zeros((T, N, 2))
    for n in range(N):
        half = 0.5 * sizes[:, n].max(axis=0)  # (w/2, h/2) at the largest scale
        lo = half + 1.0
        hi = np.array([cfg.width, cfg.height]) - half - 1.0
        p = rng.uniform(lo, hi)
        speed = rng.uniform(*cfg.speed_range)
        heading = rng.uniform(0, 2 * np.pi)
        omega = rng.choice([-1, 1]) * rng.uniform(0.01, 0.04)
        amp, period = rng.uniform(0.4, 0.9), rng.uniform(40, 100)
        go_period, go_phase = rng.uniform(60, 140), rng.uniform(0, 2 * np.pi)
        v_ou = speed * np.array([np.cos(heading), np.sin(heading)])
        v_mean = v_ou.copy()
        mirror = np.ones(2)
        for t in range(T):
            kind = kinds[n]
            if kind == "constant_velocity":
                v = speed * np.array([np.cos(heading), np.sin(heading)])
            elif kind == "turning":
                a = heading + omega * t
                v = speed * np.array([np.cos(a), np.sin(a)])
            elif kind == "weaving":
                a = heading + amp * np.sin(2 * np.pi * t / period)
                v = speed * np.array([np.cos(a), np.sin(a)])
            elif kind == "stop_and_go":
                s = speed * 1.4 * max(0.0, np.sin(2 * np.pi * t / go_period + go_phase))
                v = s * np.array([np.cos(heading), np.sin(heading)])
            elif kind == "random_accel":
                v_ou = v_ou + 0.08 * (v_mean - v_ou) + rng.normal(0.0, 0.35, 2)
                v = v_ou
            else:
                raise ValueError(f"unknown dynamics {kind!r}")
            centres[t, n] = p
            p = p + mirror * v
            for ax in range(2):  # mirror the motion at the edges
                if p[ax] < lo[ax] or p[ax] > hi[ax]:
                    mirror[ax] = -mirror[ax]
                    p[ax] = np.clip(2 * np.clip(p[ax], lo[ax], hi[ax]) - p[ax], lo[ax], hi[ax])
    return centres, kinds


def make_sequence(
    seed: int, scene: SceneConfig = SceneConfig(), detector: DetectorConfig = DetectorConfig()
) -> Sequence:
    """Generate one sequence: ground truth, visibility and simulated detections."""
    rng = np.random.default_rng([seed, 1])
    cfg = scene
    T, N, W, H = cfg.n_frames, cfg.n_objects, cfg.width, cfg.height

    base_w = rng.uniform(*cfg.width_range, N)
    base_h = base_w * rng.uniform(*cfg.aspect_range, N)
    s_period = rng.uniform(80, 200, N)
    s_phase = rng.uniform(0, 2 * np.pi, N)
    scale = 1.0 + 0.15 * np.sin(2 * np.pi * np.arange(T)[:, None] / s_period + s_phase)  # (T, N)
    sizes = np.stack([base_w * scale, base_h * scale], axis=-1)  # (T, N, 2)
    centres, kinds = _simulate_centres(cfg, sizes, rng)
    boxes = np.concatenate([centres - 0.5 * sizes, centres + 0.5 * sizes], axis=-1)  # (T, N, 4)

    depth_order = rng.permutation(N)  # far to near
    colours = np.stack([np.stack([_random_colour(rng), _random_colour(rng)]) for _ in range(N)])
    light_period = rng.uniform(60, 160, N)
    light_phase = rng.uniform(0, 2 * np.pi, N)
    brightness = (1.0 + 0.08 * np.sin(2 * np.pi * np.arange(T)[:, None] / light_period + light_phase)).astype(
        np.float32
    )
    pillars: list[tuple[int, int]] = []
    for _ in range(100 * cfg.n_pillars):  # rejection sampling: pillars at least 80 px apart
        if len(pillars) == cfg.n_pillars:
            break
        pw = rng.uniform(*cfg.pillar_width_range)
        c0 = int(rng.uniform(0.1 * W, 0.9 * W - pw))
        c1 = c0 + int(round(pw))
        if all(c1 + 80 <= a or c0 >= b + 80 for a, b in pillars):
            pillars.append((c0, c1))
    low = rng.uniform(0.3, 0.65, (H // 12 + 2, W // 12 + 2, 3))
    low = 0.6 * low + 0.4 * low.mean(axis=-1, keepdims=True)  # muted colours
    background = ndimage.zoom(low, (H / low.shape[0], W / low.shape[1], 1), order=1)[:H, :W].astype(np.float32)

    det_rng = np.random.default_rng([seed, 2])
    clutter = []
    for _ in range(detector.n_clutter):
        w = det_rng.uniform(*cfg.width_range)
        h = w * det_rng.uniform(*cfg.aspect_range)
        x, y = det_rng.uniform(0, W - w), det_rng.uniform(0, H - h)
        clutter.append(np.array([x, y, x + w, y + h]))

    gt_ids, gt_boxes, gt_vis, dets, det_gt = [], [], [], [], []
    label = np.zeros((H, W), dtype=np.int16)
    for t in range(T):
        label[:] = 0
        for n in depth_order:
            r0, r1, c0, c1 = _pixel_span(boxes[t, n], W, H)
            label[r0:r1, c0:c1] = n + 1
        for c0, c1 in pillars:
            label[:, c0:c1] = N + 1
        counts = np.bincount(label.ravel(), minlength=N + 2)
        vis = np.zeros(N)
        vis_box = boxes[t].copy()
        for n in range(N):
            r0, r1, c0, c1 = _pixel_span(boxes[t, n], W, H)
            area = max((r1 - r0) * (c1 - c0), 1)
            vis[n] = counts[n + 1] / area
            if counts[n + 1]:
                rows, cols = np.nonzero(label[r0:r1, c0:c1] == n + 1)
                vis_box[n] = [c0 + cols.min(), r0 + rows.min(), c0 + cols.max() + 1, r0 + rows.max() + 1]
        gt_ids.append(depth_order.astype(np.int64))
        gt_boxes.append(boxes[t, depth_order])
        gt_vis.append(vis[depth_order])
        d, g = _detect(boxes[t], vis, vis_box, clutter, cfg, detector, det_rng)
        dets.append(d)
        det_gt.append(g)

    return Sequence(
        config=cfg,
        seed=seed,
        gt_ids=gt_ids,
        gt_boxes=gt_boxes,
        gt_visibility=gt_vis,
        dets=dets,
        det_gt=det_gt,
        dynamics=kinds,
        colours=colours,
        brightness=brightness,
        pillars=pillars,
        background=background,
    )


def _sigmoid(x: np.ndarray | float) -> np.ndarray | float:
    return 1.0 / (1.0 + np.exp(-x))


def _detect(
    boxes: np.ndarray,
    vis: np.ndarray,
    vis_box: np.ndarray,
    clutter: list[np.ndarray],
    scene: SceneConfig,
    det: DetectorConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    rows, ids = [], []
    for n in range(len(boxes)):
        v = vis[n]
        ramp = np.clip((v - det.min_visibility) / (det.full_visibility - det.min_visibility), 0.0, 1.0)
        if v < det.min_visibility or rng.uniform() > det.p_detect * ramp:
            continue
        score = float(_sigmoid(det.score_slope * (v - det.score_mid) + rng.normal(0.0, det.score_noise)))
        target = boxes[n] + det.visible_pull * (1.0 - v) * (vis_box[n] - boxes[n])
        w, h = target[2] - target[0], target[3] - target[1]
        centre = 0.5 * (target[:2] + target[2:])
        centre = centre + rng.normal(0.0, det.box_noise * (1.0 + det.occluded_noise * (1.0 - v)), 2) * [w, h]
        w *= np.exp(rng.normal(0.0, det.size_noise))
        h *= np.exp(rng.normal(0.0, det.size_noise))
        rows.append([centre[0] - w / 2, centre[1] - h / 2, centre[0] + w / 2, centre[1] + h / 2, score])
        ids.append(n)
    for _ in range(rng.poisson(det.fp_rate)):
        w = rng.uniform(*scene.width_range)
        h = w * rng.uniform(*scene.aspect_range)
        x, y = rng.uniform(0, scene.width - w), rng.uniform(0, scene.height - h)
        rows.append([x, y, x + w, y + h, rng.beta(*det.fp_beta)])
        ids.append(-1)
    for b in clutter:
        if rng.uniform() < det.clutter_rate:
            jitter = rng.normal(0.0, 2.0, 4)
            rows.append([*(b + jitter), rng.beta(*det.clutter_beta)])
            ids.append(-1)
    if not rows:
        return np.zeros((0, 5)), np.zeros(0, dtype=np.int64)
    order = rng.permutation(len(rows))  # a detector's output order carries no identity
    return np.array(rows)[order], np.array(ids, dtype=np.int64)[order]
