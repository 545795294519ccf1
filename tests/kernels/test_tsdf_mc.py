"""kernels/tsdf marching cubes: against its NumPy reference (the same vertices, faces and order) in float32
and float64, on an analytic sphere (vertex distances to the sphere, watertightness, Euler characteristic,
area, outward normals), against Warp's own `warp.geometry.IsoSurfaceMarchingCubes` on a fully observed
grid, and with unobserved voxels (skipped cells, no stray vertices); its table against Warp's; bad input.

Marching cubes has no gradient here (the triangulation is discrete), so there is no gradient check.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from kernels import tsdf as kt
from kernels.reference.tsdf import marching_cubes_reference, voxel_centres
from kernels.tsdf import tables

DTYPES = [np.float32, np.float64]
N = 26
H = 1.0 / N
ORIGIN = np.array([-0.5, -0.5, -0.5])
CENTRE = np.array([0.013, -0.021, 0.008])
RADIUS = 0.31


def sphere_sdf(dtype=np.float64, n=N):
    x = voxel_centres(ORIGIN, 1.0 / n, (n, n, n))
    return (np.linalg.norm(x - CENTRE, axis=-1) - RADIUS).astype(dtype)


def edges_of(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0, return_counts=True)


@pytest.mark.usefixtures("warp_device")
@pytest.mark.parametrize("dtype", DTYPES)
def test_marching_cubes_matches_the_reference(dtype):
    rng = np.random.default_rng(0)
    sdf = sphere_sdf(dtype) + (0.01 * rng.standard_normal((N, N, N))).astype(dtype)
    weight = (rng.random((N, N, N)) > 0.03).astype(dtype) * 2  # a few unobserved voxels
    color = rng.random((N, N, N, 3)).astype(dtype)
    got = kt.marching_cubes(sdf, weight, ORIGIN, H, color=color, min_weight=1.0)
    v, f, c = marching_cubes_reference(sdf, weight, ORIGIN, H, min_weight=1.0, color=color)
    assert got.vertices.dtype == dtype and got.faces.dtype == np.int32 and len(f) > 500
    np.testing.assert_array_equal(got.faces, f)
    tol = 1e-13 if dtype == np.float64 else 2e-7  # positions: a few roundings of values ~0.5
    np.testing.assert_allclose(got.vertices, v, rtol=0, atol=tol)
    np.testing.assert_allclose(got.colors, c, rtol=0, atol=10 * tol)
    assert np.all(np.isin(np.arange(len(v)), f))  # every vertex belongs to a face


@pytest.mark.parametrize("dtype", DTYPES)
def test_sphere_is_watertight_close_and_outward(dtype):
    m = kt.marching_cubes(sphere_sdf(dtype), np.ones((N, N, N), dtype), ORIGIN, H)
    v, f = m.vertices.astype(np.float64), m.faces
    dist = np.abs(np.linalg.norm(v - CENTRE, axis=1) - RADIUS)
    assert dist.max() < 0.02 * H  # linear interpolation of an exact SDF: second-order error
    _, counts = edges_of(f)
    assert np.all(counts == 2)  # closed: every edge shared by two faces
    assert len(v) - len(counts) + len(f) == 2  # Euler characteristic of a sphere
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1).sum()
    assert abs(area / (4 * np.pi * RADIUS**2) - 1) < 0.01  # inscribed facets: slightly smaller
    assert np.all(np.sum(cross * (tri.mean(axis=1) - CENTRE), axis=1) > 0)  # normals point out (D increases)


def test_vertices_equal_warps_iso_surface_marching_cubes():
    from warp.geometry import IsoSurfaceMarchingCubes

    sdf = sphere_sdf(np.float32)
    ours = kt.marching_cubes(sdf, np.ones_like(sdf), ORIGIN, H)
    lo = ORIGIN + 0.5 * H
    verts, faces = IsoSurfaceMarchingCubes.extract(wp.array(sdf, dtype=wp.float32, device="cpu"), 0.0,
                                                   lower=tuple(lo), upper=tuple(lo + (N - 1) * H))
    theirs = verts.numpy()
    # Same crossings, each once; Warp orders its vertices by edge as we do.
    assert theirs.shape == ours.vertices.shape
    np.testing.assert_allclose(theirs, ours.vertices, rtol=0, atol=1e-6)
    assert faces.numpy().size == ours.faces.size


def test_table_is_warps():
    from warp.geometry import IsoSurfaceMarchingCubes as W

    flat = [e for t in tables.TRIANGLES for e in t]
    assert tuple(flat) == W.TRI_LOCAL_INDICES
    assert tables.CORNERS == W.CUBE_CORNER_OFFSETS
    assert tables.EDGE_CORNERS == W.EDGE_TO_CORNERS


def test_unobserved_voxels_make_no_surface():
    sdf = sphere_sdf()
    weight = np.ones_like(sdf)
    weight[N // 2:] = 0  # half the grid never seen
    sdf[N // 2:] = 1.0
    sdf[N // 2 - 2: N // 2] = -0.2  # a band "behind a surface" next to the unseen half
    m = kt.marching_cubes(sdf, weight, ORIGIN, H)
    x_max = ORIGIN[0] + (N // 2 - 1 + 0.5) * H
    assert len(m.faces) > 0 and m.vertices[:, 0].max() <= x_max + 1e-12
    # Open3D's rule: a cell with any unobserved corner emits nothing; no vertex is left without a face.
    assert np.all(np.isin(np.arange(len(m.vertices)), m.faces))
    empty = kt.marching_cubes(sdf, np.zeros_like(sdf), ORIGIN, H)
    assert empty.vertices.shape == (0, 3) and empty.faces.shape == (0, 3)


def test_kind_rule_and_split_launches(monkeypatch):
    sdf = sphere_sdf(np.float32)
    w = np.ones_like(sdf)
    got = kt.marching_cubes(wp.array(sdf, dtype=wp.float32), wp.array(w, dtype=wp.float32), ORIGIN, H)
    assert isinstance(got.vertices, wp.array) and isinstance(got.faces, wp.array)
    monkeypatch.setenv("DRLAB_THREADS", "1")
    one = kt.marching_cubes(sdf, w, ORIGIN, H)
    np.testing.assert_array_equal(got.vertices.numpy(), one.vertices)
    np.testing.assert_array_equal(got.faces.numpy(), one.faces)


def test_bad_input():
    sdf = sphere_sdf()
    w = np.ones_like(sdf)
    for kw, msg in [(dict(tsdf=sdf[:1]), r"tsdf: expected an \(nx, ny, nz\) array with every n >= 2"),
                    (dict(tsdf=np.where(sdf > 0.3, np.nan, sdf)), "tsdf: .*(NaN|finite)"),
                    (dict(weight=w[:-1]), "weight: expected shape"),
                    (dict(color=np.zeros((N, N, N))), "color: expected shape"),
                    (dict(voxel_size=0.0), "voxel_size"), (dict(min_weight=0.0), "min_weight"),
                    (dict(origin=[0.0, 0.0]), "origin"), (dict(iso=np.inf), "iso")]:
        args = {"tsdf": sdf, "weight": w, "origin": ORIGIN, "voxel_size": H, "iso": 0.0, "min_weight": 1.0,
                "color": None, **kw}
        with pytest.raises(ValueError, match=msg):
            kt.marching_cubes(args["tsdf"], args["weight"], args["origin"], args["voxel_size"], iso=args["iso"],
                              min_weight=args["min_weight"], color=args["color"])
