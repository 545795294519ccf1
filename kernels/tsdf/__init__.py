"""TSDF fusion and marching cubes: depth maps -> truncated signed distance volume -> triangle mesh.

    TSDFVolume(origin, voxel_size, shape, truncation, color=)   the dense grid, refused with the size it
                                                                would need when it exceeds memory     volume.py
    sees_volume(volume, K, w2c, width, height)                  whether a camera can see any voxel    volume.py
    integrate(volume, depth, K, w2c, rgb=None)                  projective TSDF update, one depth map
                                                                (Curless and Levoy 1996; Open3D's)    integrate.py
    marching_cubes(tsdf, weight, origin, voxel_size, iso=0)     the iso-surface, skipping cells with an
                                                                unobserved corner; Bourke's tables    marching_cubes.py

Conventions: OpenCV cameras (x right, y down, z forward), world-to-camera 4x4 matrices, pixel (c, r)
with its centre at (c + 1/2, r + 1/2), z-depth with 0 for "no measurement"; voxel (i, j, k) centred at
origin + (i + 1/2, j + 1/2, k + 1/2) h. tsdf is positive in front of surfaces (free space), negative
behind, cut to [-1, 1] at the truncation distance. Each module states its maths in full.

Nothing here has a gradient: integration is a weighted running mean behind a discrete pixel choice
and a truncation, and marching cubes a discrete triangulation; there is no backward pass to check.
The NumPy references are kernels/reference/tsdf.py.
"""

from kernels.tsdf.integrate import integrate
from kernels.tsdf.marching_cubes import Mesh, marching_cubes
from kernels.tsdf.volume import TSDFVolume, available_bytes, sees_volume, volume_bytes

__all__ = ["Mesh", "TSDFVolume", "available_bytes", "integrate", "marching_cubes", "sees_volume", "volume_bytes"]
