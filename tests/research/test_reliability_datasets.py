"""Reliability of ground-truth datasets: bad inputs get one clear line, faults are caught or recovered.

Two tables:

* BAD_INPUTS: a configuration, `--out` or file situation, each with the one-line ValueError it must
  raise before anything is created (nothing new appears in the folder, not even a lock file).
* Faults: tampered files of every kind, edited manifests, extra and deleted files, broken `.partial`
  folders, stale temporary files, a concurrent `ensure`, SIGKILLs of `drlab dataset` at seeded random
  points, and a tampered disparity map under the stereo_depth experiment.

Renders are tiny (spheres, 24x24, 2 spp, 3 views) so the file runs in well under a minute.
"""

from __future__ import annotations

import json
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from research import atomic, io
from research.datasets import (DatasetConfig, DatasetError, ensure, generate, load, load_flow, load_stereo,
                               provenance, verify)
from research.datasets.folders import PARTIAL_CONFIG, dataset_lock
from research.datasets.integrity import VERIFIED, content_hash

REPO = Path(__file__).resolve().parents[2]
TINY = dict(scene="spheres", views=3, res=24, spp=2)
FULL = DatasetConfig(**TINY, seed=5, stereo=True, stereo_pairs=1, flow=True, flow_frames=2)
CLI_CFG = DatasetConfig(**TINY, seed=1)  # what the kill test's command line renders
CLI = [sys.executable, "-m", "research.cli", "dataset", "--scene", "spheres", "--views", "3", "--res", "24",
       "--spp", "2", "--seed", "1"]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted render with stereo and flow, copied by the tests that tamper with it."""
    return generate(FULL, tmp_path_factory.mktemp("ref") / "full", show_progress=False)


@pytest.fixture(scope="module")
def cli_reference(tmp_path_factory) -> str:
    """The content hash of an uninterrupted render of CLI_CFG."""
    out = generate(CLI_CFG, tmp_path_factory.mktemp("cliref") / "ds", show_progress=False)
    return json.loads((out / "manifest.json").read_text())["content_hash"]


def _snapshot(root: Path) -> dict[str, bytes | None]:
    return {p.relative_to(root).as_posix(): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _leftovers(root: Path) -> list[str]:
    """Anything half-written: atomic temporary files, .partial or .drlab-old folders."""
    return [p.relative_to(root).as_posix() for p in root.rglob("*")
            if atomic.is_temporary(p.name) or p.name.endswith((".partial", ".drlab-old"))]


# --------------------------------------------------------------------------- bad inputs

def _cfg(**kw):
    return lambda tmp: generate(DatasetConfig(**{**TINY, **kw}), tmp / "ds", show_progress=False)


def _out(make, out, force=False, resume=False, cfg=None):
    """Prepare a situation under tmp (`make(tmp)`), then generate into `out` (relative to tmp)."""
    def run(tmp):
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            return generate(cfg or DatasetConfig(**TINY), out, force=force, resume=resume, show_progress=False)
        finally:
            os.chdir(cwd)
    run.make = make
    return run


def _nothing(tmp):
    pass


def _file(name):
    def make(tmp):
        (tmp / name).write_text("not a dataset\n")
    return make


def _folder_with(folder, name, text):
    """A maker of the folder `folder` holding the file `name` with `text`."""
    def make(tmp):
        (tmp / folder).mkdir()
        (tmp / folder / name).write_text(text)
    return make


_user_folder = _folder_with("thesis", "thesis.txt", "three years of work\n")
_foreign_manifest = _folder_with("other", "manifest.json", json.dumps({"name": "someone else's", "files": {}}))
_broken_manifest = _folder_with("other", "manifest.json", "{not json")
_drlab_dataset = _folder_with("ds", "manifest.json", json.dumps({"generator": "drlab dataset", "files": {}}))


def _broken_link(tmp):
    (tmp / "ds").symlink_to(tmp / "nowhere")


def _partial_of(**kw):
    return _folder_with("ds.partial", PARTIAL_CONFIG, json.dumps(asdict(DatasetConfig(**{**TINY, **kw}))))


def _ensure(**kw):
    return lambda tmp: ensure(DatasetConfig(**{**TINY, **kw}), tmp / "cache" / "ds", show_progress=False)


def _with(make, fn):
    fn.make = make
    return fn


def _load(fn, sub="ds", **kw):
    return lambda tmp: fn(tmp / sub, **kw)


def _load_without(part):
    def run(tmp):
        ds = generate(DatasetConfig(**TINY), tmp / "ds", show_progress=False)
        return (load_stereo if part == "stereo" else load_flow)(ds)
    run.keeps_files = True
    return run


def _partial_folder(tmp):
    (tmp / "ds.partial").mkdir()


BAD_INPUTS = {
    # DatasetConfig fields, named by their `drlab dataset` option
    "scene-unknown": (_cfg(scene="nope"), r"--scene: expected one of spheres, objects, cornell, backdrop, got 'nope'"),
    "scene-empty": (_cfg(scene=""), r"--scene: expected one of .*, got ''"),
    "scene-none": (_cfg(scene=None), r"--scene: expected one of .*, got None"),
    "views-zero": (_cfg(views=0), r"--views: expected a positive integer, got 0"),
    "views-two": (_cfg(views=2), r"--views: expected at least 3 \(one per split\), got 2"),
    "views-negative": (_cfg(views=-4), r"--views: expected a positive integer, got -4"),
    "views-float": (_cfg(views=3.5), r"--views: expected a positive integer, got 3.5"),
    "views-bool": (_cfg(views=True), r"--views: expected a positive integer, got True"),
    "views-string": (_cfg(views="5"), r"--views: expected a positive integer, got '5'"),
    "res-zero": (_cfg(res=0), r"--res: expected a positive integer, got 0"),
    "res-negative": (_cfg(res=-24), r"--res: expected a positive integer, got -24"),
    "res-huge": (_cfg(res=100000), r"--res: expected at most 8192 pixels, got 100000"),
    "res-float": (_cfg(res=24.0), r"--res: expected a positive integer, got 24.0"),
    "spp-zero": (_cfg(spp=0), r"--spp: expected a positive integer, got 0"),
    "spp-negative": (_cfg(spp=-2), r"--spp: expected a positive integer, got -2"),
    "spp-float": (_cfg(spp=1.5), r"--spp: expected a positive integer, got 1.5"),
    "seed-minus-one": (_cfg(seed=-1), r"--seed: expected an integer in \[0, 2\*\*63\), got -1"),
    "seed-minus-five": (_cfg(seed=-5), r"--seed: expected an integer in \[0, 2\*\*63\), got -5"),
    "seed-float": (_cfg(seed=1.5), r"--seed: expected an integer .*, got 1.5"),
    "seed-too-big": (_cfg(seed=2**64), r"--seed: expected an integer .*, got 18446744073709551616"),
    "seed-none": (_cfg(seed=None), r"--seed: expected an integer .*, got None"),
    "stereo-pairs-zero": (_cfg(stereo=True, stereo_pairs=0), r"--stereo-pairs: expected a positive integer, got 0"),
    "stereo-pairs-negative": (_cfg(stereo_pairs=-1), r"--stereo-pairs: expected a positive integer, got -1"),
    "stereo-not-bool": (_cfg(stereo="yes"), r"--stereo: expected True or False, got 'yes'"),
    "baseline-zero": (_cfg(stereo=True, baseline=0.0), r"--baseline: expected a finite distance in \(0, 1.036\] "
                                                      r"for scene spheres .*, got 0.0"),
    "baseline-negative": (_cfg(stereo=True, baseline=-0.1), r"--baseline: expected a finite distance .*, got -0.1"),
    "baseline-inf": (_cfg(stereo=True, baseline=math.inf), r"--baseline: expected a finite distance .*, got inf"),
    "baseline-nan": (_cfg(stereo=True, baseline=math.nan), r"--baseline: expected a finite distance .*, got nan"),
    "baseline-1000": (_cfg(stereo=True, baseline=1000.0),
                      r"--baseline: .*a wider baseline moves the scene out of the right view\), got 1000.0"),
    "baseline-over-cornell-limit": (_cfg(scene="cornell", stereo=True, baseline=0.8),
                                    r"--baseline: expected a finite distance in \(0, 0.6964\] for scene cornell"),
    "baseline-string": (_cfg(stereo=True, baseline="0.3"), r"--baseline: expected a finite distance .*, got '0.3'"),
    "flow-frames-zero": (_cfg(flow_frames=0), r"--flow-frames: expected a positive integer, got 0"),
    "flow-frames-one": (_cfg(flow=True, flow_frames=1), r"--flow-frames: expected at least 2, got 1"),
    "flow-frames-negative": (_cfg(flow=True, flow_frames=-3), r"--flow-frames: expected a positive integer, got -3"),
    "flow-not-bool": (_cfg(flow=1), r"--flow: expected True or False, got 1"),
    "val-fraction-too-big": (_cfg(val_fraction=0.7), r"val_fraction: expected a value in \(0, 0.5\), got 0.7"),
    "val-fraction-zero": (_cfg(val_fraction=0.0), r"val_fraction: expected a value in \(0, 0.5\), got 0.0"),
    "test-fraction-nan": (_cfg(test_fraction=math.nan), r"test_fraction: expected a value in \(0, 0.5\), got nan"),
    "fractions-leave-no-train-view": (_cfg(views=4, val_fraction=0.49, test_fraction=0.49),
                                      r"--views: 4 views leave no training view after the val and test splits"),
    "flow-step-zero": (_cfg(flow_step_deg=0.0), r"flow_step_deg: expected a camera step in \(0, 90\] degrees"),
    "flow-step-inf": (_cfg(flow_step_deg=math.inf), r"flow_step_deg: expected .*, got inf"),
    "flow-step-120": (_cfg(flow_step_deg=120.0), r"flow_step_deg: expected .*, got 120.0"),
    # --out
    "out-empty-string": (_out(_nothing, ""), r"--out: expected a directory path, got ''"),
    "out-blank": (_out(_nothing, "  "), r"--out: expected a directory path, got '  '"),
    "out-none": (_out(_nothing, None), r"--out: expected a directory path, got None"),
    "out-dot": (_out(_nothing, "."), r"--out: expected a path that names the dataset directory, got '.'"),
    "out-dotdot": (_out(_nothing, ".."), r"--out: expected a path that names the dataset directory, got '..'"),
    "out-is-a-file": (_out(_file("afile"), "afile"), r"--out: afile is a file \(or a broken link\); expected a dataset "
                                                      r"directory"),
    "out-is-a-file-with-force": (_out(_file("afile"), "afile", force=True), r"--out: afile is a file"),
    "out-broken-link": (_out(_broken_link, "ds"), r"--out: ds is a file \(or a broken link\)"),
    "out-parent-is-a-file": (_out(_file("afile"), "afile/ds"), r"--out: .*afile is a file, so afile/ds cannot be "
                                                               r"created"),
    "out-named-partial": (_out(_nothing, "x.partial"), r"--out: names ending in .partial, .drlab-old or .lock are "
                                                       r"drlab's own, got 'x.partial'"),
    "out-named-lock": (_out(_nothing, "x.lock"), r"--out: names ending in .partial.*got 'x.lock'"),
    "out-exists-without-force": (_out(_drlab_dataset, "ds"), r"--out: ds already exists; pass --force to replace it"),
    "force-on-user-folder": (_out(_user_folder, "thesis", force=True),
                             r"--out: thesis does not hold a drlab dataset \(no manifest.json written by drlab "
                             r"dataset\); --force replaces only datasets, so nothing was touched"),
    "force-on-foreign-manifest": (_out(_foreign_manifest, "other", force=True), r"--out: other does not hold a drlab "
                                                                                r"dataset"),
    "force-on-broken-manifest": (_out(_broken_manifest, "other", force=True), r"--out: other does not hold a drlab "
                                                                              r"dataset"),
    "partial-is-a-file": (_out(_file("ds.partial"), "ds"), r"--out: ds.partial is a file, and drlab keeps the "
                                                           r"unfinished dataset there; move it away"),
    "partial-left-without-resume": (_out(_partial_of(), "ds"), r"--resume: an interrupted run left ds.partial; pass "
                                                               r"--resume to finish it"),
    "resume-with-different-seed": (_out(_partial_of(seed=9), "ds", resume=True),
                                   r"--resume: ds.partial was started with a different configuration \(seed 9 there, "
                                   r"0 now\)"),
    "resume-with-different-res": (_out(_partial_of(res=32), "ds", resume=True),
                                  r"--resume: .*different configuration \(res 32 there, 24 now\)"),
    # ensure (what experiments call) validates first too
    "ensure-seed-negative": (_ensure(seed=-1), r"--seed: expected an integer in \[0, 2\*\*63\), got -1"),
    "ensure-baseline-inf": (_ensure(stereo=True, baseline=math.inf), r"--baseline: expected a finite distance"),
    "ensure-into-user-folder": (_with(_user_folder, lambda tmp: ensure(DatasetConfig(**TINY), tmp / "thesis")),
                                r"--out: .*thesis does not hold a drlab dataset"),
    # loading
    "load-missing-folder": (_load(load), r"ds: no such dataset directory$"),
    "load-unfinished-folder": (_with(_partial_folder, _load(load)), r"ds: no such dataset directory \(an interrupted run left "
                                                   r".*ds.partial; finish it with --resume\)"),
    "load-user-folder": (_with(_user_folder, _load(load, "thesis")),
                         r"thesis/manifest.json: missing \(not a drlab dataset, or an unfinished one\)"),
    "verify-foreign-manifest": (_with(_foreign_manifest, _load(verify, "other")),
                                r"other/manifest.json: not a manifest written by drlab dataset"),
    "load-stereo-without-stereo": (_load_without("stereo"), r"ds/stereo/stereo.json: missing"),
    "load-flow-without-flow": (_load_without("flow"), r"ds/flow/flow.json: missing"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS), ids=list(BAD_INPUTS))
def test_bad_input(case, tmp_path):
    fn, expected = BAD_INPUTS[case]
    getattr(fn, "make", _nothing)(tmp_path)
    before = _snapshot(tmp_path)
    with pytest.raises(ValueError) as err:
        fn(tmp_path)
    msg = str(err.value)
    assert "\n" not in msg, msg
    assert re.search(expected, msg), msg
    if not getattr(fn, "keeps_files", False):
        assert _snapshot(tmp_path) == before  # nothing created, nothing touched: no .partial, no lock file
    if case in ("force-on-user-folder", "ensure-into-user-folder", "load-user-folder"):
        assert (tmp_path / "thesis" / "thesis.txt").read_text() == "three years of work\n"
        assert sorted(p.name for p in (tmp_path / "thesis").iterdir()) == ["thesis.txt"]


# --------------------------------------------------------------------------- tampered files


def _scale_pfm(root):
    p = root / "stereo" / "p_000_disp.pfm"
    io.write_pfm(p, io.read_pfm(p) * 1.5)
    return p


def _flip_png(root):
    p = root / "train" / "r_000.png"
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0xFF
    p.write_bytes(bytes(data))
    return p


def _scale_depth(root):
    p = next(root.glob("*/r_000_depth.exr"))
    io.write_exr(p, io.read_exr(p) * 1.01)
    return p


def _shift_flow(root):
    p = root / "flow" / "f_000_flow.flo"
    io.write_flo(p, io.read_flo(p) + 0.5)
    return p


def _edit_stereo_json(root):
    p = root / "stereo" / "stereo.json"
    doc = json.loads(p.read_text())
    doc["baseline"] *= 2
    p.write_text(json.dumps(doc))
    return p


def _same_size_same_mtime(root):
    """Bytes changed in place with the old mtime put back: the fast path must still rehash (ctime)."""
    p = root / "train" / "r_000_mask.png"
    st = p.stat()
    data = bytearray(p.read_bytes())
    data[-20] ^= 0x01
    p.write_bytes(bytes(data))
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))
    return p


def _delete(root):
    p = root / "stereo" / "p_000_noc.png"
    p.unlink()
    return p


def _extra(root):
    p = root / "train" / "r_099.png"
    shutil.copy(root / "train" / "r_000.png", p)
    return p


def _edit_manifest_hash(root):
    p = root / "manifest.json"
    m = json.loads(p.read_text())
    m["files"]["cameras.json"] = "0" * 64
    p.write_text(json.dumps(m))
    return p


def _edit_manifest_consistently(root):
    """Someone re-hashes the manifest after swapping a file's hash: the file itself is then the mismatch."""
    m = json.loads((root / "manifest.json").read_text())
    m["files"]["train/r_000.exr"] = "1" * 64
    m["content_hash"] = content_hash(m["files"])
    (root / "manifest.json").write_text(json.dumps(m))
    return root / "train" / "r_000.exr"


