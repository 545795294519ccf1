"""drlab compute kernels (NVIDIA Warp): pure compute, no file I/O.

One layout per kernel family. A family that outgrows one module (about 600 lines) is a package
split by stage: `volume`, `splat`, `stereo`, `corr`; the others are single modules:
`lucas_kanade`, `ssim`, `icp` (ICP residuals, pose Jacobians and normal equations), `appearance`
(per-image bilateral-grid / affine colour transforms), `sh` (the real
spherical-harmonics basis shared by splats and voxel grids) and `optim` (the Adam optimiser every
fit uses). Each kernel module opens with the math it implements. `kernels._arrays` is the array
contract every entry point follows (NumPy or wp.array in, the same kind out, checked arguments),
`kernels.rotation` the one check that a matrix is a rotation or rigid transform (tolerance from how
the formats store matrices; re-orthonormalised), `kernels.launch` the race-free split launcher for
CPU kernels, and `kernels.reference` holds a plain NumPy forward of each family for the tests.
docs/kernels.md is the guide to using them and to adding a family. This package never imports
`research`.
"""

from kernels import cpu_target as _cpu_target

_cpu_target.apply()  # DRLAB_CPU_TARGET: compile the kernels for another CPU (kernels/cpu_target.py)
