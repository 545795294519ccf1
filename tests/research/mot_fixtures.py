"""MOTChallenge sequence folders written by the tests, in the benchmark's exact layout.

`write_sequence` writes seqinfo.ini, det/det.txt (10 columns, id -1) and gt/gt.txt (9 columns; 8 without
the visibility; 10 in MOT15's layout, its class replaced by the world coordinates -1, -1, -1) of a
random sequence whose ground truth mixes pedestrians with distractor classes (person on vehicle,
static person, distractor, reflection, non-motorized vehicle), other classes (car, occluder) and
pedestrians with consider flag 0, and whose detections cover all of them with noise, misses and
false positives. `tracker_output` makes tracker rows with id swaps, fragmentation and boxes on the
distractors, for comparing metrics.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

# class of each object: pedestrians, then every kind the preprocessing treats differently
CLASSES = [1, 1, 1, 1, 1, 1, 2, 7, 8, 12, 6, 3, 9, 1]
CONSIDER = [1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0]  # last pedestrian: consider 0 (as MOT17 marks some)


def make_gt(rng: np.random.Generator, n_frames: int, width: int = 320, height: int = 240) -> np.ndarray:
    """gt.txt rows (frame, id, left, top, w, h, consider, class, visibility)."""
    rows = []
    n = len(CLASSES)
    start = rng.uniform([0, 0], [max(width - 40, 1), max(height - 80, 1)], (n, 2))
    vel = rng.normal(0, 2.0, (n, 2))
    size = rng.uniform([12, 30], [30, 70], (n, 2))
    life = np.sort(rng.integers(1, n_frames + 1, (n, 2)), axis=1)
    life[:4] = [1, n_frames]  # some live through the whole sequence
    for o in range(n):
        for f in range(life[o, 0], life[o, 1] + 1):
            x, y = start[o] + vel[o] * (f - 1)
            rows.append([f, o + 1, round(x, 2), round(y, 2), round(size[o, 0], 2), round(size[o, 1], 2),
                         CONSIDER[o], CLASSES[o], round(rng.uniform(0, 1), 3)])
    return np.array(sorted(rows, key=lambda r: (r[0], r[1])))


def make_dets(rng: np.random.Generator, gt: np.ndarray, n_frames: int) -> np.ndarray:
    """det.txt rows: noisy copies of 85 % of the gt boxes, plus false positives."""
    rows = []
    for r in gt:
        if rng.uniform() < 0.85:
            j = rng.normal(0, 1.5, 4)
            rows.append([r[0], -1, r[2] + j[0], r[3] + j[1], max(r[4] + j[2], 2), max(r[5] + j[3], 2),
                         rng.uniform(0.05, 1.0), -1, -1, -1])
    for f in range(1, n_frames + 1):
        for _ in range(rng.integers(0, 3)):
            rows.append([f, -1, *rng.uniform([0, 0, 10, 20], [280, 160, 40, 70]), rng.uniform(0, 0.7), -1, -1, -1])
    return np.array(sorted(rows, key=lambda r: r[0]))


def tracker_output(rng: np.random.Generator, gt: np.ndarray, n_frames: int) -> list[np.ndarray]:
    """Tracker rows [x1, y1, x2, y2, id] per frame: noisy gt boxes (distractors included) with id
    swaps, new ids after gaps (fragmentation), misses and false positives."""
    ids = {int(o): 100 + int(o) for o in np.unique(gt[:, 1])}
    out = []
    next_id = 500
    for f in range(1, n_frames + 1):
        g = gt[gt[:, 0] == f]
        if rng.uniform() < 0.1 and len(g) > 1:
            a, b = rng.choice(g[:, 1].astype(int), 2, replace=False)
            ids[a], ids[b] = ids[b], ids[a]
        rows = []
        for r in g:
            o = int(r[1])
            if rng.uniform() < 0.12:
                if rng.uniform() < 0.3:
                    ids[o] = next_id
                    next_id += 1
                continue
            j = rng.normal(0, rng.choice([0.5, 3.0, 8.0]), 4)
            x1, y1 = r[2] + j[0], r[3] + j[1]
            rows.append([x1, y1, x1 + max(r[4] + j[2], 1), y1 + max(r[5] + j[3], 1), ids[o]])
        for k in range(rng.integers(0, 2)):
            x, y = rng.uniform(0, 280), rng.uniform(0, 160)
            rows.append([x, y, x + 20, y + 50, 900 + k])
        out.append(np.array(rows, dtype=float).reshape(-1, 5))
    return out


def fmt(v: float) -> str:
    return repr(float(v)) if v != int(v) else str(int(v))


def _gt_text(gt: np.ndarray, gt_columns: int) -> str:
    """gt.txt of the 9-column rows `gt` in 9 columns, 8 (no visibility) or MOT15's 10 (no class, x y z = -1)."""
    if gt_columns == 10:
        gt = np.concatenate([gt[:, :7], -np.ones((len(gt), 3))], axis=1)
    elif gt_columns == 8:
        gt = gt[:, :8]
    elif gt_columns != 9:
        raise ValueError(f"gt_columns: expected 8, 9 or 10, got {gt_columns}")
    return "".join(",".join(fmt(v) for v in r) + "\n" for r in gt)


def write_sequence(root: Path, name: str = "MOT17-02-FRCNN", n_frames: int = 30, seed: int = 0,
                   images: bool = False, width: int = 320, height: int = 240,
                   gt_columns: int = 9) -> tuple[Path, np.ndarray, np.ndarray]:
    """Write a sequence folder root/name; returns (folder, gt rows (9 columns), det rows)."""
    rng = np.random.default_rng(seed)
    seq = root / name
    (seq / "det").mkdir(parents=True, exist_ok=True)
    (seq / "gt").mkdir(parents=True, exist_ok=True)
    (seq / "seqinfo.ini").write_text(
        f"[Sequence]\nname={name}\nimDir=img1\nframeRate=30\nseqLength={n_frames}\nimWidth={width}\n"
        f"imHeight={height}\nimExt=.jpg\n")
    gt = make_gt(rng, n_frames, width, height)
    dets = make_dets(rng, gt, n_frames)
    (seq / "gt" / "gt.txt").write_text(_gt_text(gt, gt_columns))
    (seq / "det" / "det.txt").write_text("".join(",".join(fmt(v) for v in r) + "\n" for r in dets))
    if images:
        import OpenImageIO as oiio

        (seq / "img1").mkdir(exist_ok=True)
        yy, xx = np.mgrid[0:height, 0:width]
        for f in range(1, n_frames + 1):
            img = np.stack([(xx + 3 * f) % 256, (yy * 2) % 256, np.full_like(xx, 90)], axis=-1).astype(np.uint8)
            for r in gt[gt[:, 0] == f]:
                x0, y0 = int(max(r[2], 0)), int(max(r[3], 0))
                x1, y1 = int(min(r[2] + r[4], width)), int(min(r[3] + r[5], height))
                colour = np.array([(37 * r[1]) % 256, (91 * r[1]) % 256, (53 * r[1]) % 256], dtype=np.uint8)
                img[y0:y1, x0:x1] = colour
            out = oiio.ImageOutput.create(str(seq / "img1" / f"{f:06d}.jpg"))
            out.open(str(seq / "img1" / f"{f:06d}.jpg"), oiio.ImageSpec(width, height, 3, oiio.UINT8))
            out.write_image(img)
            out.close()
    return seq, gt, dets
