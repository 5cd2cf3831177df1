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

from nanovdb_mitsuba import volume_facts
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
    assert volume_facts(nano)["grid_type"] == NANOVDB_NAME[value_type]
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


# ---------------------------------------------------------------------------
#  Vec3f: a 3-channel gridvolume, in every colour mode
# ---------------------------------------------------------------------------

from conftest import _setup_variant  # noqa: E402

COLOUR_VARIANTS = ["scalar_rgb", "llvm_ad_rgb", "llvm_ad_mono", "llvm_ad_spectral",
                   "scalar_spectral"]


@pytest.fixture(params=COLOUR_VARIANTS)
def colour_variant(request):
    _setup_variant(request.param)
    return request.param


def interactions(pts, variant):
    """Interactions at the points (N, 3); spectral: 4 fixed wavelengths"""
    if dr.is_jit_v(mi.Float):
        it = dr.zeros(mi.Interaction3f, len(pts))
        it.p = mi.Point3f(pts[:, 0], pts[:, 1], pts[:, 2])
        if "spectral" in variant:
            it.wavelengths = mi.UnpolarizedSpectrum(450, 520, 600, 680)
        return [it]
    out = []
    for q in pts:
        it = mi.Interaction3f()
        it.p = mi.ScalarPoint3f(*map(float, q))
        if "spectral" in variant:
            it.wavelengths = mi.UnpolarizedSpectrum(450, 520, 600, 680)
        out.append(it)
    return out


def evaluate(volume, its, method="eval"):
    return np.array([np.array(getattr(volume, method)(it)) for it in its]).reshape(-1)


@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
@pytest.mark.parametrize("name", ["noisy_cloud", "upper_tiles", "nonzero_background"])
def test06_vec3f_equals_a_3_channel_gridvolume(colour_variant, make_grid, name, filter_type):
    # eval(): the colour (RGB), its luminance (mono), the sRGB-model spectrum
    # times 2 max(rgb) (spectral), as gridvolume computes each; max() and
    # max_per_channel() as gridvolume's on the dense export
    nvdb, vol = make_grid(name, value_type="vec3f")
    nano = load_nvdb(nvdb, filter_type=filter_type)
    dense = load_dense(vol, filter_type=filter_type)
    assert volume_facts(nano)["grid_type"] == "Vec3f"
    assert nano.max() == dense.max()
    n = 20_000 if dr.is_jit_v(mi.Float) else 400
    pts = random_points(n, 7, 0.02, 0.98)
    its = interactions(pts, colour_variant)
    a, b = evaluate(nano, its), evaluate(dense, its)
    if filter_type == "nearest":
        assert np.array_equal(a, b), f"{np.sum(a != b)} of {len(a)} values differ"
    else:
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)
    if "spectral" not in colour_variant:
        a1, b1 = evaluate(nano, its, "eval_1"), evaluate(dense, its, "eval_1")
        np.testing.assert_allclose(a1, b1, rtol=1e-5, atol=1e-6)
        a3, b3 = evaluate(nano, its, "eval_3"), evaluate(dense, its, "eval_3")
        np.testing.assert_allclose(a3, b3, rtol=1e-5, atol=1e-6)


def test07_vec3f_raw_and_channel_errors(make_grid):
    nvdb, vol = make_grid("noisy_cloud", value_type="vec3f")
    _setup_variant("scalar_spectral")
    it = mi.Interaction3f()
    it.p = mi.ScalarPoint3f(0.5, 0.5, 0.5)
    it.wavelengths = mi.UnpolarizedSpectrum(450, 520, 600, 680)
    # Spectral, raw=false: a spectrum only (eval_1 / eval_3 refuse, as gridvolume)
    nano = load_nvdb(nvdb)
    for method in ["eval_1", "eval_3"]:
        with pytest.raises(RuntimeError, match=r"(?s)noisy_cloud.*raw=false"):
            getattr(nano, method)(it)
    # raw=true: the vector (as gridvolume), no spectrum
    raw, dense_raw = load_nvdb(nvdb, raw=True), load_dense(vol, raw=True)
    assert np.array_equal(np.array(raw.eval_3(it)), np.array(dense_raw.eval_3(it)))
    assert raw.max() == dense_raw.max()
    with pytest.raises(RuntimeError, match=r"(?s)noisy_cloud.*raw=true"):
        raw.eval(it)
    # A scalar grid has no 3-vector
    _setup_variant("scalar_rgb")
    scalar, _ = make_grid("noisy_cloud", dense=False)
    it = mi.Interaction3f()
    it.p = mi.ScalarPoint3f(0.5, 0.5, 0.5)
    with pytest.raises(RuntimeError, match="single channel"):
        load_nvdb(scalar).eval_3(it)


def test08_vec3f_memory(variant_llvm_ad_rgb, make_grid):
    # The backend holds the grid once (its bytes padded to 64); spectral
    # variants add one float per leaf voxel (the scales) and keep no colours
    nvdb, _ = make_grid("noisy_cloud", value_type="vec3f", dense=False)
    f = volume_facts(load_nvdb(nvdb))
    grid_bytes, backend = f["grid_bytes"], f["backend_bytes"]
    assert backend == (grid_bytes + 63) // 64 * 64
    assert f["spectral_scale_bytes"] == 0
    _setup_variant("llvm_ad_spectral")
    f = volume_facts(load_nvdb(nvdb))
    assert f["backend_bytes"] == backend
    scale_bytes = f["spectral_scale_bytes"]
    # 2048 bytes per 6272-byte leaf (+ 4 per root tile): at most a third
    assert 0 < scale_bytes <= grid_bytes / 3, (scale_bytes, grid_bytes)


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_spectral"])
@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
def test09_albedo_from_vec3f_beside_a_scalar_density(make_grid, variant, filter_type):
    # The typical use: sigma_t from a float grid, albedo from a Vec3f grid
    # (the fog sphere's colours: every channel in [0, 1]); the image equals
    # the one with two gridvolumes
    _setup_variant(variant)
    density, density_vol = make_grid("noisy_cloud")
    albedo, albedo_vol = make_grid("fog_sphere", value_type="vec3f")

    def scene(sigma_t, colour):
        return mi.load_dict({
            "type": "scene",
            "integrator": {"type": "volpath", "max_depth": 16},
            "sensor": {"type": "perspective", "fov": 35,
                       "to_world": mi.ScalarTransform4f().look_at(
                           origin=[2.2, 1.6, 2.6], target=[0.5, 0.5, 0.5], up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 24, "height": 24,
                                "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                       "sampler": {"type": "independent", "sample_count": 4}},
            "emitter": {"type": "constant"},
            "cube": {"type": "cube",
                     "to_world": mi.ScalarTransform4f().translate([0.5, 0.5, 0.5]).scale(0.5),
                     "bsdf": {"type": "null"},
                     "interior": {"type": "heterogeneous", "sigma_t": sigma_t,
                                  "albedo": colour, "scale": 6.0}},
        })
    a = np.array(mi.render(scene(load_nvdb(density, filter_type=filter_type),
                                 load_nvdb(albedo, filter_type=filter_type)), seed=0))
    b = np.array(mi.render(scene(load_dense(density_vol, filter_type=filter_type),
                                 load_dense(albedo_vol, filter_type=filter_type)), seed=0))
    assert np.mean(a) > 0.01
    assert_renders_match(a, b, filter_type)
