"""Readers of the optical-flow benchmarks' training folders: MPI-Sintel, KITTI 2012/2015 flow, Middlebury flow.

    from research.datasets.flow_benchmarks import open_benchmark
    bench = open_benchmark("data/MPI-Sintel", pass_="final")    # the format is detected, or give fmt=
    for item in bench.items:
        seq = bench.load(item)                                   # a research.datasets.loader.FlowSequence

Layouts (the folder given may be the benchmark's root or its `training/` folder):

* **MPI-Sintel** (`sintel`): `training/{clean,final}/<scene>/frame_NNNN.png` (frames 1..N),
  `training/flow/<scene>/frame_NNNN.flo` (flow k -> k + 1, k = 1..N-1), `training/occlusions/<scene>/
  frame_NNNN.png` (8-bit, white = occluded in frame k + 1; required) and `training/invalid/<scene>/
  frame_NNNN.png` (8-bit, white = invalid; optional, none invalid when the folder is absent). One
  FlowSequence per scene; `invalid` pixels are left out of every region of the Sintel protocol.
* **KITTI flow** (`kitti`): `training/flow_occ/NNNNNN_10.png` and `training/flow_noc/NNNNNN_10.png`,
  16-bit 3-channel PNGs holding u = (R - 2^15) / 64, v = (G - 2^15) / 64 and B = 1 where the flow is
  known (0: unknown; any B > 0 is read as known, as the KITTI devkit's readFlowField does); frames
  `image_2/NNNNNN_{10,11}.png` (KITTI 2015), else `colored_0/` or the grey `image_0/` (KITTI 2012). One
  two-frame FlowSequence per pair: `flow` from flow_occ, `valid` = flow_noc's known pixels, `valid_all` =
  flow_occ's, `occluded` = known in flow_occ only. With KITTI 2015's `obj_map/` folder every pair needs its
  `NNNNNN_10.png` there: `foreground` = its objects (> 0, read as the devkit reads it:
  research.datasets.stereo_benchmarks.read_kitti_object_map), for the Fl-bg / Fl-fg split.
* **Middlebury flow** (`middlebury`): `other-gt-flow/<scene>/flow10.flo` and `other-data/<scene>/
  frame10.png`, `frame11.png` (or `other-data-gray/`). Flow components above 1e9 mean unknown: such
  pixels are left out of `valid` and their flow is set to 0 (Middlebury gives no occlusion masks, so
  `valid` here is every known pixel, occluded or not).

`open_benchmark` checks the whole layout from file headers, before any pixel is read: every file a pair
needs exists, every image is a PNG of the expected bit depth and channels, every .flo's magic, size and
length are right, and the files of a pair share one size. Pixels are read per sequence by
`FlowBenchmark.load`, which checks them for meaning (flow_noc knows no pixel flow_occ does not; a .flo
holds no NaN; a PNG decodes to its end). `FlowBenchmark.verify` runs those reads over the pairs an
experiment will use before it starts work.
Every error is a DatasetError (a ValueError) of one line naming the file.

Frames are returned as drlab's sequences hold them: linear RGBA with alpha 1 (research.io.read_png
inverts the sRGB curve of the 8-bit PNG; research.flow.raft.srgb gives the stored values back),
grey frames repeated into three channels. The flow PNGs and .flo files go through research.io.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from research import io
from research.datasets.integrity import DatasetError, read_or_fail
from research.datasets.loader import FlowSequence
from research.datasets.stereo_benchmarks import read_kitti_object_map

FORMATS = ("sintel", "kitti", "middlebury")
PASSES = ("clean", "final")
UNKNOWN_FLOW = 1e9  # Middlebury: a component above this is unknown
KITTI_IMAGE_DIRS = (("image_2", "2015"), ("colored_0", "2012"), ("image_0", "2012"))

PROTOCOLS = {
    "sintel": "MPI-Sintel: EPE (px) over all, matched (visible in the next frame) and unmatched (occluded) "
              "pixels, invalid pixels left out, pooled over every pixel of every pair",
    "kitti": "KITTI flow: Fl-all (% of pixels with EPE > 3 px and > 5% of |gt|) and EPE (px) over noc "
             "(flow_noc) and occ (flow_occ, all known) pixels, pooled over every pixel of every pair",
    "middlebury": "Middlebury flow: EPE (px) and angular error AE (deg) over pixels with known flow, per "
                  "sequence and averaged over sequences",
}


# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class FlowItem:
    """The files of one sequence (Sintel scene) or pair (KITTI, Middlebury); checked by `open_benchmark`."""

    name: str
    frames: tuple[Path, ...]  # N images
    flows: tuple[Path, ...]  # N - 1 ground truths: .flo, or KITTI's flow_occ PNG
    noc: tuple[Path, ...] = ()  # KITTI flow_noc PNGs
    occlusions: tuple[Path, ...] = ()  # Sintel occlusion masks
    invalid: tuple[Path, ...] = ()  # Sintel invalid masks (empty: none invalid)
    objects: tuple[Path, ...] = ()  # KITTI 2015 obj_map PNGs (empty: no foreground split)
    size: tuple[int, int] = (0, 0)  # width, height

    @property
    def pairs(self) -> int:
        return len(self.flows)


@dataclass(frozen=True)
class FlowBenchmark:
    """A checked benchmark folder: its format, names for tables, and its sequences' files."""

    format: str
    dataset: str  # e.g. "MPI-Sintel training (final pass)", "KITTI 2015 flow training"
    protocol: str
    root: Path
    pass_: str | None
    items: list[FlowItem] = field(default_factory=list)
    year: str | None = None  # KITTI: "2012" or "2015"

    @property
    def pairs(self) -> int:
        return sum(i.pairs for i in self.items)

    def load(self, item: FlowItem) -> FlowSequence:
        """Read one sequence's pixels (module docstring)."""
        return _LOADERS[self.format](item)

    def verify(self, items: list[FlowItem] | None = None) -> None:
        """Read every file of `items` (default: all) once and drop the pixels: what the header check cannot
        see (a PNG cut short after its header, NaN in a .flo, a flow_noc that knows more than flow_occ) is
        refused before an experiment starts work, one sequence in memory at a time."""
        for item in self.items if items is None else items:
            self.load(item)


