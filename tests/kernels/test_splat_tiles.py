"""kernels/splat/tiles.py and the rasteriser's pixel spans: the CPU's counting sort by tile gives
the radix sort's lists, and the spans (each splat's pixels inside its 1/255 ellipse, widened for
rounding) leave out no pixel that blends the splat, even for splats at the edges of what the
margin covers: near-degenerate conics, huge and tiny splats, opacities just above 1/255.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from kernels import splat as ks
from kernels.reference import splat as ref
from kernels.splat.raster import _rasterize_wp, background_array
from kernels.splat.tiles import SERIAL_SORT_MAX, SORT_CHUNK_MIN, _bin_tiles
from research.bench.splat import bench_scene
from research.checks import splat as cs

TOL = {np.float32: dict(rtol=2e-4, atol=2e-5), np.float64: dict(rtol=1e-10, atol=1e-11)}
W, H = 56, 40


def _conic(sigma_major: float, ratio: float, angle: float) -> np.ndarray:
    """(Q00, Q01, Q11) of the covariance with standard deviations sigma_major, sigma_major / ratio."""
    c, s = math.cos(angle), math.sin(angle)
    R = np.array([[c, -s], [s, c]])
    cov = R @ np.diag([sigma_major ** 2, (sigma_major / ratio) ** 2]) @ R.T
    q = np.linalg.inv(cov)
    return np.array([q[0, 0], q[0, 1], q[1, 1]])


def hard_splats(seed: int) -> dict[str, np.ndarray]:
    """Screen-space splats at the margins' edges (see the module docstring), in float64."""
    rng = np.random.default_rng(seed)
    rows = []
    # Axis ratios 40 (1 - rho = 1.25e-3 at 45 degrees: spans) and 50 (8e-4: no spans, the whole box).
    for ratio in (40.0, 50.0, 30.0):
        angle = math.pi / 4 + rng.uniform(-0.02, 0.02)
        rows.append((rng.uniform(0, W), rng.uniform(0, H), _conic(rng.uniform(8, 30), ratio, angle),
                     rng.uniform(0.3, 0.9)))
    rows.append((W / 2, H / 2, _conic(200.0, 1.5, 0.3), 0.2))  # covers the image
    rows.append((-25.0, H + 20.0, _conic(40.0, 2.0, 1.0), 0.7))  # centred off the image
    rows.append((rng.uniform(0, W), rng.uniform(0, H), _conic(0.25, 1.2, 0.0), 0.95))  # sub-pixel
    rows.append((rng.uniform(0, W), rng.uniform(0, H), _conic(6.0, 3.0, 0.7), 1.0001 / 255))  # 1/255 just reached
    for _ in range(40):
        rows.append((rng.uniform(-15, W + 15), rng.uniform(-15, H + 15),
                     _conic(math.exp(rng.uniform(math.log(0.4), math.log(25))), math.exp(rng.uniform(0, math.log(45))),
                            rng.uniform(0, math.pi)), rng.uniform(1 / 255, 1.0)))
    n = len(rows)
    m2 = np.array([[r[0], r[1]] for r in rows])
    conics = np.array([r[2] for r in rows])
    opac = np.array([r[3] for r in rows])
    cov_major = np.array([np.linalg.eigvalsh(np.linalg.inv([[q[0], q[1]], [q[1], q[2]]])).max() for q in conics])
    radii = np.ceil(3 * np.sqrt(cov_major)).astype(np.int32)
    return {"means2d": m2, "conics": conics, "colors": rng.uniform(0.2, 1.0, (n, 3)), "opacities": opac,
            "depths": rng.permutation(n) + rng.uniform(0.1, 0.9, n), "radii": radii}


@pytest.mark.parametrize("mode", ks.MODES)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("seed", [0, 1])
def test_spans_leave_out_no_blended_pixel(seed, dtype, mode):
    sp = hard_splats(seed)
    bg = np.array([0.1, 0.3, 0.2])
    keys = ("means2d", "conics", "colors", "opacities", "depths")
    # The reference evaluates the splats' stored (dtype-rounded) values in float64.
    vals = {k: sp[k].astype(dtype) for k in keys}
    want = ref.rasterize(*(vals[k].astype(np.float64) for k in keys), sp["radii"], W, H, bg, mode=mode)
    r, tiles = ks.rasterize(ks.splats_2d(*(vals[k] for k in keys), sp["radii"]), W, H, bg.astype(dtype), mode=mode)
    hy = tiles.packed.numpy()[:, 14]
    assert np.any(hy < 0) and np.any(hy >= 0)  # both the span and the whole-box paths ran
    assert want[1].max() > 0.9 and np.count_nonzero(want[1]) > 0.9 * W * H
    for got, w in zip((r.rgb, r.alpha, r.depth), want):
        np.testing.assert_allclose(got, w, **TOL[dtype])


