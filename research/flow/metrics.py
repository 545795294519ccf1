"""The optical-flow benchmarks' evaluation protocols: Sintel, KITTI flow and Middlebury flow.

Per pixel, with flow (u, v) and ground truth (u', v'):

* EPE, the endpoint error: |(u, v) - (u', v')| in px;
* AE, Middlebury's angular error: the angle in degrees between (u, v, 1) and (u', v', 1),
  arccos((u u' + v v' + 1) / sqrt((u^2 + v^2 + 1) (u'^2 + v'^2 + 1)));
* a KITTI outlier: EPE > 3 px AND EPE > 5% of |(u', v')|. Fl is the percentage of outliers (KITTI
  2015's Fl; KITTI 2012's own tables count EPE > 3 px alone, Out-Noc / Out-All, reported beside it).

Regions (boolean masks over the pixels of a pair):

* Sintel (`sintel_regions`): all = pixels not invalid; matched = those visible in the next frame;
  unmatched = those occluded in it. EPE on each, pooled over every pixel of every pair.
* KITTI (`kitti_regions`): noc = known in flow_noc; occ = known in flow_occ (occluded or not). Fl and EPE
  on each, pooled over every pixel of every pair (outlier count / pixel count over the whole set).
* Middlebury (`middlebury_regions`): all = pixels with known flow. EPE and AE per sequence; the table
  averages the sequences.

`FlowTally` pools sums over pairs; `summary()` gives the means. A region with no pixel reports None
(no value) rather than a number. `sintel_metrics`, `kitti_metrics` and `middlebury_metrics` score one pair.
"""

from __future__ import annotations

import numpy as np

from research.datasets.loader import FlowSequence

KITTI_ABS_PX = 3.0
KITTI_REL = 0.05


