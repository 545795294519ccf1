"""Saving and loading splats in the standard 3DGS PLY layout, through `plyfile`.

The layout (what the reference 3DGS code writes): one `vertex` element with the float32
properties x, y, z, nx, ny, nz (zeros), f_dc_0..2, f_rest_0..(3 (K-1) - 1), opacity (logit),
scale_0..2 (log), rot_0..3 (quaternion w, x, y, z). f_rest is channel-major, as the 3DGS code
writes it: f_rest_{c (K-1) + k} holds SH coefficient k + 1 of channel c.

Writing (`save_ply`, `to_bytes`) always uses that layout with SH degree 3, binary little endian
float32, the header plyfile writes for it; the file is written to a temporary name beside the
target and renamed (research/atomic.py), so an interrupted write leaves no partial file.

Reading (`load_ply`) accepts what the reference loader reads:
  * ASCII, binary little endian and binary big endian files;
  * float or double properties (double values are rounded to float32, as the model stores them);
  * files without nx, ny, nz (gsplat's export);
  * SH degree 0-3, inferred from the number of f_rest properties (0, 9, 24 or 45); the
    missing higher coefficients are set to zero;
  * extra vertex properties (e.g. `uchar red`) and extra elements, which are ignored with ONE
    warning of category `PlyNote` that names them (silence it with
    `warnings.simplefilter("ignore", PlyNote)`).
Anything else raises a one-line ValueError naming the file and the property (or element) at
fault: not a PLY file, a truncated or malformed body, no vertex element, a missing required
property, a required property that is a list or not float/double, a count of scale_, rot_,
f_dc_ or f_rest_ properties other than the layout's, and NaN or infinite values.
"""

from __future__ import annotations

import io
import re
import warnings
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement, PlyListProperty

from research import atomic
from research.splats.model import SH_COEFFS, GaussianModel

# SH degree of each valid f_rest count (3 channels x ((d + 1)^2 - 1) coefficients).
_DEGREE_OF_REST = {3 * ((d + 1) ** 2 - 1): d for d in range(4)}
_GROUPS = {"f_dc_": 3, "scale_": 3, "rot_": 4}  # fixed-size numbered groups
_FLOAT_TYPES = ("f4", "f8")  # NumPy codes of the PLY float and double property types
_PLY_TYPE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
                   "f4": "float", "f8": "double"}


class PlyNote(UserWarning):
    """Something in a PLY file that `load_ply` ignored (extra properties or elements)."""


def property_names(n_rest: int = SH_COEFFS - 1, normals: bool = True) -> list[str]:
    """Vertex property names of the layout with `n_rest` SH coefficients per channel beyond the DC term."""
    return (["x", "y", "z"] + (["nx", "ny", "nz"] if normals else []) + [f"f_dc_{i}" for i in range(3)]
            + [f"f_rest_{i}" for i in range(3 * n_rest)] + ["opacity"] + [f"scale_{i}" for i in range(3)]
            + [f"rot_{i}" for i in range(4)])


def _vertex_array(model: GaussianModel) -> np.ndarray:
    names = property_names()
    data = np.zeros(model.n, dtype=[(name, "<f4") for name in names])
    for i, axis in enumerate("xyz"):
        data[axis] = model.means[:, i]
    for c in range(3):
        data[f"f_dc_{c}"] = model.sh_dc[:, 0, c]
    rest = model.sh_rest.transpose(0, 2, 1).reshape(model.n, -1)  # channel-major
    for i in range(rest.shape[1]):
        data[f"f_rest_{i}"] = rest[:, i]
    data["opacity"] = model.opacity_logits
    for i in range(3):
        data[f"scale_{i}"] = model.log_scales[:, i]
    for i in range(4):
        data[f"rot_{i}"] = model.quats[:, i]
    return data


def to_bytes(model: GaussianModel) -> bytes:
    """The model as a 3DGS PLY file (binary little endian float32, SH degree 3)."""
    buf = io.BytesIO()
    PlyData([PlyElement.describe(_vertex_array(model), "vertex")], byte_order="<").write(buf)
    return buf.getvalue()


def save_ply(path: str | Path, model: GaussianModel) -> Path:
    """Write `model` atomically (temporary file, then rename); returns the path."""
    if not isinstance(model, GaussianModel):
        raise ValueError(f"model: expected a GaussianModel, got {type(model).__name__}")
    atomic.write_bytes(path, to_bytes(model))
    return Path(path)


def _read(path: Path) -> PlyData:
    if path.is_dir():
        raise ValueError(f"{path}: is a directory; expected a PLY file")
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    try:
        return PlyData.read(str(path), mmap=False)
    except ValueError:
        raise
    except Exception as e:  # plyfile's header and element parse errors, and NumPy's short reads
        msg = " ".join(str(e).split()) or type(e).__name__
        raise ValueError(f"{path}: not a readable PLY file ({msg})") from None


