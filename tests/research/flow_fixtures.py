"""Tiny flow-benchmark folders in each exact layout, written by the tests (nothing is downloaded).

Each writer returns what it wrote (uint8 frames, ground-truth flow, masks), so the tests can compare
what the readers give back. Frame 2 is frame 1 shifted by a whole number of pixels, so the estimators
have real texture and motion to work on; the ground truth is that shift plus a small sub-pixel field
(the readers do not care whether it is exact).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from research import io
from research.datasets.flow_benchmarks import kitti_encode

H, W = 96, 128  # the LK baseline's 4 levels need >= 9 px at the coarsest level


def texture(seed: int, h: int = H, w: int = W, grey: bool = False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = ndimage.gaussian_filter(rng.uniform(0, 1, (h, w, 3)), sigma=(2.0, 2.0, 0))
    img = (img - img.min()) / (img.max() - img.min())
    u8 = np.floor(img * 255 + 0.5).astype(np.uint8)
    return u8[..., 0] if grey else u8


def shifted(u8: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """Frame 2 for flow (dx, dy): frame2(x + dx, y + dy) = frame1(x, y) (wrapping at the borders)."""
    return np.roll(u8, (dy, dx), axis=(0, 1))


def gt_flow(seed: int, dx: float, dy: float, h: int = H, w: int = W) -> np.ndarray:
    rng = np.random.default_rng(seed + 1000)
    return (np.array([dx, dy], np.float32) + rng.uniform(-0.2, 0.2, (h, w, 2))).astype(np.float32)


def write_sintel(root: Path, scenes: dict[str, int] | None = None, invalid: bool = True) -> dict:
    """training/{clean,final,flow,occlusions,invalid}/<scene>/frame_NNNN.*; scenes: name -> frame count."""
    scenes = scenes or {"alley_1": 3, "cave_2": 2}
    base = root / "training"
    out = {}
    for s, (scene, n) in enumerate(scenes.items()):
        rec = {"clean": [], "final": [], "flow": [], "occluded": [], "invalid": []}
        clean = texture(10 * s)
        for k in range(1, n + 1):
            final = np.clip(clean.astype(int) + 12, 0, 255).astype(np.uint8)  # a different rendering
            for pass_, img in (("clean", clean), ("final", final)):
                (base / pass_ / scene).mkdir(parents=True, exist_ok=True)
                io.write_png_u8(base / pass_ / scene / f"frame_{k:04d}.png", img)
                rec[pass_].append(img)
            if k < n:
                flow = gt_flow(10 * s + k, 2.0, 1.0)
                occ = np.zeros((H, W), bool)
                occ[:, :2] = True  # revealed at the left border: no match in the next frame
                occ[10:20, 30:50] = True
                inv = np.zeros((H, W), bool)
                inv[0:4, 60:70] = True
                for name, arr in (("flow", flow),):
                    (base / name / scene).mkdir(parents=True, exist_ok=True)
                    io.write_flo(base / "flow" / scene / f"frame_{k:04d}.flo", arr)
                (base / "occlusions" / scene).mkdir(parents=True, exist_ok=True)
                io.write_png_u8(base / "occlusions" / scene / f"frame_{k:04d}.png", (occ * 255).astype(np.uint8))
                rec["flow"].append(flow)
                rec["occluded"].append(occ)
                rec["invalid"].append(inv)
            if invalid:
                (base / "invalid" / scene).mkdir(parents=True, exist_ok=True)
                inv_k = rec["invalid"][k - 1] if k < n else np.zeros((H, W), bool)
                io.write_png_u8(base / "invalid" / scene / f"frame_{k:04d}.png", (inv_k * 255).astype(np.uint8))
            clean = shifted(clean, 2, 1)
        out[scene] = rec
    return out


def kitti_pair(seed: int) -> dict:
    """One KITTI pair: frames, flow (multiples of 1/64 px), and the occ / noc known masks."""
    rng = np.random.default_rng(seed)
    img1 = texture(seed)
    flow = np.round(gt_flow(seed, 3.0, -1.0) * 64) / 64
    known_occ = rng.uniform(size=(H, W)) < 0.7  # sparse, as LiDAR ground truth is
    known_noc = known_occ.copy()
    known_noc[:, -3:] = False  # leaving the frame at the right border
    known_noc[40:50, 20:40] = False
    return {"frames": [img1, shifted(img1, 3, -1)], "flow": flow.astype(np.float32), "known_occ": known_occ,
            "known_noc": known_noc}


def write_object_map(path: Path, foreground: np.ndarray) -> None:
    """A KITTI 2015 obj_map as a palette PNG (Pillow): index 0 black background, objects 1 and 2 in colour."""
    from PIL import Image

    index = foreground.astype(np.uint8)
    index[:, : foreground.shape[1] // 2] *= 2  # two objects, two palette entries
    image = Image.fromarray(index, "P")
    image.putpalette([0, 0, 0, 142, 0, 0, 0, 0, 230])
    path.parent.mkdir(parents=True, exist_ok=True)
    image.save(path)


def write_kitti(root: Path, year: str = "2015", pairs: int = 2, objects: bool = False) -> dict:
    """training/{image_2|colored_0}/NNNNNN_1{0,1}.png, training/flow_{occ,noc}/NNNNNN_10.png, and with
    `objects` training/obj_map/NNNNNN_10.png (its foreground in the record)."""
    base = root / "training"
    image_dir = base / ("image_2" if year == "2015" else "colored_0")
    for d in (image_dir, base / "flow_occ", base / "flow_noc"):
        d.mkdir(parents=True, exist_ok=True)
    out = {}
    for n in range(pairs):
        rec = kitti_pair(100 + n)
        stem = f"{n:06d}"
        io.write_png_u8(image_dir / f"{stem}_10.png", rec["frames"][0])
        io.write_png_u8(image_dir / f"{stem}_11.png", rec["frames"][1])
        io.write_png_u16(base / "flow_occ" / f"{stem}_10.png", kitti_encode(rec["flow"], rec["known_occ"]))
        io.write_png_u16(base / "flow_noc" / f"{stem}_10.png", kitti_encode(rec["flow"], rec["known_noc"]))
        if objects:
            rec["foreground"] = np.zeros((H, W), bool)
            rec["foreground"][10 + 4 * n:30, 8:40] = True
            write_object_map(base / "obj_map" / f"{stem}_10.png", rec["foreground"])
        out[stem] = rec
    return out


def write_middlebury(root: Path, scenes: tuple[str, ...] = ("Grove2", "Venus")) -> dict:
    """other-data/<scene>/frame1{0,1}.png, other-gt-flow/<scene>/flow10.flo with unknown (1e10) pixels."""
    out = {}
    for s, scene in enumerate(scenes):
        grey = scene == "Venus"  # a grey sequence, read as colour
        img1 = texture(200 + s, grey=grey)
        flow = gt_flow(200 + s, -2.0, 1.0)
        unknown = np.zeros((H, W), bool)
        unknown[:8, :8] = True
        flow[unknown] = 1e10
        (root / "other-data" / scene).mkdir(parents=True, exist_ok=True)
        (root / "other-gt-flow" / scene).mkdir(parents=True, exist_ok=True)
        io.write_png_u8(root / "other-data" / scene / "frame10.png", img1)
        io.write_png_u8(root / "other-data" / scene / "frame11.png", shifted(img1, -2, 1))
        io.write_flo(root / "other-gt-flow" / scene / "flow10.flo", flow)
        out[scene] = {"frames": [img1, shifted(img1, -2, 1)], "flow": flow, "unknown": unknown}
    return out