def _drop_generator(root):
    p = root / "manifest.json"
    m = json.loads(p.read_text())
    del m["generator"]
    p.write_text(json.dumps(m))
    return p


TAMPERED = {
    # name: (tamper, loader, expected message after the file's path)
    "png-byte-flipped": (_flip_png, load, r": content does not match its SHA-256 in manifest.json"),
    "exr-depth-scaled": (_scale_depth, load, r": content does not match its SHA-256"),
    "pfm-disparity-scaled-1.5": (_scale_pfm, load_stereo, r": content does not match its SHA-256"),
    "flo-flow-shifted": (_shift_flow, load_flow, r": content does not match its SHA-256"),
    "stereo-json-baseline-doubled": (_edit_stereo_json, load_stereo, r": content does not match its SHA-256"),
    "same-size-same-mtime": (_same_size_same_mtime, load, r": content does not match its SHA-256"),
    "file-deleted": (_delete, load_stereo, r": listed in manifest.json but missing"),
    "extra-file": (_extra, load, r": not listed in manifest.json \(a file added after the dataset was written\)"),
    "manifest-hash-edited": (_edit_manifest_hash, load, r": content_hash does not match the file hashes it lists"),
    "manifest-rehashed-after-edit": (_edit_manifest_consistently, load_flow, r": content does not match its SHA-256"),
    "manifest-generator-removed": (_drop_generator, load, r": not a manifest written by drlab dataset"),
}


