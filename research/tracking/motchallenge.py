"""MOTChallenge (MOT15, MOT16, MOT17, MOT20) sequence folders: reader, the evaluation's preprocessing, result files.

Layout of one sequence folder `<seq>/` (the benchmark's train and test splits hold one per sequence):

    seqinfo.ini   [Sequence] name, imDir, frameRate, seqLength, imWidth, imHeight (imExt, default .jpg);
                  keys in any case (seqlength, SEQLENGTH), other keys and sections ignored, as TrackEval's
                  ConfigParser reads it
    det/det.txt   frame, id (-1), bb_left, bb_top, bb_width, bb_height, conf[, x, y, z]   (7 to 10 columns)
    gt/gt.txt     frame, id, bb_left, bb_top, bb_width, bb_height, consider, class, visibility   (9 columns;
                  8, without the visibility, as TrackEval reads it; absent in the test split)
                  MOT15 (2D MOT 2015): frame, id, bb_left, bb_top, bb_width, bb_height, consider, x, y, z
                  (10 columns, the world coordinates -1): no classes, every box a pedestrian
    <imDir>/000001<imExt> ...   the frames (optional here: only the appearance tracker reads them)

Text files are comma-separated (spaces around the commas and one trailing comma allowed) or, a
row without a comma, whitespace-separated, as TrackEval's reader takes them; blank lines are skipped.
Frames are numbered from 1 to seqLength; boxes are the top-left pixel corner and the size. drlab's
trackers take xyxy rows, with x2 = bb_left + bb_width and y2 = bb_top + bb_height (the same sums the
evaluation does, so no rounding differs). Detection scores are kept as the file gives them.

Ground-truth classes (MOT17 and MOT20): 1 pedestrian, 2 person on vehicle, 3 car, 4 bicycle,
5 motorbike, 6 non-motorized vehicle, 7 static person, 8 distractor, 9 occluder, 10 occluder on the
ground, 11 occluder full, 12 reflection, 13 crowd.

Evaluation (`evaluation_frames`), as TrackEval's MotChallenge2DBox preprocessing does it, frame by frame:
1. the tracker's boxes are matched to every ground-truth box (any class, consider flag 0 included)
   by a Hungarian matching that maximises the total IoU over pairs with IoU >= 0.5; a tracker box
   matched to a distractor class (2, 7, 8, 12, and for MOT20 also 6) is removed: it is neither a
   true nor a false positive;
2. only ground truth of class 1 (pedestrian) with a non-zero consider flag is kept.
The visibility column is read and returned (NaN where the file has none: MOT15, 8-column rows) but does
not enter the evaluation. MOT15 has no classes, so TrackEval skips step 1 for it and step 2 keeps every
box with a non-zero consider flag; here its boxes are all pedestrians and it has no distractor class,
which gives the same. The benchmark is the caller's (`load_sequence(benchmark=)`), else MOT20 for a
sequence named MOT20-..., MOT15 for a gt.txt of 10 columns (MOT15's world coordinates), else MOT17.

Result files (`write_results`) follow the MOTChallenge result format, one row per box:
`frame,id,bb_left,bb_top,bb_width,bb_height,conf,-1,-1,-1` (conf -1: the trackers report none).

Errors: a malformed file raises DatasetError (a ValueError) with one line naming the file and, where
it applies, the line number (`path:line: ...`), before any tracker runs.
"""

from __future__ import annotations

import configparser
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence as Seq

import numpy as np
from scipy.optimize import linear_sum_assignment

from research import atomic
from research.datasets.integrity import DatasetError
from research.tracking.metrics import box_iou

CLASS_NAMES = {1: "pedestrian", 2: "person_on_vehicle", 3: "car", 4: "bicycle", 5: "motorbike",
               6: "non_mot_vehicle", 7: "static_person", 8: "distractor", 9: "occluder",
               10: "occluder_on_ground", 11: "occluder_full", 12: "reflection", 13: "crowd"}
PEDESTRIAN = 1
DISTRACTORS = {"MOT15": (), "MOT17": (2, 7, 8, 12), "MOT20": (2, 6, 7, 8, 12)}  # MOT16 reads as MOT17
BENCHMARKS = tuple(DISTRACTORS)
SEQINFO_KEYS = ("name", "imDir", "frameRate", "seqLength", "imWidth", "imHeight")
DET_COLUMNS = ("frame", "id", "bb_left", "bb_top", "bb_width", "bb_height", "conf", "x", "y", "z")
GT_COLUMNS = ("frame", "id", "bb_left", "bb_top", "bb_width", "bb_height", "consider", "class", "visibility")
GT15_COLUMNS = ("frame", "id", "bb_left", "bb_top", "bb_width", "bb_height", "consider", "x", "y", "z")
_EPS = np.finfo(float).eps


