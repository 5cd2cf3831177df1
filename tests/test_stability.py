"""
Numerical stability of nanovdbvolume on stiff and extreme cases.

References, as the issue asks: Mitsuba's dense `gridvolume` on the dense
export of the same active box where it fits (lookups: nearest exactly equal,
trilinear to float rounding), and analytic transmittance where it does not:
an orthographic camera looks along +z through a box of medium with albedo 0
in front of a uniform environment of radiance 1, so every pixel is
exp(-tau) with tau = integral of scale * density along the ray. Renders use
delta tracking, whose estimate per sample is 0 or 1: the tolerances below
are 5 binomial standard deviations of the averaged samples (stated per test).

Grids come from build/bin/nvdb_make_stability_grid (OpenVDB -> NanoVDB's own
converter and writer, tests/make_stability_grid.cpp) and, for the grid
beyond 4 GiB, build/bin/nvdb_big_grid (tests/big_grid.cpp).

Precision of far-away grids (measured by test05, see its comments):
 * Default mode: the local point u in [0, 1]^3 gives the index position
   m + u * d - 0.5 relative to the box minimum m, and the integer m is added
   last. The precision therefore does not depend on where the grid is: boxes
   at |ijk| = 10^6 ... 2.1 * 10^9 pick exactly the voxels gridvolume picks.
 * use_grid_transform: world -> index is composed in double with to_world
   and rounded once to a float matrix; the index position of a float world
   point p is computed to about one float ulp of |p| / voxel_size. The world
   coordinate itself is a float, so what limits a lookup is the spacing of
   floats at |p|: 2^-23 * |p|. A nearest lookup picks the right voxel for
   points at least a quarter voxel from a voxel boundary as long as
   |p| / voxel_size <= 2^21 (2.1e6 voxels from the world origin; e.g.
   |p| <= 2.1e6 for 1-unit voxels, 2.1e4 for 0.01); beyond that, move the
   grid with to_world or use the default mode.
"""

import os
import shutil
import subprocess

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from conftest import (BUILD, eval_points, gpu_used_bytes, load_dense, load_nvdb, read_vol,
                      rss_bytes, settle_gpu, trim_heap)
from conftest import make_stability_grid as make

BIG = BUILD / "bin" / "nvdb_big_grid"


# ---------------------------------------------------------------------------
#  Helpers
# ---------------------------------------------------------------------------

def n_points(jit, scalar):
    return jit if dr.is_jit_v(mi.Float) else scalar


def render_transmittance(volume, scale=1.0, size=16, spp=64, box=((0, 0, 0), (1, 1, 1)),
                         view=(0.1, 0.9), seed=0):
    """Orthographic view along +z through the medium box `box` (world space),
    albedo 0, environment radiance 1: each pixel estimates exp(-tau). `view`:
    the part of the box's x/y extent that the film covers."""
    lo, hi = np.array(box[0], dtype=float), np.array(box[1], dtype=float)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    cover = (view[1] - view[0]) / 2
    cx, cy = lo[:2] + (hi[:2] - lo[:2]) * (view[0] + view[1]) / 2
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": 64},
        "sensor": {
            "type": "orthographic",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[cx, cy, lo[2] - 1.0 - half[2]], target=[cx, cy, centre[2]],
                up=[0, 1, 0]) @ mi.ScalarTransform4f().scale(
                    [cover * 2 * half[0], cover * 2 * half[1], 1]),
            "film": {"type": "hdrfilm", "width": size, "height": size,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "emitter": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "cube": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().translate(centre.tolist()).scale(half.tolist()),
            "bsdf": {"type": "null"},
            "interior": {"type": "heterogeneous", "sigma_t": volume, "albedo": 0.0,
                         "scale": scale},
        },
    })
    img = np.array(mi.render(scene, seed=seed))
    assert np.all(np.isfinite(img)), "NaN or Inf in a pixel"
    return img[..., 0]


def binomial_tol(t, n, img=None):
    """5 standard deviations of the mean of n Bernoulli(t) samples, at least
    1e-6. Spectral variants add the colour noise of their wavelength sampling
    (each path carries one wavelength, converted to RGB: about +-3 % per pixel
    at 64 spp even where T = 1); for them, 5 standard errors of the pixel
    values of `img` are added."""
    tol = max(5 * np.sqrt(max(t * (1 - t), 0.0) / n), 1e-6)
    if img is not None and mi.is_spectral:
        tol += 5 * float(np.std(img)) / np.sqrt(img.size)
    return tol