def _scenes():
    rng = np.random.default_rng(3)
    sc = cs.random_scene(rng, n=300, width=90, height=70)
    g = ks.gaussian_inputs(*(sc.params[k] for k in cs.PARAMS))
    yield "random300", g, sc.camera
    g, cam = bench_scene(2000, 96, 128)
    yield "bench2000", g, cam


@pytest.mark.parametrize("mode", ks.MODES)
def test_counting_sort_lists_equal_the_radix_sort(mode):
    """The CPU's two counting sorts (one serial kernel for few entries, the chunked one, cut into any
    number of chunks) and CUDA's radix sort, all run on the CPU, give the same lists."""
    for name, g, cam in _scenes():
        p = ks.project(g, cam, mode=mode)
        s = ks.splats_2d(p.means2d, p.conics, p.colors, p.opacities, p.depths, p.radii)
        b = _bin_tiles(s, cam.width, cam.height, mode, counting_sort=False)
        assert 0 < b.n_entries <= SERIAL_SORT_MAX, name  # bin_tiles takes the serial kernel here
        # the serial kernel; the chunked sort as one chunk, as SORT_CHUNKS chunks and as a few uneven ones
        for serial_max, chunk_min in ((SERIAL_SORT_MAX, SORT_CHUNK_MIN), (0, SORT_CHUNK_MIN), (0, 1), (0, 977)):
            a = _bin_tiles(s, cam.width, cam.height, mode, counting_sort=True, serial_max=serial_max,
                           chunk_min=chunk_min)
            assert a.n_entries == b.n_entries, name
            e = a.n_entries
            for k in ("starts", "counts", "ranges", "packed"):
                np.testing.assert_array_equal(getattr(a, k).numpy(), getattr(b, k).numpy(), err_msg=f"{name} {k}")
            for k in ("sorted_gid", "sorted_entry"):
                np.testing.assert_array_equal(getattr(a, k).numpy()[:e], getattr(b, k).numpy()[:e],
                                              err_msg=f"{name} {k}")
        assert len(np.unique(b.ranges.numpy()[:, 0])) > 4, name  # many non-empty tiles


@pytest.mark.parametrize("mode", ks.MODES)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_tile_and_pixel_layouts_agree_bit_for_bit(dtype, mode):
    """The CPU's forward (a thread per tile over each splat's spans) and CUDA's (a thread per pixel
    over the tile's whole list), both run on the CPU: every output byte-identical."""
    sp = hard_splats(2)
    keys = ("means2d", "conics", "colors", "opacities", "depths")
    s = ks.splats_2d(*(sp[k].astype(dtype) for k in keys), sp["radii"])
    bg = background_array(s.inputs(), np.array([0.1, 0.3, 0.2], dtype))
    tiles = ks.bin_tiles(s, W, H, mode)
    a, _ = _rasterize_wp(s, W, H, bg, tiles, mode, per_tile=True)
    b, _ = _rasterize_wp(s, W, H, bg, tiles, mode, per_tile=False)
    assert np.count_nonzero(a.alpha.numpy()) > 0.9 * W * H
    # bit-equal by construction: each pixel blends the same splats in the same list order with the same float
    # operations in both layouts (no contraction across Warp's statements; the float32 row blend's C++ keeps that
    # order and its exp has expf's bits, kernels.splat.rowblend); only which thread owns the pixel differs
    for k in ("rgb", "alpha", "depth", "final_T", "n_contrib"):
        assert getattr(a, k).numpy().tobytes() == getattr(b, k).numpy().tobytes(), k


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_stop_threshold_is_each_modes_comparison(dtype):
    """The rasterisers' one comparison next_t < stop_below(mode) is "3dgs"'s next_t < T_MIN and
    "gsplat"'s next_t <= T_MIN, on T_MIN itself and the floats around it."""
    from kernels.splat.raster import T_MIN, stop_below

    t = dtype(T_MIN)
    xs = [t, np.nextafter(t, dtype(0)), np.nextafter(t, dtype(1)), np.nextafter(np.nextafter(t, dtype(1)), dtype(1)),
          dtype(0), dtype(1), dtype(np.nan)]
    t3, tg = dtype(stop_below("3dgs", np.dtype(dtype))), dtype(stop_below("gsplat", np.dtype(dtype)))
    for x in xs:
        assert (x < t3) == (x < t)
        assert (x < tg) == (x <= t)


def test_image_side_limit():
    """Pixel centres step by one in float32 in the rasteriser: sides above 2^23 are refused up front."""
    from kernels.splat.tiles import MAX_SIDE

    K = np.array([[100.0, 0, 10], [0, 100.0, 10], [0, 0, 1]])
    with pytest.raises(ValueError, match="width"):
        ks.SplatCamera(np.eye(4), K, MAX_SIDE + 1, 4)
    with pytest.raises(ValueError, match="height"):
        ks.SplatCamera(np.eye(4), K, 4, MAX_SIDE + 1)
    ks.SplatCamera(np.eye(4), K, MAX_SIDE, 4)
