"""
The volpathlocal integrator (src/integrators/volpathlocal.cpp) against
independent references: analytic transmittance, and Mitsuba's own volpath
on the same scene.

volpathlocal must have volpath's expected value on every scene; it draws
other random numbers (delta and ratio tracking against per-node majorants
instead of one global majorant), so the images are compared statistically.
The test, as the issue states it: render each integrator with two seeds
(volpath: 0 and 1, volpathlocal: 2 and 3), through a box reconstruction
filter so that pixels are independent, and per channel form

    z = sum_p (mean_a(p) - mean_b(p)) / sqrt(sum_p (var_a(p) / 2 + var_b(p) / 2))

where mean_* and var_* (ddof=1) are over the two seeds of one side. Summed
over ~600 pixels, z is standard normal when the expectations agree (the
variance estimate has that many degrees of freedom: ~6 % relative error),
and |z| < 5 is asserted: a false alarm probability of 5.7e-7 per check
(two-sided normal tail), below 1e-6; the ~240 checks of this file (z-tests
and analytic means together) raise a false alarm about once in 7000 runs.
Per-pixel standard deviations are floored at 1e-6 of the pixel value (see
ROUNDING), for pixels that neither side renders with noise.

volpathlocal falls back to volpath's tracking for media whose local
majorants would save little (max_majorant_ratio); the tests force the walk
(TRACK_ALWAYS) and check through traverse() (integrator_facts) that it tracks
the media it should, so that a test cannot pass by falling back.

Analytic references: an orthographic camera looks along +z through a box of
medium with albedo 0 in front of a uniform environment of radiance 1, so
every pixel is exp(-tau) with tau = scale * density * length (constant
densities, nearest lookups), as in tests/test_stability.py. Delta tracking
makes each sample 0 or 1 (binomial); shadow rays (ratio tracking) are
checked through a plane lit by a sun behind the medium.
"""

import math
import subprocess

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from conftest import MAKE_GRID, _setup_variant, load_dense, load_nvdb
from conftest import make_stability_grid as make_stab
from nanovdb_mitsuba import integrator_facts, volume_facts


def T4():
    """An identity ScalarTransform4f of the current variant."""
    return mi.ScalarTransform4f()


# volpathlocal tracks a nanovdbvolume medium through the walk only where its
# local majorants average at most max_majorant_ratio (default 0.5) of the
# global one, and otherwise as volpath does. The tests force the walk on
# every grid (1.0: always), so that what they check is the tracking; test17
# checks the default's choice.
TRACK_ALWAYS = {"max_majorant_ratio": 1.0}

# |z| below this for every channel: at most a 1e-6 false-alarm rate per check
# (P(|N(0,1)| > 5) = 5.7e-7)
Z_MAX = 5.0


# ---------------------------------------------------------------------------
#  Helpers: scenes, renders, the z-test
# ---------------------------------------------------------------------------

def pixel_format():
    return "luminance" if mi.is_monochromatic else "rgb"


def film(size):
    return {"type": "hdrfilm", "width": size, "height": size,
            "rfilter": {"type": "box"}, "pixel_format": pixel_format()}


def medium(volume, scale, albedo=(0.9, 0.75, 0.6), g=0.4):
    """A heterogeneous medium on `volume`: RGB-varying albedo, HG phase."""
    return {"type": "heterogeneous", "sigma_t": volume, "scale": scale,
            "albedo": {"type": "rgb", "value": list(albedo)},
            "phase": {"type": "hg", "g": g}}


def unit_cube(interior, bsdf=None, to_world=None):
    """The cube [0, 1]^3 (or `to_world` of [-1, 1]^3) holding `interior`."""
    return {"type": "cube",
            "to_world": to_world if to_world is not None
            else T4().translate([0.5, 0.5, 0.5]).scale(0.5),
            "bsdf": bsdf or {"type": "null"},
            "interior": interior}


def sky_and_sun_scene(integrator, shapes, size=24, spp=64, max_depth=64, target=(0.5, 0.5, 0.5),
                      distance=1.0, **integrator_args):
    """A perspective view of `shapes` (the cube [0, 1]^3 fills most of the
    image) under a blue sky and a sun."""
    t = np.array(target, dtype=float)
    origin = t + distance * np.array([1.7, 1.1, 2.1])
    scene = {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": max_depth, **integrator_args},
        "sensor": {
            "type": "perspective", "fov": 38,
            "to_world": T4().look_at(origin=origin.tolist(), target=t.tolist(), up=[0, 1, 0]),
            "film": film(size),
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.5, 0.6, 0.8]}},
        "sun": {"type": "directional", "direction": [-1.0, -1.3, -0.4],
                "irradiance": {"type": "rgb", "value": [3.0, 2.7, 2.3]}},
    }
    scene.update(shapes)
    return scene


def render(scene_dict, seeds):
    """Renders of one loaded scene, one per seed: (len(seeds), H, W, C),
    and the scene."""
    scene = mi.load_dict(scene_dict)
    imgs = np.stack([np.array(mi.render(scene, seed=s), dtype=np.float64) for s in seeds])
    assert np.all(np.isfinite(imgs)), "NaN or Inf in a pixel"
    return imgs, scene


def tracked_media(scene):
    """How many media volpathlocal tracks through the walk in `scene` (after
    a render has prepared it)"""
    return integrator_facts(scene.integrator())["tracked_media"]


# Float32 rounding of a pixel's accumulated radiance: a few ulps (6e-8
# relative each). Per-pixel standard deviations are floored at this much of
# the pixel value, so that pixels without noise on either side (sky seen
# through empty space) that differ by rounding alone do not read as a bias.
ROUNDING = 1e-6


def z_scores(a, b):
    """Per-channel z of the mean difference of two sides, each (2, H, W, C):
    two seeds of one integrator (see the module docstring)."""
    def floored_var(x):
        return np.maximum(x.var(axis=0, ddof=1), (ROUNDING * x.mean(axis=0)) ** 2)
    diff = (a.mean(axis=0) - b.mean(axis=0)).sum(axis=(0, 1))
    var = (floored_var(a) / 2 + floored_var(b) / 2).sum(axis=(0, 1))
    # Both sides noiseless (e.g. an empty medium under a constant sky in
    # RGB): the images must then be equal
    return np.where(var > 0, diff / np.sqrt(np.where(var > 0, var, 1.0)),
                    np.where(diff == 0, 0.0, np.inf))