def in_unit_range(img):
    """Transmittance pixels lie in [0, 1]; in spectral variants the colour
    weights of the sampled wavelengths scale them (only >= 0 holds)."""
    return bool(np.all(img >= 0) and (mi.is_spectral or np.all(img <= 1)))


# ---------------------------------------------------------------------------
#  Density scales: almost empty to optically very thick
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("density", [1e-6, 1e-3, 1.0, 1e3, 1e6])
def test01_density_scales_analytic_transmittance(variants_rgb, tmp_path, density):
    # A constant box of `density` (8^3 voxels, nearest: constant up to the
    # faces). Along +z the ray crosses length 1 of the unit cube:
    #  scale 1:          T = exp(-density): 1 - 1e-6 ... exp(-1e6) = 0
    #  scale 1/density:  T = exp(-1) whatever the density (the product
    #                    scale * density is formed in float: 1 ulp)
    nvdb, _, _ = make(tmp_path, "c", "--value", density, dense=False)
    vol = load_nvdb(nvdb, filter_type="nearest")
    assert vol.max() == np.float32(density)
    size, spp = (16, 64) if dr.is_jit_v(mi.Float) else (8, 16)
    n = size * size * spp
    for scale in [1.0, 1.0 / density]:
        img = render_transmittance(vol, scale=scale, size=size, spp=spp)
        expect = np.exp(-float(np.float32(density)) * scale)
        tol = binomial_tol(expect, n, img)
        assert abs(img.mean() - expect) <= tol, (scale, img.mean(), expect, tol)
        assert in_unit_range(img)


def test02_values_spanning_1e6_to_1e6_match_dense(variants_rgb, tmp_path):
    # Log-uniform values in [1e-6, 1e6] inside one 24^3 grid crossing leaf
    # boundaries. Nearest: exactly gridvolume's voxel. Trilinear: the same
    # arithmetic as gridvolume inside the box; measured difference 0 (a
    # tolerance of 2 ulps of the largest of the 8 corners is allowed, the
    # reordering of the 8 fmadds that either may do).
    nvdb, vol, _ = make(tmp_path, "span", "--min", -5, -13, 3, "--max", 18, 10, 26,
                        "--fill", "random", "--lo", 1e-6, "--hi", 1e6)
    res, _, values = read_vol(vol)
    values = np.array(values, dtype=np.float32)
    assert values.min() < 1e-5 and values.max() > 1e5
    nano, dense = load_nvdb(nvdb, filter_type="nearest"), load_dense(vol, filter_type="nearest")
    assert nano.max() == values.max()
    rng = np.random.default_rng(2)
    pts = rng.uniform(0, 0.999999, size=(n_points(100_000, 3000), 3)).astype(np.float32)
    a, b = eval_points(nano, pts), eval_points(dense, pts)
    assert np.array_equal(a, b)
    assert np.all(np.isfinite(a)) and np.all(a > 0)
    nano_t, dense_t = load_nvdb(nvdb), load_dense(vol)
    margin = 0.5 / np.array(res, dtype=np.float32)
    pts = rng.uniform(margin, 1 - margin, size=(n_points(100_000, 3000), 3)).astype(np.float32)
    a, b = eval_points(nano_t, pts), eval_points(dense_t, pts)
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=2.5e-7 * values.max())


