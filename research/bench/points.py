"""Benchmark family "points": kNN, ball query, farthest-point sampling and the chamfer distance
(kernels/points), each beside SciPy's cKDTree and Open3D on the same inputs, in the same run.

Clouds: N points uniform in the unit cube (seed 0), float32. Sizes (points N; full / quick / tiny):

  points.knn         N = 100000 / 20000 / 2000, k = 16, the cloud's own points as queries;
  points.ball_query  N as above, the first N / 10 points as queries, r = 2 (k / N)^(1/3) (about 33
                     points in a ball), at most K = 32 neighbours;
  points.fps         N as above, S = 1024 / 256 / 64 samples from index 0;
  points.chamfer     X of N points, Y of N points (seed 1); fwd_s the distance, fwd_bwd_s distance
                     and gradient w.r.t. both clouds.

Phases, each the median of REPEATS runs after a warm-up (research.bench.time_medians, interleaved, so
the libraries see the same machine drift); every timing includes building the search structure
(drlab's hash grid, cKDTree's tree, Open3D's index):

  <phase>_s                 kernels.points on the named device (CPU: kernels.launch threads): knn_s,
                            ball_query_s, fps_s, and for the chamfer distance fwd_s (the distance) and
                            fwd_bwd_s (distance and gradient w.r.t. both clouds);
  ref_<phase>_s             SciPy's cKDTree (tree, then `query`, `query_ball_point`, or both ways for the
                            chamfer distance), `workers` = drlab's thread count; "ref" names it. SciPy has no
                            FPS: points.fps takes Open3D as its "ref" (or says `ref_missing`);
  ref_open3d_<phase>_s      Open3D when importable (the `open3d-cpu` wheel of the `[bench]` extra; else
                            `open3d_missing`): `core.nns.NearestNeighborSearch` knn_search / hybrid_search
                            (the K NEAREST within r, not PointNet++'s first K: the same search, another
                            selection), `PointCloud.compute_point_cloud_distance` both ways; Open3D picks its
                            own thread count;
  speedup_<phase>, speedup_open3d_<phase>: reference time / drlab time (> 1: drlab faster).
The references have no gradient: fwd_bwd_s stands alone.
"""

from __future__ import annotations

from typing import Any, Callable, Iterator

import numpy as np
import warp as wp

from kernels import points as kp
from kernels.launch import default_threads
from research.bench import SETTLE_S, time_medians

SIZES = {"full": (100_000, 1024), "quick": (20_000, 256), "tiny": (2_000, 64)}
K = 16
BALL_K = 32
REPEATS = 3


def _open3d() -> Any:
    try:
        import open3d as o3d  # noqa: F401 (the [bench] extra)
    except Exception:  # not installed, or a missing system library
        return None
    return o3d


def _row(case: str, device: str, sizes: dict, phase: str, fns: dict[str, Callable[[], Any]], sync, o3d,
         ref: str) -> dict:
    """One row: fns["drlab"] (and any other drlab phase) against fns["ref"] and fns["open3d"] when present."""
    t = time_medians(fns, repeats=REPEATS, sync=sync, settle_s=SETTLE_S)
    row: dict[str, Any] = {"bench": f"points.{case}", "device": device, "threads": default_threads(), **sizes,
                           "dtype": "float32", f"{phase}_s": t.pop("drlab")}
    for name in [n for n in t if n not in ("ref", "open3d")]:
        row[f"{name}_s"] = t.pop(name)
    if "ref" in t:
        row["ref"] = ref
        row[f"ref_{phase}_s"] = t["ref"]
        row[f"speedup_{phase}"] = t["ref"] / row[f"{phase}_s"]
    if "open3d" in t:
        row[f"ref_open3d_{phase}_s"] = t["open3d"]
        row[f"speedup_open3d_{phase}"] = t["open3d"] / row[f"{phase}_s"]
    if o3d is None:
        row["open3d_missing" if case != "fps" else "ref_missing"] = "open3d (pip install open3d-cpu: the [bench] extra)"
    return row


