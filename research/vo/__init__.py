"""Classical RGB-D feature visual odometry: the baseline of the splat SLAM experiment.

* features.py: ORB keypoints and descriptors (OpenCV), ratio-test + mutual matching, depth at keypoints;
* odometry.py: essential-matrix initialisation with scale from depth, guided PnP RANSAC tracking,
  keyframes, landmarks (triangulated or back-projected from depth), tracking failures;
* ba.py: local bundle adjustment, reprojection residuals and Jacobians from the Warp kernel kernels.ba,
  the SE(3) left Jacobian chain, scipy's sparse least squares with a robust loss;
* loop.py: loop detection against the first keyframes, PnP verification, SE(3) pose-graph optimisation.

Poses follow research/poses/se3.py: world-to-camera T_cw, left se(3) perturbation T_cw <- exp(xi^) T_cw,
xi = (rho, phi) translation first.
"""

from research.vo.ba import BAResult, bundle_adjust, se3_left_jacobian
from research.vo.loop import Loop, LoopConfig, detect_loops, optimise_pose_graph
from research.vo.odometry import TrackingError, VOConfig, VOResult, check_sequence, run_vo

__all__ = ["BAResult", "bundle_adjust", "se3_left_jacobian", "Loop", "LoopConfig", "detect_loops",
           "optimise_pose_graph", "TrackingError", "VOConfig", "VOResult", "check_sequence", "run_vo"]
