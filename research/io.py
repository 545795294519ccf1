"""Image I/O: PNG and EXR through OpenImageIO, hand-written PFM and .flo.

Formats and conventions
-----------------------
All arrays are row-major ``(H, W)`` or ``(H, W, C)`` with row 0 at the top of the
image, whatever the file stores.

**PNG** (8-bit, sRGB, straight alpha). ``write_png`` takes LINEAR float values.
A 4-channel input is premultiplied RGBA, which is what Mitsuba renders: RGB is
divided by alpha where alpha > 0 (and set to 0 where alpha == 0), then encoded
with the exact piecewise sRGB curve of IEC 61966-2-1::

    s = 12.92 * l                        if l <= 0.0031308
    s = 1.055 * l ** (1 / 2.4) - 0.055   otherwise

then clamped to [0, 1] and quantised with round-half-up, ``floor(s * 255 + 0.5)``.
The file holds straight (unassociated) alpha. OpenImageIO assumes buffers are
premultiplied and would alter the values, so every PNG is written and read with
the attribute ``oiio:UnassociatedAlpha = 1``; ``write_png_u8`` / ``read_png_u8``
therefore round-trip uint8 data bit-exactly, alpha == 0 pixels included.
``read_png(linear=True)`` inverts the curve on the colour channels (never on
alpha) and returns straight alpha. ``write_png_u16`` / ``read_png_u16`` store and read 16-bit
PNGs (KITTI's flow and disparity maps) as raw uint16 codes, bit-exactly, with no colour curve.

**EXR**: float32 channels (never HALF), zip compression, any number of channels.
OpenEXR sorts channels by name on disk, so the written order is kept in the
header attribute ``drlab:channelnames`` and restored on read. A single-channel
file reads back as ``(H, W)``. Values are stored bit-exactly, inf and NaN included.

**PFM** (Middlebury disparity): header ``"Pf\\n{W} {H}\\n{scale}\\n"`` (``"PF"`` for
3 channels), then float32 samples. A negative scale means little-endian; we
write ``-1.0``, and read either byte order. Rows are stored BOTTOM-TO-TOP, so they
are flipped on both write and read. Infinity (Middlebury's "unknown") is allowed,
NaN is rejected. The reader takes the header as Middlebury's own readers do
(Scharstein's pfmLib and the MiddEval3 SDK): the magic, then width, height and
scale as tokens separated by any whitespace (one line each, as pfmLib writes
them, or ``W H`` on one line), ``#`` comment lines between them, and exactly one
newline (``\\r\\n`` too, spaces before it allowed) after the scale before the samples.

**.flo** (Middlebury optical flow), little-endian: float32 magic 202021.25 (the
bytes ``PIEH``), int32 width, int32 height, then H*W*2 float32 interleaved
``(u, v)`` in row-major order, top row first. ``flow[..., 0] = u`` points right
(+x), ``flow[..., 1] = v`` points down (+y). Middlebury marks unknown flow with
values > 1e9; they are stored and read back as they are. NaN is rejected.

Every write goes to a temporary file beside the target and is renamed onto it
only on success (`research.atomic.atomic_path`). Bad input raises ValueError
before anything is written; a missing file raises FileNotFoundError and a
corrupt one ValueError, both naming the file.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Literal, Sequence, overload

import numpy as np
import numpy.typing as npt
import OpenImageIO as oiio

from research.atomic import atomic_path

__all__ = [
    "linear_to_srgb",
    "srgb_to_linear",
    "write_png",
    "read_png",
    "write_png_u8",
    "read_png_u8",
    "write_exr",
    "read_exr",
    "write_pfm",
    "read_pfm",
    "write_flo",
    "read_flo",
]

PathLike = str | os.PathLike
FLO_MAGIC = np.float32(202021.25)  # the bytes b"PIEH" as a little-endian float32
_EXR_ORDER_ATTR = "drlab:channelnames"


# ----------------------------------------------------------------------------- sRGB curve


def _float_out(x: npt.ArrayLike) -> tuple[np.ndarray, np.dtype]:
    a = np.asarray(x)
    if a.dtype.kind not in "fiub":
        raise ValueError(f"x: expected a real numeric array, got dtype {a.dtype}")
    out_dtype = a.dtype if a.dtype.kind == "f" else np.dtype(np.float64)
    return a.astype(np.float64), out_dtype


def linear_to_srgb(x: npt.ArrayLike) -> np.ndarray:
    """Linear -> sRGB-encoded values with the exact IEC 61966-2-1 curve (no clamping).

    Computed in float64; float inputs keep their dtype, others become float64.
    """
    a, dt = _float_out(x)
    with np.errstate(invalid="ignore"):
        s = np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.power(np.maximum(a, 0.0031308), 1 / 2.4) - 0.055)
    return s.astype(dt)


def srgb_to_linear(x: npt.ArrayLike) -> np.ndarray:
    """sRGB-encoded -> linear values, the exact inverse curve of `linear_to_srgb`."""
    a, dt = _float_out(x)
    with np.errstate(invalid="ignore"):
        l = np.where(a <= 0.04045, a / 12.92, np.power((np.maximum(a, 0.04045) + 0.055) / 1.055, 2.4))
    return l.astype(dt)


# ----------------------------------------------------------------------------- helpers


def _as_float32(arg: str, x: npt.ArrayLike) -> np.ndarray:
    """`x` as a C-contiguous float32 array; ValueError for non-numeric dtypes."""
    a = np.asarray(x)
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{arg}: expected a real float or integer array, got dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float32)


def _check_image_shape(arg: str, a: np.ndarray, channels: Sequence[int] | None) -> np.ndarray:
    """Validate (H, W) or (H, W, C); return it as (H, W, C)."""
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise ValueError(f"{arg}: expected shape (H, W) or (H, W, C), got {a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0 or a.shape[2] == 0:
        raise ValueError(f"{arg}: expected a non-empty image, got shape {a.shape}")
    if channels is not None and a.shape[2] not in channels:
        raise ValueError(f"{arg}: expected C in {tuple(channels)} channels, got shape {a.shape}")
    return a


def _reject_nan(arg: str, a: np.ndarray) -> None:
    if np.isnan(a).any():
        raise ValueError(f"{arg}: expected no NaN values, got {int(np.isnan(a).sum())} NaN")


def _missing(path: Path) -> FileNotFoundError:
    return FileNotFoundError(errno.ENOENT, "No such file", str(path))


def _write_binary(path: Path, chunks: Sequence[bytes]) -> None:
    """Write `chunks` to `path` in order and fsync (the temporary file of an atomic write)."""
    with open(path, "wb") as f:
        for chunk in chunks:
            f.write(chunk)
        f.flush()
        os.fsync(f.fileno())


def _oiio_write(path: Path, spec: oiio.ImageSpec, pixels: np.ndarray, target: Path) -> None:
    """Write `pixels` (H, W, C) to `path` with OpenImageIO; `target` names the file in errors."""
    # OpenEXR stamps the write time (capDate) unless DateTime is set; a fixed value keeps the
    # bytes reproducible, so the same data always gives the same file hash (dataset manifests).
    spec.attribute("DateTime", "1970:01:01 00:00:00")
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise OSError(f"{target}: OpenImageIO has no writer for it: {oiio.geterror()}")
    try:
        if not out.open(str(path), spec):
            raise OSError(f"{target}: cannot open for writing: {out.geterror()}")
        if not out.write_image(np.ascontiguousarray(pixels)):
            raise OSError(f"{target}: write failed: {out.geterror()}")
    finally:
        closed = out.close()
    if not closed:
        raise OSError(f"{target}: write failed on close: {out.geterror()}")


def _oiio_read(path: PathLike, fmt_name: str, pixel_format: str | None) -> tuple[np.ndarray, oiio.ImageSpec]:
    """Read the first subimage of an image file as (H, W, C), alpha left unassociated.

    `fmt_name` is OpenImageIO's format name the file must have ("png", "openexr").
    `pixel_format` is the OIIO type to convert to, or None for the file's own type.
    """
    p = Path(path)
    if not p.is_file():
        raise _missing(p)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(p), config)
    if inp is None:
        raise ValueError(f"{p}: not a readable image: {oiio.geterror()}")
    try:
        if inp.format_name() != fmt_name:
            raise ValueError(f"{p}: expected a {fmt_name} file, got {inp.format_name()}")
        spec = inp.spec()
        fmt = pixel_format if pixel_format is not None else str(spec.format)
        pixels = inp.read_image(0, 0, 0, spec.nchannels, fmt)
        err = inp.geterror() if pixels is None else ""
    finally:
        inp.close()
    if pixels is None or not isinstance(pixels, np.ndarray):
        raise ValueError(f"{p}: corrupt or truncated image: {err}")
    if pixels.ndim == 2:  # OIIO drops the channel axis for some single-channel reads
        pixels = pixels[:, :, None]
    if pixels.ndim != 3:
        raise ValueError(f"{p}: expected a 2-D image, got pixel array of shape {pixels.shape}")
    return pixels, spec


# ----------------------------------------------------------------------------- PNG


def write_png_u8(path: PathLike, u8: npt.ArrayLike) -> None:
    """Write uint8 (H, W) or (H, W, C), C in {1, 2, 3, 4}, to an 8-bit PNG exactly as given.

    Channels 2 and 4 are alpha, stored unassociated: no value is changed.
    """
    _write_png_exact(path, u8, "u8", "uint8", (1, 2, 3, 4))


def write_png_u16(path: PathLike, u16: npt.ArrayLike) -> None:
    """Write uint16 (H, W) or (H, W, C), C in {1, 3, 4}, to a 16-bit PNG exactly as given (no colour curve)."""
    _write_png_exact(path, u16, "u16", "uint16", (1, 3, 4))


def _write_png_exact(path: PathLike, values: npt.ArrayLike, name: str, dtype: str, channels: tuple[int, ...]) -> None:
    """`values` of `dtype` ("uint8" or "uint16") to a PNG as given; 2 channels are grey + unassociated alpha."""
    a = np.asarray(values)
    if a.dtype != np.dtype(dtype):
        raise ValueError(f"{name}: expected dtype {dtype}, got {a.dtype}")
    a = _check_image_shape(name, a, channels)
    h, w, c = a.shape
    spec = oiio.ImageSpec(w, h, c, dtype)
    if c == 2:
        spec.channelnames = ("Y", "A")
        spec.alpha_channel = 1
    spec.attribute("oiio:UnassociatedAlpha", 1)
    target = Path(path)
    with atomic_path(target) as tmp:
        _oiio_write(tmp, spec, a, target)


def read_png_u8(path: PathLike) -> np.ndarray:
    """Read an 8-bit PNG as uint8 (H, W, C), exactly as stored (straight alpha)."""
    pixels, spec = _oiio_read(path, "png", None)
    if pixels.dtype != np.uint8:
        raise ValueError(f"{path}: expected an 8-bit PNG, got pixel format {spec.format}")
    return pixels


def read_png_raw(path: PathLike) -> np.ndarray:
    """Read an 8- or 16-bit PNG as uint8 or uint16 (H, W, C), exactly as stored (no colour curve)."""
    pixels, spec = _oiio_read(path, "png", None)
    if pixels.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{path}: expected an 8- or 16-bit PNG, got pixel format {spec.format}")
    return pixels


def read_png_u16(path: PathLike) -> np.ndarray:
    """Read a 16-bit PNG as uint16 (H, W, C), exactly as stored (KITTI's flow and disparity maps)."""
    pixels = read_png_raw(path)
    if pixels.dtype != np.uint16:
        raise ValueError(f"{path}: expected a 16-bit PNG, got {pixels.dtype.itemsize * 8}-bit")
    return pixels


def write_png(
    path: PathLike, img: npt.ArrayLike, *, srgb: bool = True, premultiplied: bool = True
) -> None:
    """Write an image to an 8-bit sRGB PNG with straight alpha.

    img: float (H, W) or (H, W, C), C in {1, 3, 4}, holding LINEAR values; with
    C == 4 the RGB is premultiplied by alpha (Mitsuba's output) unless
    `premultiplied=False`. RGB is divided by alpha where alpha > 0 (0 where alpha
    == 0), encoded with `linear_to_srgb` if `srgb`, clamped to [0, 1] and quantised
    as floor(x * 255 + 0.5). Alpha is only clamped and quantised.
    A uint8 `img` is written as is (`write_png_u8`).
    """
    a = np.asarray(img)
    if a.dtype == np.uint8:
        _check_image_shape("img", a, (1, 3, 4))
        write_png_u8(path, a)
        return
    if a.dtype.kind != "f":
        raise ValueError(f"img: expected a float array (linear values) or uint8, got dtype {a.dtype}")
    a = _check_image_shape("img", a, (1, 3, 4)).astype(np.float64)
    _reject_nan("img", a)
    colour = a[..., :3] if a.shape[2] == 4 else a
    if a.shape[2] == 4:
        alpha = a[..., 3:]
        if premultiplied:
            safe = np.where(alpha > 0, alpha, 1.0)
            colour = np.where(alpha > 0, colour / safe, 0.0)
    if srgb:
        colour = linear_to_srgb(colour)
    out = colour if a.shape[2] != 4 else np.concatenate([colour, a[..., 3:]], axis=2)
    u8 = np.floor(np.clip(out, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    write_png_u8(path, u8)


def read_png(path: PathLike, *, linear: bool = True) -> np.ndarray:
    """Read a PNG as float32 (H, W, C) with straight alpha.

    linear=True inverts the sRGB curve on the colour channels (not on alpha);
    linear=False returns the stored values scaled to [0, 1], without the curve.
    """
    pixels, spec = _oiio_read(path, "png", None)
    if pixels.dtype.kind != "u":
        raise ValueError(f"{path}: unexpected PNG pixel format {spec.format}")
    x = pixels.astype(np.float32) / np.float32(np.iinfo(pixels.dtype).max)
    if linear:
        c = x.shape[2]
        alpha = spec.alpha_channel if 0 <= spec.alpha_channel < c else (c - 1 if c in (2, 4) else -1)
        colour = [i for i in range(c) if i != alpha]
        x[..., colour] = srgb_to_linear(x[..., colour])
    return x


# ----------------------------------------------------------------------------- EXR


def _default_channel_names(c: int) -> tuple[str, ...]:
    return {1: ("Y",), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}.get(c, tuple(f"C{i}" for i in range(c)))


def write_exr(path: PathLike, arr: npt.ArrayLike, channel_names: Sequence[str] | None = None) -> None:
    """Write a float32 (H, W) or (H, W, C) image to a zip-compressed EXR, any C >= 1.

    Channels are always stored as 32-bit float, never HALF; other real dtypes are
    converted to float32. Values are stored as they are (inf and NaN included).
    Default names: Y (C=1), RGB (3), RGBA (4), else C0, C1, ...
    """
    a = _check_image_shape("arr", _as_float32("arr", arr), None)
    c = a.shape[2]
    if channel_names is None:
        names = _default_channel_names(c)
    else:
        if isinstance(channel_names, str):
            raise ValueError(f"channel_names: expected a sequence of {c} strings, got the string {channel_names!r}")
        names = tuple(channel_names)
        if len(names) != c or not all(isinstance(n, str) and n for n in names):
            raise ValueError(f"channel_names: expected {c} non-empty strings, got {names!r}")
        if len(set(names)) != c:
            raise ValueError(f"channel_names: expected unique names, got {names!r}")
    spec = oiio.ImageSpec(a.shape[1], a.shape[0], c, "float")
    spec.channelnames = names
    spec.attribute("compression", "zip")
    spec.attribute(_EXR_ORDER_ATTR, json.dumps(list(names)))
    target = Path(path)
    with atomic_path(target) as tmp:
        _oiio_write(tmp, spec, a, target)


@overload
def read_exr(path: PathLike, with_names: Literal[False] = ...) -> np.ndarray: ...
@overload
def read_exr(path: PathLike, with_names: Literal[True]) -> tuple[np.ndarray, list[str]]: ...
def read_exr(path: PathLike, with_names: bool = False) -> np.ndarray | tuple[np.ndarray, list[str]]:
    """Read an EXR as float32 (H, W) for one channel, else (H, W, C), in the written order.

    with_names=True also returns the channel names.
    """
    pixels, spec = _oiio_read(path, "openexr", "float")
    names = list(spec.channelnames)
    try:
        order = json.loads(spec.get_string_attribute(_EXR_ORDER_ATTR) or "null")
    except json.JSONDecodeError:
        order = None
    if isinstance(order, list) and sorted(order) == sorted(names) and len(set(names)) == len(names):
        pixels = pixels[..., [names.index(n) for n in order]]
        names = list(order)
    out = np.ascontiguousarray(pixels[..., 0] if pixels.shape[2] == 1 else pixels, dtype=np.float32)
    return (out, names) if with_names else out


# ----------------------------------------------------------------------------- PFM


def write_pfm(path: PathLike, disp: npt.ArrayLike) -> None:
    """Write (H, W) ("Pf") or (H, W, 3) ("PF") float32 to a little-endian Middlebury PFM.

    Rows are written bottom-to-top, as PFM requires. inf is allowed, NaN is not.
    """
    a = np.asarray(disp)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    a = _as_float32("disp", a)
    a = _check_image_shape("disp", a, (1, 3))
    _reject_nan("disp", a)
    h, w, c = a.shape
    header = f"{'PF' if c == 3 else 'Pf'}\n{w} {h}\n-1.0\n".encode("ascii")
    data = np.ascontiguousarray(a[::-1], dtype="<f4").tobytes()
    with atomic_path(path) as tmp:
        _write_binary(tmp, [header, data])


def _pfm_header(p: Path, raw: bytes) -> tuple[bytes, int, int, float, int]:
    """(magic, width, height, scale, offset of the samples) of a PFM's bytes (module docstring)."""
    kind, pos, tokens = raw[:2], 2, []
    while len(tokens) < 3:
        while pos < len(raw) and raw[pos:pos + 1] in b" \t\r\n":
            pos += 1
        if raw[pos:pos + 1] == b"#":  # a comment runs to the end of its line
            end = raw.find(b"\n", pos)
            pos = len(raw) if end < 0 else end + 1
            continue
        start = pos
        while pos < len(raw) and raw[pos:pos + 1] not in b" \t\r\n#":
            pos += 1
        if start == pos:
            raise ValueError(f"{p}: corrupt PFM header (ends before width, height and scale)")
        tokens.append(raw[start:pos])
    while raw[pos:pos + 1] in (b" ", b"\t"):  # tolerated before the newline, as line-based readers do
        pos += 1
    if raw[pos:pos + 2] == b"\r\n":
        pos += 2
    elif raw[pos:pos + 1] == b"\n":
        pos += 1
    else:
        raise ValueError(f"{p}: corrupt PFM header (expected one newline after the scale, got {raw[pos:pos + 1]!r})")
    try:
        w, h, scale = int(tokens[0]), int(tokens[1]), float(tokens[2])
    except ValueError as e:
        raise ValueError(f"{p}: corrupt PFM header ({e})") from None
    if kind not in (b"Pf", b"PF") or w <= 0 or h <= 0 or scale == 0 or not np.isfinite(scale):
        raise ValueError(f"{p}: corrupt PFM header (type {kind!r}, size {w} {h}, scale {scale})")
    return kind, w, h, scale, pos


def read_pfm(path: PathLike) -> np.ndarray:
    """Read a PFM (either byte order; header as in the module docstring) as float32 (H, W) or (H, W, 3),
    top row first."""
    p = Path(path)
    if not p.is_file():
        raise _missing(p)
    raw = p.read_bytes()
    kind, w, h, scale, offset = _pfm_header(p, raw)
    c = 3 if kind == b"PF" else 1
    n = w * h * c * 4
    if len(raw) - offset != n:
        raise ValueError(f"{p}: expected {n} bytes of PFM data for {w}x{h}x{c}, got {len(raw) - offset}")
    a = np.frombuffer(raw, dtype="<f4" if scale < 0 else ">f4", offset=offset).reshape(h, w, c)[::-1]
    a = a.astype(np.float32)  # native byte order, contiguous copy
    return a[..., 0] if c == 1 else a


# ----------------------------------------------------------------------------- .flo


def write_flo(path: PathLike, flow: npt.ArrayLike) -> None:
    """Write flow (H, W, 2), [..., 0] = u (right), [..., 1] = v (down), to a Middlebury .flo.

    Values > 1e9 (Middlebury's "unknown") are stored as given; NaN is rejected.
    """
    a = _as_float32("flow", flow)
    if a.ndim != 3 or a.shape[2] != 2 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"flow: expected a non-empty array of shape (H, W, 2), got {a.shape}")
    _reject_nan("flow", a)
    h, w, _ = a.shape
    header = np.array([FLO_MAGIC], "<f4").tobytes() + np.array([w, h], "<i4").tobytes()
    with atomic_path(path) as tmp:
        _write_binary(tmp, [header, np.ascontiguousarray(a, dtype="<f4").tobytes()])


def read_flo(path: PathLike) -> np.ndarray:
    """Read a Middlebury .flo as float32 (H, W, 2); the magic number is checked."""
    p = Path(path)
    if not p.is_file():
        raise _missing(p)
    raw = p.read_bytes()
    if len(raw) < 12:
        raise ValueError(f"{p}: too short for a .flo header ({len(raw)} bytes)")
    magic = np.frombuffer(raw, "<f4", count=1)[0]
    if magic != FLO_MAGIC:
        raise ValueError(f"{p}: not a .flo file (magic {raw[:4]!r}, expected b'PIEH' = 202021.25)")
    w, h = (int(v) for v in np.frombuffer(raw, "<i4", count=2, offset=4))
    if w <= 0 or h <= 0:
        raise ValueError(f"{p}: invalid .flo size {w}x{h}")
    n = 12 + w * h * 2 * 4
    if len(raw) != n:
        raise ValueError(f"{p}: expected {n} bytes for a {w}x{h} .flo, got {len(raw)}")
    return np.frombuffer(raw, "<f4", offset=12).reshape(h, w, 2).astype(np.float32)
