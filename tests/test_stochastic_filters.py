"""
Stochastic filters (nanovdbvolume's filter_type "stochastic_trilinear" and
"stochastic_tricubic", nanovdb_drjit/sampler.h: stochastic_voxel) against
their deterministic counterparts.

A stochastic filter reads one voxel, drawn so that its expected value is
the filter's; delta tracking's real-collision probability and ratio
tracking's factor are linear in the density, so every image keeps the
filtered medium's expectation and only gets noisier. The checks:

  - renders: volpath with stochastic_trilinear (offsets from a hash of the
    position: eval() has no sampler) and volpathlocal with it (offsets from
    its sampler) against volpath with trilinear, by the z-test of
    test_volpathlocal.py (two seeds per side, |z| < 5), on the RGB variants
    and a spectral one; stochastic_tricubic, whose medium is smoother than
    trilinear's, between its two offset sources (volpath against
    volpathlocal);
  - eval(): around 256 points, the mean difference to trilinear is zero
    (a chi-square test over the points), and nearest's is not;
  - stiff and extreme densities: analytic transmittance through constant
    grids, 1e-6 ... 1e6, where every tap reads the same value;
  - bad values name the file and the filters.

The mean of one-voxel reads at fixed points over uniform offsets, and the
reach of the picked voxels, are checked in C++ against PNanoVDB's reads
(tests/test_sampler.cpp); the majorants that cover the tricubic reach in
tests/test_majorant_walk.cpp.
"""

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from conftest import _setup_variant, load_nvdb
from conftest import make_stability_grid as make_stab
from test_volpathlocal import (TRACK_ALWAYS, Z_MAX, assert_mean_close, binomial_std,
                               cloud_scene, render, spp_for_analytic, tracked_media,
                               transmittance_scene, z_scores)

STOCHASTIC = ["stochastic_trilinear", "stochastic_tricubic"]


def assert_same(a, b, what):
    z = z_scores(a, b)
    print(f"{mi.variant()} {what}: z = {np.round(z, 2)}, means {a.mean(axis=(0, 1, 2))} "
          f"vs {b.mean(axis=(0, 1, 2))}")
    assert np.all(np.abs(z) < Z_MAX), (what, z)


def cloud_renders(nvdb, filter_type, integrator, seeds, spp=64, **args):
    vol = load_nvdb(nvdb, filter_type=filter_type)
    if integrator == "volpathlocal":
        args = {**TRACK_ALWAYS, **args}
    imgs, scene = render(cloud_scene(vol, 8.0)(integrator, spp=spp, **args), seeds)
    if integrator == "volpathlocal":
        assert tracked_media(scene) == 1
    return imgs


def test01_stochastic_trilinear_renders_the_trilinear_medium(variants_rgb, make_grid):
    # volpath + trilinear (seeds 0, 1) against volpath + stochastic_trilinear
    # (hash offsets; seeds 2, 3) and volpathlocal + stochastic_trilinear
    # (sampler offsets; seeds 4, 5)
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    ref = cloud_renders(nvdb, "trilinear", "volpath", (0, 1))
    hashed = cloud_renders(nvdb, "stochastic_trilinear", "volpath", (2, 3))
    sampled = cloud_renders(nvdb, "stochastic_trilinear", "volpathlocal", (4, 5))
    assert_same(ref, hashed, "volpath, hash offsets")
    assert_same(ref, sampled, "volpathlocal, sampler offsets")
    assert ref.std() > 0.01  # the medium is seen


def test02_stochastic_tricubic_offset_sources_agree(variants_rgb, make_grid):
    # The tricubic medium through both offset sources and both integrators;
    # and it differs from nearest's far more than noise: the filter is used
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    hashed = cloud_renders(nvdb, "stochastic_tricubic", "volpath", (0, 1))
    sampled = cloud_renders(nvdb, "stochastic_tricubic", "volpathlocal", (2, 3))
    assert_same(hashed, sampled, "tricubic: volpath (hash) vs volpathlocal (sampler)")


@pytest.mark.parametrize("variant", ["llvm_ad_spectral", "scalar_spectral"])
def test03_spectral(make_grid, variant):
    _setup_variant(variant)
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    spp = 64 if dr.is_jit_v(mi.Float) else 32
    ref = cloud_renders(nvdb, "trilinear", "volpath", (0, 1), spp=spp)
    sampled = cloud_renders(nvdb, "stochastic_trilinear", "volpathlocal", (2, 3), spp=spp)
    assert_same(ref, sampled, "spectral volpathlocal, sampler offsets")


