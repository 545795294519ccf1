"""Synthetic shape-classification clouds: parametric surfaces and small meshes, sampled uniformly by area,
in random poses, with anisotropic scale and jitter.

Classes (`CLASSES`), each a closed or open surface in its own frame, of extent about 2:

    sphere       unit sphere                                  (a normalised Gaussian vector)
    cube         [-1, 1]^3's six faces                        (a face, then a uniform point on it)
    cylinder     radius 1, z in [-1, 1], with both caps        (side 4 pi : caps pi + pi, by area)
    cone         base radius 1 at z = -1, apex at z = 1, with its base disk
                 (side pi sqrt(5) : base pi; on the side the distance from the apex is sqrt(U) times the slant,
                 since the area within distance t of the apex grows as t^2)
    torus        radii R = 1, r = 0.35     (tube angle v accepted with probability (R + r cos v) / (R + r),
                 the area element's dependence on v)
    plane        the square [-1, 1]^2 at z = 0
    tetrahedron  regular, vertices at alternate corners of [-1, 1]^3
    octahedron   vertices at +-e_x, +-e_y, +-e_z
    l_prism      the L-shaped hexagon (0,0) (2,0) (2,1) (1,1) (1,2) (0,2) extruded over z in [0, 1] (non-convex)

On a mesh, a triangle (a, b, c) is picked with probability proportional to its area, then the point
(1 - sqrt(u)) a + sqrt(u) (1 - v) b + sqrt(u) v c with u, v ~ U(0, 1), uniform on the triangle.

Every disk or square is sampled uniformly too (radius sqrt(U) on a disk). A cloud of `n_points` is then

    x = R (diag(a) p) s + t + sigma s e,

with R a uniformly random rotation (scipy.spatial.transform.Rotation.random), anisotropic factors
a = exp(U(-A, A)) per axis (`aniso`), a global scale s = exp(U(log 0.5, log 2)), a translation
t ~ U(-1, 1)^3 and Gaussian jitter e ~ N(0, I) of `noise` sigma relative to the shape's size. Every
method sees the same clouds after `normalise`: the centroid moved to the origin and the largest
distance from it scaled to 1 (PointNet's unit-sphere normalisation), so pose translation and global
scale are removed, while rotation, anisotropy and noise stay for the classifier to cope with.

All randomness comes from one seed; `make_splits` draws train, validation and test clouds from
independent streams of it (numpy SeedSequence spawn), so the splits never share a cloud.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

CLASSES = ("sphere", "cube", "cylinder", "cone", "torus", "plane", "tetrahedron", "octahedron", "l_prism")

TORUS_R, TORUS_r = 1.0, 0.35


def _disk(rng: np.random.Generator, n: int) -> np.ndarray:
    """n points uniform on the unit disk in the xy plane, as (n, 2)."""
    rad = np.sqrt(rng.uniform(size=n))
    ang = rng.uniform(0.0, 2.0 * np.pi, size=n)
    return np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)


def _by_area(rng: np.random.Generator, n: int, areas: list[float]) -> np.ndarray:
    """Which of the parts (of the given areas) each of n points falls on."""
    p = np.asarray(areas, float)
    return rng.choice(len(p), size=n, p=p / p.sum())


def sphere(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def cube(rng: np.random.Generator, n: int) -> np.ndarray:
    face = rng.integers(0, 6, size=n)
    out = rng.uniform(-1.0, 1.0, size=(n, 3))
    axis, sign = face // 2, np.where(face % 2 == 0, -1.0, 1.0)
    out[np.arange(n), axis] = sign
    return out


def cylinder(rng: np.random.Generator, n: int) -> np.ndarray:
    part = _by_area(rng, n, [4.0 * np.pi, np.pi, np.pi])  # side 2 pi r h (r = 1, h = 2), two caps pi r^2
    out = np.empty((n, 3))
    ang = rng.uniform(0.0, 2.0 * np.pi, size=n)
    side = part == 0
    out[side] = np.stack([np.cos(ang[side]), np.sin(ang[side]), rng.uniform(-1.0, 1.0, side.sum())], axis=1)
    for cap, z in ((1, -1.0), (2, 1.0)):
        m = part == cap
        out[m, :2] = _disk(rng, int(m.sum()))
        out[m, 2] = z
    return out


def cone(rng: np.random.Generator, n: int) -> np.ndarray:
    part = _by_area(rng, n, [np.pi * np.sqrt(5.0), np.pi])  # side pi r l (slant l = sqrt(1 + 2^2)), base pi r^2
    out = np.empty((n, 3))
    side = part == 0
    t = np.sqrt(rng.uniform(size=side.sum()))  # fraction of the way from the apex to the base
    ang = rng.uniform(0.0, 2.0 * np.pi, size=side.sum())
    out[side] = np.stack([t * np.cos(ang), t * np.sin(ang), 1.0 - 2.0 * t], axis=1)
    base = ~side
    out[base, :2] = _disk(rng, int(base.sum()))
    out[base, 2] = -1.0
    return out


def torus(rng: np.random.Generator, n: int) -> np.ndarray:
    v = np.empty(0)
    while v.size < n:  # rejection: area element (R + r cos v) du dv
        cand = rng.uniform(0.0, 2.0 * np.pi, size=2 * n)
        keep = rng.uniform(size=2 * n) < (TORUS_R + TORUS_r * np.cos(cand)) / (TORUS_R + TORUS_r)
        v = np.concatenate([v, cand[keep]])
    v = v[:n]
    u = rng.uniform(0.0, 2.0 * np.pi, size=n)
    ring = TORUS_R + TORUS_r * np.cos(v)
    return np.stack([ring * np.cos(u), ring * np.sin(u), TORUS_r * np.sin(v)], axis=1)


def plane(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.concatenate([rng.uniform(-1.0, 1.0, size=(n, 2)), np.zeros((n, 1))], axis=1)


def sample_mesh(rng: np.random.Generator, n: int, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """n points uniform by area on the triangles `faces` (F, 3) of `vertices` (V, 3)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    tri = _by_area(rng, n, list(areas))
    su = np.sqrt(rng.uniform(size=(n, 1)))
    v = rng.uniform(size=(n, 1))
    return (1.0 - su) * a[tri] + su * (1.0 - v) * b[tri] + su * v * c[tri]


