"""Saving and loading splats in the standard 3DGS PLY layout.

One binary little-endian `vertex` element of float32 properties, in this order:
x, y, z, nx, ny, nz (zeros), f_dc_0..2, f_rest_0..(3 (K-1) - 1), opacity (logit),
scale_0..2 (log), rot_0..3 (quaternion w, x, y, z). f_rest is channel-major, as
the 3DGS code writes it: f_rest_{c (K-1) + k} holds SH coefficient k + 1 of
channel c. Files with fewer SH coefficients (degree < 3) load with the missing
ones set to zero.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from research import atomic
from research.splats.model import SH_COEFFS, GaussianModel


def property_names(n_rest: int = SH_COEFFS - 1) -> list[str]:
    return (["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)]
            + [f"f_rest_{i}" for i in range(3 * n_rest)] + ["opacity"] + [f"scale_{i}" for i in range(3)]
            + [f"rot_{i}" for i in range(4)])


def to_bytes(model: GaussianModel) -> bytes:
    names = property_names()
    data = np.zeros(model.n, dtype=[(name, "<f4") for name in names])
    for i, axis in enumerate("xyz"):
        data[axis] = model.means[:, i]
    for c in range(3):
        data[f"f_dc_{c}"] = model.sh_dc[:, 0, c]
    rest = model.sh_rest.transpose(0, 2, 1).reshape(model.n, -1)  # channel-major
    for i in range(rest.shape[1]):
        data[f"f_rest_{i}"] = rest[:, i]
    data["opacity"] = model.opacity_logits
    for i in range(3):
        data[f"scale_{i}"] = model.log_scales[:, i]
    for i in range(4):
        data[f"rot_{i}"] = model.quats[:, i]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {model.n}"]
    header += [f"property float {name}" for name in names] + ["end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + data.tobytes()


def save_ply(path: str | Path, model: GaussianModel) -> Path:
    """Write `model` atomically; returns the path."""
    atomic.write_bytes(path, to_bytes(model))
    return Path(path)


def load_ply(path: str | Path) -> GaussianModel:
    """Read a 3DGS PLY file (module docstring); ValueError naming the file on anything unexpected."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise ValueError(f"{path}: not a PLY file (missing 'ply' magic or 'end_header')")
    lines = raw[:end].decode("ascii", errors="replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ValueError(f"{path}: expected 'format binary_little_endian 1.0'")
    count, names, in_vertex = None, [], False
    for line in lines[1:]:
        parts = line.split()
        if parts[:1] == ["element"]:
            in_vertex = parts[1] == "vertex"
            if in_vertex:
                count = int(parts[2])
            elif count is not None:
                raise ValueError(f"{path}: unexpected element {parts[1]!r} after 'vertex'")
        elif parts[:1] == ["property"] and in_vertex:
            if parts[1] != "float" or len(parts) != 3:
                raise ValueError(f"{path}: property {' '.join(parts[1:])!r}: expected 'float NAME'")
            names.append(parts[2])
    if count is None:
        raise ValueError(f"{path}: no 'vertex' element")
    n_rest3 = sum(name.startswith("f_rest_") for name in names)
    if n_rest3 % 3 or (n_rest3 // 3 + 1) not in (1, 4, 9, 16):
        raise ValueError(f"{path}: {n_rest3} f_rest properties; expected 3 ((d+1)^2 - 1) for SH degree d <= 3")
    missing = [p for p in property_names(n_rest3 // 3) if p not in names]
    if missing:
        raise ValueError(f"{path}: missing properties {missing}")
    dtype = np.dtype([(name, "<f4") for name in names])
    body = raw[end + len(b"end_header\n"):]
    if len(body) != count * dtype.itemsize:
        raise ValueError(f"{path}: expected {count * dtype.itemsize} bytes of vertex data, got {len(body)}")
    data = np.frombuffer(body, dtype=dtype, count=count)
    k_rest = n_rest3 // 3
    rest = np.stack([data[f"f_rest_{i}"] for i in range(n_rest3)], axis=1).reshape(count, 3, k_rest) \
        if k_rest else np.zeros((count, 3, 0), np.float32)
    sh_rest = np.zeros((count, SH_COEFFS - 1, 3), dtype=np.float32)
    sh_rest[:, :k_rest] = rest.transpose(0, 2, 1)
    try:
        return GaussianModel(
            means=np.stack([data["x"], data["y"], data["z"]], axis=1),
            log_scales=np.stack([data[f"scale_{i}"] for i in range(3)], axis=1),
            quats=np.stack([data[f"rot_{i}"] for i in range(4)], axis=1),
            opacity_logits=data["opacity"].copy(),
            sh_dc=np.stack([data[f"f_dc_{c}"] for c in range(3)], axis=1)[:, None, :],
            sh_rest=sh_rest)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