def test03_columns_1e6_to_1e6_analytic_transmittance(variants_rgb, tmp_path):
    # 13 columns along x with densities 1e-6, 1e-5, ..., 1e6 in one grid
    # (nearest), seen along +z with scale 1e-5: tau = 1e-11 ... 10. The
    # majorant is 1e6 * 1e-5 = 10, so a ray through the 1e-6 column makes
    # ~10 null collisions and must come out with T = 1 - 1e-11.
    nvdb, vol, _ = make(tmp_path, "cols", "--min", 0, 0, 0, "--max", 12, 3, 3,
                        "--fill", "columns", "--lo", 1e-6, "--ratio", 10)
    _, _, values = read_vol(vol)
    vol_ = load_nvdb(nvdb, filter_type="nearest")
    cols = np.array(values, dtype=np.float32)[:13]
    assert cols[0] == np.float32(1e-6) and cols[12] == np.float32(1e6)
    per = 3                                   # pixels per column
    size = 13 * per
    spp = 128 if dr.is_jit_v(mi.Float) else 8
    img = render_transmittance(vol_, scale=1e-5, size=size, spp=spp, view=(0.0, 1.0))
    # Which way the image x axis runs: decided by the two extreme columns
    col_means = img.mean(axis=0)
    if col_means[1] < col_means[-2]:
        img = img[:, ::-1]
    for c in range(13):
        centre = img[:, c * per + 1]          # the pixel column inside voxel column c
        expect = np.exp(-float(cols[c]) * 1e-5)
        tol = binomial_tol(expect, size * spp, centre)
        assert abs(centre.mean() - expect) <= tol, (c, centre.mean(), expect, tol)


# ---------------------------------------------------------------------------
#  Far from the origin
# ---------------------------------------------------------------------------

FAR_BOXES = [
    (1_000_000, -1_000_000, 5),
    (-1_000_016, 999_990, -1_000_008),
    (123_456_789, -987_654_321, 555_555_555),
    (1_000_000_000, -1_000_000_000, 1_000_000_000),
    (2_000_000_000, -2_000_000_000, 2_000_000_000),
    (2_147_483_647 - 15, -2_147_483_648, 2_147_483_647 - 15),  # the int32 extremes
]


@pytest.mark.parametrize("origin", FAR_BOXES, ids=[f"{o[0]:.0e}" for o in FAR_BOXES])
def test04_far_index_coordinates_match_dense(variants_rgb, tmp_path, origin):
    # A 16^3 random box at |ijk| from 1e6 to 2^31 - 1: default mode reads
    # the same voxels as gridvolume on the dense export (positions relative
    # to the box minimum, which is added last as an integer).
    lo = np.array(origin, dtype=np.int64)
    hi = lo + 15
    nvdb, vol, s = make(tmp_path, "far", "--min", *lo, "--max", *hi,
                        "--fill", "random", "--lo", 0.5, "--hi", 2.0)
    assert s["bbox"] == [*lo, *hi]
    nano, dense = load_nvdb(nvdb, filter_type="nearest"), load_dense(vol, filter_type="nearest")
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 0.999999, size=(n_points(50_000, 2000), 3)).astype(np.float32)
    assert np.array_equal(eval_points(nano, pts), eval_points(dense, pts))
    pts = rng.uniform(1 / 32, 31 / 32, size=(n_points(50_000, 2000), 3)).astype(np.float32)
    np.testing.assert_allclose(eval_points(load_nvdb(nvdb), pts),
                               eval_points(load_dense(vol), pts), rtol=1e-6, atol=1e-6)
    img = render_transmittance(load_nvdb(nvdb), size=8, spp=4)
    assert in_unit_range(img)


def index_error(vol, world, lo_index, h, origin):
    """Trilinear on an x ramp (value = i - min) returns the index position:
    its difference from the exact index of the float world point."""
    got = eval_points(vol, world).astype(np.float64)
    exact = (world[:, 0].astype(np.float32).astype(np.float64) - origin[0]) / h[0] - lo_index
    return got - exact


@pytest.mark.parametrize("W,h", [(1e5, 1.0), (1e6, 1.0), (1e7, 1.0), (1e5, 0.01),
                                 (-3e6, 0.5), (1e7, 16.0)])
