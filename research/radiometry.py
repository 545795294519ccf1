"""A radiometric stress set: what a real camera pair does to a clean linear render.

Rendered pairs are radiometrically perfect: both views see the same radiance through the same
ideal sensor. Real stereo rigs and video frames differ in exposure and gain, add sensor noise, darken
towards the corners and blur slightly, and store 8 bits. `stress` applies those effects to a linear
render, deterministically from a NumPy random generator, so methods (and their defaults) can be
tried on pairs whose photometry differs the way real ones do.

Model, in this order, for a linear image E (H, W) or (H, W, 3) (an RGBA render's alpha is dropped),
with each camera's parameters drawn once (`draw_camera`) from the ranges of `Stress`:

1. optics, slight blur: E <- G_sigma * E, a Gaussian of standard deviation sigma ~ U[0, blur_sigma] px
   (scipy.ndimage.gaussian_filter, "nearest" border), per channel;
2. optics, vignetting: E <- E (1 - v (r / r_c)^2), v ~ U[0, vignetting], r the distance to the image
   centre and r_c the centre-to-corner distance (so the corners lose the fraction v);
3. exposure and gain: E <- 2^s E + o, s ~ U[-exposure_stops, exposure_stops] (stops of exposure
   times analogue gain), o ~ U[-offset, offset] (black level), one value per camera for every channel;
4. sensor noise, Poisson-Gaussian: E <- E + n, n ~ N(0, shot_noise^2 max(E, 0) + read_noise^2) per
   pixel and channel;
5. clip to [0, 1], sRGB encoding (research.io.linear_to_srgb, the exact IEC 61966-2-1 curve), and
   quantisation to `bits` bits: round(255 x) for 8 bits (uint8), round(65535 x) for 16 (uint16).

`clean(E)` is step 5 alone (the same encoding and quantisation with no stress), so a clean pair and a
stressed one differ only by steps 1-4. Images come back colour if they went in colour (drlab's
stereo and flow take them through research.images.to_unit_grey / to_unit; OpenCV takes them as
they are).

Determinism: `stress(image, rng)` draws, from `rng` and in this order, the camera (sigma, v, s, o)
and then the noise field (rng.standard_normal of the image's shape), so one seed gives one result
on every machine. `stress_pair(first, second, seed)` builds np.random.default_rng(seed) and stresses
`first` then `second` with it: two cameras with independent parameters, as a stereo rig, or two
frames of one camera whose auto-exposure moved, as in video. `Stress.none()` disables every effect
(then `stress` equals `clean`).

Defaults (`Stress()`): up to +-0.3 stops per camera (0.6 between two), black level +-0.01, corner
falloff up to 25 %, blur up to 0.8 px, shot noise 0.01 and read noise 0.003 (standard deviation
0.0052 at 18 % grey, linear 0.18: 1.6 codes of 255 after encoding, measured), 8 bits. They
describe a consumer camera pair; no method's result chose them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from research import values
from research.io import linear_to_srgb

_BITS = {8: np.uint8, 16: np.uint16}


@dataclass(frozen=True)
class Stress:
    """Ranges of the per-camera effects (module docstring); every value >= 0."""

    exposure_stops: float = 0.3
    offset: float = 0.01
    vignetting: float = 0.25
    blur_sigma: float = 0.8
    shot_noise: float = 0.01
    read_noise: float = 0.003
    bits: int = 8

    def __post_init__(self) -> None:
        for name in ("exposure_stops", "offset", "vignetting", "blur_sigma", "shot_noise", "read_noise"):
            values.number(name, getattr(self, name), 0)
        if self.vignetting > 1:
            raise ValueError(f"vignetting: expected a corner falloff in [0, 1], got {self.vignetting!r}")
        if isinstance(self.bits, bool) or self.bits not in _BITS:
            raise ValueError(f"bits: expected 8 or 16, got {self.bits!r}")

    @classmethod
    def none(cls, bits: int = 8) -> "Stress":
        """No effect at all: `stress` then equals `clean`."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, bits)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Camera:
    """One camera's draw: blur sigma (px), corner falloff v, exposure s (stops), black level o."""

    blur_sigma: float
    vignetting: float
    exposure_stops: float
    offset: float