def _check_group(path: Path, names: list[str], prefix: str, expected: int | None) -> int:
    """Count of `prefix`N properties; they must be exactly prefix0..prefix{count-1} (and `expected` many)."""
    nums = sorted(int(m.group(1)) for n in names if (m := re.fullmatch(re.escape(prefix) + r"(\d+)", n)))
    if expected is not None and nums != list(range(expected)):
        missing = [f"{prefix}{i}" for i in range(expected) if i not in nums]
        if missing:
            raise ValueError(f"{path}: missing property {missing[0]!r} ({len(nums)} {prefix}* properties; "
                             f"expected {prefix}0..{prefix}{expected - 1})")
        raise ValueError(f"{path}: property '{prefix}{nums[-1]}': {len(nums)} {prefix}* properties; expected "
                         f"{prefix}0..{prefix}{expected - 1}")
    if nums != list(range(len(nums))):
        gap = next(i for i in range(len(nums) + 1) if i not in nums)
        raise ValueError(f"{path}: missing property '{prefix}{gap}' ({prefix}* must be numbered 0..N-1)")
    return len(nums)


def load_ply(path: str | Path) -> GaussianModel:
    """Read a 3DGS PLY file (module docstring); ValueError naming the file on anything unexpected."""
    path = Path(path)
    ply = _read(path)
    elements = [e.name for e in ply.elements]
    if "vertex" not in elements:
        raise ValueError(f"{path}: no 'vertex' element (elements: {elements})")
    vertex = ply["vertex"]
    props = {p.name: p for p in vertex.properties}
    names = list(props)
    for name in ("x", "y", "z", "opacity"):
        if name not in props:
            raise ValueError(f"{path}: missing property {name!r} of element 'vertex'")
    for prefix, count in _GROUPS.items():
        _check_group(path, names, prefix, count)
    n_rest3 = _check_group(path, names, "f_rest_", None)
    if n_rest3 not in _DEGREE_OF_REST:
        raise ValueError(f"{path}: property 'f_rest_*': {n_rest3} f_rest properties; expected 0, 9, 24 or 45 "
                         "(SH degree 0-3)")
    normals = [n for n in ("nx", "ny", "nz") if n in props]
    required = property_names(n_rest3 // 3, normals=False) + normals
    for name in required:
        p = props[name]
        code = p.val_dtype.lstrip("<>=|")
        if isinstance(p, PlyListProperty) or code not in _FLOAT_TYPES:
            kind = "a list" if isinstance(p, PlyListProperty) else _PLY_TYPE_NAMES.get(code, code)
            raise ValueError(f"{path}: property {name!r} is {kind}; expected float or double")
    extra_props = [n for n in names if n not in required]
    extra_elems = [e for e in elements if e != "vertex"]
    if extra_props or extra_elems:
        what = ([f"vertex properties {extra_props}"] if extra_props else []) + \
            ([f"elements {extra_elems}"] if extra_elems else [])
        warnings.warn(f"{path}: ignored {' and '.join(what)}", PlyNote, stacklevel=2)

    data = vertex.data
    count = len(data)

    def col(name: str) -> np.ndarray:
        raw = np.asarray(data[name])
        if not np.all(np.isfinite(raw)):
            raise ValueError(f"{path}: property {name!r} has NaN or infinite values (vertex "
                             f"{int(np.flatnonzero(~np.isfinite(raw))[0])}); expected finite values")
        with np.errstate(over="ignore"):
            v = raw.astype(np.float32)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{path}: property {name!r} has values beyond the float32 range (vertex "
                             f"{int(np.flatnonzero(~np.isfinite(v))[0])}); expected |value| < 3.4e38")
        return v

    for name in normals:
        col(name)  # checked like every property, then dropped: the model has no normals
    k_rest = n_rest3 // 3
    sh_rest = np.zeros((count, SH_COEFFS - 1, 3), dtype=np.float32)
    if k_rest:
        rest = np.stack([col(f"f_rest_{i}") for i in range(n_rest3)], axis=1).reshape(count, 3, k_rest)
        sh_rest[:, :k_rest] = rest.transpose(0, 2, 1)
    arrays = dict(means=np.stack([col(a) for a in "xyz"], axis=1),
                  log_scales=np.stack([col(f"scale_{i}") for i in range(3)], axis=1),
                  quats=np.stack([col(f"rot_{i}") for i in range(4)], axis=1),
                  opacity_logits=col("opacity"),
                  sh_dc=np.stack([col(f"f_dc_{c}") for c in range(3)], axis=1)[:, None, :],
                  sh_rest=sh_rest)
    try:
        return GaussianModel(**arrays)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