def assert_same_expectation(make_scene, spp=64, local_args=None, tracked=1):
    """Renders make_scene(integrator, spp=..., **args) with volpath (seeds
    0, 1) and volpathlocal (seeds 2, 3; TRACK_ALWAYS and `local_args`),
    checks that volpathlocal tracks `tracked` media through the walk, and
    asserts |z| < Z_MAX for every channel. Returns (z, volpath images,
    volpathlocal images)."""
    a, _ = render(make_scene("volpath", spp=spp), seeds=(0, 1))
    b, scene = render(make_scene("volpathlocal", spp=spp, **TRACK_ALWAYS, **(local_args or {})),
                      seeds=(2, 3))
    assert tracked_media(scene) == tracked
    z = z_scores(a, b)
    print(f"{mi.variant()}: z = {np.round(z, 2)}, means {a.mean(axis=(0, 1, 2))} "
          f"vs {b.mean(axis=(0, 1, 2))}")
    assert np.all(np.abs(z) < Z_MAX), (z, a.mean(axis=(0, 1, 2)), b.mean(axis=(0, 1, 2)))
    return z, a, b


def transmittance_scene(integrator, volume, scale=1.0, size=16, spp=64,
                        box=((0, 0, 0), (1, 1, 1)), view=(0.1, 0.9), shadow=False,
                        tracked=1, **integrator_args):
    """Orthographic view along +z through the medium box `box` (world
    space), albedo 0. `view`: the part of the box's x/y extent the film
    covers.

    shadow=False: environment radiance 1 behind the box; each pixel
    estimates T = exp(-tau) (delta tracking on the camera ray).
    shadow=True: no environment; a white diffuse plane behind the box
    faces the camera, lit through the box by a sun shining along +z with
    irradiance pi, so its radiance is T; the camera ray crosses the same
    column (delta tracking) and the shadow ray crosses it back (ratio
    tracking): each pixel estimates T^2.
    volpathlocal must track `tracked` media through the walk (TRACK_ALWAYS
    is added to its arguments)."""
    if integrator == "volpathlocal":
        integrator_args = {**TRACK_ALWAYS, **integrator_args}
    lo, hi = np.array(box[0], dtype=float), np.array(box[1], dtype=float)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    cover = (view[1] - view[0]) / 2
    cx, cy = lo[:2] + (hi[:2] - lo[:2]) * (view[0] + view[1]) / 2
    scene = {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": 2 if shadow else 64, **integrator_args},
        "sensor": {
            "type": "orthographic",
            "to_world": T4().look_at(
                origin=[cx, cy, lo[2] - 1.0 - half[2]], target=[cx, cy, centre[2]],
                up=[0, 1, 0]) @ T4().scale([cover * 2 * half[0], cover * 2 * half[1], 1]),
            "film": film(size),
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "cube": unit_cube({"type": "heterogeneous", "sigma_t": volume, "albedo": 0.0,
                           "scale": scale},
                          to_world=T4().translate(centre.tolist()).scale(half.tolist())),
    }
    if shadow:
        scene["sun"] = {"type": "directional", "direction": [0, 0, 1], "irradiance": math.pi}
        # rectangle: [-1, 1]^2 at z = 0, normal +z; turned to face -z
        scene["plane"] = {"type": "rectangle",
                          "to_world": T4().translate([centre[0], centre[1], hi[2] + 0.5 * half[2]])
                          @ T4().rotate([1, 0, 0], 180) @ T4().scale([3 * half[0], 3 * half[1], 1]),
                          "bsdf": {"type": "diffuse", "reflectance": 1.0}}
    else:
        scene["sky"] = {"type": "constant", "radiance": 1.0}
    scene = mi.load_dict(scene)
    img = np.array(mi.render(scene), dtype=np.float64)[..., 0]
    assert np.all(np.isfinite(img)), "NaN or Inf in a pixel"
    if integrator == "volpathlocal":
        assert tracked_media(scene) == tracked
    return img


def spp_for_analytic():
    # (size, spp): 32768 samples, so that 5 binomial standard errors (at
    # most 0.014) are well below the shift of a 10 % majorant error in T
    # (exp(-0.9 tau) - exp(-tau): 0.03 ... 0.04 for tau = 0.5 ... 2)
    return (16, 128)


def assert_mean_close(img, spp, expect, std_per_sample, what=""):
    """The pixel mean against `expect`, 5 standard errors of the mean of
    img.size * spp independent samples of standard deviation
    `std_per_sample` (at least 1e-6: float rounding of T itself)."""
    n = img.size * spp
    tol = max(5 * std_per_sample / np.sqrt(n), 1e-6)
    assert abs(img.mean() - expect) <= tol, (what, img.mean(), expect, tol)


def binomial_std(t):
    return np.sqrt(max(t * (1 - t), 0.0))


def parse_counts(volume):
    facts = volume_facts(volume)
    return facts["lookup_count"], facts["walk_step_count"]


# ---------------------------------------------------------------------------
#  Analytic transmittance (albedo 0): volpathlocal alone
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("density", [1e-6, 1.0, 1e4, 1e6])
def test01_density_scales_analytic_transmittance(variants_rgb, tmp_path, density):
    # A constant 8^3 box of `density`, nearest: constant up to the faces,
    # so the local majorant equals the density (tight: every tentative
    # collision is real, and a majorant below it shows as a bias). Along +z
    # the ray crosses length 1:
    #  scale 1:         T = exp(-density): 1 - 1e-6 ... exp(-1e6) = 0
    #  scale 1/density: T = exp(-1) whatever the density
    # Each sample is 0 or 1: 5 binomial standard errors.
    nvdb, _, _ = make_stab(tmp_path, "c", "--value", density, dense=False)
    vol = load_nvdb(nvdb, filter_type="nearest")
    size, spp = spp_for_analytic()
    for scale in [1.0, 1.0 / density]:
        for coarse in [0.0, 2.0]:
            img = transmittance_scene("volpathlocal", vol, scale=scale, size=size, spp=spp,
                                      coarse_optical_depth=coarse)
            expect = np.exp(-float(np.float32(density)) * scale)
            assert_mean_close(img, spp, expect, binomial_std(expect), (scale, coarse))
            assert np.all((img >= 0) & (img <= 1))


STAB_CASES = {
    # name: (nvdb_make_stability_grid options, filter, T)
    "far_1e6": (["--min", 1_000_000, -1_000_000, 5, "--max", 1_000_007, -999_993, 12,
                 "--value", 1.5], "nearest", np.exp(-1.5)),
    "far_2e9": (["--min", 2_000_000_000, -2_000_000_000, 2_000_000_000,
                 "--max", 2_000_000_015, -1_999_999_985, 2_000_000_015, "--value", 1.5],
                "nearest", np.exp(-1.5)),
    # (--fill random with lo = hi: a constant; OpenVDB's denseFill, which
    # --value uses, never returns on a box that ends at INT32_MAX)
    "int32_extremes": (["--min", 2_147_483_647 - 15, -2_147_483_648, 2_147_483_647 - 15,
                        "--max", 2_147_483_647, -2_147_483_648 + 15, 2_147_483_647,
                        "--fill", "random", "--lo", 0.5, "--hi", 0.5], "nearest", np.exp(-0.5)),
    # Tiles only: one 4096^3 root tile, and two root tiles at negative
    # coordinates (no node below the root), nearest and trilinear (where
    # trilinear blends into the background, in the outer half voxels of the
    # 4096 along z, tau drops by 1e-4: far below the tolerance)
    "root_tile": (["--min", 0, 0, 0, "--max", 4095, 4095, 4095, "--value", 1.5, "--tiles"],
                  "nearest", np.exp(-1.5)),
    "root_tiles_negative_trilinear": (["--min", -8192, 4096, -4096, "--max", -1, 8191, -1,
                                       "--value", 1.5, "--tiles"], "trilinear", np.exp(-1.5)),
    # Upper- and lower-node tiles: [-128, 127] x [0, 127] x [0, 135]
    "upper_lower_tiles": (["--min", -128, 0, 0, "--max", 127, 127, 135, "--value", 0.75,
                           "--tiles"], "nearest", np.exp(-0.75)),
    "single_voxel": (["--min", -3, 7, 100, "--max", -3, 7, 100, "--value", 2.0],
                     "nearest", np.exp(-2.0)),
    # Background 0.25 around the box: inside the unit cube only the voxels
    "background_around_box": (["--min", 0, 0, 0, "--max", 15, 15, 15, "--value", 2.0,
                               "--background", 0.25], "nearest", np.exp(-2.0)),
    # An empty grid of background 0.5 is a constant medium of 0.5
    "empty_background_0.5": (["--fill", "none", "--background", 0.5], "trilinear",
                             np.exp(-0.5)),
}


@pytest.mark.parametrize("case", list(STAB_CASES))
def test02_extreme_grids_analytic_transmittance(variants_rgb, tmp_path, case):
    # Grids far from the origin (|ijk| ~ 1e6, 2e9, the int32 extremes),
    # made only of tiles, a single voxel, a non-zero background: constant
    # density over the unit cube, so T = exp(-value). Binomial, 5 standard
    # errors; with coarse_optical_depth 0 (every node walked) and the
    # default 2.
    args, filter_type, expect = STAB_CASES[case]
    nvdb, _, _ = make_stab(tmp_path, case, *args, dense=False)
    vol = load_nvdb(nvdb, filter_type=filter_type)
    size, spp = spp_for_analytic()
    for coarse in [0.0, 2.0]:
        img = transmittance_scene("volpathlocal", vol, size=size, spp=spp,
                                  coarse_optical_depth=coarse)
        assert_mean_close(img, spp, expect, binomial_std(expect), coarse)
        assert np.all((img >= 0) & (img <= 1))


def test03_empty_grid_is_no_medium(variants_rgb, tmp_path):
    # Background 0, no voxels: every pixel is exactly the environment, 1
    # (no collision can happen: a zero majorant everywhere), never NaN;
    # also through the plane and shadow rays.
    e, _, _ = make_stab(tmp_path, "empty", "--fill", "none", dense=False)
    for use_grid_transform in [False, True]:
        vol = load_nvdb(e, use_grid_transform=use_grid_transform)
        for coarse in [0.0, 2.0]:
            img = transmittance_scene("volpathlocal", vol, size=8, spp=4,
                                      coarse_optical_depth=coarse)
            assert np.all(img == 1.0)
            img = transmittance_scene("volpathlocal", vol, size=8, spp=4, shadow=True,
                                      coarse_optical_depth=coarse)
            np.testing.assert_allclose(img, 1.0, rtol=1e-5)


def ratio_tracking_second_moment(mu, sigma, length):
    """E[W^2] of ratio tracking through a constant medium sigma against a
    constant majorant mu: W = (1 - sigma / mu)^N with N ~ Poisson(mu * L),
    so E[W^2] = exp(-mu L + mu L (1 - sigma / mu)^2)."""
    return np.exp(-mu * length + mu * length * (1 - sigma / mu) ** 2)


def residual_second_moment(M, mean, L, sigma, length):
    """E[W^2] of residual ratio tracking (tracking.h) through a constant
    medium sigma in one cell of bound M, voxel mean `mean` and lower bound
    L, as the table stores them (majorant_table.h: the control is the mean
    rounded to a 4-bit fraction of M, the lower bound rounded down):
    W = exp(-c len) f^N, f = (mu_r - (sigma - c)) / mu_r, N ~ Poisson(mu_r
    len), mu_r = max(M - c, c - L), so E[W] = exp(-sigma len) and
    E[W^2] = exp(-2 c len + mu_r len (f^2 - 1))."""
    c = M * round(15 * mean / M) / 15
    lo = M * math.floor(15 * L / M) / 15
    mu_r = max(M - c, c - lo, M / 1024)
    f = (mu_r - (sigma - c)) / mu_r
    return np.exp(-2 * c * length + mu_r * length * (f * f - 1))


@pytest.mark.parametrize("estimator", ["ratio", "residual"])
@pytest.mark.parametrize("hot", [None, 4.0], ids=["tight", "loose"])
def test04_shadow_rays_ratio_tracking_analytic(variants_rgb, tmp_path, hot, estimator):
    # Density 1 over the 8^3 box (nearest), scale 1. The camera ray (delta
    # tracking) and the shadow ray to the sun (ratio or residual ratio
    # tracking) both cross one column of length 1, so each pixel estimates
    # T^2 = exp(-2).
    # tight: majorant 1 = density; ratio tracking's weight is 0 at the
    #        first collision (binomial); residual tracking's control is the
    #        density, so its weight is exp(-1) exactly.
    # loose: voxel (0, 0, 0) holds 4, which makes the leaf's majorant 4
    #        (the leaf, the whole box, is the walk's finest cell); the film
    #        covers x, y in [0.2, 0.9], away from that column, so every ray
    #        sees density 1 against majorant 4 and ratio tracking weighs
    #        each null collision by 3/4; residual tracking integrates the
    #        leaf's mean (515 / 512, as 4 bits of 4: 16 / 15) exactly and
    #        weighs its few collisions by ~1.02.
    # The lower bound is 0: the leaf's ring reaches the background.
    # Per sample X = B * W (B ~ Bernoulli(T), W the shadow ray's estimate):
    # E[X^2] = T * E[W^2]; 5 standard errors.
    args = ["--value", 1.0] + (["--set", 0, 0, 0, hot] if hot else [])
    nvdb, _, _ = make_stab(tmp_path, "ratio", *args, dense=False)
    vol = load_nvdb(nvdb, filter_type="nearest")
    size, spp = spp_for_analytic()
    mu = hot or 1.0
    t = np.exp(-1.0)
    w2 = (ratio_tracking_second_moment(mu, 1.0, 1.0) if estimator == "ratio" else
          residual_second_moment(mu, (511 + mu) / 512, 0.0, 1.0, 1.0))
    std = np.sqrt(t * w2 - t ** 4)
    for coarse in [0.0, 2.0]:
        img = transmittance_scene("volpathlocal", vol, size=size, spp=spp, view=(0.2, 0.9),
                                  shadow=True, coarse_optical_depth=coarse,
                                  transmittance=estimator)
        assert_mean_close(img, spp, t * t, std, coarse)
        assert np.all(img >= 0)
        # The estimator's variance, so that a regression shows: every pixel
        # has the same expectation, so spp x the variance of the pixel means
        # estimates a sample's variance (a standard error of ~9 % over 256
        # pixels), against E[X^2] - E[X]^2 above. A ratio-tracking step made
        # binary (zero at a collision with probability sigma / mu: unbiased)
        # gives 2.3x the variance where the majorant is loose (measured 0.94-1.10x
        # of the analytic one with ratio tracking), and fails this; so does
        # residual tracking with ratio tracking's variance (loose: 1.45x).
        measured = img.var(ddof=1) * spp
        assert 0.65 * std ** 2 <= measured <= 1.35 * std ** 2, (coarse, measured, std ** 2)
        # Samples are 0 or 1 where ratio tracking's majorant is tight;
        # fractional weights show in pixel sums that are not integers
        fractional = np.abs(img * spp - np.round(img * spp)) > 1e-3
        assert fractional.any() == (bool(hot) or estimator == "residual")


def test04b_shadow_estimates_average_independent_estimates(variants_rgb, tmp_path):
    # shadow_estimates=M (bench/variance_split.py's measurement): the shadow
    # ray's weight is the mean of M independent ratio-tracking estimates
    # W_1..W_M. test04's loose case (density 1, majorant 4): per sample
    # X = B * mean(W), E[X] = T^2 for every M, and
    # E[X^2] = T (E[W^2] / M + (M - 1) / M T^2). The variance per sample
    # is read from the spread of 48^2 identical pixels (a relative standard
    # error of 2.9 %; 15 % is 5 of them): M = 4 is 23 % below M = 1, so
    # estimates that were not independent, or not averaged, fail it.
    nvdb, _, _ = make_stab(tmp_path, "ratio", "--value", 1.0, "--set", 0, 0, 0, 4.0, dense=False)
    vol = load_nvdb(nvdb, filter_type="nearest")
    size, spp = 48, 128
    t, w2 = np.exp(-1.0), ratio_tracking_second_moment(4.0, 1.0, 1.0)
    for m in (1, 4):
        img = transmittance_scene("volpathlocal", vol, size=size, spp=spp, view=(0.2, 0.9),
                                  shadow=True, shadow_estimates=m, transmittance="ratio")
        var = t * (w2 / m + (m - 1) / m * t * t) - t ** 4
        assert_mean_close(img, spp, t * t, np.sqrt(var), m)
        measured = img.var(ddof=1) * spp
        assert abs(measured / var - 1) < 0.15, (m, measured, var)


# ---------------------------------------------------------------------------
#  Scattering: volpathlocal vs volpath (z-test)
# ---------------------------------------------------------------------------

CLOUD_SCALE = {"noisy_cloud": 8.0, "fog_sphere": 6.0}


def cloud_scene(volume, scale):
    return lambda integrator, **kw: sky_and_sun_scene(
        integrator, {"cube": unit_cube(medium(volume, scale))}, **kw)


@pytest.mark.parametrize("coarse", [0.0, 2.0, 100.0])
@pytest.mark.parametrize("name", ["noisy_cloud", "fog_sphere"])
def test05_scattering_matches_volpath(variants_rgb, make_grid, name, coarse):
    # Albedo (0.9, 0.75, 0.6), HG 0.4, sky and sun, max_depth 64: multiple
    # scattering, emitter sampling through the medium (ratio tracking) and
    # MIS. Every leaf walked (coarse 0), the default (2: at these densities
    # hardly a node is thin enough), and internal nodes crossed whole
    # wherever their optical depth is below 100.
    nvdb, _ = make_grid(name, dense=False)
    vol = load_nvdb(nvdb)
    _, a, _ = assert_same_expectation(cloud_scene(vol, CLOUD_SCALE[name]),
                                      local_args={"coarse_optical_depth": coarse})
    # The medium is seen: the image is not the sky alone
    assert a.std() > 0.01


@pytest.mark.parametrize("variant", ["llvm_ad_mono", "scalar_mono", "llvm_ad_spectral",
                                     "scalar_spectral"])
def test06_scattering_mono_and_spectral(make_grid, variant):
    # The same in a monochrome and a spectral variant (whichever of each
    # this Mitsuba build has): spectral paths carry 4 wavelengths, and the
    # RGB albedo becomes a spectrum (the null-collision weights
    # mu_n / mean(mu_n) of volpathlocal are 1 for a grey extinction).
    _setup_variant(variant)
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    vol = load_nvdb(nvdb)
    spp = 64 if dr.is_jit_v(mi.Float) else 32
    assert_same_expectation(cloud_scene(vol, 8.0), spp=spp)


def test07_surface_inside_medium(variants_rgb, make_grid):
    # A diffuse sphere inside the cloud's cube: tracking stops at the
    # surface, paths scatter there and continue in the same medium; shadow
    # rays from it cross the medium.
    nvdb, _ = make_grid("fog_sphere", dense=False)
    vol = load_nvdb(nvdb)
    med = medium(vol, 3.0)

    def scene(integrator, **kw):
        return sky_and_sun_scene(integrator, {
            "cube": unit_cube(med),
            "ball": {"type": "sphere", "center": [0.45, 0.55, 0.5], "radius": 0.22,
                     "bsdf": {"type": "diffuse",
                              "reflectance": {"type": "rgb", "value": [0.8, 0.3, 0.2]}},
                     "interior": med, "exterior": med},
        }, **kw)
    assert_same_expectation(scene)


def test08_medium_inside_dielectric(variants_rgb, make_grid):
    # The cloud's cube bounded by glass (ior 1.33): refraction into and out
    # of the medium, internal reflection, shadow rays blocked by the
    # boundary (only specular chains reach the sky from inside).
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    vol = load_nvdb(nvdb)

    def scene(integrator, **kw):
        return sky_and_sun_scene(integrator, {
            "cube": unit_cube(medium(vol, 6.0), bsdf={"type": "dielectric", "int_ior": 1.33}),
        }, **kw)
    assert_same_expectation(scene)


@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
def test09_rotated_scaled_grid_transform(variants_rgb, make_grid, filter_type):
    # noisy_cloud's own index-to-world map (voxel 0.5, offset (1, 2, 3))
    # with use_grid_transform, then a to_world that moves its box's centre
    # to the origin, scales it non-uniformly and rotates it about a skew
    # axis; a cube shape with the same transform bounds the medium. The
    # walk must follow world -> index through all of that (the medium's
    # box is the world AABB of the turned box: lookups outside the grid
    # read background 0).
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    grid_box = load_nvdb(nvdb, use_grid_transform=True).bbox()
    lo, hi = np.array(grid_box.min, dtype=float), np.array(grid_box.max, dtype=float)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    to_world = (T4().translate([0.5, 0.5, 0.5]) @ T4().rotate([1, 2, 0.5], 37)
                @ T4().scale([0.045, 0.03, 0.055]) @ T4().translate((-centre).tolist()))
    vol = load_nvdb(nvdb, use_grid_transform=True, filter_type=filter_type, to_world=to_world)
    box = to_world @ T4().translate(centre.tolist()) @ T4().scale(half.tolist())

    def scene(integrator, **kw):
        return sky_and_sun_scene(integrator, {"cube": unit_cube(medium(vol, 14.0),
                                                                to_world=box)}, **kw)
    _, a, _ = assert_same_expectation(scene)
    assert a.std() > 0.01


@pytest.mark.parametrize("name", ["lower_tiles", "upper_tiles", "root_tiles_negative", "empty"])
def test10_tile_and_multi_root_grids(variants_rgb, make_grid, name):
    # Tiles at every level beside voxels, several root entries at negative
    # coordinates, inactive non-background tiles, and an empty grid (both
    # images are then the sky)
    nvdb, _ = make_grid(name, dense=False)
    vol = load_nvdb(nvdb)
    scale = {"lower_tiles": 4.0, "upper_tiles": 3.0, "root_tiles_negative": 2.0}.get(name, 5.0)
    for coarse in [0.0, 2.0]:
        assert_same_expectation(cloud_scene(vol, scale),
                                local_args={"coarse_optical_depth": coarse})


FAR_RANDOM = {
    # 24^3 random boxes (0.5 ... 2), |ijk| ~ 1e6 and 2e9; the second
    # straddles root tiles (4096 * 488281 = 1999998976) in x, y and z
    "far_1e6": (1_000_000 - 12, -1_000_000 - 12, 5),
    "far_2e9_8_roots": (1_999_998_976 - 12, -1_999_998_976 - 12, 1_999_998_976 - 12),
}


@pytest.mark.parametrize("case", list(FAR_RANDOM))
@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
def test11_far_from_origin_scattering(variants_rgb, tmp_path, case, filter_type):
    # Resolvable grids far from the origin (default mode: the unit cube
    # spans the 24^3 box), across leaves, lower and upper nodes and, for
    # the second, root tiles; random values, so the walk's per-node
    # majorants differ along a ray.
    lo = np.array(FAR_RANDOM[case], dtype=np.int64)
    nvdb, _, _ = make_stab(tmp_path, case, "--min", *lo, "--max", *(lo + 23), "--fill",
                           "random", "--lo", 0.5, "--hi", 2.0, dense=False)
    vol = load_nvdb(nvdb, filter_type=filter_type)
    _, a, _ = assert_same_expectation(cloud_scene(vol, 3.0))
    assert a.std() > 0.01


def test12_far_coords_spanning_2e9_voxels(variants_rgb, make_grid):
    # far_coords: 111 voxels in root entries up to |ijk| = 1e9, so in default
    # mode the unit cube spans 2e9 voxels, each 5e-10 wide (below the float
    # resolution of a local point, 6e-8): the image is the sky up to
    # rounding. The walk crosses the empty root space between root tiles in
    # one step (walk_far; measured: 0.42 walk steps per sample, against
    # 1.8e5 when it went cell by cell, and 6 lookups per sample for volpath)
    nvdb, _ = make_grid("far_coords", dense=False)
    vol = load_nvdb(nvdb)
    _, a, b = assert_same_expectation(
        lambda integrator, **kw: cloud_scene(vol, 5.0)(integrator, size=8, **kw), spp=4)
    np.testing.assert_allclose(b.mean(axis=(0, 1, 2)), a.mean(axis=(0, 1, 2)), rtol=1e-6)


# ---------------------------------------------------------------------------
#  Fallback media and mixed scenes
# ---------------------------------------------------------------------------

def test13_fallback_media_match_volpath(variants_rgb, make_grid):
    # A homogeneous medium and a gridvolume-based heterogeneous medium (the
    # dense export of the cloud) are not tracked: volpathlocal samples them
    # through the medium's own sample_interaction, as volpath does.
    _, dense = make_grid("noisy_cloud")
    grid = load_dense(dense)

    def scene(integrator, **kw):
        return sky_and_sun_scene(integrator, {
            "cube": unit_cube(medium(grid, 8.0)),
            "ball": {"type": "sphere", "center": [0.5, 0.5, 1.5], "radius": 0.35,
                     "bsdf": {"type": "null"},
                     "interior": {"type": "homogeneous",
                                  "sigma_t": {"type": "rgb", "value": [0.5, 0.75, 1.0]},
                                  "scale": 4.0,
                                  "albedo": {"type": "rgb", "value": [0.9, 0.7, 0.5]}}},
        }, target=(0.5, 0.5, 0.8), distance=1.3, **kw)
    assert_same_expectation(scene, tracked=0)


def test14_tracked_and_homogeneous_media_side_by_side(variants_rgb, make_grid):
    # A tracked nanovdb medium in one cube and a homogeneous medium in a
    # slab above it, 0.05 apart: paths cross from one medium into the other
    # through the vacuum between, and shadow rays cross both.
    nvdb, _ = make_grid("fog_sphere", dense=False)
    vol = load_nvdb(nvdb)

    def scene(integrator, **kw):
        return sky_and_sun_scene(integrator, {
            "cube": unit_cube(medium(vol, 5.0)),
            "slab": unit_cube({"type": "homogeneous",
                               "sigma_t": {"type": "rgb", "value": [0.6, 0.8, 1.0]},
                               "scale": 2.5,
                               "albedo": 0.8},
                              to_world=T4().translate([0.5, 1.3, 0.5]).scale([0.6, 0.25, 0.6])),
        }, target=(0.5, 0.8, 0.5), distance=1.3, **kw)
    assert_same_expectation(scene)


# ---------------------------------------------------------------------------
#  Work done, parameters
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["noisy_cloud", "upper_tiles", "fog_sphere"])
def test15_fewer_lookups_than_volpath(variants_rgb, make_grid, name):
    # count_lookups: volpath looks the grid up at every tentative collision
    # against the global majorant (scale * max()); volpathlocal skips empty
    # and thin space by the walk, so it looks up less for the same image.
    # Tracked whatever the ratio (local_majorant_ratio: noisy_cloud 0.55,
    # upper_tiles 0.68, fog_sphere 0.84, all above the default 0.5, which
    # test17 covers). The counters are cumulative: differences around each
    # render.
    nvdb, _ = make_grid(name, dense=False)
    vol = load_nvdb(nvdb, count_lookups=True)
    counts = {}
    for integrator, args in [("volpath", {}), ("volpathlocal", TRACK_ALWAYS)]:
        before = parse_counts(vol)
        _, scene = render(sky_and_sun_scene(integrator, {"cube": unit_cube(medium(vol, 4.0))},
                                            size=16, spp=16, **args), seeds=(0,))
        after = parse_counts(vol)
        counts[integrator] = (after[0] - before[0], after[1] - before[1])
    print(f"{mi.variant()} {name}: (lookups, walk steps) {counts}")
    assert tracked_media(scene) == 1
    assert counts["volpath"][0] > 0 and counts["volpath"][1] == 0
    assert counts["volpathlocal"][1] > 0
    assert counts["volpathlocal"][0] < counts["volpath"][0]


