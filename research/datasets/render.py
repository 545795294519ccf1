"""Mitsuba render passes for one camera: colour, and exact per-pixel geometry.

Two passes per view (docs/mitsuba.md):

* RGB: integrator `path` with `hide_emitters` (except the Cornell box, whose only emitter
  is its ceiling light), film `hdrfilm` RGBA with a box pixel filter. The result is
  linear, premultiplied RGB with alpha = antialiased coverage.
* Geometry: integrator `aov` (`dd:depth, pp:position, nn:sh_normal`) with one
  non-jittered stratified sample per pixel and a box filter, i.e. exactly one ray
  through each pixel centre. Multi-sample AOVs would average depth with the zeros
  of missed rays at silhouettes, so they are never used as ground truth.
  The AOV depth is measured from the near-clip plane:
      z-depth = depth_aov * cos(theta) + near_clip,  cos(theta) = 1 / |K^{-1}[u, v, 1]|.
  Misses are 0 in every AOV, so the hit mask is depth_aov > 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from research.cameras import Camera
from research.datasets.scenes import SceneSpec
from research.mitsuba_env import select_variant


@dataclass
class GeometryPass:
    depth: np.ndarray  # (H, W) z-depth, 0 where no surface
    position: np.ndarray  # (H, W, 3) world position, 0 where no surface
    normal: np.ndarray  # (H, W, 3) world shading normal, 0 where no surface
    mask: np.ndarray  # (H, W) bool, True where the pixel-centre ray hits a surface


class SceneRenderer:
    """Loads a scene once and renders colour and geometry for any Camera."""

    def __init__(self, spec: SceneSpec, spp: int = 64, max_depth: int = 8):
        if spp <= 0:
            raise ValueError(f"spp: expected a positive sample count, got {spp}")
        import mitsuba as mi

        self.variant = select_variant()
        self.mi = mi
        self.spec = spec
        self.spp = int(spp)
        self.scene = mi.load_dict(spec.build())
        self.rgb_integrator = mi.load_dict({"type": "path", "hide_emitters": spec.hide_emitters,
                                             "max_depth": max_depth})
        self.aov_integrator = mi.load_dict({"type": "aov", "aovs": "dd:depth,pp:position,nn:sh_normal"})
        self._sensors: dict[tuple, tuple[Any, Any]] = {}

    def _sensor(self, cam: Camera, geometry: bool) -> Any:
        """A sensor for `cam`. Sensors are cached per (intrinsics, size, pass) and moved by
        updating `to_world`: a freshly loaded sensor would make Dr.Jit recompile its kernels
        (about 1.7 s per view at 256x256), while an updated one reuses them."""
        mi = self.mi
        key = (geometry, cam.width, cam.height, cam.K.tobytes())
        if key not in self._sensors:
            film: dict[str, Any] = {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                                    "component_format": "float32"}
            if geometry:
                film["rfilter"] = {"type": "box"}
                film["pixel_format"] = "rgb"  # ignored by the AOV integrator's own channels
                sampler = {"type": "stratified", "sample_count": 1, "jitter": False}
            else:
                # Box filter: each pixel is the average radiance over its own area, the quantity a
                # NeRF or splat renderer that jitters rays inside the pixel estimates. It is also
                # about 25% faster than the default Gaussian, which splats every sample to 16 pixels.
                film["rfilter"] = {"type": "box"}
                film["pixel_format"] = "rgba"
                sampler = {"type": "independent", "sample_count": self.spp}
            sensor = mi.load_dict({
                "type": "perspective",
                **cam.mitsuba_intrinsics(),
                "near_clip": self.spec.near_clip,
                "far_clip": self.spec.far_clip,
                "film": film,
                "sampler": sampler,
            })
            self._sensors[key] = (sensor, mi.traverse(sensor))
        sensor, params = self._sensors[key]
        params["to_world"] = mi.Transform4f(cam.to_mitsuba().tolist())
        params.update()
        return sensor

    def render_rgba(self, cam: Camera, seed: int) -> np.ndarray:
        """Linear premultiplied RGBA (H, W, 4) float32 at `self.spp` samples per pixel."""
        img = self.mi.render(self.scene, sensor=self._sensor(cam, geometry=False),
                             integrator=self.rgb_integrator, seed=int(seed), spp=self.spp)
        out = np.array(img, dtype=np.float32)
        if out.shape != (cam.height, cam.width, 4):
            raise RuntimeError(f"Mitsuba returned an RGBA image of shape {out.shape}")
        return out

    def render_geometry(self, cam: Camera) -> GeometryPass:
        """Exact geometry through pixel centres (one ray per pixel)."""
        img = self.mi.render(self.scene, sensor=self._sensor(cam, geometry=True),
                             integrator=self.aov_integrator, seed=0, spp=1)
        arr = np.array(img, dtype=np.float64)
        if arr.shape[:2] != (cam.height, cam.width) or arr.shape[2] < 7:
            raise RuntimeError(f"Mitsuba returned an AOV image of shape {arr.shape}, expected (H, W, 7)")
        # Channels: [depth, P.xyz, N.xyz] (no nested integrator).
        d_aov, pos, nrm = arr[..., 0], arr[..., 1:4], arr[..., 4:7]
        mask = d_aov > 0
        depth = np.where(mask, d_aov * cam.ray_cosines() + self.spec.near_clip, 0.0)
        pos = np.where(mask[..., None], pos, 0.0)
        nrm = np.where(mask[..., None], nrm, 0.0)
        return GeometryPass(depth=depth, position=pos, normal=nrm, mask=mask)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact first hits of arbitrary world-space rays: (distance t along `directions`, world point).

        Misses get t = inf and a NaN point. Vectorised on the LLVM variant; a
        Python loop on scalar_rgb (fine for tests, slow for images).
        """
        mi = self.mi
        o = np.ascontiguousarray(np.asarray(origins, np.float64).reshape(-1, 3))
        d = np.ascontiguousarray(np.asarray(directions, np.float64).reshape(-1, 3))
        norm = np.linalg.norm(d, axis=1)
        du = d / norm[:, None]
        if self.variant.startswith("scalar"):
            t = np.full(len(o), np.inf)
            for k in range(len(o)):
                si = self.scene.ray_intersect(mi.Ray3f(mi.Point3f(*o[k]), mi.Vector3f(*du[k])))
                if si.is_valid():
                    t[k] = float(si.t)
        else:
            ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, i]) for i in range(3)]),
                           mi.Vector3f(*[mi.Float(du[:, i]) for i in range(3)]))
            si = self.scene.ray_intersect(ray)
            valid = np.array(si.is_valid(), dtype=bool)
            t = np.where(valid, np.array(si.t, dtype=np.float64), np.inf)
        t_along = t / norm  # distance in units of the given directions
        points = np.where(np.isfinite(t)[:, None], o + t_along[:, None] * d, np.nan)
        shape = np.asarray(origins).shape[:-1]
        return t_along.reshape(shape), points.reshape(shape + (3,))