def cases(device: str, quick: bool, tiny: bool = False) -> Iterator[dict]:
    from scipy.spatial import cKDTree

    n, s = SIZES["tiny" if tiny else ("quick" if quick else "full")]
    dev = wp.get_device(device)
    sync = (lambda: wp.synchronize_device(dev)) if dev.is_cuda else None
    threads = default_threads()
    o3d = _open3d()
    rng = np.random.default_rng(0)
    p = rng.uniform(0.0, 1.0, (n, 3)).astype(np.float32)
    y = np.random.default_rng(1).uniform(0.0, 1.0, (n, 3)).astype(np.float32)
    pw, yw = wp.array(p, dtype=wp.float32, device=dev), wp.array(y, dtype=wp.float32, device=dev)
    q = p[: n // 10]
    qw = wp.array(q, dtype=wp.float32, device=dev)
    r = (3.0 * BALL_K / (4.0 * np.pi * n)) ** (1.0 / 3.0)  # about BALL_K points in a ball inside the cube

    if o3d is not None:
        c = o3d.core
        pt, qt = c.Tensor(p), c.Tensor(q)
        pc, yc = (o3d.geometry.PointCloud(o3d.utility.Vector3dVector(v.astype(np.float64))) for v in (p, y))

        def o3d_knn():
            nns = c.nns.NearestNeighborSearch(pt)
            nns.knn_index()
            return nns.knn_search(pt, K)

        def o3d_ball():
            nns = c.nns.NearestNeighborSearch(pt)
            nns.hybrid_index(r)
            return nns.hybrid_search(qt, r, BALL_K)

    # k nearest neighbours
    fns = {"drlab": lambda: kp.knn(pw, K), "ref": lambda: cKDTree(p).query(p, K, workers=threads)}
    if o3d is not None:
        fns["open3d"] = o3d_knn
    yield _row("knn", device, {"points": n, "queries": n, "k": K}, "knn", fns, sync, o3d,
               "scipy cKDTree(points).query(points, k)")

    # ball query
    fns = {"drlab": lambda: kp.ball_query(pw, qw, r, BALL_K),
           "ref": lambda: cKDTree(p).query_ball_point(q, r, workers=threads)}
    if o3d is not None:
        fns["open3d"] = o3d_ball
    yield _row("ball_query", device, {"points": n, "queries": len(q), "radius": r, "max_neighbors": BALL_K},
               "ball_query", fns, sync, o3d, "scipy cKDTree(points).query_ball_point(queries, r)")

    # farthest-point sampling (SciPy has none)
    fns = {"drlab": lambda: kp.farthest_point_sampling(pw, s)}
    if o3d is not None:
        fns["ref"] = lambda: pc.farthest_point_down_sample(s, 0)
    yield _row("fps", device, {"points": n, "samples": s}, "fps", fns, sync, o3d,
               "open3d PointCloud.farthest_point_down_sample(S, 0)")

    # chamfer distance, forward (and forward + backward for drlab)
    def fwd_bwd():
        res = kp.chamfer_distance(pw, yw)
        return kp.chamfer_backward(pw, yw, res)

    def scipy_chamfer():
        a, _ = cKDTree(y).query(p, workers=threads)
        b, _ = cKDTree(p).query(y, workers=threads)
        return float(np.mean(a * a) + np.mean(b * b))

    fns = {"drlab": lambda: kp.chamfer_distance(pw, yw), "fwd_bwd": fwd_bwd, "ref": scipy_chamfer}
    if o3d is not None:
        fns["open3d"] = lambda: (np.asarray(pc.compute_point_cloud_distance(yc)),
                                 np.asarray(yc.compute_point_cloud_distance(pc)))
    row = _row("chamfer", device, {"points_x": n, "points_y": n}, "fwd", fns, sync, o3d,
               "scipy cKDTree both ways")
    row["chamfer"] = kp.chamfer_distance(pw, yw).value
    row["scipy_chamfer"] = scipy_chamfer()
    yield row
