"""
nanovdbvolume on the value types beyond float (Half, Fp4, Fp8, Fp16, FpN):
against Mitsuba's gridvolume on a dense export of the decoded values
(NanoVDB's own accessor; Half: the CPU's F16C rounding of the float grid),
for both filters on scalar_rgb and llvm_ad_rgb, and through volpathlocal's
majorant walk. The reads themselves are compared with PNanoVDB in
tests/test_value_types.cpp.
"""

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from conftest import assert_renders_match, eval_points, load_dense, load_nvdb, read_vol
from test_nanovdbvolume import point_count, random_points, render

TYPES = ["fp4", "fp8", "fp16", "fpn", "half"]
NANOVDB_NAME = {"fp4": "Fp4", "fp8": "Fp8", "fp16": "Fp16", "fpn": "FpN", "half": "Half"}


@pytest.mark.parametrize("value_type", TYPES)
@pytest.mark.parametrize("name", ["noisy_cloud", "upper_tiles", "nonzero_background"])
def test01_nearest_equals_gridvolume(variants_rgb, make_grid, name, value_type):
    nvdb, vol = make_grid(name, value_type=value_type)
    nano = load_nvdb(nvdb, filter_type="nearest")
    dense = load_dense(vol, filter_type="nearest")
    assert nano.max() == dense.max()
    assert f"grid_type = {NANOVDB_NAME[value_type]}," in str(nano)
    pts = random_points(point_count(), seed=3, lo=0.0, hi=0.999999)
    a, b = eval_points(nano, pts), eval_points(dense, pts)
    assert np.array_equal(a, b), f"{np.sum(a != b)} of {len(a)} lookups differ"


@pytest.mark.parametrize("value_type", TYPES)
@pytest.mark.parametrize("name", ["noisy_cloud", "upper_tiles"])
def test02_trilinear_equals_gridvolume_inside(variants_rgb, make_grid, name, value_type):
    nvdb, vol = make_grid(name, value_type=value_type)
    res, _, _ = read_vol(vol)
    nano, dense = load_nvdb(nvdb), load_dense(vol)
    margin = 0.5 / np.array(res, dtype=np.float32)
    rng = np.random.default_rng(4)
    pts = rng.uniform(margin, 1 - margin, size=(point_count(), 3)).astype(np.float32)
    a, b = eval_points(nano, pts), eval_points(dense, pts)
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
    assert np.all(a <= nano.max())


@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
@pytest.mark.parametrize("value_type", ["fp8", "fpn", "half"])
def test03_render_matches_gridvolume(variants_rgb, make_grid, value_type, filter_type):
    nvdb, vol = make_grid("noisy_cloud", value_type=value_type)
    nano = load_nvdb(nvdb, filter_type=filter_type)
    dense = load_dense(vol, filter_type=filter_type)
    assert nano.max() == dense.max()
    spp = 4 if dr.is_jit_v(mi.Float) else 1
    a, b = render(nano, spp=spp), render(dense, spp=spp)
    assert np.mean(a) > 0.01
    assert_renders_match(a, b, filter_type)


@pytest.mark.parametrize("value_type", TYPES)
def test04_quantized_values_stay_near_the_float_grid(variant_llvm_ad_rgb, make_grid, value_type):
    # The decoded values differ from the float grid's by at most half a
    # quantization step of their leaf: at most (max - min) / (2^bits - 1) / 2
    # of the grid's range for Fp4/8/16, FpN's tolerance (0.01 for fog
    # volumes) and a half's relative rounding (2^-11) for Half.
    nvdb_f, _ = make_grid("noisy_cloud", dense=False)
    nvdb_q, _ = make_grid("noisy_cloud", dense=False, value_type=value_type)
    f = eval_points(load_nvdb(nvdb_f, filter_type="nearest"), random_points(100_000, 5, 0, 1))
    q = eval_points(load_nvdb(nvdb_q, filter_type="nearest"), random_points(100_000, 5, 0, 1))
    err = np.abs(q - f)
    bound = {"fp4": f.max() / 15 / 2, "fp8": f.max() / 255 / 2, "fp16": f.max() / 65535 / 2,
             "fpn": 0.01, "half": f.max() * 2.0 ** -11}[value_type]
    assert err.max() <= bound * 1.001 + 1e-7, (err.max(), bound)
    assert err.max() > 0  # quantized for real


@pytest.mark.parametrize("value_type", ["fp4", "fpn", "half"])
def test05_volpathlocal_walks_typed_grids(variants_rgb, make_grid, value_type):
    # The majorant walk reads the typed grid's tiles and per-node bounds: its
    # image has the expectation of volpath's (z-test, as tests/test_volpathlocal.py)
    from test_volpathlocal import assert_same_expectation, medium, sky_and_sun_scene, unit_cube
    nvdb, _ = make_grid("upper_tiles", dense=False, value_type=value_type)
    vol = load_nvdb(nvdb)
    assert_same_expectation(
        lambda integrator, **kw: sky_and_sun_scene(integrator, {"cube": unit_cube(medium(vol, 4.0))}, **kw))