# --------------------------------------------------------------------------- header checks


def _png_header(path: Path) -> tuple[int, int, int, int]:
    """(width, height, channels, bits per sample) of a PNG, from its header alone."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        why = (oiio.geterror().strip().splitlines() or ["unknown reason"])[0]
        raise DatasetError(f"{path}: not a readable image ({why})")
    try:
        if inp.format_name() != "png":
            raise DatasetError(f"{path}: expected a PNG file, got {inp.format_name()}")
        spec = inp.spec()
        bits = {"uint8": 8, "uint16": 16}.get(str(spec.format), 0)  # 0: anything else (1-bit, float...)
        return spec.width, spec.height, spec.nchannels, bits
    finally:
        inp.close()


def _check_png(path: Path, bits: int, channels: tuple[int, ...], what: str) -> tuple[int, int]:
    w, h, c, b = _png_header(path)
    if b != bits or c not in channels:
        want = "/".join(map(str, channels))
        raise DatasetError(f"{path}: expected {what} ({bits}-bit, {want} channel{'s' if channels != (1,) else ''}), "
                           f"got {f'a {b}-bit PNG' if b else 'a PNG of another bit depth'} with {c} channel"
                           f"{'s' if c != 1 else ''}")
    return w, h


def _flo_size(path: Path) -> tuple[int, int]:
    """(width, height) of a .flo from its 12-byte header, its length checked against them."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing")
    with open(path, "rb") as f:
        head = f.read(12)
    if len(head) < 12:
        raise DatasetError(f"{path}: too short for a .flo header ({len(head)} bytes)")
    if np.frombuffer(head, "<f4", count=1)[0] != io.FLO_MAGIC:
        raise DatasetError(f"{path}: not a .flo file (magic {head[:4]!r}, expected b'PIEH')")
    w, h = (int(v) for v in np.frombuffer(head, "<i4", count=2, offset=4))
    if w <= 0 or h <= 0:
        raise DatasetError(f"{path}: invalid .flo size {w}x{h}")
    expected = 12 + 8 * w * h
    size = path.stat().st_size
    if size != expected:
        raise DatasetError(f"{path}: truncated or padded .flo: {size} bytes, expected {expected} for {w}x{h}")
    return w, h


def _same_size(path: Path, size: tuple[int, int], ref: Path, ref_size: tuple[int, int]) -> None:
    if size != ref_size:
        raise DatasetError(f"{path}: is {size[0]}x{size[1]}, expected {ref_size[0]}x{ref_size[1]} like {ref}")