def _pair(flow: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    flow, gt = np.asarray(flow, dtype=np.float64), np.asarray(gt, dtype=np.float64)
    if flow.ndim != 3 or flow.shape[-1] != 2:
        raise ValueError(f"flow: expected shape (H, W, 2), got {flow.shape}")
    if gt.shape != flow.shape:
        raise ValueError(f"gt: expected the shape of flow {flow.shape}, got {gt.shape}")
    if not np.all(np.isfinite(flow)):
        raise ValueError(f"flow: expected finite values, got {int((~np.isfinite(flow)).sum())} NaN or infinite")
    return flow, gt


def endpoint_error(flow: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W) |flow - gt| in px."""
    return _epe(*_pair(flow, gt))


def _epe(flow: np.ndarray, gt: np.ndarray) -> np.ndarray:
    return np.linalg.norm(flow - gt, axis=-1)


def angular_error(flow: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W) angle in degrees between (u, v, 1) and (u', v', 1) (module docstring)."""
    return _ae(*_pair(flow, gt))


def _ae(flow: np.ndarray, gt: np.ndarray) -> np.ndarray:
    num = (flow * gt).sum(-1) + 1.0
    den = np.sqrt(((flow ** 2).sum(-1) + 1.0) * ((gt ** 2).sum(-1) + 1.0))
    return np.degrees(np.arccos(np.clip(num / den, -1.0, 1.0)))


def kitti_outliers(epe: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W) bool: EPE > 3 px and > 5% of |gt|."""
    return (epe > KITTI_ABS_PX) & (epe > KITTI_REL * np.linalg.norm(np.asarray(gt, dtype=np.float64), axis=-1))


class FlowTally:
    """EPE, AE, KITTI-outlier and > 3 px sums per region, pooled over the pairs added."""

    _KEYS = ("epe", "ae", "outliers", "over_3px", "pixels")

    def __init__(self) -> None:
        self.sums: dict[str, dict[str, float]] = {}  # region -> sums of _KEYS

    def _slot(self, name: str) -> dict[str, float]:
        return self.sums.setdefault(name, dict.fromkeys(self._KEYS, 0))

    def add(self, flow: np.ndarray, gt: np.ndarray, regions: dict[str, np.ndarray]) -> None:
        flow, gt = _pair(flow, gt)  # checked once for both errors
        epe = _epe(flow, gt)
        per_pixel = {"epe": epe, "ae": _ae(flow, gt), "outliers": kitti_outliers(epe, gt),
                     "over_3px": epe > KITTI_ABS_PX}
        for name, mask in regions.items():
            mask = np.asarray(mask)
            if mask.dtype != bool or mask.shape != epe.shape:
                raise ValueError(f"regions[{name!r}]: expected a bool mask of shape {epe.shape}, got "
                                 f"{mask.dtype} {mask.shape}")
            s = self._slot(name)
            for key, values in per_pixel.items():
                s[key] += values[mask].sum().item()
            s["pixels"] += int(mask.sum())

    def merge(self, other: "FlowTally") -> None:
        for name, sums in other.sums.items():
            s = self._slot(name)
            for key in self._KEYS:
                s[key] += sums[key]

    def summary(self) -> dict[str, dict]:
        """Per region: epe (px), ae_deg, fl_percent (KITTI outliers, %), out3_percent (% with EPE > 3 px, KITTI
        2012's Out-Noc / Out-All) and pixels; None where the region has no pixel."""
        out = {}
        for name, s in self.sums.items():
            n = s["pixels"]
            if n == 0:
                out[name] = {"epe": None, "ae_deg": None, "fl_percent": None, "out3_percent": None, "pixels": 0}
            else:
                out[name] = {"epe": s["epe"] / n, "ae_deg": s["ae"] / n, "fl_percent": 100.0 * s["outliers"] / n,
                             "out3_percent": 100.0 * s["over_3px"] / n, "pixels": int(n)}
        return out


def _bool(name: str, mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {mask.shape}")
    return mask.astype(bool)


def sintel_regions(occluded: np.ndarray, invalid: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """all / matched / unmatched, each without the invalid pixels."""
    occluded = np.asarray(occluded).astype(bool)
    keep = ~_bool("invalid", invalid, occluded.shape) if invalid is not None else np.ones(occluded.shape, bool)
    return {"all": keep, "matched": keep & ~occluded, "unmatched": keep & occluded}


def kitti_regions(valid_noc: np.ndarray, valid_occ: np.ndarray,
                  foreground: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """noc / occ: the known pixels of flow_noc and of flow_occ; with KITTI 2015's object map also each
    split into noc_bg / noc_fg and occ_bg / occ_fg (Fl-bg, Fl-fg)."""
    valid_occ = np.asarray(valid_occ).astype(bool)
    regions = {"noc": _bool("valid_noc", valid_noc, valid_occ.shape), "occ": valid_occ}
    if foreground is not None:
        fg = _bool("foreground", foreground, valid_occ.shape)
        for r in ("noc", "occ"):
            regions[f"{r}_bg"], regions[f"{r}_fg"] = regions[r] & ~fg, regions[r] & fg
    return regions


def middlebury_regions(valid: np.ndarray) -> dict[str, np.ndarray]:
    return {"all": np.asarray(valid).astype(bool)}


def protocol_regions(fmt: str, seq: FlowSequence, k: int) -> dict[str, np.ndarray]:
    """The protocol's regions for pair k of a sequence read by research.datasets.flow_benchmarks."""
    if fmt == "sintel":
        invalid = seq.invalid[k] if seq.invalid is not None else None
        occluded = seq.occluded[k] if seq.occluded is not None else np.zeros(seq.valid[k].shape, bool)
        return sintel_regions(occluded, invalid)
    if fmt == "kitti":
        return kitti_regions(seq.valid[k], seq.valid_all[k], None if seq.foreground is None else seq.foreground[k])
    if fmt == "middlebury":
        return middlebury_regions(seq.valid[k])
    raise ValueError(f"fmt: expected 'sintel', 'kitti' or 'middlebury', got {fmt!r}")


def _one(flow, gt, regions) -> dict[str, dict]:
    t = FlowTally()
    t.add(flow, gt, regions)
    return t.summary()


def sintel_metrics(flow: np.ndarray, gt: np.ndarray, occluded: np.ndarray,
                   invalid: np.ndarray | None = None) -> dict[str, float | None]:
    """epe_all, epe_matched, epe_unmatched (px) of one pair, and their pixel counts."""
    s = _one(flow, gt, sintel_regions(_bool("occluded", occluded, np.shape(gt)[:2]), invalid))
    return {f"epe_{r}": s[r]["epe"] for r in ("all", "matched", "unmatched")} | {
        f"pixels_{r}": s[r]["pixels"] for r in ("all", "matched", "unmatched")}


def kitti_metrics(flow: np.ndarray, gt: np.ndarray, valid_noc: np.ndarray, valid_occ: np.ndarray,
                  foreground: np.ndarray | None = None) -> dict[str, float | None]:
    """fl_noc, fl_occ (% outliers), out3_noc, out3_occ (% EPE > 3 px), epe_noc, epe_occ (px) of one pair,
    and their pixel counts; with `foreground` (KITTI 2015's obj_map) the same for noc_bg, noc_fg, occ_bg
    and occ_fg."""
    s = _one(flow, gt, kitti_regions(valid_noc, _bool("valid_occ", valid_occ, np.shape(gt)[:2]), foreground))
    return {f"{m}_{r}": s[r][key] for r in s
            for m, key in (("fl", "fl_percent"), ("out3", "out3_percent"), ("epe", "epe"))} | {
        f"pixels_{r}": s[r]["pixels"] for r in s}


def middlebury_metrics(flow: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> dict[str, float | None]:
    """epe (px) and ae_deg of one pair over its known pixels."""
    s = _one(flow, gt, middlebury_regions(_bool("valid", valid, np.shape(gt)[:2])))["all"]
    return {"epe": s["epe"], "ae_deg": s["ae_deg"], "pixels": s["pixels"]}