def _tetrahedron() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    return v, np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])


def _octahedron() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    f = [[x, y, z] for x in (0, 1) for y in (2, 3) for z in (4, 5)]
    return v, np.array(f)


def _l_prism() -> tuple[np.ndarray, np.ndarray]:
    outline = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    m = len(outline)
    v = np.concatenate([np.c_[outline, np.zeros(m)], np.c_[outline, np.ones(m)]]) - np.array([0.8, 0.8, 0.5])
    cap = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]  # the L as a fan from the corner (0, 0): all inside it
    faces = cap + [[i + m, j + m, k + m] for i, j, k in cap]
    for i in range(m):
        j = (i + 1) % m
        faces += [[i, j, j + m], [i, j + m, i + m]]
    return v, np.array(faces)


MESHES = {"tetrahedron": _tetrahedron(), "octahedron": _octahedron(), "l_prism": _l_prism()}
PARAMETRIC = {"sphere": sphere, "cube": cube, "cylinder": cylinder, "cone": cone, "torus": torus, "plane": plane}


def sample_shape(name: str, rng: np.random.Generator, n: int) -> np.ndarray:
    """n points (n, 3) uniform by area on shape `name` in its own frame."""
    if name in PARAMETRIC:
        return PARAMETRIC[name](rng, n)
    if name in MESHES:
        return sample_mesh(rng, n, *MESHES[name])
    raise ValueError(f"name: expected one of {', '.join(CLASSES)}, got {name!r}")