@dataclass(frozen=True)
class SeqInfo:
    """The [Sequence] section of seqinfo.ini."""

    name: str
    im_dir: str
    frame_rate: float
    seq_length: int
    im_width: int
    im_height: int
    im_ext: str = ".jpg"


@dataclass
class GroundTruth:
    """gt.txt, per frame (index t = frame - 1): ids (N,), xyxy boxes (N, 4), consider flags (N,),
    classes (N,) and visibilities (N,)."""

    ids: list[np.ndarray]
    boxes: list[np.ndarray]
    consider: list[np.ndarray]
    classes: list[np.ndarray]
    visibility: list[np.ndarray]


@dataclass
class MOTSequence:
    root: Path
    info: SeqInfo
    benchmark: str  # "MOT15", "MOT17" or "MOT20": which classes are distractors
    dets: list[np.ndarray]  # per frame (N, 5) rows [x1, y1, x2, y2, score]
    gt: GroundTruth | None  # None when the folder has no gt/gt.txt (the test split)

    @property
    def name(self) -> str:
        return self.info.name

    @property
    def n_frames(self) -> int:
        return len(self.dets)

    def image_path(self, t: int) -> Path:
        """Frame t (0-based) of the image folder: <imDir>/<t + 1, six digits><imExt>."""
        return self.root / self.info.im_dir / f"{t + 1:06d}{self.info.im_ext}"

    def missing_images(self, n_frames: int | None = None) -> list[Path]:
        """The files of the first n_frames frames (all by default) that are not there."""
        n = self.n_frames if n_frames is None else min(n_frames, self.n_frames)
        return [p for p in (self.image_path(t) for t in range(n)) if not p.is_file()]

    def read_image(self, t: int) -> np.ndarray:
        """Frame t (0-based) as uint8 RGB (H, W, 3); a grey image is repeated over the channels."""
        return read_image_u8(self.image_path(t), (self.info.im_width, self.info.im_height))


# --------------------------------------------------------------------------- seqinfo.ini


def _ini_line(text: str, pattern: str) -> int | None:
    for i, line in enumerate(text.splitlines(), 1):
        if re.match(pattern, line.strip(), flags=re.IGNORECASE):
            return i
    return None


def read_seqinfo(path: str | Path) -> SeqInfo:
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: missing (a MOTChallenge sequence folder has seqinfo.ini)")
    text = path.read_text(errors="replace")
    cp = configparser.ConfigParser(interpolation=None)  # keys lower-cased, as TrackEval's ConfigParser reads them
    try:
        cp.read_string(text, source=str(path))
    except configparser.Error as e:
        line = getattr(e, "lineno", None)
        if line is None and getattr(e, "errors", None):  # ParsingError: [(lineno, line), ...]
            line = e.errors[0][0]
        where = f"{path}:{line}" if line else str(path)
        kind = {"MissingSectionHeaderError": "no [section] header before this line",
                "ParsingError": "expected key=value", "DuplicateOptionError": "a key appears twice",
                "DuplicateSectionError": "a section appears twice"}.get(type(e).__name__, type(e).__name__)
        raise DatasetError(f"{where}: not a valid ini file ({kind})") from None
    if not cp.has_section("Sequence"):
        raise DatasetError(f"{path}: expected a [Sequence] section")
    sec = cp["Sequence"]  # a SectionProxy: its keys are looked up case-insensitively
    head = _ini_line(text, r"\[Sequence\]")
    for key in SEQINFO_KEYS:
        if key not in sec:
            raise DatasetError(f"{path}:{head}: [Sequence] has no key {key!r} (expected {', '.join(SEQINFO_KEYS)})")

    def line_of(key: str) -> int | None:
        return _ini_line(text, key + r"\s*[=:]")

    def positive(key: str, kind: type):
        raw = sec[key].strip()
        try:
            v = kind(raw)
        except ValueError:
            v = None
        if v is None or not np.isfinite(v) or v <= 0:
            what = "an integer" if kind is int else "a number"
            raise DatasetError(f"{path}:{line_of(key)}: {key} expected {what} > 0, got {raw!r}")
        return v

    for key in ("name", "imDir"):
        if not sec[key].strip():
            raise DatasetError(f"{path}:{line_of(key)}: {key} expected a non-empty value")
    im_ext = sec.get("imExt", ".jpg").strip() or ".jpg"
    return SeqInfo(sec["name"].strip(), sec["imDir"].strip(), positive("frameRate", float),
                   positive("seqLength", int), positive("imWidth", int), positive("imHeight", int), im_ext)