@pytest.mark.parametrize("name,value", [("coarse_optical_depth", -1.0),
                                        ("coarse_optical_depth", float("inf")),
                                        ("coarse_optical_depth", float("nan")),
                                        ("max_majorant_ratio", -0.5),
                                        ("max_majorant_ratio", 1.5),
                                        ("max_majorant_ratio", float("nan")),
                                        ("shadow_estimates", 0)])
def test16_bad_parameters(variant_scalar_rgb, name, value):
    # Checked in the constructor; the message names the parameter
    with pytest.raises(RuntimeError, match=name):
        mi.load_dict({"type": "volpathlocal", name: value})


def test17_default_tracks_only_where_local_majorants_pay(variants_rgb, make_grid, tmp_path):
    # Default max_majorant_ratio 0.5: a cube of one density (local
    # majorants = the global one, ratio 1) is tracked as volpath does; the
    # noisy cloud at scale 2 (ratio 0.34) through the walk.
    nvdb, _, _ = make_stab(tmp_path, "cube", "--max", 15, 15, 15, "--value", 1.0, dense=False)
    cloud = str(tmp_path / "cloud2.nvdb")
    subprocess.run([str(MAKE_GRID), "noisy_cloud", cloud, "--scale", "2"], check=True,
                   capture_output=True)
    for path, tracked in [(nvdb, 0), (cloud, 1)]:
        vol = load_nvdb(path)
        _, scene = render(sky_and_sun_scene("volpathlocal", {"cube": unit_cube(medium(vol, 2.0))},
                                            size=4, spp=1), seeds=(0,))
        assert tracked_media(scene) == tracked, path


