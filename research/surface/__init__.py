"""Surface reconstruction: depth maps fused into a TSDF (kernels.tsdf), meshes, and their scores against
the true geometry.

    fusion.py       fusion_grid (the voxel grid over a scene box), fuse (drlab's Warp TSDF and marching
                    cubes), fuse_open3d (Open3D's ScalableTSDFVolume on the same depth maps: the baseline)
    depth.py        depth maps rendered from a splat fit and from a radiance-field fit, masked by opacity
    mesh.py         area-weighted surface sampling of a mesh, atomic PLY writing (plyfile)
    groundtruth.py  points and normals sampled on the Mitsuba scene's shapes, kept where a view saw them
    metrics.py      accuracy, completeness, chamfer, precision / recall / F-score at distance thresholds
                    (Knapitsch et al., "Tanks and Temples", 2017), normal consistency
"""
