"""Tiny stereo benchmark folders in each benchmark's exact format, for the reader and experiment tests.

Written without drlab's writers: PNGs with OpenCV (8- and 16-bit), PFM by hand (little-endian,
bottom row first, inf = unknown), calib.txt and KITTI calibration files as text.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

H, W = 24, 48
NDISP = 16
CALIB = {"f": 100.0, "cx": 23.5, "cy": 11.5, "doffs": 2.5, "baseline": 193.001}


def write_pfm(path: Path, a: np.ndarray, little_endian: bool = True) -> None:
    h, w = a.shape
    scale = -1.0 if little_endian else 1.0
    data = np.ascontiguousarray(a[::-1], dtype="<f4" if little_endian else ">f4").tobytes()
    path.write_bytes(f"Pf\n{w} {h}\n{scale}\n".encode("ascii") + data)


def write_png(path: Path, a: np.ndarray) -> None:
    """uint8/uint16 grey (H, W) or RGB (H, W, 3) through OpenCV (which stores BGR, hence the flip)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    img = a[..., ::-1] if a.ndim == 3 else a
    assert cv2.imwrite(str(path), np.ascontiguousarray(img))


def scene(seed: int = 0, colour: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured left image, the right image it gives, and its disparity: 3 px background, 6 px square."""
    rng = np.random.default_rng(seed)
    pad = 16
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (H, W + pad, 3)).astype(np.float32), (0, 0), 0.8)
    disp = np.full((H, W), 3.0, np.float32)
    disp[6:18, 14:30] = 6.0
    left = np.zeros((H, W, 3), np.float32)
    right = np.zeros((H, W, 3), np.float32)
    xs = np.arange(W)
    for y in range(H):
        left[y] = tex[y, xs + pad]
        right[y] = tex[y, xs + pad]  # background first, then the square drawn over it
    for y in range(H):  # right(x - d) = left(x): move each left pixel by its disparity
        for x in np.argsort(disp[y]):
            xr = int(x - disp[y, x])
            if 0 <= xr < W:
                right[y, xr] = left[y, x]
    left8, right8 = (np.clip(np.rint(a), 0, 255).astype(np.uint8) for a in (left, right))
    if not colour:
        left8, right8 = left8[..., 1].copy(), right8[..., 1].copy()
    return left8, right8, disp


def calib_text(width: int = W, height: int = H, ndisp: int | None = NDISP, doffs: float = CALIB["doffs"],
               extra: str = "vmin=2\nvmax=7\n") -> str:
    f, cx, cy = CALIB["f"], CALIB["cx"], CALIB["cy"]
    lines = [f"cam0=[{f} 0 {cx}; 0 {f} {cy}; 0 0 1]", f"cam1=[{f} 0 {cx + doffs}; 0 {f} {cy}; 0 0 1]",
             f"doffs={doffs}", f"baseline={CALIB['baseline']}", f"width={width}", f"height={height}"]
    if ndisp is not None:
        lines.append(f"ndisp={ndisp}")
    return "\n".join(lines) + "\nisint=0\n" + extra


def middlebury_pair(folder: Path, seed: int = 0, colour: bool = True, gt_name: str = "disp0.pfm",
                    with_mask: bool = True, doffs: float = CALIB["doffs"]) -> dict:
    """A Middlebury 2014 pair folder; returns what was written (ground truth with inf, masks)."""
    folder.mkdir(parents=True, exist_ok=True)
    left, right, disp = scene(seed, colour)
    gt = disp.copy()
    gt[0:2, 0:5] = np.inf  # unknown
    occluded = np.zeros((H, W), bool)
    occluded[6:18, 30:33] = True  # right of the square, hidden in the right view
    write_png(folder / "im0.png", left)
    write_png(folder / "im1.png", right)
    write_pfm(folder / gt_name, gt)
    mask = np.where(np.isfinite(gt), np.where(occluded, 128, 255), 0).astype(np.uint8)
    if with_mask:
        write_png(folder / "mask0nocc.png", mask)
    (folder / "calib.txt").write_text(calib_text(doffs=doffs))
    return {"left": left, "right": right, "gt": gt, "mask": mask}


def eth3d_pair(folder: Path, seed: int = 0) -> dict:
    return middlebury_pair(folder, seed, colour=False, gt_name="disp0GT.pfm", doffs=0.0)


KITTI_F, KITTI_B = 72.0, 0.54


def kitti_folder(root: Path, version: int = 2015, ids: tuple[str, ...] = ("000000", "000001"),
                 calib: bool = True) -> dict:
    """A KITTI training folder (root/training); returns the raw 16-bit ground truths written."""
    t = root / "training"
    lname, rname = ("image_2", "image_3") if version == 2015 else ("colored_0", "colored_1")
    occ_dir, noc_dir = ("disp_occ_0", "disp_noc_0") if version == 2015 else ("disp_occ", "disp_noc")
    written = {}
    for k, i in enumerate(ids):
        left, right, disp = scene(k)
        raw_occ = np.rint(disp * 256).astype(np.uint16)
        raw_occ[::5, ::3] = 0  # LiDAR gaps: invalid
        raw_noc = raw_occ.copy()
        raw_noc[6:18, 30:33] = 0
        write_png(t / lname / f"{i}_10.png", left)
        write_png(t / rname / f"{i}_10.png", right)
        write_png(t / occ_dir / f"{i}_10.png", raw_occ)
        write_png(t / noc_dir / f"{i}_10.png", raw_noc)
        if version == 2015:
            obj = np.zeros((H, W), np.uint8)
            obj[6:18, 14:30] = 1
            write_png(t / "obj_map" / f"{i}_10.png", obj)
        if calib:
            P = lambda tx: " ".join(f"{v:.12e}" for v in  # noqa: E731
                                    [KITTI_F, 0, 23.5, tx, 0, KITTI_F, 11.5, 0, 0, 0, 1, 0])
            if version == 2015:
                (t / "calib_cam_to_cam").mkdir(parents=True, exist_ok=True)
                (t / "calib_cam_to_cam" / f"{i}.txt").write_text(
                    f"calib_time: 09-Jan-2012 13:57:47\nP_rect_02: {P(KITTI_F * 0.06)}\n"
                    f"P_rect_03: {P(KITTI_F * (0.06 - KITTI_B))}\n")
            else:
                (t / "calib").mkdir(parents=True, exist_ok=True)
                (t / "calib" / f"{i}.txt").write_text(
                    f"P0: {P(0)}\nP1: {P(-KITTI_F * KITTI_B)}\nP2: {P(KITTI_F * 0.06)}\n"
                    f"P3: {P(KITTI_F * (0.06 - KITTI_B))}\n")
        written[i] = {"occ": raw_occ, "noc": raw_noc, "left": left}
    return written


def write_pgm(path: Path, a: np.ndarray) -> None:
    """A binary (P5) PGM, 8-bit (maxval 255) for uint8, 16-bit big-endian (maxval 65535) for uint16."""
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = a.shape
    maxval = 255 if a.dtype == np.uint8 else 65535
    data = np.ascontiguousarray(a, dtype=">u2" if maxval > 255 else np.uint8).tobytes()
    path.write_bytes(f"P5\n{w} {h}\n{maxval}\n".encode("ascii") + data)


def middlebury2003_scene(folder: Path, seed: int = 0, scale: int = 4, tsukuba_names: bool = False,
                         pgm: bool = False, colour: bool = True) -> dict:
    """A Middlebury 2001/2003 scene folder: im2.png/im6.png/disp2.png (or im3/im4/disp3 as tsukuba), the
    ground truth stored as round(d * scale) in 8 bits with 0 = unknown (here the two left-most columns)."""
    left, right, disp = scene(seed, colour)
    lname, rname, gname = ("im3.png", "im4.png", "disp3") if tsukuba_names else ("im2.png", "im6.png", "disp2")
    write_png(folder / lname, left)
    write_png(folder / rname, right)
    raw = np.rint(disp * scale).astype(np.uint8)
    raw[:, :2] = 0
    (write_pgm if pgm else write_png)(folder / (gname + (".pgm" if pgm else ".png")), raw)
    return {"left": left, "right": right, "disparity": np.where(raw > 0, raw / scale, 0.0), "known": raw > 0}
