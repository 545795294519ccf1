"""The TSDF volume: a dense grid of voxels with a truncated signed distance, a weight and an optional colour.

Grid. Voxel (i, j, k), 0 <= i < nx, 0 <= j < ny, 0 <= k < nz, has its centre at

    x_ijk = origin + (i + 1/2, j + 1/2, k + 1/2) h                  (h: the voxel size)

(Open3D's UniformTSDFVolume places its voxels so too). Its values live in flat arrays of nx ny nz
entries in C order, index (i ny + j) nz + k, so `tsdf.reshape(nx, ny, nz)[i, j, k]` is voxel (i, j, k):

    tsdf    D in [-1, 1], the weighted mean of the truncated distances seen so far (1 where never seen);
    weight  W >= 0, the number of observations (0: never seen);
    color   (N, 3) the weighted mean colour of the pixels that observed the voxel (optional).

Memory. A volume holds nx ny nz (2 + 3 [colour]) scalars. `TSDFVolume` refuses, before allocating
anything, a grid whose arrays would need more than `max_bytes` (default: the memory the device
reports available: MemAvailable of /proc/meminfo on the CPU, the free memory of a CUDA device), with
the size it would need; and a grid of more than 2^31 - 1 voxels (the kernels index with int32).

Visibility. `sees_volume(volume, K, w2c, width, height)` is False when the camera's view frustum and the
volume's box are separated by one of the frustum's five planes (the image plane z = 0 and the four planes
through the camera centre and the image borders): then no voxel can project into the image. The test is
conservative (it can say True for a box that only comes near a frustum edge), never the other way round.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
import warp as wp

from kernels import _arrays as A

def available_bytes(device: Any) -> int:
    """Memory the device reports available, in bytes: a CUDA device's free memory; on the CPU MemAvailable
    of /proc/meminfo, or the free pages where that file is absent (a lower bound)."""
    dev = A.get_device(device)
    if dev.is_cuda:
        return int(dev.free_memory)
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def volume_bytes(shape: tuple[int, int, int], dtype: Any, color: bool) -> int:
    """Bytes the arrays of a volume of `shape` voxels take: (2 + 3 [colour]) scalars per voxel."""
    scalar = np.dtype(dtype).itemsize
    return math.prod(shape) * (2 + (3 if color else 0)) * scalar


def _gb(n: int) -> str:
    return f"{n / 1e9:.3g} GB"


class TSDFVolume:
    """A dense TSDF volume (module docstring) on one device, float32 or float64.

    origin (3,): the grid's lower corner (the corner of voxel (0, 0, 0), half a voxel below its centre);
    voxel_size h > 0; shape (nx, ny, nz), each >= 2; truncation: the distance tau > 0 at which the
    signed distance is cut off (tsdf = min(1, sdf / tau), observations with sdf <= -tau are skipped);
    color: keep a colour per voxel; max_bytes: refuse a volume larger than this (default: the device's
    available memory). Arrays start at tsdf 1, weight 0, colour 0.
    """

    def __init__(self, origin: Any, voxel_size: float, shape: Any, truncation: float, *, color: bool = False,
                 dtype: Any = np.float32, device: Any = None, max_bytes: int | None = None):
        origin = np.asarray(origin, dtype=np.float64)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f"origin: expected 3 finite numbers, got {origin.tolist()}")
        self.voxel_size = A.check_float("voxel_size", voxel_size, positive=True)
        self.truncation = A.check_float("truncation", truncation, positive=True)
        shape = tuple(shape) if isinstance(shape, (tuple, list, np.ndarray)) else None
        if shape is None or len(shape) != 3:
            raise ValueError(f"shape: expected three voxel counts (nx, ny, nz), got {shape}")
        self.shape = tuple(A.check_int(f"shape[{a}]", n, minimum=2) for a, n in enumerate(shape))
        if np.dtype(dtype) not in (np.float32, np.float64):
            raise ValueError(f"dtype: expected float32 or float64, got {np.dtype(dtype)}")
        self.np_dtype = np.dtype(dtype)
        self.scalar = wp.float32 if self.np_dtype == np.float32 else wp.float64
        self.device = A.get_device(device)
        n = math.prod(self.shape)
        size = "x".join(map(str, self.shape))
        need = volume_bytes(self.shape, self.np_dtype, color)
        limit = available_bytes(self.device) if max_bytes is None else A.check_int("max_bytes", max_bytes, minimum=0)
        if need > limit:
            kind = f"{self.np_dtype}{', with colour' if color else ''}"
            raise ValueError(f"shape: a TSDF volume of {size} voxels ({kind}) needs {_gb(need)} ({need} bytes); "
                             f"only {_gb(limit)} is available on {self.device}"
                             f"{'' if max_bytes is None else ' (max_bytes)'}: use a larger voxel_size or a smaller box")
        if n * 3 > 2**31 - 1:
            raise ValueError(f"shape: a volume of {size} voxels has more than the (2^31 - 1) / 3 the kernels "
                             "index with int32")
        self.origin = origin
        self.n_voxels = n
        self.tsdf = wp.full(n, self.scalar(1.0), dtype=self.scalar, device=self.device)
        self.weight = wp.zeros(n, dtype=self.scalar, device=self.device)
        self.color = wp.zeros((n, 3), dtype=self.scalar, device=self.device) if color else None

    @property
    def has_color(self) -> bool:
        return self.color is not None

    @property
    def nbytes(self) -> int:
        return volume_bytes(self.shape, self.np_dtype, self.has_color)

    def centres(self) -> np.ndarray:
        """(nx, ny, nz, 3) voxel centres, float64."""
        axes = [self.origin[a] + (np.arange(self.shape[a]) + 0.5) * self.voxel_size for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def box(self) -> np.ndarray:
        """(2, 3): the lowest and highest voxel centres (the region the grid samples)."""
        lo = self.origin + 0.5 * self.voxel_size
        return np.stack([lo, lo + (np.array(self.shape) - 1) * self.voxel_size])

    def numpy(self) -> dict[str, np.ndarray]:
        """Host copies: tsdf and weight (nx, ny, nz), color (nx, ny, nz, 3) when kept."""
        out = {"tsdf": self.tsdf.numpy().reshape(self.shape), "weight": self.weight.numpy().reshape(self.shape)}
        if self.color is not None:
            out["color"] = self.color.numpy().reshape(*self.shape, 3)
        return out


def sees_volume(volume: TSDFVolume, K: Any, w2c: Any, width: int, height: int) -> bool:
    """Whether any voxel centre of `volume` can project into the image (module docstring): False when one
    of the frustum's planes has every corner of the box of voxel centres on its outer side."""
    K = np.asarray(K, dtype=np.float64)
    w2c = np.asarray(w2c, dtype=np.float64)
    lo, hi = volume.box()
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pc = corners @ w2c[:3, :3].T + w2c[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    # Inner side of each plane: z > 0, u = fx x / z + cx >= 0 <=> fx x + cx z >= 0, u <= W, v >= 0, v <= H.
    sides = [pc[:, 2], fx * pc[:, 0] + cx * pc[:, 2], width * pc[:, 2] - (fx * pc[:, 0] + cx * pc[:, 2]),
             fy * pc[:, 1] + cy * pc[:, 2], height * pc[:, 2] - (fy * pc[:, 1] + cy * pc[:, 2])]
    return not any(np.all(s <= 0) for s in sides)