def test18_spectral_extinction_analytic(variants_rgb):
    # A Vec3f extinction (1, 0.5, 0.25) x 2 through a unit cube, albedo 0,
    # tracked through the walk: each channel's transmittance is exp(-sigma_c).
    # Delta tracking samples against the largest channel; a path that meets
    # no real collision keeps the product of its null collisions' spectral
    # factors (an estimate that lost them read exp(-mean sigma) in every
    # channel: 0.097 instead of 0.135 / 0.368 / 0.607). The per-pixel means
    # are independent (one density, orthographic): 5 standard errors of
    # their mean.
    data = np.zeros((8, 8, 8, 3), dtype=np.float32)
    data[...] = [1.0, 0.5, 0.25]
    vol = {"type": "nanovdbvolume", "data": mi.TensorXf(data), "filter_type": "nearest"}
    size, spp = 16, (256 if dr.is_jit_v(mi.Float) else 64)
    expect = np.exp(-2.0 * np.array([1.0, 0.5, 0.25]))
    if mi.is_monochromatic:
        # (NVDB_TEST_VARIANTS=..._mono: the volume's eval() is the colour's
        # luminance, one extinction)
        expect = np.exp(-2.0 * np.array([np.dot([0.212671, 0.715160, 0.072169], [1.0, 0.5, 0.25])]))
    full = np.array(mi.render(mi.load_dict({
        "type": "scene",
        "integrator": {"type": "volpathlocal", **TRACK_ALWAYS},
        "sensor": {"type": "orthographic",
                   "to_world": T4().look_at(origin=[0.5, 0.5, -1.0], target=[0.5, 0.5, 0.5],
                                            up=[0, 1, 0]) @ T4().scale([0.4, 0.4, 1]),
                   "film": film(size), "sampler": {"type": "independent", "sample_count": spp}},
        "sky": {"type": "constant", "radiance": 1.0},
        "cube": unit_cube({"type": "heterogeneous", "sigma_t": vol, "albedo": 0.0,
                           "scale": 2.0})})), dtype=np.float64)
    means = full.reshape(-1, full.shape[-1])
    tol = 5 * means.std(axis=0, ddof=1) / np.sqrt(len(means))
    print(mi.variant(), means.mean(axis=0), expect, tol)
    assert np.all(np.abs(means.mean(axis=0) - expect) <= np.maximum(tol, 1e-4))