def draw_camera(rng: np.random.Generator, params: Stress = Stress()) -> Camera:
    """One camera's parameters from `params`' ranges, drawn from `rng` in the order sigma, v, s, o."""
    _check_rng(rng)
    sigma, v, s, o = rng.uniform(0.0, 1.0, 4)
    return Camera(blur_sigma=float(sigma * params.blur_sigma), vignetting=float(v * params.vignetting),
                  exposure_stops=float((2.0 * s - 1.0) * params.exposure_stops),
                  offset=float((2.0 * o - 1.0) * params.offset))


def _check_rng(rng: Any) -> None:
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected a numpy.random.Generator (np.random.default_rng(seed)), got "
                         f"{type(rng).__name__}")


def _linear(image: Any, name: str) -> np.ndarray:
    """A finite, non-negative linear float image (H, W) or (H, W, 3) in float64; RGBA loses its alpha."""
    a = np.asarray(image)
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"{name}: expected a linear float image (a render), got dtype {a.dtype}")
    if a.ndim == 3 and a.shape[2] == 4:
        a = a[..., :3]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name}: expected a non-empty (H, W), (H, W, 3) or (H, W, 4) image, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    if float(a.min()) < 0.0:
        raise ValueError(f"{name}: a linear radiance image must be >= 0, got a minimum of {float(a.min()):.6g}")
    return a.astype(np.float64)


def _encode(linear: np.ndarray, bits: int) -> np.ndarray:
    """Clip to [0, 1], sRGB-encode and round to `bits` bits (step 5)."""
    top = float(2 ** bits - 1)
    return np.floor(np.clip(linear_to_srgb(np.clip(linear, 0.0, 1.0)), 0.0, 1.0) * top + 0.5).astype(_BITS[bits])


def clean(image: Any, bits: int = 8, name: str = "image") -> np.ndarray:
    """The encoding alone: clip, sRGB, `bits`-bit quantisation of a linear image (module docstring, step 5)."""
    Stress(bits=bits)  # validates bits
    return _encode(_linear(image, name), bits)


def apply_camera(image: Any, camera: Camera, rng: np.random.Generator, params: Stress = Stress(),
                 name: str = "image") -> np.ndarray:
    """Steps 1-5 of the module docstring with a given `camera`; the noise is drawn from `rng`."""
    from scipy.ndimage import gaussian_filter

    _check_rng(rng)
    e = _linear(image, name)
    if camera.blur_sigma > 0:
        sigma = (camera.blur_sigma, camera.blur_sigma) + ((0.0,) if e.ndim == 3 else ())
        e = gaussian_filter(e, sigma, mode="nearest")
    if camera.vignetting > 0:
        h, w = e.shape[:2]
        y, x = np.mgrid[0:h, 0:w].astype(np.float64)
        cy, cx = (h - 1) / 2.0, (w - 1) / 2.0
        r2 = ((y - cy) ** 2 + (x - cx) ** 2) / max(cy ** 2 + cx ** 2, 1e-12)
        fall = 1.0 - camera.vignetting * r2
        e = e * (fall[..., None] if e.ndim == 3 else fall)
    e = e * 2.0 ** camera.exposure_stops + camera.offset
    noise = rng.standard_normal(e.shape)
    if params.shot_noise > 0 or params.read_noise > 0:
        e = e + noise * np.sqrt(params.shot_noise ** 2 * np.maximum(e, 0.0) + params.read_noise ** 2)
    return _encode(e, params.bits)


def stress(image: Any, rng: np.random.Generator, params: Stress = Stress(), name: str = "image") -> np.ndarray:
    """One image through one freshly drawn camera: `apply_camera(image, draw_camera(rng, params), rng, params)`.

    `image`: linear float (H, W), (H, W, 3) or (H, W, 4), >= 0 (a render). Returns uint8 (uint16 for
    bits=16) sRGB-encoded values with the image's channels (alpha dropped).
    """
    _check_rng(rng)
    _linear(image, name)  # bad input fails before any draw
    return apply_camera(image, draw_camera(rng, params), rng, params, name)


def stress_pair(first: Any, second: Any, seed: int, params: Stress = Stress(),
                names: tuple[str, str] = ("left", "right")) -> tuple[np.ndarray, np.ndarray]:
    """Both images of a pair, each through its own camera, from np.random.default_rng(seed) (module docstring)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: expected an integer >= 0, got {seed!r}")
    a, b = _linear(first, names[0]), _linear(second, names[1])
    if a.shape != b.shape:
        raise ValueError(f"{names[0]}, {names[1]}: expected images of one shape, got {a.shape} and {b.shape}")
    rng = np.random.default_rng(int(seed))
    return stress(a, rng, params, names[0]), stress(b, rng, params, names[1])