def test05_far_world_origin_precision(variants_rgb, tmp_path, W, h):
    # use_grid_transform with the grid's voxel (0,0,0) at world (W, W/2, -W)
    # and voxel size h. A 16^3 x ramp (value = i) turns trilinear into a
    # measurement of the computed index position.
    origin = np.array([W, W / 2, -W])
    nvdb, _, _ = make(tmp_path, "ramp", "--min", 0, 0, 0, "--max", 15, 15, 15,
                      "--fill", "ramp", "--voxel", h, h, h, "--translate", *origin,
                      dense=False)
    tri = load_nvdb(nvdb, use_grid_transform=True)
    near = load_nvdb(nvdb, use_grid_transform=True, filter_type="nearest")
    rng = np.random.default_rng(5)
    n = n_points(20_000, 1000)
    idx = rng.uniform(1.0, 14.0, size=(n, 3))                 # away from the border
    world = (origin + h * idx).astype(np.float32)
    # (1) the index position: within ~1 ulp of |world| / h (+ the weight
    #     rounding of the ramp, 16 * 2^-24)
    err = index_error(tri, world, 0, np.array([h] * 3), origin)
    ulp = np.spacing(np.float32(np.max(np.abs(world)))) / h
    assert np.max(np.abs(err)) <= 1.5 * ulp + 1e-5, (np.max(np.abs(err)), ulp)
    # (2) nearest: right voxel for points at least a quarter voxel from a
    #     boundary, wherever |world| / h <= 2^21 (see the module docstring)
    centres = rng.integers(1, 15, size=(n, 3))
    offs = rng.choice([-0.25, 0.0, 0.25], size=(n, 3))
    wpts = (origin + h * (centres + offs)).astype(np.float32)
    got = eval_points(near, wpts)
    ok = got == centres[:, 0]
    if np.max(np.abs(wpts)) / h <= 2 ** 21:
        assert ok.all(), f"{(~ok).sum()} of {n} nearest lookups picked another voxel"
    else:
        # Beyond 2^21 voxels the float world coordinate itself cannot hold a
        # quarter voxel: measured, and only checked to stay finite.
        assert np.all(np.isfinite(got))
    print(f"W={W:g} h={h:g}: max index error {np.max(np.abs(err)):.3g} voxels "
          f"(1 ulp of |p|/h = {ulp:.3g}); nearest right for {ok.mean():.1%}")


# ---------------------------------------------------------------------------
#  Floors, boundaries, backgrounds, tiles, empty and single-voxel grids
# ---------------------------------------------------------------------------

def test06_negative_coordinates_floor_and_boundaries(variants_rgb, tmp_path):
    # Box [-20, 11]^3 (d = 32, so u = k / 32 is exact in float): the local
    # point on the boundary between voxels k - 1 and k reads voxel m + k
    # (floor, not truncation towards zero: voxel -1 is not voxel 0), and just
    # below it reads m + k - 1. Crosses the leaf boundaries -16, -8, 0, 8.
    nvdb, vol, _ = make(tmp_path, "neg", "--min", -20, -20, -20, "--max", 11, 11, 11,
                        "--fill", "random", "--lo", 0.1, "--hi", 10)
    res, _, values = read_vol(vol)
    values = np.array(values, dtype=np.float32).reshape(res[2], res[1], res[0])
    nano = load_nvdb(nvdb, filter_type="nearest")
    dense = load_dense(vol, filter_type="nearest")
    k = np.arange(32)
    u = (k / 32).astype(np.float32)
    below = np.nextafter(u, np.float32(-1))
    for pts_u, expect_k in [(u, k), (below[1:], k[1:] - 1)]:
        pts = np.stack([pts_u, np.full_like(pts_u, 0.5), np.full_like(pts_u, 0.5)], axis=1)
        got = eval_points(nano, pts)
        assert np.array_equal(got, values[16, 16, expect_k])
        assert np.array_equal(got, eval_points(dense, pts))
    # Just outside the minimum face: floor gives voxel m - 1 (background 0);
    # truncation towards zero would give voxel m.
    out = eval_points(nano, [[-0.01, 0.5, 0.5], [0.5, -1e-6, 0.5], [0.5, 0.5, -0.03]])
    assert np.all(out == 0.0)
    # use_grid_transform (identity map): world x = i - 0.5 is the boundary
    # between voxels i - 1 and i: floor(x + 0.5) = i, also for negative i.
    # (The position is formed relative to the box minimum, x - m, whose float
    # spacing at |x - m| < 32 is 4e-6: 1e-4 below a boundary is resolved,
    # one float ulp of x below it is not.)
    gt = load_nvdb(nvdb, filter_type="nearest", use_grid_transform=True)
    i = np.arange(-19, 12)
    for x, expect in [(i - 0.5, i), (i - 0.5 - 1e-4, i - 1)]:
        pts = np.stack([x, np.zeros_like(x, dtype=float) - 4, np.zeros_like(x, dtype=float) + 3],
                       axis=1).astype(np.float32)
        got = eval_points(gt, pts)
        assert np.array_equal(got, values[3 + 20, -4 + 20, expect + 20])
    assert np.all(eval_points(gt, [[-20.5 - 1e-4, -4, 3], [-20.75, 0, 0], [0, -21, 0]]) == 0.0)
    assert eval_points(gt, [[-20.5, -4, 3]])[0] == values[23, 16, 0]
    # Node boundaries: a box crossing x = -4096 (root tile / upper node),
    # y = -128 (lower node) and z = 0, against gridvolume
    nvdb2, vol2, s = make(tmp_path, "nodes", "--min", -4100, -132, -8, "--max", -4085, -117, 7,
                          "--fill", "random", "--lo", 0.1, "--hi", 10)
    assert s["uppers"] >= 2 and s["lowers"] >= 4
    pts = np.random.default_rng(6).uniform(0, 0.999999, size=(n_points(50_000, 2000), 3))
    assert np.array_equal(eval_points(load_nvdb(nvdb2, filter_type="nearest"), pts),
                          eval_points(load_dense(vol2, filter_type="nearest"), pts))
    np.testing.assert_allclose(eval_points(load_nvdb(nvdb2), pts * 0.9 + 0.05),
                               eval_points(load_dense(vol2), pts * 0.9 + 0.05),
                               rtol=1e-6, atol=1e-6)