def test19_spectral_extinction_scattering_matches_volpath(variants_rgb):
    # The same Vec3f extinction, varying from voxel to voxel, albedo 0.8,
    # under a sky: camera paths (delta tracking) and shadow rays (ratio
    # tracking) through a spectrally varying extinction, against volpath
    rng = np.random.default_rng(0)
    data = np.zeros((8, 8, 8, 3), dtype=np.float32)
    data[...] = [1.0, 0.5, 0.25]
    data *= rng.uniform(0.2, 1.0, (8, 8, 8, 1)).astype(np.float32)
    vol = {"type": "nanovdbvolume", "data": mi.TensorXf(data)}
    med = {"type": "heterogeneous", "sigma_t": vol, "albedo": 0.8, "scale": 4.0}

    def scene(integrator, **kw):
        return sky_and_sun_scene(integrator, {"cube": unit_cube(med)}, **kw)
    assert_same_expectation(scene, spp=64 if dr.is_jit_v(mi.Float) else 16)


@pytest.mark.parametrize("estimator", ["ratio", "residual"])
def test20_columns_stiff_shadow_rays_analytic(variants_rgb, tmp_path, estimator):
    # Issue 34's stiff cases: 13 columns along
    # x with densities 1e-6, 1e-5, ..., 1e6 in one grid (nearest), scale
    # 1e-3, so that a ray along +z through column c has optical depth
    # tau_c = 1e-9 ... 1e3. With the sun behind the camera (shadow=True)
    # each pixel estimates T^2 = exp(-2 tau): delta tracking on the camera
    # ray, (residual) ratio tracking on the shadow ray, against each leaf's majorant
    # (the column of 1e6 shares leaf 1 with those of 1e2 ... 1e5, which
    # ratio tracking then crosses with fractional weights). Every estimate
    # is finite and in [0, 1]; each column's mean (its 3 x 39 pixels) is within 5 standard
    # errors of exp(-2 tau) (a variable in [0, 1] of mean m has variance
    # at most m (1 - m)), and the two stiffest columns (tau = 100 and 1000)
    # are exactly 0. Residual ratio tracking (the default) promises
    # estimates >= 0, not <= 1 (its factors lie in [0, 2]: a thin column
    # in a leaf whose mean is dense gains weight), so there each column's
    # tolerance is 5 standard errors of its pixels' spread.
    nvdb, _, _ = make_stab(tmp_path, "cols", "--min", 0, 0, 0, "--max", 12, 3, 3,
                           "--fill", "columns", "--lo", 1e-6, "--ratio", 10, dense=False)
    vol = load_nvdb(nvdb, filter_type="nearest")
    per, scale = 3, 1e-3  # (pixels per column)
    size = 13 * per
    spp = 256 if dr.is_jit_v(mi.Float) else 32
    taus = np.array([float(np.float32(1e-6 * 10.0 ** c)) for c in range(13)]) * scale
    for coarse in [0.0, 2.0]:
        img = transmittance_scene("volpathlocal", vol, scale=scale, size=size, spp=spp,
                                  view=(0.0, 1.0), shadow=True, coarse_optical_depth=coarse,
                                  transmittance=estimator)
        assert np.all(np.isfinite(img)) and np.all(img >= 0)
        assert estimator == "residual" or np.all(img <= 1 + 1e-6)
        if img.mean(axis=0)[1] < img.mean(axis=0)[-2]:  # (which way the image's x runs)
            img = img[:, ::-1]
        for c in range(13):
            centre = img[:, c * per:(c + 1) * per]  # the pixel columns inside voxel column c
            expect = math.exp(-2.0 * taus[c])
            if taus[c] >= 100:
                assert np.all(centre == 0.0), (c, coarse, centre.max())
                continue
            tol = max(5 * math.sqrt(expect * (1 - expect) / (centre.size * spp)), 1e-6)
            if estimator == "residual":
                tol = max(tol, 5 * float(np.std(centre, ddof=1)) / math.sqrt(centre.size))
            if mi.is_spectral:  # (colour noise of the wavelength sampling)
                tol += 5 * float(np.std(centre)) / math.sqrt(centre.size)
            assert abs(centre.mean() - expect) <= tol, (c, coarse, centre.mean(), expect, tol)


