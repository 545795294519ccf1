"""Point-cloud kernels: k nearest neighbours and ball query on a uniform hash grid, farthest-point
sampling, normals by local PCA, and the chamfer distance with its gradient.

A cloud is an (N, 3) float32 or float64 array (NumPy or wp.array, kernels/_arrays.py's contract) with
N >= 1 and finite coordinates. Every distance is the squared Euclidean distance

    d2(q, p) = (q_x - p_x)^2 + (q_y - p_y)^2 + (q_z - p_z)^2        (evaluated in this order),

and every choice between points is made by the key (d2, index), smaller first, so ties go to the
smaller index and the results are exact and deterministic: the same as brute force over all pairs
(kernels/reference/points.py) on the CPU, bit for bit.

    knn(points, k, queries=None)             the k nearest points of each query          grid.py
    ball_query(points, queries, r, K)        the first K indices with d2 < r^2 (PointNet++) grid.py
    farthest_point_sampling(points, S)       PointNet++'s FPS from index 0                sampling.py
    estimate_normals(points, k, viewpoint)   smallest-eigenvector PCA normals             normals.py
    chamfer_distance(x, y), chamfer_backward  mean squared nearest distance both ways       chamfer.py
                                             (PyTorch3D / Kaolin), and dCD/dx, dCD/dy

Each module's docstring states its maths and conventions in full. Only the chamfer distance has a
gradient (hand-written, checked by float64 finite differences: research/checks/points.py); the other
results are indices. Bad input (an empty or non-finite cloud, k or K out of range, r <= 0) raises
ValueError naming the argument before any kernel runs; a degenerate neighbourhood of the normals
gives NaN and valid = False.
"""

from kernels.points.chamfer import ChamferResult, chamfer_backward, chamfer_distance
from kernels.points.grid import BallResult, KnnResult, PointGrid, ball_query, build_grid, knn
from kernels.points.normals import NormalsResult, estimate_normals
from kernels.points.sampling import farthest_point_sampling

__all__ = [
    "BallResult", "ChamferResult", "KnnResult", "NormalsResult", "PointGrid",
    "ball_query", "build_grid", "chamfer_backward", "chamfer_distance", "estimate_normals",
    "farthest_point_sampling", "knn",
]