@pytest.mark.parametrize("case", list(TAMPERED), ids=list(TAMPERED))
def test_tampered_file_is_named(case, reference, tmp_path):
    tamper, loader, expected = TAMPERED[case]
    root = tmp_path / "ds"
    shutil.copytree(reference, root)
    verify(root)  # the copy is clean, and the fast-path cache now knows every file
    bad = tamper(root)
    for fn in (loader, provenance, lambda r: ensure(FULL, r, show_progress=False)):
        with pytest.raises(ValueError) as err:
            fn(root)
        msg = str(err.value)
        assert "\n" not in msg, msg
        if case == "manifest-generator-removed" and fn not in (loader, provenance):
            # ensure will not replace a folder whose manifest drlab did not write
            assert msg == f"--out: {root} does not hold a drlab dataset (no manifest.json written by drlab dataset); " \
                          "--force replaces only datasets, so nothing was touched"
            continue
        assert isinstance(err.value, DatasetError) and msg.startswith(f"{bad}:"), msg
        assert re.search(expected, msg), msg
    assert bad.exists() or case == "file-deleted"  # never silently replaced
    assert load(reference) is not None  # the original is untouched


def _set_pixel(path, read, write, yx, value):
    """Rewrite the image at `path` (read/write: its io functions) with one pixel set to `value`; returns path."""
    image = read(path)
    image[yx] = value
    write(path, image)
    return path