# --------------------------------------------------------------------------- text files


def _tokens(line: str) -> list[str]:
    """The columns of one non-blank row: comma-separated (spaces around the commas and one trailing comma
    allowed), or whitespace-separated when the row has no comma, as TrackEval's reader takes them."""
    toks = [t.strip() for t in line.split(",")] if "," in line else line.split()
    if len(toks) > 1 and toks[-1] == "":  # a trailing comma, which TrackEval drops too
        toks.pop()
    return toks


def _read_table(path: Path, columns: Seq[str], min_cols: int, max_cols: int, n_frames: int,
                what: str, fill: float = -1.0) -> tuple[np.ndarray, np.ndarray]:
    """Rows of a MOTChallenge text file as float64 (N, max_cols), optional trailing columns that a row
    leaves out filled with `fill`, and each row's line number. Every check names the file and line."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    rows, lines = [], []
    with open(path, errors="replace") as f:
        for lineno, line in enumerate(f, 1):
            s = line.strip()
            if not s:
                continue
            toks = _tokens(s)
            if not (min_cols <= len(toks) <= max_cols):
                span = f"{min_cols}" if min_cols == max_cols else f"{min_cols} to {max_cols}"
                raise DatasetError(f"{path}:{lineno}: expected {span} comma-separated columns "
                                   f"({', '.join(columns[:min_cols])}{', ...' if max_cols > min_cols else ''}) "
                                   f"in a {what}, got {len(toks)}")
            vals = []
            for c, tok in enumerate(toks):
                try:
                    vals.append(float(tok))
                except ValueError:
                    raise DatasetError(f"{path}:{lineno}: column {c + 1} ({columns[c]}) expected a number, "
                                       f"got {tok!r}") from None
            vals += [fill] * (max_cols - len(vals))
            rows.append(vals)
            lines.append(lineno)
    data = np.array(rows, dtype=float).reshape(-1, max_cols)
    lines = np.array(lines, dtype=np.int64)

    def fail(mask: np.ndarray, message: Callable[[np.ndarray], str]) -> None:
        bad = np.flatnonzero(mask)
        if len(bad):
            raise DatasetError(f"{path}:{lines[bad[0]]}: {message(data[bad[0]])}")

    for c in range(min_cols):
        fail(~np.isfinite(data[:, c]), lambda r, c=c: f"{columns[c]} expected a finite number, got {r[c]:g}")
    frame = data[:, 0]
    fail((frame != np.round(frame)) | (frame < 1) | (frame > n_frames),
         lambda r: f"frame expected an integer in [1, {n_frames}] (seqLength), got {r[0]:g}")
    fail(data[:, 1] != np.round(data[:, 1]), lambda r: f"id expected an integer, got {r[1]:g}")
    fail((data[:, 4] <= 0) | (data[:, 5] <= 0),
         lambda r: f"bb_width and bb_height expected > 0, got {r[4]:g} x {r[5]:g}")
    return data, lines


def _by_frame(frame: np.ndarray, n_frames: int) -> list[np.ndarray]:
    """Row indices of each frame 1..n_frames, in file order."""
    order = np.argsort(frame, kind="stable")
    starts = np.searchsorted(frame[order], np.arange(1, n_frames + 2))
    return [order[starts[t]:starts[t + 1]] for t in range(n_frames)]


def _xyxy(data: np.ndarray) -> np.ndarray:
    return np.stack([data[:, 2], data[:, 3], data[:, 2] + data[:, 4], data[:, 3] + data[:, 5]], axis=1)


def read_detections(path: str | Path, n_frames: int) -> list[np.ndarray]:
    """det/det.txt -> per frame (N, 5) rows [x1, y1, x2, y2, score]."""
    data, _ = _read_table(Path(path), DET_COLUMNS, 7, 10, n_frames, "det.txt")
    rows = np.concatenate([_xyxy(data), data[:, 6:7]], axis=1)
    return [rows[idx] for idx in _by_frame(data[:, 0], n_frames)]


def read_ground_truth(path: str | Path, n_frames: int, benchmark: str = "MOT17") -> GroundTruth:
    """gt/gt.txt -> GroundTruth (module docstring: 8 or 9 columns, MOT15's 10); ids must be unique within
    a frame, classes 1..13, consider 0 or 1, visibility in [0, 1] where given."""
    path = Path(path)
    if benchmark == "MOT15":
        data, lines = _read_table(path, GT15_COLUMNS, 8, 10, n_frames, "MOT15 gt.txt")
        data = np.concatenate([data[:, :7], np.full((len(data), 1), float(PEDESTRIAN)),
                               np.full((len(data), 1), np.nan)], axis=1)
    else:
        data, lines = _read_table(path, GT_COLUMNS, 8, 9, n_frames, "gt.txt", fill=np.nan)
    checks = [
        (~np.isin(data[:, 7], list(CLASS_NAMES)), lambda r: f"class expected an integer in 1..13, got {r[7]:g}"),
        (~np.isin(data[:, 6], (0, 1)), lambda r: f"consider expected 0 or 1, got {r[6]:g}"),
        ((data[:, 8] < 0) | (data[:, 8] > 1), lambda r: f"visibility expected a number in [0, 1], got {r[8]:g}"),
    ]
    for mask, message in checks:
        bad = np.flatnonzero(mask)
        if len(bad):
            raise DatasetError(f"{path}:{lines[bad[0]]}: {message(data[bad[0]])}")
    per_frame = _by_frame(data[:, 0], n_frames)
    for idx in per_frame:
        ids = data[idx, 1]
        uniq, first, counts = np.unique(ids, return_index=True, return_counts=True)
        if np.any(counts > 1):
            dup = uniq[counts > 1][0]
            second = idx[np.flatnonzero(ids == dup)[1]]
            raise DatasetError(f"{path}:{lines[second]}: id {dup:g} appears twice in frame {data[second, 0]:g}")
    boxes = _xyxy(data)
    return GroundTruth(
        ids=[data[idx, 1].astype(np.int64) for idx in per_frame],
        boxes=[boxes[idx] for idx in per_frame],
        consider=[data[idx, 6].astype(np.int64) for idx in per_frame],
        classes=[data[idx, 7].astype(np.int64) for idx in per_frame],
        visibility=[data[idx, 8] for idx in per_frame],
    )


def _first_row_columns(path: Path) -> int:
    """The column count of a MOTChallenge file's first non-blank row (0 when it has none)."""
    with open(path, errors="replace") as f:
        for line in f:
            s = line.strip()
            if s:
                return len(_tokens(s))
    return 0


def benchmark_of(name: str, gt_path: Path | None = None) -> str:
    """"MOT20" for a sequence named MOT20-..., "MOT15" for a gt.txt of 10 columns, else "MOT17" (MOT16 and
    MOT17 share the classes)."""
    if name.upper().startswith("MOT20"):
        return "MOT20"
    if gt_path is not None and gt_path.is_file() and _first_row_columns(gt_path) == 10:
        return "MOT15"
    return "MOT17"


def load_sequence(path: str | Path, benchmark: str | None = None) -> MOTSequence:
    """One sequence folder (module docstring). `benchmark`: "MOT15", "MOT17" or "MOT20"; by default from the
    name and gt.txt (`benchmark_of`)."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such sequence folder")
    info = read_seqinfo(root / "seqinfo.ini")
    gt_path = root / "gt" / "gt.txt"
    if benchmark is None:
        benchmark = benchmark_of(info.name, gt_path)
    if benchmark not in DISTRACTORS:
        raise ValueError(f"benchmark: expected one of {BENCHMARKS}, got {benchmark!r}")
    dets = read_detections(root / "det" / "det.txt", info.seq_length)
    gt = read_ground_truth(gt_path, info.seq_length, benchmark) if gt_path.is_file() else None
    return MOTSequence(root, info, benchmark, dets, gt)


def find_sequences(path: str | Path) -> list[Path]:
    """Sequence folders under `path`: `path` itself when it holds seqinfo.ini, else its sub-folders
    (and theirs: MOT17/train/MOT17-02-FRCNN) that do, sorted."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such folder")
    if (root / "seqinfo.ini").is_file():
        return [root]
    found = sorted(p.parent for p in root.glob("*/seqinfo.ini"))
    if not found:
        found = sorted(p.parent for p in root.glob("*/*/seqinfo.ini"))
    return found


