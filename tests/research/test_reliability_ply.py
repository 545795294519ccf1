"""Reliability of the 3DGS PLY reader and writer (research/splats/ply.py): bad files and faults.

Every bad file must give ONE-line ValueError naming the file and the property (or element) at
fault, before a model exists; every fault (truncation, a writer killed or failing mid-write) must
leave either a clear error or the previous file intact, never a partial file at the destination.
The fixtures are written here, with plyfile or as raw bytes.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyElement

from research import atomic
from research.splats import model as sm, ply
from tests.research.test_splats import layout_props, random_model, write_ply

ROOT = Path(__file__).resolve().parents[2]


def _props(**changes) -> dict:
    """The layout's properties of a 4-splat model, with `changes` (None removes a property)."""
    props = layout_props(random_model(4, seed=1))
    for k, v in changes.items():
        if v is None:
            props.pop(k)
        else:
            props[k] = v
    return props


def _with(name: str, value: float, at: int = 2) -> np.ndarray:
    v = _props()[name].copy()
    v[at] = value
    return v


def _good_bytes() -> bytes:
    return ply.to_bytes(random_model(4, seed=1))


# Each case: id -> (writer(path), expected message regex after the file name).
def _plyfile(**kw):
    extra = kw.pop("_extra", None)
    return lambda p: write_ply(p, _props(**kw), extra_elements=extra or ())


def _raw(data: bytes):
    return lambda p: p.write_bytes(data)


def _header_swap(old: bytes, new: bytes):
    return _raw(_good_bytes().replace(old, new, 1))


def _ascii_edit(fn):
    def write(p):
        write_ply(p, _props(), text=True)
        p.write_text(fn(p.read_text()))
    return write


def _only_face(p):
    face = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "O")])
    from plyfile import PlyData
    PlyData([PlyElement.describe(face, "face")]).write(str(p))


def _x_as_list(p):
    from plyfile import PlyData
    props = _props()
    dt = [("x", "O")] + [(k, "<f4") for k in props if k != "x"]
    data = np.empty(4, dtype=dt)
    for k in props:
        data[k] = [np.array([1.0, 2.0], np.float32) for _ in range(4)] if k == "x" else props[k]
    PlyData([PlyElement.describe(data, "vertex")]).write(str(p))