def test04_eval_mean_is_trilinear(variant_llvm_ad_rgb, make_grid):
    # Hash offsets in eval(), around 256 random points of the cloud's box:
    # 4096 distinct positions within 0.01 voxel of each (distinct hashes).
    # Per cluster, the paired difference d = stochastic - trilinear has
    # mean 0 if and only if the filter's expectation is trilinear's there;
    # sum over the k clusters that hold values of (mean(d) / its standard
    # error)^2 is then chi-square with k degrees of freedom: below its
    # 1 - 1e-6 quantile (Wilson-Hilferty). nearest, another filter, lies
    # far above.
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    vol = load_nvdb(nvdb, filter_type="trilinear")
    dims = np.array(mi.traverse(vol)["index_dims"], dtype=np.float64)
    rng = np.random.default_rng(5)
    clusters, per = 256, 4096
    centres = rng.random((3, clusters)) * 0.8 + 0.1
    jitter = (rng.random((3, clusters, per)) - 0.5) * 0.02 / dims[:, None, None]
    pts = (centres[:, :, None] + jitter).reshape(3, -1).astype(np.float32)
    it = dr.zeros(mi.Interaction3f, clusters * per)
    it.p = mi.Point3f(pts)

    def values(filter_type):
        v = load_nvdb(nvdb, filter_type=filter_type).eval_1(it)
        return np.array(v, dtype=np.float64).reshape(clusters, per)

    tri = values("trilinear")
    chi2 = {}
    for filt in ["stochastic_trilinear", "nearest"]:
        d = values(filt) - tri
        # (floored at float rounding: trilinear's weighted sum of a constant
        # is a few ulps off the value, which one-voxel reads return exactly)
        se = np.maximum(d.std(axis=1, ddof=1) / np.sqrt(per), 1e-6 * np.abs(tri).mean(axis=1))
        varying = se > 0  # (clusters in empty space: d is 0 there)
        chi2[filt] = float(np.sum((d.mean(axis=1)[varying] / se[varying]) ** 2))
        chi2[filt + " clusters"] = int(varying.sum())
    k = chi2["stochastic_trilinear clusters"]
    limit = k * (1 - 2 / (9 * k) + 4.75 * np.sqrt(2 / (9 * k))) ** 3  # P = 1e-6
    print(chi2, "limit", limit)
    assert k > 100, chi2
    assert chi2["stochastic_trilinear"] < limit, chi2
    assert chi2["nearest"] > limit, chi2
    # The same point always reads the same voxel
    assert np.array_equal(values("stochastic_trilinear"), values("stochastic_trilinear"))


@pytest.mark.parametrize("density", [1e-6, 1.0, 1e4, 1e6])
@pytest.mark.parametrize("filter_type", STOCHASTIC)
def test05_stiff_densities_analytic_transmittance(variants_rgb, tmp_path, density, filter_type):
    # A constant 8^3 box, wrap_mode clamp (every tap reads the box), so the
    # filtered medium is the constant: T = exp(-density * scale) along the
    # unit length, for scale 1 and 1 / density; volpath and volpathlocal
    nvdb, _, _ = make_stab(tmp_path, "c", "--value", density, dense=False)
    vol = load_nvdb(nvdb, filter_type=filter_type, wrap_mode="clamp")
    size, spp = spp_for_analytic()
    for integrator in ["volpath", "volpathlocal"]:
        for scale in [1.0, 1.0 / density]:
            img = transmittance_scene(integrator, vol, scale=scale, size=size, spp=spp)
            expect = np.exp(-float(np.float32(density)) * scale)
            assert_mean_close(img, spp, expect, binomial_std(expect), (integrator, scale))
            assert np.all((img >= 0) & (img <= 1))


def test06_bad_filter_type(variant_scalar_rgb, make_grid):
    nvdb, _ = make_grid("noisy_cloud", dense=False)
    with pytest.raises(RuntimeError) as e:
        load_nvdb(nvdb, filter_type="stochastic")
    msg = str(e.value)
    assert nvdb in msg or "noisy_cloud" in msg, msg
    for name in ["nearest", "trilinear", "stochastic_trilinear", "stochastic_tricubic"]:
        assert f'"{name}"' in msg, msg