# --------------------------------------------------------------------------- images


def read_image_u8(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """A frame (JPEG, PNG, ...) as uint8 RGB (H, W, 3), through OpenImageIO; `size` (W, H) is checked."""
    import OpenImageIO as oiio

    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing frame")
    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        raise DatasetError(f"{path}: not a readable image ({buf.geterror()})")
    spec = buf.spec()
    pixels = buf.get_pixels(oiio.UINT8)
    if pixels is None or buf.has_error:
        raise DatasetError(f"{path}: corrupt or truncated image ({buf.geterror()})")
    pixels = np.asarray(pixels).reshape(spec.height, spec.width, spec.nchannels)
    if size is not None and (spec.width, spec.height) != tuple(size):
        raise DatasetError(f"{path}: image is {spec.width}x{spec.height}, seqinfo.ini says {size[0]}x{size[1]}")
    if spec.nchannels == 1 or spec.nchannels == 2:
        return np.repeat(pixels[..., :1], 3, axis=2)
    return np.ascontiguousarray(pixels[..., :3])


# --------------------------------------------------------------------------- evaluation


def distractor_matches(gt_boxes: np.ndarray, gt_classes: np.ndarray, hyp_boxes: np.ndarray,
                       benchmark: str) -> np.ndarray:
    """Indices of the tracker boxes that the evaluation removes in one frame (step 1 of the module
    docstring)."""
    if len(gt_boxes) == 0 or len(hyp_boxes) == 0:
        return np.zeros(0, dtype=np.int64)
    score = box_iou(gt_boxes, hyp_boxes)
    score[score < 0.5 - _EPS] = 0
    rows, cols = linear_sum_assignment(-score)
    matched = score[rows, cols] > _EPS
    rows, cols = rows[matched], cols[matched]
    return cols[np.isin(gt_classes[rows], DISTRACTORS[benchmark])]


def evaluation_frames(seq: MOTSequence, outputs: Seq[np.ndarray]
                      ) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[tuple[np.ndarray, np.ndarray]], int]:
    """Ground truth and tracker output of the first len(outputs) frames after the MOTChallenge
    preprocessing: (gt frames, tracker frames, tracker boxes removed), each frame (ids, xyxy boxes).
    `outputs` are tracker rows [x1, y1, x2, y2, id] per frame."""
    if seq.gt is None:
        raise DatasetError(f"{seq.root / 'gt' / 'gt.txt'}: missing; the sequence cannot be evaluated")
    if len(outputs) > seq.n_frames:
        raise ValueError(f"outputs: expected at most {seq.n_frames} frames, got {len(outputs)}")
    gt_frames, hyp_frames, removed = [], [], 0
    g = seq.gt
    for t, out in enumerate(outputs):
        out = np.asarray(out, dtype=float).reshape(-1, 5)
        drop = distractor_matches(g.boxes[t], g.classes[t], out[:, :4], seq.benchmark)
        keep = np.ones(len(out), bool)
        keep[drop] = False
        removed += int(len(drop))
        hyp_frames.append((out[keep, 4].astype(np.int64), out[keep, :4]))
        k = (g.consider[t] != 0) & (g.classes[t] == PEDESTRIAN)
        gt_frames.append((g.ids[t][k], g.boxes[t][k]))
    return gt_frames, hyp_frames, removed


