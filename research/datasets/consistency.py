"""Geometric consistency of a dataset on disk against Mitsuba itself.

Each check compares what the generator stored (depth EXR, cameras.json, PFM
disparity, .flo flow) with an independent source: Mitsuba's world-position AOV
and exact ray casts into the scene. The tests assert thresholds on these
numbers and `experiments/datasets.py` reports them.

* `aov_reprojection`: Mitsuba's position AOV of every view, projected with our
  camera, lands on the pixel centre; stored z-depth equals its z.
* `multiview_reprojection`: view A's stored depth and pose, reprojected into B,
  land on B's surface (an exact ray cast from B), where a shadow ray says the
  point is visible from B. Grazing views (|cos| < 0.05) are left out: there,
  float32 positions decide whether a ray hits or misses a silhouette.
* `stereo_correspondence`: the left position AOV, projected into the right
  camera, lands at (x - d, y) for non-occluded pixels.
* `flow_correspondence`: frame 2's position AOV sampled (bilinearly) at x + flow
  and projected into frame 1 lands on x.
"""

from __future__ import annotations

import numpy as np

from research import io
from research.datasets.loader import Dataset, FlowSequence, StereoPair
from research.datasets.render import SceneRenderer


def bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear sample of (H, W, C) at continuous (u, v); `ok` where all four neighbours are non-zero."""
    H, W = img.shape[:2]
    x, y = u - 0.5, v - 0.5
    i0, j0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ok = (i0 >= 0) & (j0 >= 0) & (i0 + 1 < W) & (j0 + 1 < H)
    i0, j0 = np.clip(i0, 0, W - 2), np.clip(j0, 0, H - 2)
    fx, fy = (x - i0)[..., None], (y - j0)[..., None]
    corners = [img[j0, i0], img[j0, i0 + 1], img[j0 + 1, i0], img[j0 + 1, i0 + 1]]
    for c in corners:
        ok &= np.any(c != 0, axis=-1)
    val = ((1 - fx) * (1 - fy) * corners[0] + fx * (1 - fy) * corners[1]
           + (1 - fx) * fy * corners[2] + fx * fy * corners[3])
    return val, ok


def aov_reprojection(ds: Dataset, renderer: SceneRenderer) -> dict[str, float]:
    px, rel, mask_mismatch = [], [], 0
    for view in ds.views:
        g = renderer.render_geometry(view.camera)
        depth = io.read_exr(view.path("_depth.exr"))
        mask_mismatch += int(np.sum((depth > 0) != g.mask))
        uv, z = view.camera.project(g.position[g.mask])
        u, v = view.camera.pixel_centers()
        px.append(np.hypot(uv[:, 0] - u[g.mask], uv[:, 1] - v[g.mask]))
        rel.append(np.abs(z - depth[g.mask]) / z)
    px_all, rel_all = np.concatenate(px), np.concatenate(rel)
    return {"views": len(ds.views), "points": int(px_all.size), "pixel_err_max": float(px_all.max()),
            "depth_rel_err_max": float(rel_all.max()), "mask_mismatches": mask_mismatch}


def multiview_reprojection(ds: Dataset, renderer: SceneRenderer, max_views: int = 6,
                           min_points: int = 50) -> dict[str, float]:
    views = ds.views[:max_views]
    rels, pxs, pairs = [], [], 0
    for a in views:
        depth_a = io.read_exr(a.path("_depth.exr"))
        hit_a = depth_a > 0
        X = a.camera.backproject(np.where(hit_a, depth_a, 1.0))[hit_a]
        pos_a = renderer.render_geometry(a.camera).position[hit_a]
        normal_a = io.read_exr(a.path("_normal.exr"))[hit_a]
        for b in views:
            if a is b:
                continue
            cam = b.camera
            uv, z = cam.project(X)
            inside = np.all((uv >= 0) & (uv < [cam.width, cam.height]), axis=1)
            Xi, zi = X[inside], z[inside]
            # z-depth of B's first surface along B's ray through X (unnormalised rays: t is z-depth).
            dirs = cam.camera_directions(uv[inside, 0], uv[inside, 1]) @ cam.R.T
            t, _ = renderer.cast(np.broadcast_to(cam.center, dirs.shape), dirs)
            # Visibility from an independent shadow ray X -> B's centre, leaving X by 2 mm.
            to_b = cam.center - Xi
            start = Xi + 2e-3 * to_b / np.linalg.norm(to_b, axis=1, keepdims=True)
            t_shadow, _ = renderer.cast(start, cam.center - start)  # t = 1 reaches B
            cos = np.abs(np.einsum("nc,nc->n", normal_a[inside], to_b)) / np.linalg.norm(to_b, axis=1)
            visible = np.isfinite(t) & ~(t_shadow < 1.0) & (cos > 0.05)
            if visible.sum() < min_points:
                continue
            rels.append(np.abs(t[visible] - zi[visible]) / zi[visible])
            # Our depth + pose path vs Mitsuba's world positions of view A, in B's pixels.
            uv_aov, _ = cam.project(pos_a[inside][visible])
            pxs.append(np.hypot(*(uv_aov - uv[inside][visible]).T))
            pairs += 1
    if not pairs:
        raise ValueError("multiview_reprojection: no pair of views shares enough visible surface")
    rel, px = np.concatenate(rels), np.concatenate(pxs)
    # The maximum alone can be one grazing-edge point, where B's camera ray and the shadow ray along
    # the same line disagree about an occluder's edge; the 99.9th percentile and the count above
    # 1e-3 say whether the depth maps disagree anywhere else.
    return {"pairs": pairs, "points": int(rel.size), "depth_rel_err_max": float(rel.max()),
            "depth_rel_err_median": float(np.median(rel)), "depth_rel_err_p999": float(np.quantile(rel, 0.999)),
            "depth_rel_outliers": int(np.count_nonzero(rel > 1e-3)), "pixel_err_max": float(px.max())}


def stereo_correspondence(pairs: list[StereoPair], renderer: SceneRenderer) -> dict[str, float]:
    errs, noc_frac = [], []
    for p in pairs:
        g = renderer.render_geometry(p.left_camera)
        uv_r, _ = p.right_camera.project(g.position[p.noc])
        u, v = p.left_camera.pixel_centers()
        du = uv_r[:, 0] - (u[p.noc] - p.disparity[p.noc])
        dv = uv_r[:, 1] - v[p.noc]
        errs.append(np.hypot(du, dv))
        noc_frac.append(p.noc.sum() / max(1, p.mask.sum()))
    e = np.concatenate(errs)
    return {"pairs": len(pairs), "points": int(e.size), "pixel_err_max": float(e.max()),
            "pixel_err_median": float(np.median(e)), "noc_fraction": float(np.mean(noc_frac)),
            "disparity_max": float(max(p.disparity.max() for p in pairs))}


def flow_correspondence(seq: FlowSequence, renderer: SceneRenderer) -> dict[str, float]:
    errs, mags, valid_frac = [], [], []
    for k in range(len(seq.cameras) - 1):
        c1, c2 = seq.cameras[k], seq.cameras[k + 1]
        flow, valid = seq.flow[k], seq.valid[k]
        g2 = renderer.render_geometry(c2)
        u, v = c1.pixel_centers()
        P, ok = bilinear(g2.position, u[valid] + flow[valid][:, 0], v[valid] + flow[valid][:, 1])
        uv1, _ = c1.project(P[ok])
        errs.append(np.hypot(uv1[:, 0] - u[valid][ok], uv1[:, 1] - v[valid][ok]))
        mags.append(np.hypot(*flow[valid].T))
        valid_frac.append(valid.sum() / max(1, (seq.depth[k] > 0).sum()))
    e, m = np.concatenate(errs), np.concatenate(mags)
    return {"pairs": len(seq.cameras) - 1, "points": int(e.size), "pixel_err_median": float(np.median(e)),
            "pixel_err_p95": float(np.percentile(e, 95)), "flow_magnitude_median": float(np.median(m)),
            "valid_fraction": float(np.mean(valid_frac))}