BAD_FILES = {
    "not_a_ply_text": (_raw(b"hello, this is a thesis\n"), r"not a readable PLY file"),
    "empty_file": (_raw(b""), r"not a readable PLY file"),
    "no_end_header": (_raw(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"),
                      r"not a readable PLY file"),
    "bad_format_line": (_header_swap(b"binary_little_endian", b"binary_middle_endian"), r"not a readable PLY file"),
    "bad_property_type": (_header_swap(b"property float x", b"property flaot x"), r"not a readable PLY file"),
    "missing_x": (_plyfile(x=None), r"missing property 'x'"),
    "missing_y": (_plyfile(y=None), r"missing property 'y'"),
    "missing_z": (_plyfile(z=None), r"missing property 'z'"),
    "missing_opacity": (_plyfile(opacity=None), r"missing property 'opacity'"),
    "rot_count_3": (_plyfile(rot_3=None), r"missing property 'rot_3'"),
    "rot_count_5": (_plyfile(rot_4=np.zeros(4, np.float32)), r"property 'rot_4': 5 rot_\* properties"),
    "scale_count_2": (_plyfile(scale_2=None), r"missing property 'scale_2'"),
    "scale_count_4": (_plyfile(scale_3=np.zeros(4, np.float32)), r"property 'scale_3': 4 scale_\* properties"),
    "f_dc_count_2": (_plyfile(f_dc_1=None), r"missing property 'f_dc_1'"),
    "f_rest_count_44": (_plyfile(f_rest_44=None), r"property 'f_rest_\*': 44 f_rest properties; expected 0, 9, 24 "
                                                  r"or 45"),
    "f_rest_count_10": (lambda p: write_ply(p, {**layout_props(random_model(4, seed=1), n_rest=3),
                                                "f_rest_9": np.zeros(4, np.float32)}),
                        r"property 'f_rest_\*': 10 f_rest properties"),
    "f_rest_gap": (lambda p: write_ply(p, {k: v for k, v in layout_props(random_model(4), n_rest=3).items()
                                           if k != "f_rest_3"} | {"f_rest_9": np.zeros(4, np.float32)}),
                   r"missing property 'f_rest_3'"),
    "nan_x": (_plyfile(x=_with("x", np.nan)), r"property 'x' has NaN or infinite values \(vertex 2\)"),
    "inf_opacity": (_plyfile(opacity=_with("opacity", np.inf)), r"property 'opacity' has NaN or infinite values"),
    "nan_rot_0": (_plyfile(rot_0=_with("rot_0", np.nan, 0)), r"property 'rot_0' has NaN or infinite values "
                                                             r"\(vertex 0\)"),
    "nan_f_rest_7": (_plyfile(f_rest_7=_with("f_rest_7", np.nan)), r"property 'f_rest_7' has NaN"),
    "nan_normal": (_plyfile(ny=_with("ny", np.nan)), r"property 'ny' has NaN"),
    "float64_overflows_float32": (_plyfile(scale_1=np.full(4, 1e300)),
                                  r"property 'scale_1' has values beyond the float32 range"),
    "no_vertex_element": (_only_face, r"no 'vertex' element"),
    "x_is_uchar": (_plyfile(x=np.arange(4, dtype=np.uint8)), r"property 'x' is uchar; expected float or double"),
    "opacity_is_int": (_plyfile(opacity=np.arange(4, dtype=np.int32)), r"property 'opacity' is int; expected"),
    "x_is_a_list": (_x_as_list, r"property 'x' is a list; expected float or double"),
    "ascii_word_in_row": (_ascii_edit(lambda t: t.replace("end_header\n", "end_header\nabc ", 1)),
                          r"not a readable PLY file"),
    "ascii_short_row": (_ascii_edit(lambda t: t[:t.rindex(" ")] + "\n"), r"not a readable PLY file"),
}

FAULT_FILES = {
    "binary_truncated_mid_row": (_raw(_good_bytes()[:-5]), r"not a readable PLY file"),
    "binary_truncated_after_header": (_raw(_good_bytes()[:_good_bytes().index(b"end_header\n") + 11]),
                                      r"not a readable PLY file"),
    "binary_truncated_mid_header": (_raw(_good_bytes()[:40]), r"not a readable PLY file"),
    "ascii_missing_rows": (_ascii_edit(lambda t: "\n".join(t.splitlines()[:-2]) + "\n"), r"not a readable PLY file"),
}


@pytest.mark.parametrize("case", list(BAD_FILES) + list(FAULT_FILES))
def test_bad_file_gives_one_line_error_naming_file_and_property(tmp_path, case):
    write, expected = {**BAD_FILES, **FAULT_FILES}[case]
    path = tmp_path / f"{case}.ply"
    write(path)
    with pytest.raises(ValueError) as err:
        ply.load_ply(path)
    msg = str(err.value)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: "), msg
    assert re.search(expected, msg), msg
    assert msg.count(str(path)) == 1, msg


def _face():
    return PlyElement.describe(np.array([([0, 1, 2],)], dtype=[("vertex_indices", "O")]), "face")


# Files the reference loader reads: accepted, with ONE PlyNote naming what was ignored.
NOTED = {
    "uchar_red": (dict(red=np.arange(4, dtype=np.uint8)), False, ["vertex properties ['red']"]),
    "rgb_and_alpha": (dict(red=np.zeros(4, np.uint8), green=np.zeros(4, np.uint8), blue=np.zeros(4, np.uint8),
                           alpha=np.zeros(4, np.float32)), False, ["'red', 'green', 'blue', 'alpha'"]),
    "face_element": ({}, True, ["elements ['face']"]),
    "property_and_element": (dict(red=np.zeros(4, np.uint8)), True, ["['red']", "['face']"]),
}


@pytest.mark.parametrize("case", list(NOTED))
def test_extras_are_ignored_with_one_note(tmp_path, case):
    extra, face, expected = NOTED[case]
    m = random_model(4, seed=1)
    write_ply(tmp_path / "x.ply", {**layout_props(m), **extra}, extra_elements=[_face()] if face else ())
    with pytest.warns(ply.PlyNote) as rec:
        back = ply.load_ply(tmp_path / "x.ply")
    assert len(rec) == 1
    msg = str(rec[0].message)
    assert "\n" not in msg and msg.startswith(f"{tmp_path / 'x.ply'}: ignored ")
    for part in expected:
        assert part in msg, msg
    for k, v in m.arrays().items():
        np.testing.assert_array_equal(getattr(back, k), v, err_msg=k)


@pytest.mark.parametrize("case, arg, expected", [
    ("missing_path", "nope.ply", r"nope.ply: no such file"),
    ("a_directory", ".", r": is a directory; expected a PLY file"),
])
def test_bad_path(tmp_path, case, arg, expected):
    with pytest.raises(ValueError, match=expected):
        ply.load_ply(tmp_path / arg)


@pytest.mark.parametrize("case, model", [("a_dict", {"means": np.zeros((1, 3))}), ("none", None)])
def test_save_rejects_non_models_before_creating_a_file(tmp_path, case, model):
    with pytest.raises(ValueError, match="model: expected a GaussianModel"):
        ply.save_ply(tmp_path / "out.ply", model)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- faults while writing


def _no_temp_files(folder: Path) -> bool:
    return not any(".tmp" in p.name for p in folder.iterdir())


@pytest.mark.parametrize("fault", ["oserror_in_write", "keyboard_interrupt_in_fsync"])
def test_failed_write_leaves_previous_file_and_no_temp(tmp_path, monkeypatch, fault):
    path = ply.save_ply(tmp_path / "m.ply", random_model(3, seed=7))
    before = path.read_bytes()
    if fault == "oserror_in_write":
        def boom(*a, **k):
            raise OSError(28, "No space left on device")
        monkeypatch.setattr(atomic.os, "fsync", boom)
        exc = OSError
    else:
        def interrupt(*a, **k):
            raise KeyboardInterrupt
        monkeypatch.setattr(atomic.os, "fsync", interrupt)
        exc = KeyboardInterrupt
    with pytest.raises(exc):
        ply.save_ply(path, random_model(50, seed=8))
    assert path.read_bytes() == before
    assert _no_temp_files(tmp_path)
    monkeypatch.undo()
    ply.load_ply(path)  # still a good file


def _kill_after(script: str, line: bytes, delay: float) -> int:
    """Run `script`, wait for it to print `line`, SIGKILL it `delay` seconds later; its return code."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, env=env, cwd=ROOT) as proc:
        try:
            assert proc.stdout.readline().strip() == line
            time.sleep(delay)
            os.kill(proc.pid, signal.SIGKILL)
            return proc.wait(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()


def test_writer_killed_before_rename_leaves_destination_untouched(tmp_path):
    """SIGKILL a process that has written the temporary file but not renamed it yet."""
    dest = tmp_path / "m.ply"
    ply.save_ply(dest, random_model(3, seed=9))
    before = dest.read_bytes()
    script = textwrap.dedent(f"""
        import os, sys, time
        import numpy as np
        from research import atomic
        from research.splats import ply, model as sm
        def stall(src, dst):
            print("written", flush=True)
            time.sleep(60)
        atomic.os.replace = stall
        rng = np.random.default_rng(0)
        n = 2000
        m = sm.GaussianModel(means=rng.normal(size=(n, 3)), log_scales=rng.normal(size=(n, 3)),
                             quats=rng.normal(size=(n, 4)), opacity_logits=rng.normal(size=n),
                             sh_dc=rng.normal(size=(n, 1, 3)), sh_rest=rng.normal(size=(n, 15, 3)))
        ply.save_ply({str(dest)!r}, m)
    """)
    assert _kill_after(script, b"written", 0.0) == -signal.SIGKILL
    assert dest.read_bytes() == before  # the destination is the previous, complete file
    temps = [p for p in tmp_path.iterdir() if p != dest]
    assert len(temps) == 1 and temps[0].name.startswith(".m.") and ".tmp" in temps[0].name  # hidden leftover
    assert ply.load_ply(dest).n == 3


def test_writer_killed_at_random_points_never_leaves_a_partial_destination(tmp_path):
    """SIGKILL a process rewriting the same file in a loop; whatever was there is a complete file."""
    dest = tmp_path / "m.ply"
    script = textwrap.dedent(f"""
        import numpy as np
        from research.splats import ply, model as sm
        rng = np.random.default_rng(0)
        for i in range(10**6):
            n = int(rng.integers(1, 400))
            m = sm.GaussianModel(means=rng.normal(size=(n, 3)), log_scales=rng.normal(size=(n, 3)),
                                 quats=rng.normal(size=(n, 4)), opacity_logits=rng.normal(size=n),
                                 sh_dc=rng.normal(size=(n, 1, 3)), sh_rest=rng.normal(size=(n, 15, 3)))
            ply.save_ply({str(dest)!r}, m)
            if i == 0:
                print("first", flush=True)
    """)
    assert _kill_after(script, b"first", float(np.random.default_rng().uniform(0.05, 0.4))) == -signal.SIGKILL
    model = ply.load_ply(dest)  # complete and valid, whichever iteration it came from
    assert isinstance(model, sm.GaussianModel) and model.n >= 1