def _check_item(item: FlowItem, flow_sizer) -> FlowItem:
    """Every file of an item exists, has the right kind, and one size; returns it with its size."""
    ref = item.frames[0]
    ref_size = _check_png(ref, 8, (1, 3, 4), "an 8-bit image")
    for p in item.frames[1:]:
        _same_size(p, _check_png(p, 8, (1, 3, 4), "an 8-bit image"), ref, ref_size)
    for p in item.flows + item.noc:
        _same_size(p, flow_sizer(p), ref, ref_size)
    for p in item.occlusions + item.invalid:
        _same_size(p, _check_png(p, 8, (1,), "an 8-bit grey mask"), ref, ref_size)
    for p in item.objects:  # any PNG form the devkit reads: here only its presence and size
        _same_size(p, _png_header(p)[:2], ref, ref_size)
    return replace(item, size=ref_size)


def _kitti_flow_size(path: Path) -> tuple[int, int]:
    return _check_png(path, 16, (3,), "a KITTI flow PNG")


# --------------------------------------------------------------------------- layouts


def _base(root: Path, marker: str) -> Path | None:
    for base in (root / "training", root):
        if (base / marker).is_dir():
            return base
    return None


def detect_format(path: str | Path) -> str | None:
    """The format whose layout `path` holds (module docstring), or None."""
    root = Path(path)
    if _base(root, "flow") is not None and any(_base(root, "flow").joinpath(p).is_dir() for p in PASSES):
        return "sintel"
    if _base(root, "flow_occ") is not None:
        return "kitti"
    if (root / "other-gt-flow").is_dir():
        return "middlebury"
    return None


_EXPECTED = {
    "sintel": "training/flow/<scene>/frame_NNNN.flo beside training/{clean,final}/",
    "kitti": "training/flow_occ/NNNNNN_10.png",
    "middlebury": "other-gt-flow/<scene>/flow10.flo",
}


def open_benchmark(path: str | Path, fmt: str | None = None, pass_: str | None = None) -> FlowBenchmark:
    """Check a benchmark folder's layout from headers (module docstring) and list its sequences.

    `fmt`: one of FORMATS, or None to detect it. `pass_`: Sintel's "clean" (default) or "final"; the
    other formats have no pass and refuse one.
    """
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such folder")
    if fmt is not None and fmt not in FORMATS:
        raise ValueError(f"format: expected one of {FORMATS}, got {fmt!r}")
    if pass_ is not None and pass_ not in PASSES:
        raise ValueError(f"pass: expected one of {PASSES}, got {pass_!r}")
    found = detect_format(root)
    fmt = fmt or found
    if fmt is None:
        raise DatasetError(f"{root}: not a Sintel, KITTI flow or Middlebury flow folder (expected one of "
                           + "; ".join(_EXPECTED.values()) + ")")
    if found != fmt:
        raise DatasetError(f"{root}: not a {fmt} folder (expected {_EXPECTED[fmt]})")
    if pass_ is not None and fmt != "sintel":
        raise ValueError(f"pass: only MPI-Sintel has clean and final passes, and {root} is a {fmt} folder")
    return {"sintel": _open_sintel, "kitti": _open_kitti, "middlebury": _open_middlebury}[fmt](root, pass_)


def _numbered(folder: Path, pattern: str) -> dict[int, Path]:
    rx = re.compile(pattern)
    out = {}
    for p in folder.iterdir():
        m = rx.fullmatch(p.name)
        if m:
            out[int(m.group(1))] = p
    return out


def _subfolders(folder: Path, what: str) -> list[str]:
    """The names of `folder`'s subfolders, sorted; a DatasetError when it has none."""
    names = sorted(p.name for p in folder.iterdir() if p.is_dir())
    if not names:
        raise DatasetError(f"{folder}: holds no {what} folders")
    return names


