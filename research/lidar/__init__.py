"""LiDAR odometry on range scans that Mitsuba ray-casts: a rotating 360-degree scanner, ICP registration,
scan-to-scan and scan-to-local-map odometry, and the KISS-ICP / Open3D baselines.

    scene.py         a closed hall with a street of boxes and pillars (Mitsuba), and a sensor path through it
    scanner.py       the rotating scanner model (beams, elevation range, azimuth steps, range noise, ranges)
                     and its scans along a path, ray-cast with mi.Scene.ray_intersect
    registration.py  ICP: nearest-neighbour correspondences (kernels.points), Gauss-Newton steps from
                     kernels.icp's normal equations (point-to-point or point-to-plane, robust weights)
    odometry.py      voxel downsampling, the voxel local map, KISS-ICP's adaptive threshold, and the
                     scan-to-scan and scan-to-map odometry loops with a constant-velocity prediction
    baselines.py     KISS-ICP (the `kiss-icp` wheel) on the same scans, Open3D's registration_icp on pairs

Frames: the sensor frame is x forward, y left, z up (the usual LiDAR frame); poses are sensor-to-world
4x4 matrices, so research.poses.se3's ATE and RPE apply to them as to camera-to-world poses.
"""
