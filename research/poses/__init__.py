"""Camera poses: SE(3) and trajectories, similarity alignment, joint pose refinement, structure from motion.

    se3.py            SO(3)/SE(3) exponential and logarithm, the left se(3) perturbation of world-to-camera,
                      TUM trajectory files, trajectory alignment, ATE and RPE, camera paths
    align.py          Umeyama's similarity alignment of two point sets, and camera pose errors after it
    refine_volume.py  BARF-style joint refinement of poses and a voxel-grid radiance field (volume renderer)
    refine_splats.py  BARF-style joint refinement of poses and Gaussian splats (splat renderer)
    sfm.py            photographs to a COLMAP model through pycolmap (`drlab sfm`)

Cameras themselves (OpenCV convention, conversions to Mitsuba and NeRF) live in research/cameras.py.
"""