def _open_sintel(root: Path, pass_: str | None) -> FlowBenchmark:
    pass_ = pass_ or "clean"
    base = _base(root, "flow")
    frames_dir, flow_dir, occ_dir, inv_dir = (base / pass_, base / "flow", base / "occlusions", base / "invalid")
    if not frames_dir.is_dir():
        raise DatasetError(f"{frames_dir}: missing (the {pass_} pass's frames)")
    if not occ_dir.is_dir():
        raise DatasetError(f"{occ_dir}: missing (the matched / unmatched regions need Sintel's occlusion masks)")
    scenes = _subfolders(flow_dir, "scene")
    items = []
    for scene in scenes:
        flows = _numbered(flow_dir / scene, r"frame_(\d{4})\.flo")
        if not flows:
            raise DatasetError(f"{flow_dir / scene}: holds no frame_NNNN.flo")
        first, last = min(flows), max(flows)
        for k in range(first, last + 1):
            if k not in flows:
                raise DatasetError(f"{flow_dir / scene / f'frame_{k:04d}.flo'}: missing (the scene's flows run "
                                   f"from frame_{first:04d} to frame_{last:04d})")
        ks = range(first, last + 1)
        frames = tuple(frames_dir / scene / f"frame_{k:04d}.png" for k in range(first, last + 2))
        occ = tuple(occ_dir / scene / f"frame_{k:04d}.png" for k in ks)
        inv = tuple(inv_dir / scene / f"frame_{k:04d}.png" for k in ks) if inv_dir.is_dir() else ()
        item = FlowItem(scene, frames, tuple(flows[k] for k in ks), occlusions=occ, invalid=inv)
        items.append(_check_item(item, _flo_size))
    return FlowBenchmark("sintel", f"MPI-Sintel training ({pass_} pass)", PROTOCOLS["sintel"], root, pass_, items)


def _open_kitti(root: Path, pass_: str | None) -> FlowBenchmark:
    base = _base(root, "flow_occ")
    image_dir, year = next(((base / d, y) for d, y in KITTI_IMAGE_DIRS if (base / d).is_dir()), (None, None))
    if image_dir is None:
        raise DatasetError(f"{base}: holds no frame folder (expected image_2/ for KITTI 2015, colored_0/ or "
                           "image_0/ for KITTI 2012)")
    noc_dir = base / "flow_noc"
    if not noc_dir.is_dir():
        raise DatasetError(f"{noc_dir}: missing (the noc region needs KITTI's flow_noc maps)")
    pairs = _numbered(base / "flow_occ", r"(\d{6})_10\.png")
    if not pairs:
        raise DatasetError(f"{base / 'flow_occ'}: holds no NNNNNN_10.png flow maps")
    obj_dir = base / "obj_map"
    items = []
    for n in sorted(pairs):
        stem = f"{n:06d}"
        objects = (obj_dir / f"{stem}_10.png",) if obj_dir.is_dir() else ()
        item = FlowItem(stem, (image_dir / f"{stem}_10.png", image_dir / f"{stem}_11.png"), (pairs[n],),
                        noc=(noc_dir / f"{stem}_10.png",), objects=objects)
        items.append(_check_item(item, _kitti_flow_size))
    protocol = PROTOCOLS["kitti"] + ("; KITTI 2012's Out (% of pixels with EPE > 3 px) beside it" if year == "2012"
                                     else "")
    if obj_dir.is_dir():
        protocol += "; Fl-bg and Fl-fg over obj_map's background and objects (> 0)"
    return FlowBenchmark("kitti", f"KITTI {year} flow training ({image_dir.name})", protocol, root, None, items,
                         year)


def _open_middlebury(root: Path, pass_: str | None) -> FlowBenchmark:
    gt_dir = root / "other-gt-flow"
    data_dir = next((root / d for d in ("other-data", "other-data-gray") if (root / d).is_dir()), None)
    if data_dir is None:
        raise DatasetError(f"{root / 'other-data'}: missing (the frames of the other-gt-flow sequences)")
    scenes = _subfolders(gt_dir, "sequence")
    items = []
    for scene in scenes:
        item = FlowItem(scene, (data_dir / scene / "frame10.png", data_dir / scene / "frame11.png"),
                        (gt_dir / scene / "flow10.flo",))
        items.append(_check_item(item, _flo_size))
    return FlowBenchmark("middlebury", f"Middlebury flow ({data_dir.name}, other-gt-flow)", PROTOCOLS["middlebury"],
                         root, None, items)


# --------------------------------------------------------------------------- pixels