# --------------------------------------------------------------------------- result files


def write_results(path: str | Path, outputs: Iterable[np.ndarray]) -> None:
    """Tracker rows [x1, y1, x2, y2, id] per frame (frame t + 1) -> a MOTChallenge result file
    (module docstring); values written with Python's shortest round-trip repr."""
    lines = []
    for t, rows in enumerate(outputs):
        rows = np.asarray(rows, dtype=float).reshape(-1, 5)
        if not np.all(np.isfinite(rows)):
            raise ValueError(f"outputs: frame {t + 1} has a non-finite value")
        for x1, y1, x2, y2, i in rows:
            if i != round(i):
                raise ValueError(f"outputs: frame {t + 1}: track id expected an integer, got {i!r}")
            lines.append(f"{t + 1},{int(i)},{float(x1)!r},{float(y1)!r},{float(x2 - x1)!r},{float(y2 - y1)!r},"
                         "-1,-1,-1,-1\n")
    atomic.write_text(path, "".join(lines))


def read_results(path: str | Path, n_frames: int) -> list[np.ndarray]:
    """A MOTChallenge result file -> tracker rows [x1, y1, x2, y2, id] per frame (n_frames frames)."""
    path = Path(path)
    data, lines = _read_table(path, DET_COLUMNS, 6, 10, n_frames, "result file")
    rows = np.concatenate([_xyxy(data), data[:, 1:2]], axis=1)
    out = []
    for idx in _by_frame(data[:, 0], n_frames):
        ids = rows[idx, 4]
        uniq, counts = np.unique(ids, return_counts=True)
        if np.any(counts > 1):
            second = idx[np.flatnonzero(ids == uniq[counts > 1][0])[1]]
            raise DatasetError(f"{path}:{lines[second]}: id {uniq[counts > 1][0]:g} appears twice in frame "
                               f"{data[second, 0]:g}")
        out.append(rows[idx])
    return out