def _gt_edit(root, what):
    if what == "negative-disparity":
        p = _set_pixel(root / "stereo" / "p_000_disp.pfm", io.read_pfm, io.write_pfm, (0, 0), -2.0)
        return p, load_stereo, r"disparity must be >= 0, found -2"
    if what in ("nan-baseline", "negative-baseline"):
        p = root / "stereo" / "stereo.json"
        doc = json.loads(p.read_text())
        doc["baseline"] = float("nan") if what == "nan-baseline" else -0.4
        p.write_text(json.dumps(doc))
        return p, load_stereo, r"baseline must be a finite distance > 0, got " + ("nan" if "nan" in what else "-0.4")
    if what == "negative-depth":
        p = _set_pixel(root / "flow" / "f_001_depth.exr", io.read_exr, io.write_exr, (3, 3), -1.0)
        return p, load_flow, r"depth must be >= 0, found -1"
    if what == "nan-flow":
        p = root / "flow" / "f_000_flow.flo"  # io.write_flo refuses NaN: patch the bytes
        raw = bytearray(p.read_bytes())
        w = int(np.frombuffer(raw, "<i4", count=1, offset=4)[0])
        at = 12 + (2 * w + 2) * 2 * 4
        raw[at:at + 4] = np.array([np.nan], "<f4").tobytes()
        p.write_bytes(bytes(raw))
        return p, load_flow, r"contains non-finite values"
    raise AssertionError(what)