def _frame(path: Path, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 4) linear RGBA, alpha 1, from an 8-bit sRGB PNG (grey repeated, a stored alpha dropped)."""
    rgb = read_or_fail(lambda p: io.read_png(p, linear=True), path)
    c = rgb.shape[2]
    rgb = np.repeat(rgb[..., :1], 3, axis=2) if c in (1, 2) else rgb[..., :3]
    if rgb.shape[:2] != (size[1], size[0]):
        raise DatasetError(f"{path}: is {rgb.shape[1]}x{rgb.shape[0]}, expected {size[0]}x{size[1]}")
    return np.concatenate([rgb, np.ones(rgb.shape[:2] + (1,), np.float32)], axis=2)


def _mask(path: Path) -> np.ndarray:
    return read_or_fail(io.read_png_u8, path)[..., 0] > 127


def _flo(path: Path) -> np.ndarray:
    flow = read_or_fail(io.read_flo, path)
    if np.isnan(flow).any():
        raise DatasetError(f"{path}: holds {int(np.isnan(flow).sum())} NaN flow values")
    return flow


def kitti_decode(codes: np.ndarray, path: Path | str = "flow") -> tuple[np.ndarray, np.ndarray]:
    """Flow (H, W, 2) float32 and known (H, W) bool from a KITTI flow PNG's uint16 (H, W, 3) codes.

    u = (R - 2^15) / 64, v = (G - 2^15) / 64, known where B > 0 (the devkit's test; KITTI writes 1);
    unknown pixels get flow 0.
    """
    if codes.dtype != np.uint16 or codes.ndim != 3 or codes.shape[2] != 3:
        raise DatasetError(f"{path}: expected 16-bit 3-channel KITTI flow codes, got {codes.dtype} {codes.shape}")
    known = codes[..., 2] > 0
    flow = (codes[..., :2].astype(np.float32) - np.float32(2 ** 15)) / np.float32(64.0)
    return np.where(known[..., None], flow, np.float32(0.0)), known


def kitti_encode(flow: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The uint16 (H, W, 3) codes of a KITTI flow PNG: the inverse of `kitti_decode` (flow rounded to 1/64 px)."""
    flow = np.asarray(flow, dtype=np.float64)
    if flow.ndim != 3 or flow.shape[2] != 2 or known.shape != flow.shape[:2]:
        raise ValueError(f"flow, known: expected (H, W, 2) and (H, W), got {flow.shape} and {known.shape}")
    known = known.astype(bool)
    if known.any() and np.abs(flow[known]).max() >= 2 ** 15 / 64:
        raise ValueError(f"flow: KITTI's PNG holds |flow| < 512 px, got {float(np.abs(flow[known]).max()):.6g}")
    codes = np.where(known[..., None], np.rint(flow * 64.0 + 2 ** 15), 2 ** 15)
    return np.concatenate([codes, known[..., None]], axis=2).astype(np.uint16)


def _load_sintel(item: FlowItem) -> FlowSequence:
    frames = np.stack([_frame(p, item.size) for p in item.frames])
    flow = np.stack([_flo(p) for p in item.flows])
    occluded = np.stack([_mask(p) for p in item.occlusions])
    invalid = (np.stack([_mask(p) for p in item.invalid]) if item.invalid
               else np.zeros(occluded.shape, dtype=bool))
    return FlowSequence([], frames, None, flow, ~occluded & ~invalid, name=item.name, occluded=occluded & ~invalid,
                        invalid=invalid, valid_all=~invalid)


def _load_kitti(item: FlowItem) -> FlowSequence:
    frames = np.stack([_frame(p, item.size) for p in item.frames])
    flow, known_all = kitti_decode(read_or_fail(io.read_png_u16, item.flows[0]), item.flows[0])
    noc_flow, known_noc = kitti_decode(read_or_fail(io.read_png_u16, item.noc[0]), item.noc[0])
    if (known_noc & ~known_all).any():
        raise DatasetError(f"{item.noc[0]}: marks {int((known_noc & ~known_all).sum())} pixels known that "
                           f"{item.flows[0].name} in flow_occ does not")
    foreground = read_kitti_object_map(item.objects[0], known_all.shape)[None] if item.objects else None
    return FlowSequence([], frames, None, flow[None], known_noc[None], name=item.name,
                        occluded=(known_all & ~known_noc)[None], invalid=np.zeros((1,) + known_all.shape, bool),
                        valid_all=known_all[None], foreground=foreground)


def _load_middlebury(item: FlowItem) -> FlowSequence:
    frames = np.stack([_frame(p, item.size) for p in item.frames])
    flow = _flo(item.flows[0])
    known = np.all(np.abs(flow) <= UNKNOWN_FLOW, axis=-1)
    flow = np.where(known[..., None], flow, np.float32(0.0))
    return FlowSequence([], frames, None, flow[None], known[None], name=item.name, valid_all=known[None])


_LOADERS = {"sintel": _load_sintel, "kitti": _load_kitti, "middlebury": _load_middlebury}


def load_flow_benchmark(path: str | Path, fmt: str | None = None, pass_: str | None = None) -> list[FlowSequence]:
    """Every sequence of a benchmark folder, read at once (`open_benchmark`, then `FlowBenchmark.load`)."""
    bench = open_benchmark(path, fmt, pass_)
    return [bench.load(item) for item in bench.items]