@pytest.mark.parametrize("scale", [0.05, 0.3])
def test21_ramp_along_the_ray_analytic(variants_rgb, tmp_path, scale):
    # Issue 34's linear ramp: 16 x 4 x 4
    # voxels of value i along x (nearest: 0, 1, ..., 15), turned by the
    # volume's to_world so that the grid's x runs along the rays (+z). Each
    # ray crosses voxels 0..15, 1/16 of the box each: tau = scale x 120 / 16
    # exactly. The density varies inside each of the two leaves (majorants
    # 7 and 15), so ratio tracking weighs null collisions by different
    # fractions along one segment, and delta tracking accepts with
    # different probabilities. Every estimate is in [0, 1], so a pixel mean
    # of mean m has variance at most m (1 - m) / samples; 5 standard errors.
    nvdb, _, _ = make_stab(tmp_path, "ramp", "--min", 0, 0, 0, "--max", 15, 3, 3,
                           "--fill", "ramp", dense=False)
    T = mi.ScalarTransform4f
    vol = load_nvdb(nvdb, filter_type="nearest",
                    to_world=T().translate([1, 0, 0]) @ T().rotate([0, 1, 0], -90))
    tau = scale * 120.0 / 16.0
    size, spp = (16, 256) if dr.is_jit_v(mi.Float) else (8, 64)
    for shadow, expect, estimator in [(False, math.exp(-tau), "ratio"),
                                      (True, math.exp(-2.0 * tau), "ratio"),
                                      (True, math.exp(-2.0 * tau), "residual")]:
        img = transmittance_scene("volpathlocal", vol, scale=scale, size=size, spp=spp,
                                  shadow=shadow, transmittance=estimator)
        assert np.all(np.isfinite(img)) and np.all(img >= 0)
        # Residual ratio tracking's factors lie in [0, 2]: its estimates may
        # exceed 1, so its bound is 5 standard errors of the pixels' spread
        std = math.sqrt(expect * (1 - expect))
        if estimator == "residual":
            std = max(std, float(np.std(img, ddof=1)) * math.sqrt(spp))
        else:
            assert np.all(img <= 1 + 1e-6)
        assert_mean_close(img, spp, expect, std, f"shadow={shadow}, {estimator}")


