"""Ground-truth datasets: geometric consistency, conventions, determinism, interruption, validation.

The consistency checks compare the files on disk (depth EXR, cameras.json,
PFM disparity, .flo flow) with Mitsuba's own world-space position AOV, rendered
again here, so the stored geometry is checked against an independent source.
"""

import json
import math
import shutil

import numpy as np
import pytest

from research import io
from research.cameras import Camera
from research.datasets import consistency
from research.datasets import (DatasetConfig, DatasetError, cache_dir, ensure, generate, get_scene, load, load_flow,
                               load_stereo, provenance)
from research.datasets.generate import GENERATOR_REVISION
from research.datasets.groundtruth import sample_depth
from research.datasets.render import SceneRenderer

RES = 64


@pytest.fixture(scope="module")
def objects_ds(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "objects"
    cfg = DatasetConfig("objects", views=5, res=RES, spp=4, seed=3, stereo=True, stereo_pairs=2, flow=True,
                        flow_frames=3)
    generate(cfg, out, show_progress=False)
    return out


@pytest.fixture(scope="module")
def renderer():
    return SceneRenderer(get_scene("objects"), spp=4)



def interrupt_after_views(monkeypatch, views: int):
    """Make the renderer raise KeyboardInterrupt (Ctrl-C) after `views` colour renders; returns the
    real render function, to put back with monkeypatch.setattr."""
    from research.datasets.render import SceneRenderer

    original, calls = SceneRenderer.render_rgba, {"n": 0}

    def dying(self, cam, seed):
        calls["n"] += 1
        if calls["n"] > views:
            raise KeyboardInterrupt
        return original(self, cam, seed)

    monkeypatch.setattr(SceneRenderer, "render_rgba", dying)
    return original

def test_layout_and_manifest(objects_ds):
    ds = load(objects_ds, verify_hashes=True)
    assert {v.split for v in ds.views} == {"train", "val", "test"}
    m = ds.manifest
    assert m["seed"] == 3 and m["config"]["scene"] == "objects"
    assert m["mitsuba_variant"] in ("llvm_ad_rgb", "scalar_rgb")
    assert "mitsuba" in m["versions"] and len(m["content_hash"]) == 64
    assert m["host"]["cpus"] >= 1 and m["host"]["cpu"]  # hashes are reproducible per kind of CPU
    assert provenance(objects_ds) == {"name": objects_ds.name, "generator_revision": GENERATOR_REVISION,
                                      "content_hash": m["content_hash"], "host": m["host"]}
    assert "stereo/p_000_disp.pfm" in m["files"] and "flow/f_000_flow.flo" in m["files"]
    t = json.loads((objects_ds / "transforms_train.json").read_text())
    for key in ("camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h", "frames"):
        assert key in t
    frame = t["frames"][0]
    assert (objects_ds / frame["file_path"]).is_file() and (objects_ds / frame["depth_file_path"]).is_file()
    split = ds.load_split("train")
    assert split.rgba.shape[1:] == (RES, RES, 4) and split.depth.shape[1:] == (RES, RES)
    # Depth is positive exactly on the mask; alpha is coverage, so it is 1 inside objects.
    assert np.all((split.depth > 0) == split.mask)
    assert np.all(split.rgba[..., 3][split.mask].mean() > 0.9)
    # The PNG is straight-alpha sRGB of the linear premultiplied EXR.
    png = io.read_png(objects_ds / f"{split.names[0]}.png", linear=True)
    a = split.rgba[0, ..., 3:]
    straight = np.where(a > 0.05, split.rgba[0, ..., :3] / np.maximum(a, 1e-8), 0)
    sel = (a[..., 0] > 0.05) & (straight.max(-1) < 0.95)
    np.testing.assert_allclose(png[..., :3][sel], straight[sel], atol=0.02)


def test_positions_project_to_pixel_centres_and_match_depth(objects_ds, renderer):
    r = consistency.aov_reprojection(load(objects_ds), renderer)
    assert r["mask_mismatches"] == 0
    assert r["pixel_err_max"] < 1e-3  # Mitsuba's position AOV lands on our pixel centres
    assert r["depth_rel_err_max"] < 1e-5  # stored z-depth (near-clip corrected) is the position's z


def test_multiview_reprojection(objects_ds, renderer):
    """View A's depth and pose, reprojected into view B, land on B's surface (exact ray casts)."""
    r = consistency.multiview_reprojection(load(objects_ds), renderer)
    assert r["pairs"] >= 6 and r["points"] > 1000
    assert r["depth_rel_err_max"] < 1e-3
    assert r["depth_rel_outliers"] == 0 and r["depth_rel_err_p999"] <= r["depth_rel_err_max"]
    assert r["pixel_err_max"] < 1e-3


def test_stereo_correspondence(objects_ds, renderer):
    pairs = load_stereo(objects_ds)
    for p in pairs:
        assert np.allclose(p.right_camera.R, p.left_camera.R)
        offset = p.left_camera.w2c[:3, :3] @ (p.right_camera.center - p.left_camera.center)
        np.testing.assert_allclose(offset, [p.baseline, 0, 0], atol=1e-12)
        assert np.all(np.isfinite(p.disparity)) and np.all(p.disparity[~p.mask] == 0)
        assert not np.any(p.noc & ~p.mask)
        # The right view's own geometry agrees: same z-depth at (x - d, y) where visible.
        gr = renderer.render_geometry(p.right_camera)
        u, v = p.left_camera.pixel_centers()
        zs, _ = sample_depth(gr.depth, gr.mask, u[p.noc] - p.disparity[p.noc], v[p.noc])
        assert np.median(np.abs(zs - p.depth[p.noc]) / p.depth[p.noc]) < 1e-4
    r = consistency.stereo_correspondence(pairs, renderer)
    assert r["pixel_err_max"] < 1e-3
    assert r["noc_fraction"] > 0.5 and r["disparity_max"] > 1.0


def test_flow_matches_second_frame_surface(objects_ds, renderer):
    seq = load_flow(objects_ds)
    r = consistency.flow_correspondence(seq, renderer)
    assert r["pixel_err_median"] < 1e-2
    assert r["valid_fraction"] > 0.5
    assert 0.2 < r["flow_magnitude_median"] < 20  # a real but small motion
    # The flow carries frame 1's surface point (Mitsuba's AOV) to its projection in frame 2.
    for k in range(len(seq.cameras) - 1):
        g1 = renderer.render_geometry(seq.cameras[k])
        valid = seq.valid[k]
        uv2, _ = seq.cameras[k + 1].project(g1.position[valid])
        u, _ = seq.cameras[k].pixel_centers()
        np.testing.assert_allclose(uv2[:, 0] - u[valid], seq.flow[k][valid][:, 0], atol=1e-3)


def test_nerfstudio_style_reading_matches_cameras_json(objects_ds):
    """Read transforms_*.json as nerfstudio does (OpenGL c2w, camera_angle_x) and back-project depth."""
    cams = {v["name"]: v for v in json.loads((objects_ds / "cameras.json").read_text())["views"]}
    for split in ("train", "val", "test"):
        t = json.loads((objects_ds / f"transforms_{split}.json").read_text())
        W, H = t["w"], t["h"]
        f = 0.5 * W / math.tan(0.5 * t["camera_angle_x"])
        for frame in t["frames"]:
            c2w = np.array(frame["transform_matrix"])
            depth = io.read_exr(objects_ds / frame["depth_file_path"])
            i, j = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
            dirs = np.stack([(i - W / 2) / f, -(j - H / 2) / f, -np.ones_like(i)], -1)  # OpenGL camera
            pts_gl = c2w[:3, 3] + (depth[..., None] * dirs) @ c2w[:3, :3].T
            ref = cams[frame["file_path"].removesuffix(".png")]
            K, c2w_cv = np.array(ref["K"]), np.array(ref["c2w"])
            d_cv = np.stack([i, j, np.ones_like(i)], -1) @ np.linalg.inv(K).T
            pts_cv = c2w_cv[:3, 3] + (depth[..., None] * d_cv) @ c2w_cv[:3, :3].T
            np.testing.assert_allclose(pts_gl, pts_cv, atol=1e-9)


def test_same_seed_same_hash_and_resume_after_interruption(tmp_path, monkeypatch):
    cfg = DatasetConfig("spheres", views=4, res=16, spp=2, seed=11, stereo=True, stereo_pairs=1)
    h1 = json.loads((generate(cfg, tmp_path / "a", show_progress=False) / "manifest.json").read_text())
    h2 = json.loads((generate(cfg, tmp_path / "b", show_progress=False) / "manifest.json").read_text())
    assert h1["content_hash"] == h2["content_hash"]
    other = DatasetConfig("spheres", views=4, res=16, spp=2, seed=12, stereo=True, stereo_pairs=1)
    h3 = json.loads((generate(other, tmp_path / "c", show_progress=False) / "manifest.json").read_text())
    assert h3["content_hash"] != h1["content_hash"]

    # Kill the run after two views.
    original = interrupt_after_views(monkeypatch, 2)
    out = tmp_path / "d"
    with pytest.raises(KeyboardInterrupt):
        generate(cfg, out, show_progress=False)
    assert not out.exists()
    assert (tmp_path / "d.partial").is_dir() and not (tmp_path / "d.partial" / "manifest.json").exists()
    with pytest.raises(DatasetError, match="resume"):
        load(out)
    with pytest.raises(ValueError, match="--resume"):
        generate(cfg, out, show_progress=False)
    monkeypatch.setattr(SceneRenderer, "render_rgba", original)
    with pytest.raises(ValueError, match="different configuration"):
        generate(other, out, resume=True, show_progress=False)
    generate(cfg, out, resume=True, show_progress=False)
    h4 = json.loads((out / "manifest.json").read_text())
    assert h4["content_hash"] == h1["content_hash"]
    assert not (tmp_path / "d.partial").exists()
    with pytest.raises(ValueError, match="--force"):
        generate(cfg, out, show_progress=False)


def test_ensure_reuses_matching_data_and_regenerates_stale(tmp_path):
    cfg = DatasetConfig("spheres", views=3, res=8, spp=1, seed=2)
    out = cache_dir(cfg, tmp_path)
    assert out == tmp_path / "spheres-views3-res8-spp1-seed2"
    assert cache_dir(DatasetConfig("spheres", stereo=True), tmp_path).name == "spheres-stereo"
    ensure(cfg, out, show_progress=False)
    manifest = out / "manifest.json"
    first = json.loads(manifest.read_text())
    assert first["generator_revision"] == GENERATOR_REVISION
    stamp = manifest.stat().st_mtime_ns
    assert ensure(cfg, out, show_progress=False) == out and manifest.stat().st_mtime_ns == stamp  # reused

    # A dataset from an older generator revision (here: no revision recorded) is rendered again.
    del first["generator_revision"]
    manifest.write_text(json.dumps(first))
    ensure(cfg, out, show_progress=False)
    again = json.loads(manifest.read_text())
    assert again["generator_revision"] == GENERATOR_REVISION
    assert again["content_hash"] == first["content_hash"]


def test_loader_errors_name_the_file(objects_ds, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(objects_ds, bad)
    (bad / "train" / "r_000_depth.exr").unlink()
    with pytest.raises(DatasetError, match="r_000_depth.exr"):
        load(bad)

    bad2 = tmp_path / "bad2"
    shutil.copytree(objects_ds, bad2)
    io.write_exr(bad2 / "test" / "r_000.exr", np.zeros((RES // 2, RES, 4), np.float32))
    with pytest.raises(DatasetError, match="r_000.exr"):
        load(bad2)

    bad3 = tmp_path / "bad3"
    shutil.copytree(objects_ds, bad3)
    doc = json.loads((bad3 / "cameras.json").read_text())
    doc["views"][1]["c2w"][0][3] = float("nan")
    (bad3 / "cameras.json").write_text(json.dumps(doc))
    with pytest.raises(DatasetError, match="cameras.json: content does not match"):
        load(bad3)
    with pytest.raises(DatasetError, match="cameras.json.*c2w"):  # the structural check, without hashes
        load(bad3, verify_hashes=False)

    bad4 = tmp_path / "bad4"
    shutil.copytree(objects_ds, bad4)
    (bad4 / "manifest.json").unlink()
    with pytest.raises(DatasetError, match="manifest.json"):
        load(bad4)


@pytest.mark.parametrize("kwargs, field", [
    (dict(scene="nope"), "scene"), (dict(views=2), "views"), (dict(res=0), "res"), (dict(spp=-1), "spp"),
    (dict(baseline=0.0), "baseline"), (dict(val_fraction=0.7), "val_fraction"),
])
def test_bad_config(kwargs, field, tmp_path):
    base = dict(scene="spheres", views=4, res=8, spp=1)
    base.update(kwargs)
    with pytest.raises(ValueError, match=field):
        generate(DatasetConfig(**base), tmp_path / "x", show_progress=False)
    assert not (tmp_path / "x.partial").exists()


def test_every_scene_renders_with_bbox_containing_geometry(renderer):
    from research.datasets import SCENES

    for name, spec in SCENES.items():
        r = renderer if name == "objects" else SceneRenderer(spec, spp=1)
        for pose in spec.view_poses(2, 0):
            cam = Camera.from_fov(spec.fov_x_deg, 32, 32, pose)
            g = r.render_geometry(cam)
            assert g.mask.mean() > 0.1, name
            P = g.position[g.mask]
            lo, hi = spec.bbox
            inside = np.all(P >= lo - 1e-3, axis=1) & np.all(P <= hi + 1e-3, axis=1)
            if spec.unbounded:  # the box holds the foreground; the background lies beyond it
                assert 0.02 < inside.mean() < 0.98, name
            else:
                assert np.all(inside), name


def test_verification_fast_path_rehashes_only_changed_files(tmp_path, monkeypatch):
    from research.datasets import integrity as verify_mod

    out = generate(DatasetConfig("spheres", views=3, res=8, spp=1, seed=4), tmp_path / "ds", show_progress=False)
    hashed = []
    original = verify_mod.file_sha256
    monkeypatch.setattr(verify_mod, "file_sha256", lambda p: hashed.append(p.name) or original(p))
    m = json.loads((out / "manifest.json").read_text())
    assert verify_mod.verify(out) == m["content_hash"] and hashed == []  # the generator left the cache
    assert provenance(out)["content_hash"] == m["content_hash"] and hashed == []
    png = out / "train" / "r_000.png"
    png.write_bytes(png.read_bytes())  # same bytes, new mtime: rehashed once, then trusted again
    load(out)
    assert hashed == ["r_000.png"]
    load(out)
    assert hashed == ["r_000.png"]
    (out / verify_mod.VERIFIED).unlink()  # no cache: everything is hashed
    load(out)
    assert len(hashed) == 1 + len(m["files"])