def test07_nonzero_background(variants_rgb, tmp_path):
    # Background 0.25 around a box of 2.0: inside = dense, outside = 0.25;
    # an empty grid with background 0.5 is a constant medium of 0.5 (VDB
    # semantics: every lookup returns the background), T = exp(-0.5).
    nvdb, vol, _ = make(tmp_path, "bg", "--min", 0, 0, 0, "--max", 15, 15, 15,
                        "--value", 2.0, "--background", 0.25)
    nano = load_nvdb(nvdb, filter_type="nearest")
    assert nano.max() == 2.0
    assert np.all(eval_points(nano, [[-0.5, 0.5, 0.5], [0.5, 1.5, 0.5], [3, 3, 3]]) == 0.25)
    # trilinear at a face: half voxel, half background
    assert np.allclose(eval_points(load_nvdb(nvdb), [[0.0, 0.5, 0.5]]), (2.0 + 0.25) / 2)
    e, _, s = make(tmp_path, "empty_bg", "--fill", "none", "--background", 0.5, dense=False)
    assert s["leaves"] == 0
    vol_e = load_nvdb(e)
    assert vol_e.max() == 0.5 and list(vol_e.resolution()) == [1, 1, 1]
    size, spp = (16, 64) if dr.is_jit_v(mi.Float) else (8, 16)
    img = render_transmittance(vol_e, size=size, spp=spp)
    assert abs(img.mean() - np.exp(-0.5)) <= binomial_tol(np.exp(-0.5), size * size * spp, img)


def test08_empty_grid_is_no_medium(variants_rgb, tmp_path):
    # Background 0, no voxels: the image is exactly the environment.
    e, _, _ = make(tmp_path, "empty", "--fill", "none", dense=False)
    vol = load_nvdb(e)
    assert vol.max() == 0.0
    img = render_transmittance(vol, size=8, spp=4)
    if mi.is_spectral:  # one wavelength per path: colour noise around 1
        assert abs(img.mean() - 1.0) <= binomial_tol(1.0, img.size, img)
    else:
        assert np.all(img == 1.0)
    vol_t = load_nvdb(e, use_grid_transform=True)
    assert np.all(eval_points(vol_t, [[0, 0, 0], [1e6, -1e6, 3]]) == 0.0)


