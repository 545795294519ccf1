"""Tests for research.io: PNG/EXR through OpenImageIO, hand-written PFM and .flo."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from research import io as rio


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    """Exact equality of float32 arrays, bit for bit (NaN payloads and -0.0 included)."""
    same_kind = a.shape == b.shape and a.dtype == b.dtype == np.float32
    return same_kind and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def _nasty_float32(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Random float32 over many magnitudes, with negatives, -0.0, tiny and huge values."""
    x = rng.standard_normal(shape) * 10.0 ** rng.integers(-30, 30, shape)
    x = x.astype(np.float32)
    flat = x.reshape(-1)
    specials = np.array([-0.0, 3.0e38, -1e-40], np.float32)  # -0, huge, denormal
    flat[: min(3, flat.size)] = specials[: flat.size]
    return x


def _dir_listing(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


# ----------------------------------------------------------------------------- sRGB curve


def test_srgb_curve_known_values():
    assert rio.linear_to_srgb(0.0031308) == pytest.approx(0.04045, abs=1e-6)
    assert rio.linear_to_srgb(0.5) == pytest.approx(0.7353569830524495, abs=1e-12)
    assert rio.linear_to_srgb(np.array([0.0, 1.0])).tolist() == pytest.approx([0.0, 1.0], abs=1e-12)
    assert rio.srgb_to_linear(0.04045) == pytest.approx(0.04045 / 12.92, abs=1e-12)
    assert rio.srgb_to_linear(0.5) == pytest.approx(0.21404114048223255, abs=1e-12)
    assert rio.linear_to_srgb(0.001) == pytest.approx(0.01292, abs=1e-12)  # linear segment


def test_srgb_curve_inverse_and_dtype():
    x = np.random.default_rng(0).random(1000)
    assert np.allclose(rio.srgb_to_linear(rio.linear_to_srgb(x)), x, rtol=0, atol=1e-12)
    assert rio.linear_to_srgb(x.astype(np.float32)).dtype == np.float32
    assert rio.srgb_to_linear(x).dtype == np.float64


# ----------------------------------------------------------------------------- PNG


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_png_u8_round_trip_exact(tmp_path, channels):
    rng = np.random.default_rng(10 + channels)
    u8 = rng.integers(0, 256, (17, 23, channels), dtype=np.uint8)
    if channels in (2, 4):
        u8[:4, :, -1] = 0  # fully transparent pixels with nonzero colour must survive
        u8[:4, :, 0] = rng.integers(1, 256, (4, 23), dtype=np.uint8)
        u8[4:6, :, -1] = 255
    rio.write_png_u8(tmp_path / "a.png", u8)
    back = rio.read_png_u8(tmp_path / "a.png")
    assert back.dtype == np.uint8 and back.shape == u8.shape
    assert np.array_equal(back, u8)
    assert _dir_listing(tmp_path) == ["a.png"]


def test_png_uint8_through_write_png_is_written_as_is(tmp_path):
    u8 = np.random.default_rng(1).integers(0, 256, (6, 5, 4), dtype=np.uint8)
    u8[0, 0] = (200, 100, 50, 0)
    rio.write_png(tmp_path / "a.png", u8)
    assert np.array_equal(rio.read_png_u8(tmp_path / "a.png"), u8)
    # linear=False is the stored code / 255, with no curve and no alpha change
    assert np.array_equal(rio.read_png(tmp_path / "a.png", linear=False), u8.astype(np.float32) / np.float32(255))


def test_png_quantisation_matches_formula(tmp_path):
    rng = np.random.default_rng(2)
    x = rng.uniform(-0.2, 1.2, (32, 32, 3)).astype(np.float32)
    rio.write_png(tmp_path / "s.png", x)
    expect = np.floor(np.clip(rio.linear_to_srgb(x.astype(np.float64)), 0, 1) * 255 + 0.5).astype(np.uint8)
    assert np.array_equal(rio.read_png_u8(tmp_path / "s.png"), expect)

    rio.write_png(tmp_path / "n.png", x, srgb=False)
    expect = np.floor(np.clip(x.astype(np.float64), 0, 1) * 255 + 0.5).astype(np.uint8)
    assert np.array_equal(rio.read_png_u8(tmp_path / "n.png"), expect)


def test_png_known_codes(tmp_path):
    x = np.array([[0.0, 0.5, 1.0, 0.0031308, 2.0, -1.0]], np.float32)[..., None]
    rio.write_png(tmp_path / "k.png", x)
    # 0.5 -> 0.735357 * 255 = 187.52 -> 188; 0.0031308 -> 0.04045 * 255 = 10.31 -> 10; clamped ends
    assert rio.read_png_u8(tmp_path / "k.png")[0, :, 0].tolist() == [0, 188, 255, 10, 255, 0]
    rio.write_png(tmp_path / "h.png", np.array([[[0.5], [0.25]]], np.float32), srgb=False)
    assert rio.read_png_u8(tmp_path / "h.png")[0, :, 0].tolist() == [128, 64]  # 127.5 -> 128 (floor(x + 0.5))


def test_png_premultiplied_reads_back_straight(tmp_path):
    rng = np.random.default_rng(3)
    h, w = 24, 31
    straight = rng.random((h, w, 3)).astype(np.float32)
    alpha = rng.uniform(0.05, 1.0, (h, w, 1)).astype(np.float32)
    alpha[0, :5] = 0.0
    alpha[1, :5] = 1.0
    premult = np.concatenate([straight * alpha, alpha], axis=2)
    premult[0, :5, :3] = 0.0  # what a renderer gives where nothing is covered
    rio.write_png(tmp_path / "p.png", premult)

    q = 0.5 / 255 + 1e-6
    enc = rio.read_png(tmp_path / "p.png", linear=False)
    assert enc.dtype == np.float32 and enc.shape == (h, w, 4)
    covered = alpha[..., 0] > 0
    assert np.abs(enc[..., :3] - rio.linear_to_srgb(straight))[covered].max() <= q
    assert np.abs(enc[..., 3] - alpha[..., 0]).max() <= q
    assert np.all(enc[0, :5, :3] == 0.0) and np.all(enc[0, :5, 3] == 0.0)

    lin = rio.read_png(tmp_path / "p.png", linear=True)
    assert lin.dtype == np.float32
    # linear error is the sRGB quantisation error times the curve's slope (<= 2.4 / 1.055 ~ 2.28)
    assert np.abs(lin[..., :3] - straight)[covered].max() <= 2.28 * q
    assert np.array_equal(lin[..., 3], enc[..., 3])  # alpha never goes through the curve
    assert np.allclose(lin[..., :3], rio.srgb_to_linear(enc[..., :3]), rtol=0, atol=1e-7)


def test_png_straight_alpha_option(tmp_path):
    img = np.array([[[0.25, 0.5, 1.0, 0.5]]], np.float32)
    rio.write_png(tmp_path / "s.png", img, srgb=False, premultiplied=False)
    assert rio.read_png_u8(tmp_path / "s.png")[0, 0].tolist() == [64, 128, 255, 128]
    rio.write_png(tmp_path / "p.png", img, srgb=False)
    assert rio.read_png_u8(tmp_path / "p.png")[0, 0].tolist() == [128, 255, 255, 128]  # 0.25/0.5, clamp(2)


def test_png_greyscale_2d_input(tmp_path):
    x = np.random.default_rng(4).random((9, 8)).astype(np.float32)
    rio.write_png(tmp_path / "g.png", x)
    back = rio.read_png(tmp_path / "g.png")
    assert back.shape == (9, 8, 1)
    assert np.abs(rio.linear_to_srgb(back[..., 0]) - rio.linear_to_srgb(x)).max() <= 0.5 / 255 + 1e-6


@pytest.mark.parametrize(
    "img, match",
    [
        (np.zeros((4, 4, 2), np.float32), "img: expected C in"),
        (np.zeros((4, 4, 5), np.float32), "img: expected C in"),
        (np.zeros((4,), np.float32), r"img: expected shape \(H, W\)"),
        (np.zeros((2, 4, 4, 3), np.float32), r"img: expected shape \(H, W\)"),
        (np.zeros((0, 4, 3), np.float32), "non-empty"),
        (np.zeros((4, 4, 3), np.int32), "img: expected a float array"),
        (np.full((4, 4, 3), np.nan, np.float32), "img: expected no NaN"),
        (np.array([[["a", "b", "c"]]]), "img: expected a float array"),
    ],
)
def test_png_bad_input(tmp_path, img, match):
    with pytest.raises(ValueError, match=match):
        rio.write_png(tmp_path / "x.png", img)
    assert _dir_listing(tmp_path) == []


def test_png_u8_bad_input(tmp_path):
    with pytest.raises(ValueError, match="u8: expected dtype uint8"):
        rio.write_png_u8(tmp_path / "x.png", np.zeros((4, 4, 3), np.uint16))
    with pytest.raises(ValueError, match="u8: expected C in"):
        rio.write_png_u8(tmp_path / "x.png", np.zeros((4, 4, 5), np.uint8))
    assert _dir_listing(tmp_path) == []


# ----------------------------------------------------------------------------- EXR


@pytest.mark.parametrize("channels", [1, 2, 3, 4, 7])
def test_exr_round_trip_bit_exact(tmp_path, channels):
    rng = np.random.default_rng(20 + channels)
    x = _nasty_float32(rng, (13, 19, channels))
    x[2, 3, 0], x[2, 4, -1], x[2, 5, 0] = np.inf, -np.inf, np.nan
    rio.write_exr(tmp_path / "a.exr", x)
    back, names = rio.read_exr(tmp_path / "a.exr", with_names=True)
    assert _bits_equal(back, x[..., 0] if channels == 1 else x)
    assert len(names) == channels
    assert _dir_listing(tmp_path) == ["a.exr"]


def test_exr_2d_and_channel_order_kept(tmp_path):
    rng = np.random.default_rng(5)
    depth = (rng.random((8, 6)) * 100).astype(np.float32)
    rio.write_exr(tmp_path / "d.exr", depth, ["Z"])
    back, names = rio.read_exr(tmp_path / "d.exr", with_names=True)
    assert _bits_equal(back, depth) and names == ["Z"]

    # OpenEXR sorts channels by name on disk; the written order must come back.
    names = ["depth", "B", "A", "N.z", "N.x", "G", "R"]
    x = _nasty_float32(rng, (5, 4, len(names)))
    rio.write_exr(tmp_path / "m.exr", x, names)
    back, got = rio.read_exr(tmp_path / "m.exr", with_names=True)
    assert got == names and _bits_equal(back, x)


def test_exr_stored_as_float_zip(tmp_path):
    import OpenImageIO as oiio

    rio.write_exr(tmp_path / "d.exr", np.random.default_rng(6).random((4, 4, 3)), ["a", "b", "c"])  # float64 in
    inp = oiio.ImageInput.open(str(tmp_path / "d.exr"))
    spec = inp.spec()
    inp.close()
    assert str(spec.format) == "float" and all(str(f) == "float" for f in spec.channelformats or [spec.format])
    assert spec.get_string_attribute("compression") == "zip"


def test_exr_bad_input(tmp_path):
    x = np.zeros((4, 4, 3), np.float32)
    with pytest.raises(ValueError, match="channel_names: expected 3"):
        rio.write_exr(tmp_path / "x.exr", x, ["R", "G"])
    with pytest.raises(ValueError, match="channel_names: expected unique"):
        rio.write_exr(tmp_path / "x.exr", x, ["R", "R", "G"])
    with pytest.raises(ValueError, match="channel_names: expected a sequence"):
        rio.write_exr(tmp_path / "x.exr", x, "RGB")
    with pytest.raises(ValueError, match=r"arr: expected shape \(H, W\)"):
        rio.write_exr(tmp_path / "x.exr", np.zeros((2, 2, 2, 2), np.float32))
    with pytest.raises(ValueError, match="arr: expected a real float or integer array"):
        rio.write_exr(tmp_path / "x.exr", np.zeros((2, 2), np.complex64))
    assert _dir_listing(tmp_path) == []


# ----------------------------------------------------------------------------- PFM


@pytest.mark.parametrize("shape", [(11, 7), (5, 9, 3), (1, 1)])
def test_pfm_round_trip_bit_exact(tmp_path, shape):
    x = _nasty_float32(np.random.default_rng(30 + len(shape)), shape)
    x.reshape(-1)[-1] = np.inf  # Middlebury's "unknown disparity"
    rio.write_pfm(tmp_path / "d.pfm", x)
    assert _bits_equal(rio.read_pfm(tmp_path / "d.pfm"), x)
    raw = (tmp_path / "d.pfm").read_bytes()
    h, w = shape[:2]
    header = f"{'PF' if len(shape) == 3 else 'Pf'}\n{w} {h}\n-1.0\n".encode()
    assert raw.startswith(header) and len(raw) == len(header) + x.size * 4


def test_pfm_hand_made_orientation(tmp_path):
    # 2 rows x 3 columns; the file stores the BOTTOM row first.
    bottom, top = [1.0, 2.0, 3.0], [4.0, 5.0, 6.0]
    (tmp_path / "le.pfm").write_bytes(b"Pf\n3 2\n-1.0\n" + struct.pack("<6f", *bottom, *top))
    expect = np.array([top, bottom], np.float32)
    assert _bits_equal(rio.read_pfm(tmp_path / "le.pfm"), expect)
    # big-endian (positive scale), with a scale magnitude other than 1
    (tmp_path / "be.pfm").write_bytes(b"Pf\n3 2\n2.5\n" + struct.pack(">6f", *bottom, *top))
    assert _bits_equal(rio.read_pfm(tmp_path / "be.pfm"), expect)
    # colour: pixels are interleaved RGB, bottom row first
    vals = np.arange(18, dtype=np.float32)
    (tmp_path / "c.pfm").write_bytes(b"PF\n3 2\n-1.0\n" + vals.astype("<f4").tobytes())
    assert _bits_equal(rio.read_pfm(tmp_path / "c.pfm"), vals.reshape(2, 3, 3)[::-1].copy())
    # and the writer produces exactly the hand-made bytes
    rio.write_pfm(tmp_path / "w.pfm", expect)
    assert (tmp_path / "w.pfm").read_bytes() == (tmp_path / "le.pfm").read_bytes()


@pytest.mark.parametrize("header", [
    b"Pf\n3 2\n-1.0\n",             # Middlebury 2014 / MiddEval3 files
    b"Pf\n3\n2\n-1\n",              # Scharstein's pfmLib writer: one token a line
    b"Pf\r\n3 2\r\n-1.0\r\n",       # Windows line endings
    b"Pf\n# written by hand\n3 2\n-1.0\n",  # a comment line (MiddEval3 SDK's skip_comment)
    b"Pf 3 2 -1.0\n",               # the whole header on one line
    b"Pf\n3 2\n-1.0 \n",            # a space before the last newline (line-based readers strip it)
], ids=["middlebury", "pfmlib", "crlf", "comment", "one-line", "trailing-space"])
def test_pfm_headers_middlebury_readers_accept(tmp_path, header):
    bottom, top = [1.0, 2.0, float("inf")], [4.0, 5.0, 6.0]
    (tmp_path / "d.pfm").write_bytes(header + struct.pack("<6f", *bottom, *top))
    assert _bits_equal(rio.read_pfm(tmp_path / "d.pfm"), np.array([top, bottom], np.float32))


def test_pfm_bad_input_and_files(tmp_path):
    with pytest.raises(ValueError, match="disp: expected no NaN"):
        rio.write_pfm(tmp_path / "x.pfm", np.array([[1.0, np.nan]], np.float32))
    with pytest.raises(ValueError, match="disp: expected C in"):
        rio.write_pfm(tmp_path / "x.pfm", np.zeros((2, 2, 2), np.float32))
    with pytest.raises(ValueError, match=r"disp: expected shape \(H, W\)"):
        rio.write_pfm(tmp_path / "x.pfm", np.zeros(4, np.float32))
    with pytest.raises(ValueError, match="disp: expected a real float"):
        rio.write_pfm(tmp_path / "x.pfm", np.array([["a"]]))
    assert _dir_listing(tmp_path) == []

    with pytest.raises(FileNotFoundError, match="missing.pfm"):
        rio.read_pfm(tmp_path / "missing.pfm")
    bad_files = [  # (name, bytes, what the error says after the name)
        ("bad", b"P6\n3 2\n255\n" + bytes(18), ""),
        ("short", b"Pf\n3 2\n-1.0\n" + bytes(20), ".*24 bytes"),
        ("junk", b"Pf\nthree two\n-1\n", ""),
        ("nonl", b"Pf\n3 2\n-1.0X" + bytes(23), ": corrupt PFM header .expected one newline"),
        ("cut", b"Pf\n3 2\n", ": corrupt PFM header"),
    ]
    for name, raw, message in bad_files:
        (tmp_path / f"{name}.pfm").write_bytes(raw)
        with pytest.raises(ValueError, match=f"{name}.pfm{message}"):
            rio.read_pfm(tmp_path / f"{name}.pfm")


# ----------------------------------------------------------------------------- .flo


def test_flo_round_trip_bit_exact(tmp_path):
    x = _nasty_float32(np.random.default_rng(40), (9, 14, 2))
    x[0, 0] = (1e10, 1e10)  # Middlebury's "unknown flow" is kept as stored
    rio.write_flo(tmp_path / "f.flo", x)
    back = rio.read_flo(tmp_path / "f.flo")
    assert _bits_equal(back, x)
    assert back[0, 0, 0] == np.float32(1e10)
    raw = (tmp_path / "f.flo").read_bytes()
    assert raw[:4] == b"PIEH" and struct.unpack("<ii", raw[4:12]) == (14, 9) and len(raw) == 12 + x.size * 4


def test_flo_hand_made_layout(tmp_path):
    # W=3, H=2: (u, v) interleaved, row-major, top row first.
    vals = [float(i) for i in range(12)]
    (tmp_path / "h.flo").write_bytes(struct.pack("<f2i12f", 202021.25, 3, 2, *vals))
    flow = rio.read_flo(tmp_path / "h.flo")
    assert flow.shape == (2, 3, 2)
    assert flow[0, 0].tolist() == [0.0, 1.0]  # top-left: u=0, v=1
    assert flow[0, 2].tolist() == [4.0, 5.0]  # top-right
    assert flow[1, 0].tolist() == [6.0, 7.0]  # bottom-left
    rio.write_flo(tmp_path / "w.flo", flow)
    assert (tmp_path / "w.flo").read_bytes() == (tmp_path / "h.flo").read_bytes()


def test_flo_bad_input_and_files(tmp_path):
    with pytest.raises(ValueError, match=r"flow: expected a non-empty array of shape \(H, W, 2\)"):
        rio.write_flo(tmp_path / "x.flo", np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match=r"flow: expected a non-empty array of shape \(H, W, 2\)"):
        rio.write_flo(tmp_path / "x.flo", np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="flow: expected no NaN"):
        rio.write_flo(tmp_path / "x.flo", np.full((2, 2, 2), np.nan, np.float32))
    with pytest.raises(ValueError, match="flow: expected a real float"):
        rio.write_flo(tmp_path / "x.flo", np.zeros((2, 2, 2), np.complex64))
    assert _dir_listing(tmp_path) == []

    with pytest.raises(FileNotFoundError, match="missing.flo"):
        rio.read_flo(tmp_path / "missing.flo")
    (tmp_path / "magic.flo").write_bytes(struct.pack("<f2i4f", 1.0, 1, 1, 0, 0, 0, 0))
    with pytest.raises(ValueError, match="magic.flo.*not a .flo file"):
        rio.read_flo(tmp_path / "magic.flo")
    (tmp_path / "short.flo").write_bytes(struct.pack("<f2i3f", 202021.25, 1, 2, 0, 0, 0))
    with pytest.raises(ValueError, match="short.flo.*expected 28 bytes"):
        rio.read_flo(tmp_path / "short.flo")
    (tmp_path / "tiny.flo").write_bytes(b"PIE")
    with pytest.raises(ValueError, match="tiny.flo"):
        rio.read_flo(tmp_path / "tiny.flo")


# ----------------------------------------------------------------------------- reading bad image files


@pytest.mark.parametrize("reader, name", [(rio.read_png, "m.png"), (rio.read_png_u8, "m.png"), (rio.read_exr, "m.exr")])
def test_image_missing_file(tmp_path, reader, name):
    with pytest.raises(FileNotFoundError, match=name):
        reader(tmp_path / name)


def test_image_corrupt_files(tmp_path):
    (tmp_path / "junk.png").write_bytes(b"not an image at all" * 10)
    with pytest.raises(ValueError, match="junk.png"):
        rio.read_png(tmp_path / "junk.png")
    (tmp_path / "junk.exr").write_bytes(b"not an image at all" * 10)
    with pytest.raises(ValueError, match="junk.exr"):
        rio.read_exr(tmp_path / "junk.exr")

    rng = np.random.default_rng(7)
    rio.write_png_u8(tmp_path / "ok.png", rng.integers(0, 256, (64, 64, 4), dtype=np.uint8))
    raw = (tmp_path / "ok.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="cut.png"):
        rio.read_png_u8(tmp_path / "cut.png")
    rio.write_exr(tmp_path / "ok.exr", rng.standard_normal((64, 64, 3)))
    raw = (tmp_path / "ok.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="cut.exr"):
        rio.read_exr(tmp_path / "cut.exr")
    # the wrong format under the expected reader
    with pytest.raises(ValueError, match="ok.exr.*expected a png"):
        rio.read_png(tmp_path / "ok.exr")


# ----------------------------------------------------------------------------- atomic writes


class _Boom(RuntimeError):
    pass


_RNG = np.random.default_rng(50)
_CASES = {
    "png": ("a.png", "_oiio_write", lambda p: rio.write_png(p, _RNG.random((8, 8, 4)).astype(np.float32))),
    "png_u8": ("a.png", "_oiio_write", lambda p: rio.write_png_u8(p, _RNG.integers(0, 256, (8, 8, 3), dtype=np.uint8))),
    "exr": ("a.exr", "_oiio_write", lambda p: rio.write_exr(p, _RNG.random((8, 8, 3)).astype(np.float32))),
    "pfm": ("a.pfm", "_write_binary", lambda p: rio.write_pfm(p, _RNG.random((8, 8)).astype(np.float32))),
    "flo": ("a.flo", "_write_binary", lambda p: rio.write_flo(p, _RNG.random((8, 8, 2)).astype(np.float32))),
}


@pytest.mark.parametrize("kind", sorted(_CASES))
@pytest.mark.parametrize("existing", [False, True])
def test_writes_are_atomic(tmp_path, monkeypatch, kind, existing):
    name, writer_name, write = _CASES[kind]
    target = tmp_path / name
    if existing:
        target.write_bytes(b"previous contents")
    real = getattr(rio, writer_name)
    written: list[Path] = []

    def write_then_fail(path, *args, **kwargs):
        # The real writer fills the temporary file; then the run "dies" before the rename.
        real(path, *args, **kwargs)
        assert path.exists() and path.stat().st_size > 0 and path != target
        written.append(path)
        raise _Boom("interrupted")

    monkeypatch.setattr(rio, writer_name, write_then_fail)
    with pytest.raises(_Boom):
        write(target)
    assert len(written) == 1 and not written[0].exists()
    if existing:
        assert _dir_listing(tmp_path) == [name] and target.read_bytes() == b"previous contents"
    else:
        assert _dir_listing(tmp_path) == []

    monkeypatch.setattr(rio, writer_name, real)
    write(target)
    assert _dir_listing(tmp_path) == [name] and target.read_bytes() != b"previous contents"


def test_temporary_name_keeps_extension(tmp_path, monkeypatch):
    seen: list[Path] = []
    real = rio._oiio_write
    monkeypatch.setattr(rio, "_oiio_write", lambda p, *a: (seen.append(p), real(p, *a)))
    rio.write_exr(tmp_path / "d.exr", np.zeros((2, 2), np.float32))
    assert seen[0].suffix == ".exr" and seen[0].parent == tmp_path
