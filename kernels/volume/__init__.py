"""Volume rendering (NeRF-style) as Warp kernels with hand-written backward passes.

The family follows NeRF (Mildenhall et al. 2020) for the rendering equation and the frequency
encoding, instant-ngp (Mueller et al. 2022) for the hash encoding, occupancy grid and early ray
termination, Plenoxels / DVGO (Fridovich-Keil et al. 2022; Sun et al. 2022) for voxel grids.
For a ray r(t) = o + t d through samples t_k with interval lengths delta_k,

    C = sum_k T_k (1 - exp(-sigma_k delta_k)) c_k + T_N b,   T_k = exp(-sum_{j<k} sigma_j delta_j),

with expected depth D = sum_k w_k z_k and opacity A = 1 - T_N. Every module opens with its own
equations:

    sampling   ray-AABB slab test, stratified samples, occupancy skipping, packed layout
    composite  the quadrature above, forward and hand-written reverse pass (one thread per ray)
    occupancy  occupancy grid with EMA-max updates and a threshold
    spheres    analytic soft spheres (the Video and 3D Vision textbook chapter's scene)   Field
               (its plain Warp kernels in spheres_kernels, the CPU passes in spheres_passes)
    grid       dense voxel grid, trilinear density + RGB or SH <= 2                       Field
    hashgrid   multiresolution hash encoding
    encoding   frequency positional encoding
    mlp        ReLU MLP, forward and backward (Warp kernels; BLAS products on the CPU)
    neural     HashGridField (hash + MLP), PEMLPField (PE + MLP)                          Field
    render     sampling -> field -> compositing, and the chain rule back to the parameters
    rays       pinhole camera rays, NeRF's NDC map of rays, and the render's gradient wrt the camera
    field_points  a field's gradient wrt its sample points and view directions (spheres, grid)
    contract   mip-NeRF 360's scene contraction (L2) and its VJP, the s-space spacing of samples,
               ContractedField (any field on [-2, 2]^3 made to cover all of space)        Field
    proposal   proposal sampling: interval weights and their VJP, inverse-CDF resampling, the
               interlevel loss and its VJP (mip-NeRF 360, nerfacc's PropNetEstimator)
    workspace  reusable output buffers (fresh large arrays cost page faults on every call)
    _act, _checks  activations shared by the fields; the family's own argument checks

The plain NumPy forward passes the tests compare against are in kernels/reference/volume.py
(kernels/reference/volume_unbounded.py for contract and proposal).

Everything is generic over float32 and float64 and takes a `device`; the CPU is the tested path.
Inputs and outputs follow the array contract of kernels._arrays (NumPy in, NumPy out; wp.arrays
in, wp.arrays out on their device; value checks off inside `value_checks(False)`); gradients of a
field's parameters are wp.arrays like the parameters. Fitting uses kernels.optim.Adam.
Kernels whose writes are disjoint per thread run through kernels.launch.launch_split; scatters
of gradients into shared parameters (grid vertices, hash entries, sphere parameters) use atomic
adds inside a single launch, because no Warp atomic is atomic between concurrent CPU launches
(docs/warp.md). Warp's tape is not used: every adjoint is written by hand and checked against
finite differences (research/checks/volume.py).
"""

from kernels.volume.composite import (DEFAULT_T_THRESHOLD, CompositeResult, composite_backward, composite_forward,
                                      dense_offsets)
from kernels.volume.encoding import PositionalEncoding
from kernels.volume.field import Field, FieldOutput
from kernels.volume.grid import GridField
from kernels.volume.hashgrid import HashEncoding
from kernels.volume.mlp import MLP
from kernels.volume.neural import HashGridField, PEMLPField
from kernels.volume.occupancy import OccupancyGrid
from kernels.volume.render import RenderResult, render_backward, render_rays, render_samples
from kernels.volume.rays import (CameraGrad, camera_rays, camera_rays_backward, ndc_rays, ndc_rays_backward,
                                 pixel_centers, render_backward_camera, render_backward_rays)
from kernels.volume.sampling import Samples, ray_aabb, sample_rays
from kernels.volume.spheres import SphereField
from kernels.volume.workspace import Workspace

__all__ = ["DEFAULT_T_THRESHOLD", "CompositeResult", "composite_backward", "composite_forward",
           "dense_offsets", "PositionalEncoding", "Field", "FieldOutput", "GridField", "HashEncoding", "MLP",
           "HashGridField", "PEMLPField", "OccupancyGrid", "RenderResult", "render_backward", "render_rays",
           "render_samples", "Samples", "ray_aabb", "sample_rays", "SphereField", "Workspace", "CameraGrad",
           "camera_rays", "camera_rays_backward", "ndc_rays", "ndc_rays_backward", "pixel_centers",
           "render_backward_camera", "render_backward_rays"]
