"""Triangle meshes: area, area-weighted surface samples with face normals, and PLY files.

Sampling (the usual mesh-to-points step of surface benchmarks, e.g. Occupancy Networks and Tanks and
Temples): a face is drawn with probability area / total area, then a point uniformly inside it by the
square-root barycentric map p = (1 - sqrt r1) a + sqrt r1 (1 - r2) b + sqrt r1 r2 c (Osada et al.,
"Shape distributions", 2002); its normal is the face's unit normal (b - a) x (c - a) / |...|.

PLY: binary little-endian through plyfile, vertices (x, y, z as float32, red/green/blue as uint8 when
colours are given) and faces (vertex_indices as int32 lists), written to a temporary name and renamed
(research/atomic.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from research.atomic import atomic_path


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per face: the unit normal (F, 3) (NaN for a degenerate face) and the area (F,)."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return cross / norm[:, None], 0.5 * norm


def mesh_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    return float(face_normals(vertices, faces)[1].sum()) if len(faces) else 0.0


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n points uniform on the mesh's surface and their face normals, both (n, 3) float64."""
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces: expected a non-empty (F, 3) array, got shape {faces.shape}")
    if n < 1:
        raise ValueError(f"n: expected an integer >= 1, got {n}")
    normals, area = face_normals(vertices, faces)
    keep = area > 0
    if not keep.any():
        raise ValueError("faces: every face has zero area")
    rng = np.random.default_rng(seed)
    prob = np.where(keep, area, 0.0) / area[keep].sum()
    f = rng.choice(len(faces), size=n, p=prob)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    tri = np.asarray(vertices, dtype=np.float64)[faces[f]]
    p = (1 - s)[:, None] * tri[:, 0] + (s * (1 - r2))[:, None] * tri[:, 1] + (s * r2)[:, None] * tri[:, 2]
    return p, normals[f]


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None) -> Path:
    """Write a triangle mesh as binary PLY (module docstring); colors in [0, 1], (V, 3). Returns the path."""
    from plyfile import PlyData, PlyElement

    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices: expected a (V, 3) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces: expected an (F, 3) array, got shape {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces: expected vertex indices in [0, {len(v)}), got [{f.min()}, {f.max()}]")
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vert = np.empty(len(v), dtype=fields)
    vert["x"], vert["y"], vert["z"] = v[:, 0], v[:, 1], v[:, 2]
    if colors is not None:
        c = np.round(np.clip(np.asarray(colors, dtype=np.float64), 0.0, 1.0) * 255).astype(np.uint8)
        vert["red"], vert["green"], vert["blue"] = c[:, 0], c[:, 1], c[:, 2]
    face = np.empty(len(f), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = f.astype(np.int32)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(str(tmp))
    return path


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, faces (F, 3) int64) of a PLY triangle mesh (plyfile)."""
    from plyfile import PlyData

    ply = PlyData.read(str(path))
    v = ply["vertex"]
    verts = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    faces = np.stack(ply["face"]["vertex_indices"]).astype(np.int64) if ply["face"].count else np.zeros((0, 3), int)
    return verts, faces.reshape(-1, 3)