@pytest.mark.parametrize("what", ["negative-disparity", "nan-baseline", "negative-baseline", "negative-depth",
                                  "nan-flow"])
def test_ground_truth_meaning_checked_even_without_hashes(what, reference, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(reference, root)
    path, loader, expected = _gt_edit(root, what)
    with pytest.raises(DatasetError) as err:
        loader(root, verify_hashes=False)
    assert str(err.value).startswith(f"{path}:") and re.search(expected, str(err.value)), str(err.value)


# --------------------------------------------------------------------------- recovery


def _hash(out: Path) -> str:
    return json.loads((out / "manifest.json").read_text())["content_hash"]


def _garbage_config(partial):
    (partial / PARTIAL_CONFIG).write_text("{half a reco")


def _missing_config(partial):
    (partial / PARTIAL_CONFIG).unlink()


def _stale_temps(partial):
    (partial / "train").mkdir(exist_ok=True)
    for name in ("train/.r_000.abcd1234.tmp.exr", ".cameras.x_y_z012.tmp.json", "train/.r_001_mask.0000abcd.tmp.png"):
        (partial / name).write_bytes(b"")


RECOVERIES = {
    "partial-config-unreadable": (_garbage_config, dict(resume=False), "its configuration record is missing or "
                                                                       "unreadable"),
    "partial-config-missing": (_missing_config, dict(resume=True), "its configuration record is missing"),
    "stale-temp-files-swept": (_stale_temps, dict(resume=True), None),
    "force-starts-over": (lambda partial: None, dict(force=True), "--force starts over (--resume would finish it)"),
}


@pytest.mark.parametrize("case", list(RECOVERIES), ids=list(RECOVERIES))
def test_broken_partial_recovers(case, cli_reference, tmp_path, monkeypatch, capsys):
    """A run stopped after two views leaves a .partial; a damaged one is replaced (one notice), temp files swept."""
    from research.datasets.render import SceneRenderer
    from tests.research.test_datasets import interrupt_after_views

    original = interrupt_after_views(monkeypatch, 2)
    out = tmp_path / "ds"
    with pytest.raises(KeyboardInterrupt):
        generate(CLI_CFG, out, show_progress=False)
    monkeypatch.setattr(SceneRenderer, "render_rgba", original)
    damage, kwargs, notice = RECOVERIES[case]
    damage(out.with_name("ds.partial"))
    capsys.readouterr()
    generate(CLI_CFG, out, show_progress=False, **kwargs)
    err = capsys.readouterr().err.strip()
    if notice:
        assert err.count("\n") == 0 and err.startswith("note: replacing") and notice in err, err
    else:
        assert err == ""
    assert verify(out) == _hash(out) == cli_reference
    assert _leftovers(tmp_path) == []


def test_killed_between_manifest_and_rename_resumes(cli_reference, tmp_path):
    """The manifest's copy of the configuration counts when the record was already removed."""
    out = tmp_path / "ds"
    generate(CLI_CFG, out, show_progress=False)
    partial = tmp_path / "ds.partial"
    os.replace(out, partial)  # the state a kill after the manifest and before the rename leaves
    assert not (partial / PARTIAL_CONFIG).exists()
    generate(CLI_CFG, out, resume=True, show_progress=False)
    assert verify(out) == cli_reference and _leftovers(tmp_path) == []


def test_killed_during_force_swap_is_finished_by_next_run(cli_reference, tmp_path):
    out = tmp_path / "ds"
    generate(CLI_CFG, out, show_progress=False)
    shutil.copytree(out, tmp_path / "ds.drlab-old")  # killed after the new one went in, before the old one went
    assert ensure(CLI_CFG, out, show_progress=False) == out
    assert verify(out) == cli_reference and _leftovers(tmp_path) == []
    os.replace(out, tmp_path / "ds.drlab-old")  # killed after the old one went aside, before the new one came in
    assert ensure(CLI_CFG, out, show_progress=False) == out  # put back and reused
    assert verify(out) == cli_reference and _leftovers(tmp_path) == []


def test_corrupt_verification_cache_is_ignored(reference, tmp_path):
    root = tmp_path / "ds"
    shutil.copytree(reference, root)
    (root / VERIFIED).write_text("[not the cache")
    (root / ".drlab-verified.ab12cd34.tmp.json").write_text("{")  # a cache write killed half-way
    assert verify(root) == _hash(root)
    assert json.loads((root / VERIFIED).read_text())["files"]  # rewritten
    assert _leftovers(tmp_path) == []


def test_force_replaces_a_tampered_dataset_only_when_whole(reference, tmp_path):
    """--force on a drlab dataset (even a damaged one) swaps in the new render; the old one is gone."""
    root = tmp_path / "ds"
    shutil.copytree(reference, root)
    _scale_pfm(root)
    generate(FULL, root, force=True, show_progress=False)
    assert verify(root) == _hash(reference) and _leftovers(tmp_path) == []


def test_concurrent_ensure_waits_then_reuses(tmp_path):
    """A second process preparing the same cached dataset waits on the lock, then reuses the data."""
    out = tmp_path / "cache" / "ds"
    cfg = DatasetConfig(**TINY, seed=3)
    code = ("import sys; from research.datasets import DatasetConfig, ensure; "
            f"ensure(DatasetConfig(**{asdict(cfg)!r}), {str(out)!r}, show_progress=False); print('done')")
    log = tmp_path / "child.err"
    with dataset_lock(out), open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-c", code], env=_env(), stdout=subprocess.PIPE, stderr=err,
                                text=True)
        deadline = time.monotonic() + 60
        while "note: waiting" not in log.read_text() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert proc.poll() is None, log.read_text()  # the child reached the lock and waits there
        ensure(cfg, out, show_progress=False)  # this process renders while holding the lock
        stamp = (out / "manifest.json").stat().st_mtime_ns
    stdout, _ = proc.communicate(timeout=60)
    stderr = log.read_text()
    assert proc.returncode == 0, stderr
    assert stdout.strip() == "done"
    assert stderr.strip() == f"note: waiting for another process preparing {out} (lock {out}.lock)"
    assert (out / "manifest.json").stat().st_mtime_ns == stamp  # reused, not rendered again
    assert verify(out) == _hash(out) and _leftovers(tmp_path) == []