def test09_single_voxel(variants_rgb, tmp_path):
    # One voxel of 2.0 at (-3, 7, 100): in default mode the unit cube is
    # that voxel; nearest is 2 everywhere inside: T = exp(-2).
    nvdb, vol, s = make(tmp_path, "one", "--min", -3, 7, 100, "--max", -3, 7, 100,
                        "--value", 2.0)
    assert s["bbox"] == [-3, 7, 100, -3, 7, 100]
    nano = load_nvdb(nvdb, filter_type="nearest")
    assert list(nano.resolution()) == [1, 1, 1]
    assert np.all(eval_points(nano, np.random.default_rng(9).uniform(0, 0.9999, (100, 3))) == 2.0)
    size, spp = (16, 64) if dr.is_jit_v(mi.Float) else (8, 16)
    img = render_transmittance(nano, size=size, spp=spp)
    assert abs(img.mean() - np.exp(-2)) <= binomial_tol(np.exp(-2), size * size * spp, img)
    # Trilinear: the centre is the voxel, the faces blend with background 0
    tri = load_nvdb(nvdb)
    assert eval_points(tri, [[0.5, 0.5, 0.5]])[0] == 2.0
    assert np.isclose(eval_points(tri, [[0.0, 0.5, 0.5]])[0], 1.0)


def test10_grid_made_only_of_tiles(variants_rgb, tmp_path):
    # (a) One root tile of 4096^3 voxels (value 1.5, no node below the
    #     root): the dense grid (6.9e10 voxels) does not fit, so analytic
    #     transmittance, T = exp(-1.5).
    nvdb, _, s = make(tmp_path, "root_tile", "--min", 0, 0, 0, "--max", 4095, 4095, 4095,
                      "--value", 1.5, "--tiles", dense=False)
    assert s["leaves"] == 0 and s["lowers"] == 0 and s["uppers"] == 0
    vol = load_nvdb(nvdb, filter_type="nearest")
    assert list(vol.resolution()) == [4096] * 3 and vol.max() == 1.5
    size, spp = (16, 64) if dr.is_jit_v(mi.Float) else (8, 16)
    img = render_transmittance(vol, size=size, spp=spp)
    assert abs(img.mean() - np.exp(-1.5)) <= binomial_tol(np.exp(-1.5), size * size * spp, img)
    img_t = render_transmittance(load_nvdb(nvdb), size=size, spp=spp)
    assert abs(img_t.mean() - np.exp(-1.5)) <= binomial_tol(np.exp(-1.5), size * size * spp,
                                                            img_t)
    # (b) Upper-node tiles (128^3) and lower-node tiles (8^3) only, no leaf:
    #     [-128, 127] x [0, 127] x [0, 135] = 2 upper tiles + a slab of
    #     lower tiles; against gridvolume (4.5 M voxels dense).
    nvdb2, vol2, s2 = make(tmp_path, "tiles", "--min", -128, 0, 0, "--max", 127, 127, 135,
                           "--value", 0.75, "--tiles",
                           "--tile", 1, -8, 8, 128, 3.0, "--tile", 2, 0, 0, 0, 0.75)
    assert s2["leaves"] == 0
    pts = np.random.default_rng(10).uniform(0, 0.999999, size=(n_points(50_000, 2000), 3))
    assert np.array_equal(eval_points(load_nvdb(nvdb2, filter_type="nearest"), pts),
                          eval_points(load_dense(vol2, filter_type="nearest"), pts))
    assert load_nvdb(nvdb2).max() == 3.0


@pytest.mark.parametrize("voxel", [(0.5, 2.0, 1e-3), (1e-6, 1e-6, 1e-6), (1e6, 1e6, 1e6),
                                   (1e-4, 1.0, 1e4)],
                         ids=["nonuniform", "tiny", "huge", "1e-4_1_1e4"])