def slab_shadow_scene(nvdb, scale, estimator, size=16, spp=128):
    """Shadow rays alone: an orthographic camera looks along +z at a white
    diffuse plane (z = 0, facing it) through vacuum; a sun shines on the
    plane at 60 degrees from its normal (irradiance pi: radiance T / 2),
    through a slab of medium 1 thick that the camera rays miss. The slab
    is a cube turned so that its local z (and the grid's) runs along the
    sun: every shadow ray crosses the grid along an axis, through its
    middle. Each pixel estimates T / 2 with the shadow ray's estimator
    alone. Returns 2 x the image: T per pixel."""
    d = np.array([math.sin(math.pi / 3), 0.0, math.cos(math.pi / 3)])
    centre = (-3.0 * d).tolist()
    T = mi.ScalarTransform4f
    slab = (T().translate(centre) @ T().rotate([0, 1, 0], 60) @ T().scale([1.5, 1.5, 0.5]))
    volume = load_nvdb(nvdb, filter_type="nearest",
                       to_world=slab @ T().translate([-1, -1, -1]) @ T().scale(2))
    scene = {
        "type": "scene",
        "integrator": {"type": "volpathlocal", "max_depth": 2, "transmittance": estimator,
                       **TRACK_ALWAYS},
        "sensor": {"type": "orthographic",
                   "to_world": T4().look_at(origin=[0, 0, -6], target=[0, 0, 0], up=[0, 1, 0])
                   @ T4().scale([0.5, 0.5, 1]),
                   "film": film(size), "sampler": {"type": "independent", "sample_count": spp}},
        "slab": unit_cube({"type": "heterogeneous", "sigma_t": volume, "albedo": 0.0,
                           "scale": scale}, to_world=slab),
        "sun": {"type": "directional", "direction": d.tolist(), "irradiance": math.pi},
        "plane": {"type": "rectangle", "to_world": T4().rotate([1, 0, 0], 180),
                  "bsdf": {"type": "diffuse", "reflectance": 1.0}},
    }
    scene = mi.load_dict(scene)
    img = 2.0 * np.array(mi.render(scene), dtype=np.float64)[..., 0]
    assert tracked_media(scene) == 1
    return img