def _kill_when_started(cmd: list[str], partial: Path, seed: int) -> None:
    """Start `cmd`, wait for its `.partial` folder, SIGKILL it after a seeded random delay (0-1 s)."""
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not partial.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    time.sleep(random.Random(seed).uniform(0.0, 1.0))
    proc.send_signal(signal.SIGKILL)
    proc.wait()


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_sigkill_dataset_render_then_resume(seed, cli_reference, tmp_path):
    """SIGKILL `drlab dataset` at a seeded random moment of its render; `--resume` finishes it exactly."""
    out = tmp_path / "ds"
    _kill_when_started(CLI + ["--out", str(out)], tmp_path / "ds.partial", seed)
    assert not out.exists() or verify(out) == cli_reference  # either not there, or whole
    if not out.exists():
        done = subprocess.run(CLI + ["--out", str(out), "--resume"], env=_env(), capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 0, done.stderr
    assert verify(out) == _hash(out) == cli_reference
    assert load(out).manifest["content_hash"] == cli_reference
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("seed", [10, 11])
def test_sigkill_ensure_then_plain_rerun(seed, cli_reference, tmp_path):
    """SIGKILL a process preparing a cached dataset; the next ensure() resumes it (no --resume needed)."""
    out = tmp_path / "cache" / "ds"
    code = ("from research.datasets import DatasetConfig, ensure; "
            f"ensure(DatasetConfig(**{asdict(CLI_CFG)!r}), {str(out)!r}, show_progress=False)")
    _kill_when_started([sys.executable, "-c", code], out.with_name("ds.partial"), seed)
    assert ensure(CLI_CFG, out, show_progress=False) == out
    assert verify(out) == cli_reference and _leftovers(tmp_path) == []


def test_tampered_disparity_stops_stereo_depth(tmp_path):
    """One ground-truth PFM scaled by 1.5 in stereo_depth's cached data: the experiment stops, naming it."""
    from experiments.stereo_depth import SCENES, setup

    st = setup(quick=False, smoke=True)
    data = tmp_path / "data"
    scene = SCENES[0]
    cfg = DatasetConfig(scene, views=3, res=st.res, spp=st.spp, seed=0, stereo=True, stereo_pairs=st.pairs)
    cached = ensure(cfg, data / f"stereo_depth-{scene}-smoke", show_progress=False)
    bad = _scale_pfm(cached)
    res = tmp_path / "results"
    proc = subprocess.run([sys.executable, "-m", "experiments.stereo_depth", "--smoke", "--data", str(data),
                           "--out", str(res), "--no-progress"], env=_env(), capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode != 0
    assert f"{bad}: content does not match its SHA-256 in manifest.json" in proc.stderr.strip().splitlines()[-1]
    assert not res.exists() and not list(tmp_path.glob("results*"))  # no results, no false provenance