def test11_voxel_sizes(variants_rgb, tmp_path, voxel):
    # use_grid_transform: voxel ijk sits at world (i * sx, j * sy, k * sz) +
    # t. Nearest at voxel centres and a quarter voxel off must read that
    # voxel; the bbox is the voxels' cells; and, with to_world scaling the
    # grid back to a unit-sized box, the medium of density 1 has T = exp(-1)
    # across it (composition of to_world with the grid map in double).
    h = np.array(voxel)
    t = np.array([3.0, -2.0, 1.0]) * h * 5
    nvdb, vol, _ = make(tmp_path, "vox", "--min", -4, -4, -4, "--max", 11, 11, 11,
                        "--fill", "random", "--lo", 0.5, "--hi", 2.0,
                        "--voxel", *h, "--translate", *t)
    res, _, values = read_vol(vol)
    values = np.array(values, dtype=np.float32).reshape(res[2], res[1], res[0])
    near = load_nvdb(nvdb, filter_type="nearest", use_grid_transform=True)
    rng = np.random.default_rng(11)
    ijk = rng.integers(-4, 12, size=(n_points(5000, 500), 3))
    off = rng.choice([-0.25, 0.0, 0.25], size=ijk.shape)
    world = (t + h * (ijk + off)).astype(np.float32)
    got = eval_points(near, world)
    assert np.array_equal(got, values[ijk[:, 2] + 4, ijk[:, 1] + 4, ijk[:, 0] + 4])
    b = near.bbox()
    np.testing.assert_allclose(np.array(b.min), t + h * (-4.5), rtol=1e-6)
    np.testing.assert_allclose(np.array(b.max), t + h * 11.5, rtol=1e-6)
    # Constant density 1 over the same box; to_world maps it to [0, 1]^3
    c, _, _ = make(tmp_path, "vox1", "--min", -4, -4, -4, "--max", 11, 11, 11,
                   "--value", 1.0, "--voxel", *h, "--translate", *t, dense=False)
    lo_w, size_w = t + h * (-4.5), h * 16
    to_world = mi.ScalarTransform4f().scale((1 / size_w).tolist()).translate((-lo_w).tolist())
    vol_c = load_nvdb(c, filter_type="nearest", use_grid_transform=True, to_world=to_world)
    bb = vol_c.bbox()
    np.testing.assert_allclose(np.array(bb.min), 0, atol=1e-5)
    np.testing.assert_allclose(np.array(bb.max), 1, atol=1e-5)
    size, spp = (16, 64) if dr.is_jit_v(mi.Float) else (8, 16)
    img = render_transmittance(vol_c, size=size, spp=spp)
    assert abs(img.mean() - np.exp(-1)) <= binomial_tol(np.exp(-1), size * size * spp, img)


# ---------------------------------------------------------------------------
#  Beyond 4 GiB
# ---------------------------------------------------------------------------

BIG_LEAVES = 2_300_000          # 4.95e9 bytes = 4.61 GiB


def big_value(i, j, k):
    """value_at() of tests/big_grid.cpp, in numpy uint32 arithmetic."""
    i, j, k = (np.asarray(v).astype(np.int64).astype(np.uint32) for v in (i, j, k))
    with np.errstate(over="ignore"):
        h = (i * np.uint32(73856093)) ^ (j * np.uint32(19349663)) ^ (k * np.uint32(83492791))
        h ^= h >> np.uint32(13)
        h = h * np.uint32(0x5bd1e995)
        h ^= h >> np.uint32(15)
    return (np.float32(0.5) + (h & np.uint32(0xffff)).astype(np.float32) / np.float32(65536))


def big_leaf_origin(m):
    m = np.asarray(m, dtype=np.int64)
    l, e = m // 4096, m % 4096
    return np.stack([((l >> 10) & 31) * 128 + ((e >> 8) & 15) * 8,
                     ((l >> 5) & 31) * 128 + ((e >> 4) & 15) * 8,
                     (l & 31) * 128 + (e & 15) * 8], axis=-1)


@pytest.fixture(scope="module")
def big_grid(tmp_path_factory):
    d = tmp_path_factory.mktemp("big")
    free = shutil.disk_usage(d).free
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    if free < 12 * 2**30 or mem < 14 * 2**30:
        pytest.skip(f"the >4 GiB grid needs 12 GiB of disk and 14 GiB of memory "
                    f"(free disk {free / 2**30:.1f} GiB, memory {mem / 2**30:.1f} GiB)")
    path = d / "big.nvdb"
    out = subprocess.run([str(BIG), "write", str(path), str(BIG_LEAVES)], check=True,
                         capture_output=True, text=True).stdout.split()
    size, first_past = int(out[1]), int(out[out.index("past4g_leaf") + 1])
    assert size == path.stat().st_size and size > 4.5 * 2**30
    yield str(path), size, first_past
    path.unlink()