@pytest.mark.parametrize("hot", [None, 4.0], ids=["tight", "loose"])
def test22_stiff_slab_shadow_rays_analytic(variants_rgb, tmp_path, hot):
    # Issue 34's stiff cases for the shadow-ray estimators alone
    # (slab_shadow_scene: the camera rays miss the medium): a grid of
    # density 1 (loose: voxel (0, 0, 0), which no shadow ray crosses,
    # holds 4 and raises the leaf's bound), optical depth tau = scale
    # from 1e-6 to 1e3 along grid-axis rays. Every estimate is finite and
    # >= 0 (ratio tracking's also <= 1), and the mean is exp(-tau) within
    # 5 standard errors of the pixels' spread (ratio tracking: or of a
    # binomial; at least 2e-6 of T and an absolute 1e-12). Residual tracking with the tight control is
    # exp(-tau) exactly until its Russian roulette (below 1e-3, from tau
    # ~7): tau = 8 and 30 check that the roulette's survivors are weighted.
    # The variance of one estimate (loose, tau = 1): each against its
    # analytic value within 35 %, and residual's below half of ratio's.
    args = ["--value", 1.0] + (["--set", 0, 0, 0, hot] if hot else [])
    nvdb, _, _ = make_stab(tmp_path, "slab", *args, dense=False)
    size, spp = (16, 256) if dr.is_jit_v(mi.Float) else (8, 64)
    variance = {}
    for estimator in ["ratio", "residual"]:
        for tau in [1e-6, 1.0, 8.0, 30.0, 1e3]:
            img = slab_shadow_scene(nvdb, tau, estimator, size=size, spp=spp)
            assert np.all(np.isfinite(img)) and np.all(img >= 0), (estimator, tau)
            assert estimator == "residual" or np.all(img <= 1 + 1e-6)
            expect = math.exp(-float(np.float32(tau)))
            # At least 2e-6 of T: at tau = 1e-6 the walk crosses the grid's
            # whole upper node as one cell, whose mean is ~0, so residual
            # tracking is ratio tracking there, and its rare collisions,
            # 1e-6 per ray, do not show in the spread. And 6e-4 tau of T:
            # where residual tracking is exact (tight), it shows Mitsuba's
            # ray offset at the slab's entry (spawn_ray: (1 + |p|) x
            # RayEpsilon along the normal), which shortens every path in
            # the medium by 2.8e-4 here: measured 2.1e-4, 2.8e-4 and 5.2e-4
            # with the slab 2, 3 and 6 from the origin; volpath's paths
            # lose the same
            tol = max(5 * float(np.std(img, ddof=1)) / math.sqrt(img.size),
                      (2e-6 + 6e-4 * tau) * expect, 1e-12)
            if estimator == "ratio":  # (binomial where tight: spread may be 0)
                tol = max(tol, 5 * math.sqrt(expect * (1 - expect) / (img.size * spp)))
            assert abs(img.mean() - expect) <= tol, (estimator, tau, img.mean(), expect, tol)
            if tau == 1.0:
                variance[estimator] = img.var(ddof=1) * spp
    mu = hot or 1.0
    want = {"ratio": ratio_tracking_second_moment(mu, 1.0, 1.0) - math.exp(-2.0),
            "residual": residual_second_moment(mu, (511 + mu) / 512, 0.0, 1.0, 1.0)
            - math.exp(-2.0)}
    print(f"{mi.variant()} {hot}: variance per sample {variance}, analytic {want}")
    if hot:
        for estimator in want:
            assert 0.65 * want[estimator] <= variance[estimator] <= 1.35 * want[estimator], \
                (estimator, variance, want)
        assert variance["residual"] < 0.5 * variance["ratio"], variance
    else:  # tight: residual is exact (to rounding), ratio binomial
        assert variance["residual"] < 1e-6 and variance["ratio"] > 0.1, variance