@dataclass(frozen=True)
class PoseConfig:
    """The random pose and distortion of every cloud (module docstring)."""

    aniso: float = 0.25  # per-axis log-scale range: factors in [exp(-0.25), exp(0.25)] = [0.78, 1.28]
    scale_range: tuple[float, float] = (0.5, 2.0)
    translation: float = 1.0
    noise: float = 0.02  # jitter sigma, relative to the shape (before the global scale)

    def validate(self) -> "PoseConfig":
        if not (self.aniso >= 0 and np.isfinite(self.aniso)):
            raise ValueError(f"aniso: expected a finite value >= 0, got {self.aniso}")
        lo, hi = self.scale_range
        if not (0 < lo <= hi < np.inf):
            raise ValueError(f"scale_range: expected 0 < low <= high, got {self.scale_range}")
        for name in ("translation", "noise"):
            v = getattr(self, name)
            if not (v >= 0 and np.isfinite(v)):
                raise ValueError(f"{name}: expected a finite value >= 0, got {v}")
        return self


def posed_cloud(name: str, rng: np.random.Generator, n: int, pose: PoseConfig) -> np.ndarray:
    """One cloud (n, 3) of shape `name` in a random pose (module docstring), float64."""
    p = sample_shape(name, rng, n) * np.exp(rng.uniform(-pose.aniso, pose.aniso, size=3))
    s = np.exp(rng.uniform(np.log(pose.scale_range[0]), np.log(pose.scale_range[1])))
    rot = Rotation.random(random_state=rng).as_matrix()
    t = rng.uniform(-pose.translation, pose.translation, size=3)
    return (p @ rot.T) * s + t + pose.noise * s * rng.normal(size=(n, 3))


def normalise(clouds: np.ndarray) -> np.ndarray:
    """Clouds (B, N, 3) with each centroid at the origin and its farthest point at distance 1."""
    clouds = np.asarray(clouds, float)
    if clouds.ndim != 3 or clouds.shape[2] != 3 or clouds.shape[1] == 0:
        raise ValueError(f"clouds: expected a (B, N, 3) array with N >= 1, got shape {clouds.shape}")
    if not np.all(np.isfinite(clouds)):
        raise ValueError("clouds: expected finite coordinates, found NaN or infinite entries")
    c = clouds - clouds.mean(axis=1, keepdims=True)
    radius = np.linalg.norm(c, axis=2).max(axis=1)
    if np.any(radius <= 0):
        raise ValueError(f"clouds: cloud {int(np.argmin(radius))} has all its points at one place (no extent)")
    return c / radius[:, None, None]


@dataclass
class Split:
    """Normalised clouds (M, N, 3) float32 and their class labels (M,) int64 (indices into CLASSES)."""

    points: np.ndarray
    labels: np.ndarray


def make_split(rng: np.random.Generator, per_class: int, n_points: int, pose: PoseConfig,
               classes: tuple[str, ...] = CLASSES) -> Split:
    """`per_class` normalised clouds of `n_points` for each class, in class order."""
    clouds = [posed_cloud(name, rng, n_points, pose) for name in classes for _ in range(per_class)]
    labels = np.repeat(np.arange(len(classes)), per_class)
    return Split(normalise(np.stack(clouds)).astype(np.float32), labels)


def make_splits(seed: int, per_class: dict[str, int], n_points: int, pose: PoseConfig | None = None,
                classes: tuple[str, ...] = CLASSES) -> dict[str, Split]:
    """Splits name -> Split (e.g. {"train": 60, "val": 20, "test": 40} clouds per class), each from its own
    stream of `seed`."""
    pose = (pose or PoseConfig()).validate()
    if int(n_points) < 1:
        raise ValueError(f"n_points: expected an integer >= 1, got {n_points}")
    for name, count in per_class.items():
        if int(count) < 1:
            raise ValueError(f"per_class[{name!r}]: expected an integer >= 1, got {count}")
    streams = np.random.SeedSequence(seed).spawn(len(per_class))
    return {name: make_split(np.random.default_rng(s), int(count), int(n_points), pose, classes)
            for (name, count), s in zip(per_class.items(), streams)}


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """n uniformly random rotation matrices (n, 3, 3) (scipy's Rotation.random), the training augmentation."""
    return Rotation.random(n, random_state=rng).as_matrix()


def rotate(clouds: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Clouds (B, N, 3) rotated about the origin, p -> R_b p, in the clouds' dtype."""
    return np.einsum("bij,bnj->bni", rotations.astype(clouds.dtype), clouds)