@pytest.mark.slow
def test12_beyond_4gib(variants_rgb, big_grid):
    # A 4.61 GiB grid (2.3 M leaves) loads; spot reads whose value address
    # lies past 4 GiB match PNanoVDB (C, 64-bit addresses) bit for bit and
    # the generator's own formula; the backend holds <= 1.01 x the grid
    # (process RSS growth, and Dr.Jit's LLVM allocator watermark); a render
    # matches the analytic transmittance of the known values.
    path, size, first_past = big_grid
    llvm = mi.variant().startswith("llvm")
    cuda = mi.variant().startswith("cuda")
    settle_gpu() if cuda else dr.sync_thread()
    wm0 = dr.detail.malloc_watermark(dr.JitBackend.LLVM) if llvm else 0
    g0 = gpu_used_bytes() if cuda else 0
    trim_heap()
    r0 = rss_bytes()
    vol = load_nvdb(path, filter_type="nearest", use_grid_transform=True)
    dr.sync_thread()
    trim_heap()  # (the loader's temporaries, freed: not held)
    held = rss_bytes() - r0
    wm = (dr.detail.malloc_watermark(dr.JitBackend.LLVM) - wm0) if llvm else 0
    gpu = (gpu_used_bytes() - g0) if cuda else 0
    print(f"{mi.variant()}: grid {size / 2**30:.3f} GiB, RSS +{held / 2**30:.3f} GiB "
          f"({held / size:.4f} x), LLVM watermark +{wm / 2**30:.3f} GiB, "
          f"GPU +{gpu / 2**30:.4f} GiB ({gpu / size:.4f} x)")
    assert held <= 1.01 * size
    assert wm <= 1.01 * size
    if cuda:
        # The device holds the grid once, at its size (+ the driver's 2 MiB pages)
        assert 0.99 * size <= gpu <= 1.01 * size

    # Spot reads past 4 GiB: 300 leaves from the first one past the mark
    rng = np.random.default_rng(20)
    leaves = np.concatenate([[first_past, BIG_LEAVES - 1],
                             rng.integers(first_past, BIG_LEAVES, 298)])
    ijk = big_leaf_origin(leaves) + rng.integers(0, 8, size=(len(leaves), 3))
    out = subprocess.run([str(BIG), "probe", path, *map(str, ijk.ravel())], check=True,
                         capture_output=True, text=True).stdout.split("\n")
    ref = np.array([line.split() for line in out if line], dtype=object)
    addr = ref[:, 4].astype(np.uint64)
    assert np.all(addr >= 2**32), "a probe's value does not lie past 4 GiB"
    assert np.all(ref[:, 3].astype(int) == 0)                  # leaf values
    pn = ref[:, 5].astype(np.float64).astype(np.float32)
    got = eval_points(vol, ijk.astype(np.float32))
    assert np.array_equal(got, pn)
    assert np.array_equal(got, big_value(ijk[:, 0], ijk[:, 1], ijk[:, 2]))

    # Render the same volume (loaded once: a load reads and checks 4.6 GiB),
    # in its grid's world space (unit voxels: its box is the 128 x 2304 x
    # 4096 voxels' faces), rays along z through 4096 voxels of known values,
    # the medium scaled by 1 / 4096. Columns with y < 2176 are full: the film
    # covers x and y in [0.1, 0.8] of the box. Expected: the mean of
    # exp(-sum(v) / 4096) over 4000 random columns in that window (the
    # per-column spread is ~0.5 %, far below the tolerance).
    bbox = vol.bbox()
    box = (list(bbox.min), list(bbox.max))
    assert np.allclose(box, [[-0.5] * 3, [127.5, 2303.5, 4095.5]]), box
    cx = rng.integers(int(0.1 * 128), int(0.8 * 128), 4000)
    cy = rng.integers(int(0.1 * 2304), int(0.8 * 2304), 4000)
    z = np.arange(4096)
    tau = np.array([big_value(x, y, z).astype(np.float64).sum() / 4096 for x, y in zip(cx, cy)])
    expect = np.exp(-tau).mean()
    size_px, spp = (16, 64) if llvm else (8, 16)
    img = render_transmittance(vol, scale=1 / 4096, size=size_px, spp=spp, box=box,
                               view=(0.1, 0.8))
    tol = binomial_tol(expect, size_px * size_px * spp, img)
    assert abs(img.mean() - expect) <= tol, (img.mean(), expect, tol)
    del vol
