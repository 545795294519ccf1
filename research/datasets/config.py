"""The configuration of a generated dataset (`drlab dataset` options) and its validation.

`DatasetConfig.validate` raises ValueError naming the `drlab dataset` option (or the field, for
those without one) before any file or folder is created.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from research.datasets.scenes import SceneSpec


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
    flow_step_deg: float = 1.5  # camera azimuth step between consecutive flow frames (the "arc" path)
    flow_path: str = "arc"  # "arc": an open arc of flow_step_deg steps; "loop": a closed orbit back to its start

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
        if self.flow_path not in FLOW_PATHS:
            raise ValueError(f"--flow-path: expected one of {', '.join(FLOW_PATHS)}, got {self.flow_path!r}")
        if self.flow_path == "loop" and self.flow_frames < MIN_LOOP_FRAMES:
            raise ValueError(f"--flow-frames: a loop path needs at least {MIN_LOOP_FRAMES} frames, got {self.flow_frames}")
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
FLOW_PATHS = ("arc", "loop")
MIN_LOOP_FRAMES = 4
_OPTION = {"views": "--views", "res": "--res", "spp": "--spp", "stereo_pairs": "--stereo-pairs",
           "flow_frames": "--flow-frames", "stereo": "--stereo", "flow": "--flow"}
MAX_RES = 8192


def config_record(cfg: DatasetConfig) -> dict[str, Any]:
    """The configuration as manifest.json and a `.partial` folder record it: the dataclass fields, without
    `flow_path` when it is "arc" (the only path before the option existed), so datasets recorded then
    still match their configuration and are reused, not rendered again."""
    record = asdict(cfg)
    if record["flow_path"] == "arc":
        del record["flow_path"]
    return record


def is_config_record(doc: Any) -> bool:
    """Whether `doc` has the keys of a `config_record` (with or without `flow_path`)."""
    keys = set(asdict(DatasetConfig("spheres")))
    return isinstance(doc, dict) and set(doc) in (keys, keys - {"flow_path"})


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
