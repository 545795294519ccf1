"""Stereo matching on rectified pairs (the whole family in kernels/stereo/costs.py until it is split by stage)."""

from kernels.stereo.costs import (CENSUS_MAX_BITS, SGM_AXES, SGM_DIRECTIONS, SGM_LANES, census_cost,
                                  census_transform, depth_from_disparity, feature_correlation,
                                  feature_correlation_backward, left_right_check, sad_cost, sgm, soft_argmin,
                                  soft_argmin_backward, wta, wta_right, zncc_cost)
