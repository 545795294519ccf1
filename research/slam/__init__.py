"""RGB-D SLAM with a Gaussian-splat map (SplaTAM-style: Keetha et al., CVPR 2024), on the CPU kernels.

    tracking.py  a frame's world-to-camera pose optimised against the fixed map (photometric + depth loss
                 over the rendered silhouette, the splat renderer's camera gradients, Adam on se(3))
    mapping.py   the map: splats back-projected from RGB-D pixels, densification where the map's
                 silhouette or depth disagrees with a frame, and optimisation over a keyframe window
    system.py    the loop over a sequence: initialise from frame 0, track every frame (constant-velocity
                 guess), map on keyframes, record tracking failures
"""

from research.slam.mapping import MapConfig, densify_mask, init_map, map_window, new_splats
from research.slam.system import SlamConfig, SlamResult, check_sequence, run_slam
from research.slam.tracking import TrackConfig, TrackResult, track_frame

__all__ = ["MapConfig", "SlamConfig", "SlamResult", "TrackConfig", "TrackResult", "check_sequence", "densify_mask",
           "init_map", "map_window", "new_splats", "run_slam", "track_frame"]
