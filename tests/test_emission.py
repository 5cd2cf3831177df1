"""
Emissive media: the emissiveheterogeneous medium (src/media/) rendered by
volpathlocal (the emission estimator in src/integrators/tracking.h), against
independent references:

- analytic: an emitting, absorbing, non-scattering slab of constant sigma_a
  and Le seen head-on (orthographic) gives L = Le (1 - exp(-sigma_a d)).
  With a constant density the walk's majorant is sigma_a itself, so the
  first tentative collision is real and adds Le, and the path ends there
  (albedo 0): a sample is Le or 0, Bernoulli with p = 1 - exp(-sigma_a d).
  Per pixel within binomial standard errors (RGB); in spectral variants the
  sample also carries the wavelengths' weight, and the pixels (independent,
  one distribution) give its standard deviation. Temperature mode against
  Planck's law integrated with the CIE curves here, in numpy.
- a fine ray march of the emission-absorption integral through a random
  grid (nearest lookups of a numpy array, exact transmittance per step),
  against renders, z-tests;
- with scattering, a floor lit by the fire alone: the walk's local
  majorants against the global one (coarse_optical_depth 1e30 crosses the
  grid's nodes whole), z-tests;
- the emission through a thin dielectric and inside an absorbing medium
  (analytic factors), and volpath's warning that it leaves emission out.
"""

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from conftest import TEST_VARIANTS, _setup_variant, has_cuda, need_shared_data
import nanovdb_mitsuba

Z_MAX = 5.0
# Mitsuba's spectrum.h: MI_CIE_Y_NORMALIZATION (a unit spectrum has Y = 1)
CIE_Y_NORMALIZATION = 1.0 / 106.7502593994140625
# CODATA 2018 (exact SI): independent of the 2014 values Mitsuba's
# blackbody.cpp (and ours) use; they differ by 1e-8 relative
H, C, K = 6.62607015e-34, 2.99792458e8, 1.380649e-23
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])


def T4():
    return mi.ScalarTransform4f()


# The analytic tests' variants: two RGB and one spectral (NVDB_TEST_VARIANTS
# replaces them, as for the other variant-parametrized tests)
@pytest.fixture(params=TEST_VARIANTS or (["scalar_rgb", "llvm_ad_rgb", "scalar_spectral"] +
                                         (["cuda_ad_rgb"] if has_cuda() else [])))
def variants_emission(request):
    _setup_variant(request.param)
    return request.param


def planck(lambda_nm, t):
    """Planck's law, W m^-2 sr^-1 nm^-1"""
    lam = np.asarray(lambda_nm, dtype=np.float64) * 1e-9
    return 1e-9 * 2 * H * C ** 2 / (lam ** 5 * np.expm1(H * C / (lam * K * t)))


def blackbody_rgb(t, clip=None):
    """What a spectral film makes of a blackbody at t kelvin: the integral of
    Planck x CIE 1931 over [360, 830] nm (0.25 nm steps), normalized as
    Mitsuba's spectrum_to_srgb, in linear sRGB; and its luminance Y. clip
    (default: in RGB variants): negative components clipped to 0, as the RGB
    variants' table does (blackbody.h)."""
    lam = np.arange(360.0, 830.0 + 1e-9, 0.25)
    if dr.is_jit_v(mi.Float):
        cmf = np.array(mi.cie1931_xyz(mi.Float(lam)), dtype=np.float64).T
    else:
        cmf = np.array([np.array(mi.cie1931_xyz(float(l)), dtype=np.float64) for l in lam])
    p = planck(lam, t)
    w = np.full(len(lam), 0.25)
    w[0] = w[-1] = 0.125
    xyz = (p[:, None] * cmf * w[:, None]).sum(axis=0) * CIE_Y_NORMALIZATION
    rgb = XYZ_TO_SRGB @ xyz
    if clip if clip is not None else not mi.is_spectral:
        rgb = np.maximum(rgb, 0.0)
    return rgb, xyz[1]


def film(size):
    return {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
            "pixel_format": "luminance" if mi.is_monochromatic else "rgb"}


def unit_cube(interior, bsdf=None):
    return {"type": "cube", "to_world": T4().translate([0.5, 0.5, 0.5]).scale(0.5),
            "bsdf": bsdf or {"type": "null"}, "interior": interior}


def head_on_sensor(size, spp, z=-1.0, half=0.4):
    """Orthographic rays along +z through the middle of the cube [0, 1]^3"""
    return {"type": "orthographic",
            "to_world": T4().look_at(origin=[0.5, 0.5, z], target=[0.5, 0.5, 0.5],
                                     up=[0, 1, 0]) @ T4().scale([half, half, 1]),
            "film": film(size), "sampler": {"type": "independent", "sample_count": spp}}


def constant_density(value=1.0, n=8):
    return {"type": "nanovdbvolume", "data": mi.TensorXf(np.full((n, n, n), value, np.float32)),
            "filter_type": "nearest"}


def slab_scene(medium, size, spp, extra=None, estimator="collisions"):
    # (emission_sampling "collisions": the estimator whose samples are
    # Bernoulli; "mis" estimates the camera's emission by ratio tracking)
    scene = {"type": "scene",
             "integrator": {"type": "volpathlocal", "emission_sampling": estimator},
             "sensor": head_on_sensor(size, spp), "cube": unit_cube(medium)}
    scene.update(extra or {})
    return scene


def render_np(scene, seed=0, spp=0):
    return np.array(mi.render(scene, seed=seed, spp=spp), dtype=np.float64)


def check_bernoulli_pixels(img, spp, le, p, what):
    """Each pixel: the mean of spp samples that are le (per channel) with
    probability p, else 0: within Z_MAX binomial standard errors per pixel,
    and the whole image within Z_MAX of its own."""
    px = img.reshape(-1, img.shape[-1])
    le = np.broadcast_to(np.asarray(le, np.float64), px.shape[1:])
    expect = le * p
    sd = np.abs(le) * np.sqrt(p * (1 - p))
    # (+1e-5 relative: float32 colour conversions, e.g. mono's luminance of
    # an RGB colour, 1.5e-6 off the double one here)
    per_pixel = Z_MAX * sd / np.sqrt(spp) + 1e-5 * np.abs(expect)
    bad = np.abs(px - expect) > per_pixel
    assert not bad.any(), (what, px[bad.any(axis=1)][:4], expect, per_pixel)
    whole = Z_MAX * sd / np.sqrt(spp * len(px)) + 1e-5 * np.abs(expect)
    assert np.all(np.abs(px.mean(axis=0) - expect) <= whole), (what, px.mean(axis=0), expect)


def check_iid_pixels(img, expect, what, rel_bias=0.0):
    """Pixels that are independent estimates of one value (spectral: the
    wavelengths' weight varies per sample): each within 6 of their standard
    deviations of `expect`, their mean within Z_MAX standard errors (plus
    `rel_bias`: the RGB -> spectrum -> RGB round trip of an upsampled
    colour)."""
    px = img.reshape(-1, img.shape[-1])
    expect = np.broadcast_to(np.asarray(expect, np.float64), px.shape[1:])
    sd = px.std(axis=0, ddof=1)
    assert np.all(np.abs(px - expect) <= 6 * sd + 1e-6), (what, px.min(axis=0), px.max(axis=0),
                                                          expect, sd)
    tol = Z_MAX * sd / np.sqrt(len(px)) + rel_bias * np.abs(expect) + 1e-6
    assert np.all(np.abs(px.mean(axis=0) - expect) <= tol), (what, px.mean(axis=0), expect, tol)


# ---------------------------------------------------------------------------
#  Analytic
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("estimator", ["collisions", "mis"])
@pytest.mark.parametrize("sigma", [0.25, 2.0, 60.0])
def test01_slab_radiance_mode_analytic(variants_emission, sigma, estimator):
    # Le = 0.5 x (1, 0.5, 0.25) (one-channel emission 0.5 times an RGB
    # colour); d = 1. sigma 60: a stiff case, p = 1 - 1e-26 (every sample
    # collides, within a voxel of the entry face). "mis": the camera's
    # emission by ratio tracking (tracking.h), whose pixels are independent
    # estimates of one value, finite and non-negative
    size, spp = 16, 128
    color = [1.0, 0.5, 0.25]
    med = {"type": "emissiveheterogeneous", "sigma_t": constant_density(), "scale": sigma,
           "albedo": 0.0, "emission": 0.5,
           "color": {"type": "rgb", "value": color}}
    img = render_np(mi.load_dict(slab_scene(med, size, spp, estimator=estimator)))
    p = -np.expm1(-sigma)
    le = 0.5 * np.array(color)
    if estimator == "mis":
        assert np.all(np.isfinite(img)) and np.all(img >= 0.0)
        check_iid_pixels(img, (le if not mi.is_monochromatic else
                               [0.5 * np.dot([0.212671, 0.715160, 0.072169], color)]) * p,
                         f"sigma {sigma}, mis", rel_bias=0.01 if mi.is_spectral else 0.0)
    elif mi.is_spectral:
        check_iid_pixels(img, le * p, f"sigma {sigma}", rel_bias=0.01)
    elif mi.is_monochromatic:
        check_bernoulli_pixels(img, spp, [0.5 * np.dot([0.212671, 0.715160, 0.072169], color)],
                               p, f"sigma {sigma}")
    else:
        check_bernoulli_pixels(img, spp, le, p, f"sigma {sigma}")


@pytest.mark.parametrize("kelvin", [1500.0, 3000.0, 6500.0])
def test02_slab_temperature_mode_analytic(variants_emission, kelvin):
    # A temperature grid of value kelvin / 1000 with temperature_scale 1000
    # (and offset 0): a blackbody at `kelvin`, scaled to about 1 by
    # emission_scale = 1 / Y. sigma_a = 1.5 (p = 0.777).
    size, spp = 16, 128
    rgb, y = blackbody_rgb(kelvin)
    scale = 1.0 / y
    temp = {"type": "nanovdbvolume", "filter_type": "nearest",
            "data": mi.TensorXf(np.full((8, 8, 8), kelvin / 1000.0, np.float32))}
    med = {"type": "emissiveheterogeneous", "sigma_t": constant_density(), "scale": 1.5,
           "albedo": 0.0, "temperature": temp, "temperature_scale": 1000.0,
           "emission_scale": scale}
    img = render_np(mi.load_dict(slab_scene(med, size, spp)))
    p = -np.expm1(-1.5)
    le = rgb * scale
    print(mi.variant(), kelvin, "expected", le * p, "mean", img.reshape(-1, img.shape[-1]).mean(0))
    if mi.is_spectral:
        check_iid_pixels(img, le * p, f"{kelvin} K")
    elif mi.is_monochromatic:
        check_bernoulli_pixels(img, spp, [1.0], p, f"{kelvin} K")
    else:
        check_bernoulli_pixels(img, spp, le, p, f"{kelvin} K")


def test03_temperature_mapping_and_cutoff(variant_scalar_rgb):
    # Half the grid below the cutoff after the mapping (value - offset) x
    # scale: those pixels are black; the other half glows as a blackbody at
    # (3.2 - 0.2) x 1000 = 3000 K. NaN and negative temperatures: no emission.
    size, spp = 16, 64
    data = np.full((8, 8, 8), 3.2, np.float32)
    data[:, :, :4] = 0.25  # (0.25 - 0.2) x 1000 = 50 K <= cutoff 100 K
    rgb, y = blackbody_rgb(3000.0)
    med = {"type": "emissiveheterogeneous", "sigma_t": constant_density(), "scale": 1.5,
           "albedo": 0.0, "temperature_scale": 1000.0, "temperature_offset": 0.2,
           "emission_scale": 1.0 / y,
           "temperature": {"type": "nanovdbvolume", "filter_type": "nearest",
                           "data": mi.TensorXf(data)}}
    img = render_np(mi.load_dict(slab_scene(med, size, spp, {})))
    # The sensor's rays cover x in [0.1, 0.9]: the columns of x < 0.5 are
    # cold (on the image's right: the camera looks along +z, so +x is left)
    hot, cold = img[:, : size // 2 - 1], img[:, size // 2 + 1:]
    assert np.all(cold == 0.0)
    check_bernoulli_pixels(hot, spp, rgb / y, -np.expm1(-1.5), "3000 K half")


def test04_blackbody_table_against_planck(variant_llvm_ad_rgb):
    # The RGB variants' table (blackbody.h: log-spaced, interpolated) against
    # the colour integrated here, through the medium's eval_emission seen in
    # a render would be noisy; instead a constant medium with a huge density
    # (p = 1: every sample is Le exactly) at many temperatures at once: one
    # row of pixels per temperature.
    temps = np.geomspace(500.0, 60000.0, 16)
    size, spp = 16, 4
    data = np.zeros((8, 16, 8), np.float32)  # (z, y, x): rows of constant T
    data[:, :, :] = (temps / 1000.0)[None, :, None]
    med = {"type": "emissiveheterogeneous", "sigma_t": constant_density(1.0, 8), "scale": 1e4,
           "albedo": 0.0, "temperature_scale": 1000.0,
           "temperature": {"type": "nanovdbvolume", "filter_type": "nearest",
                           "data": mi.TensorXf(data)}}
    scene = slab_scene(med, size, spp)
    scene["sensor"] = head_on_sensor(size, spp, half=0.5)
    img = render_np(mi.load_dict(scene))
    # Row r of the image (top = y 1) sees grid row 15 - r
    for r in range(size):
        t = temps[size - 1 - r]
        rgb, y = blackbody_rgb(t)
        got = img[r].mean(axis=0)
        # (the table's linear interpolation of log Y: measured 2.7e-4 of Y
        # at 500 K, where log Y bends most, 1e-4 and less above 900 K)
        rtol = 4e-4
        print(f"{t:8.0f} K: relative error {np.abs(got - rgb).max() / y:.2e}")
        assert np.allclose(got, rgb, rtol=rtol, atol=rtol * y), (t, got, rgb)


# ---------------------------------------------------------------------------
#  Heterogeneous: against a ray march
# ---------------------------------------------------------------------------

def random_fire(n=12, seed=3):
    """(density, emission) arrays (z, y, x): a random density with empty
    corners and a hot core"""
    rng = np.random.default_rng(seed)
    z, y, x = np.meshgrid(*(np.arange(n) + 0.5,) * 3, indexing="ij")
    r = np.sqrt((x - n / 2) ** 2 + (y - n / 2) ** 2 + (z - n / 2) ** 2) / (n / 2)
    density = (rng.uniform(0.2, 1.0, (n, n, n)) * (r < 1.0)).astype(np.float32)
    emission = (np.clip(1.2 - r, 0, None) ** 2 * rng.uniform(0.5, 1.5, (n, n, n))).astype(np.float32)
    return density, emission


def ray_march(density, emission, scale, origins, direction, steps=1500):
    """The emission-absorption integral along rays through the unit cube of a
    nearest-lookup grid (voxel i covers [i/n, (i+1)/n]): per step dt, L +=
    T Le (1 - exp(-sigma_a dt)), T *= exp(-sigma_a dt), sigma_a = scale x
    density at the step's midpoint."""
    n = density.shape[0]
    d = np.asarray(direction, np.float64)
    with np.errstate(divide="ignore"):
        t0 = np.where(d != 0, (0.0 - origins) / d, -np.inf)
        t1 = np.where(d != 0, (1.0 - origins) / d, np.inf)
    tmin = np.maximum(np.minimum(t0, t1).max(axis=1), 0.0)
    tmax = np.maximum(t0, t1).min(axis=1)
    length = np.maximum(tmax - tmin, 0.0)
    L = np.zeros(len(origins))
    T = np.ones(len(origins))
    dt = length / steps
    for s in range(steps):
        p = origins + d[None, :] * (tmin + (s + 0.5) * dt)[:, None]
        i = np.clip((p * n).astype(int), 0, n - 1)
        sig = scale * density[i[:, 2], i[:, 1], i[:, 0]]
        le = emission[i[:, 2], i[:, 1], i[:, 0]]
        a = -np.expm1(-sig * dt)
        L += T * le * a
        T *= 1 - a
    return L


def test05_heterogeneous_against_ray_march(variants_rgb):
    # Albedo 0, a grey emission: the image is the emission-absorption
    # integral. The sensor is orthographic along a tilted direction, so that
    # rays cross voxel faces; the reference marches 8 x 8 rays per pixel
    # (stratified over its area; its own error is below 1e-3 of the image).
    # z-tests over the whole image and its four quadrants, each with the
    # per-pixel variance of 8 seeds.
    density, emission = random_fire()
    scale = 6.0
    size = 8
    spp = 64 if dr.is_jit_v(mi.Float) else 32
    origin, target = np.array([0.9, 0.75, -1.0]), np.array([0.5, 0.5, 0.5])
    to_world = T4().look_at(origin=origin.tolist(), target=target.tolist(), up=[0, 1, 0]) \
        @ T4().scale([0.45, 0.45, 1])
    med = {"type": "emissiveheterogeneous", "scale": scale, "albedo": 0.0,
           "sigma_t": {"type": "nanovdbvolume", "data": mi.TensorXf(density),
                       "filter_type": "nearest"},
           "emission": {"type": "nanovdbvolume", "data": mi.TensorXf(emission),
                        "filter_type": "nearest"}}
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "volpathlocal"},
                          "sensor": {"type": "orthographic", "to_world": to_world,
                                     "film": film(size),
                                     "sampler": {"type": "independent", "sample_count": spp}},
                          "cube": unit_cube(med)})
    # The reference: the sensor's own rays at stratified film positions
    sensor = scene.sensors()[0]
    k = 8
    u = (np.arange(size * k) + 0.5) / (size * k)
    fx, fy = np.meshgrid(u, u)
    mi_float = mi.ScalarFloat if not dr.is_jit_v(mi.Float) else mi.Float
    if dr.is_jit_v(mi.Float):
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(fx.ravel(), fy.ravel()),
                                   mi.Point2f(0.5, 0.5))
        o = np.array(ray.o, np.float64).T
        d = np.array(ray.d, np.float64)[:, 0]
    else:
        rows = [sensor.sample_ray(0.0, 0.5, mi.ScalarPoint2f(a, b), mi.ScalarPoint2f(0.5, 0.5))[0]
                for a, b in zip(fx.ravel(), fy.ravel())]
        o = np.array([np.array(r.o) for r in rows], np.float64)
        d = np.array(rows[0].d, np.float64)
    del mi_float
    ref = ray_march(density, emission, scale, o, d).reshape(size, k, size, k).mean(axis=(1, 3))
    imgs = np.stack([render_np(scene, seed=s)[..., 0] for s in range(8)])
    mean, var = imgs.mean(axis=0), imgs.var(axis=0, ddof=1) / len(imgs)
    regions = {"image": np.s_[:, :]}
    h = size // 2
    for name, sl in [("q00", np.s_[:h, :h]), ("q01", np.s_[:h, h:]), ("q10", np.s_[h:, :h]),
                     ("q11", np.s_[h:, h:])]:
        regions[name] = sl
    for name, sl in regions.items():
        z = (mean[sl] - ref[sl]).sum() / np.sqrt(var[sl].sum())
        print(mi.variant(), name, f"render {mean[sl].mean():.5f} reference {ref[sl].mean():.5f} z {z:.2f}")
        assert abs(z) < Z_MAX, (name, z, mean[sl].mean(), ref[sl].mean())


# ---------------------------------------------------------------------------
#  With scattering, surfaces and nested media
# ---------------------------------------------------------------------------

def fire_over_floor(spp, **integrator):
    density, temperature = random_fire(12, seed=7)
    return {
        "type": "scene",
        "integrator": {"type": "volpathlocal", "max_depth": 16, **integrator},
        "sensor": {"type": "perspective", "fov": 45,
                   "to_world": T4().look_at(origin=[1.9, 1.2, 2.3], target=[0.5, 0.25, 0.5],
                                            up=[0, 1, 0]),
                   "film": film(12), "sampler": {"type": "independent", "sample_count": spp}},
        "floor": {"type": "rectangle", "to_world": T4().translate([0.5, -0.02, 0.5])
                  .rotate([1, 0, 0], -90).scale(2.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb",
                                                              "value": [0.7, 0.6, 0.5]}}},
        "cube": unit_cube({
            "type": "emissiveheterogeneous", "scale": 5.0,
            "albedo": {"type": "rgb", "value": [0.8, 0.6, 0.5]},
            "phase": {"type": "hg", "g": 0.3},
            "sigma_t": {"type": "nanovdbvolume", "data": mi.TensorXf(density)},
            "temperature": {"type": "nanovdbvolume", "data": mi.TensorXf(1.5 + 2.0 * temperature)},
            "temperature_scale": 1000.0, "emission_scale": 1e-3}),
    }


def test06_scattering_local_against_global_majorants(variants_rgb):
    # Emission scattered by the medium and reflected by the floor (no other
    # light): the walk's local majorants against one majorant per node of
    # the whole grid (coarse_optical_depth 1e30: every node crossed whole),
    # 2 seeds each, z-test per channel over the image and over the floor.
    spp = 256 if dr.is_jit_v(mi.Float) else 32
    a = np.stack([render_np(mi.load_dict(fire_over_floor(spp)), seed=s) for s in (0, 1)])
    b = np.stack([render_np(mi.load_dict(fire_over_floor(spp, coarse_optical_depth=1e30)),
                            seed=s) for s in (2, 3)])
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    floor = np.s_[:, 9:, :, :]  # the bottom rows see the floor beside the fire
    assert a[floor].mean() > 0.0, "the floor receives no emission"
    for name, sl in [("image", np.s_[:, :, :, :]), ("floor", floor)]:
        va = a[sl].var(axis=0, ddof=1).sum(axis=(0, 1)) / 2
        vb = b[sl].var(axis=0, ddof=1).sum(axis=(0, 1)) / 2
        z = (a[sl].mean(axis=0) - b[sl].mean(axis=0)).sum(axis=(0, 1)) / np.sqrt(va + vb)
        print(mi.variant(), name, a[sl].mean(axis=(0, 1, 2)), b[sl].mean(axis=(0, 1, 2)), z)
        assert np.all(np.abs(z) < Z_MAX), (name, z)


def test07_through_a_thin_dielectric_and_inside_an_absorber(variants_rgb):
    # The slab of test01 (sigma 2, Le 1) seen (a) through a thin glass
    # plate (ior 1.5, normal incidence: it transmits 1 - R', R' = R + (1 -
    # R)^2 R / (1 - R^2), R = 0.04), and (b) nested in a homogeneous
    # absorber (sigma_t 0.5, albedo 0) that fills the space between the
    # camera and the cube (a box from z = -0.5 to 1.5: 0.5 before the slab,
    # absorbing exp(-0.25)) that the emission then also crosses.
    size, spp = 12, 256
    sigma = 2.0
    med = {"type": "emissiveheterogeneous", "sigma_t": constant_density(), "scale": sigma,
           "albedo": 0.0, "emission": 1.0}
    p = -np.expm1(-sigma)
    R = ((1.5 - 1) / (1.5 + 1)) ** 2
    t_glass = 1 - (R + (1 - R) ** 2 * R / (1 - R ** 2))
    glass = {"type": "rectangle", "to_world": T4().translate([0.5, 0.5, -0.3]).scale(0.6),
             "bsdf": {"type": "thindielectric", "int_ior": 1.5, "ext_ior": 1.0}}
    img = render_np(mi.load_dict(slab_scene(med, size, spp, {"glass": glass})))
    check_iid_pixels(img, p * t_glass, "thin dielectric")

    absorber = {"type": "cube", "to_world": T4().translate([0.5, 0.5, 0.5]).scale([0.7, 0.7, 1.0]),
                "bsdf": {"type": "null"},
                "interior": {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.0}}
    # The emissive cube sits inside the absorber: its exterior is the absorber
    scene = slab_scene(med, size, spp, {"absorber": absorber})
    scene["cube"]["exterior"] = dict(absorber["interior"])
    scene["cube"]["exterior"] = {"type": "ref", "id": "absorbing"}
    absorber["interior"]["id"] = "absorbing"
    scene = {k: v for k, v in scene.items() if k != "absorber"}
    scene["absorbing"] = {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.0}
    scene["absorber"] = {**absorber, "interior": {"type": "ref", "id": "absorbing"}}
    img = render_np(mi.load_dict(scene))
    # The sensor starts at z = -1, outside the absorber (z from -0.5): the
    # camera ray crosses 0.5 of it before the cube
    expect = p * np.exp(-0.5 * 0.5)
    check_iid_pixels(img, expect, "nested in an absorber")


# ---------------------------------------------------------------------------
#  Stock integrators, bad input
# ---------------------------------------------------------------------------

class Capture(mi.Appender):
    def __init__(self):
        super().__init__()
        self.messages = []

    def append(self, level, text):
        self.messages.append((level, text))

    def log_progress(self, *args):
        pass


def test08_volpath_renders_without_emission_and_warns_once(variants_rgb):
    med = {"type": "emissiveheterogeneous", "sigma_t": constant_density(), "scale": 2.0,
           "albedo": 0.0, "emission": 1.0}
    scene = slab_scene(med, 8, 16)
    scene["integrator"] = {"type": "volpath"}
    scene["sky"] = {"type": "constant", "radiance": 1.0}
    logger = mi.logger()
    capture = Capture()
    logger.add_appender(capture)
    try:
        loaded = mi.load_dict(scene)
        a = render_np(loaded, seed=0)
        b = render_np(loaded, seed=1)
    finally:
        logger.remove_appender(capture)
    warnings = [t for lvl, t in capture.messages
                if lvl == mi.LogLevel.Warn and "without its emission" in t]
    assert len(warnings) == 1, capture.messages
    # Without emission: the sky through an absorber, exp(-2)
    for img in (a, b):
        assert np.all(np.isfinite(img))
        assert abs(img.mean() - np.exp(-2.0)) < 0.05, img.mean()
    # volpathlocal on a fresh load of the same scene: the emission, no warning
    scene["integrator"] = {"type": "volpathlocal"}
    capture = Capture()
    logger.add_appender(capture)
    try:
        img = render_np(mi.load_dict(scene))
    finally:
        logger.remove_appender(capture)
    assert not [t for lvl, t in capture.messages if "without its emission" in t]
    assert abs(img.mean() - 1.0) < 0.05, img.mean()  # exp(-2) sky + (1 - exp(-2)) emission


@pytest.mark.parametrize("case", ["neither", "both", "vec3_temperature", "color_with_vec3",
                                  "negative_scale", "nan_cutoff"])
def test09_bad_parameters(variant_scalar_rgb, case):
    base = {"type": "emissiveheterogeneous", "sigma_t": constant_density()}
    vec3 = {"type": "nanovdbvolume", "data": mi.TensorXf(np.ones((4, 4, 4, 3), np.float32))}
    cases = {
        "neither": ({}, "exactly one of"),
        "both": ({"emission": 1.0, "temperature": 1000.0}, "exactly one of"),
        "vec3_temperature": ({"temperature": vec3}, "temperature.*3 channels"),
        "color_with_vec3": ({"emission": vec3, "color": {"type": "rgb", "value": [1, 0, 0]}},
                            "already has three"),
        "negative_scale": ({"emission": 1.0, "emission_scale": -1.0}, "emission_scale"),
        "nan_cutoff": ({"temperature": 1000.0, "temperature_cutoff": float("nan")},
                       "temperature_cutoff"),
    }
    extra, message = cases[case]
    with pytest.raises(RuntimeError, match=message):
        mi.load_dict({**base, **extra})


def converted(tmp_path, name, *options):
    """A shared .vdb converted to .nvdb (every grid) by vdb2nvdb"""
    import subprocess
    src = need_shared_data(name) / name
    out = tmp_path / (src.stem + ".nvdb")
    subprocess.run([nanovdb_mitsuba.vdb2nvdb(), *options, str(src), str(out)], check=True,
                   capture_output=True)
    return str(out)


def test10_bad_grids_name_the_file_and_grid(variant_scalar_rgb, tmp_path):
    # A temperature grid missing from the file; a level set as emission
    # (signed distances); a Vec3f grid as temperature. Each error names the
    # file and the grid.
    fire = converted(tmp_path, "usd_density_heat_fog.vdb")
    density = {"type": "nanovdbvolume", "filename": fire, "grid": "density"}
    with pytest.raises(RuntimeError, match=r"usd_density_heat_fog.*temperature"):
        mi.load_dict({"type": "emissiveheterogeneous", "sigma_t": density,
                      "temperature": {"type": "nanovdbvolume", "filename": fire,
                                      "grid": "temperature"}})
    ls = converted(tmp_path, "openvdb_sphere_ls.vdb", "--keep-level-sets")
    with pytest.raises(RuntimeError, match=r"openvdb_sphere_ls.nvdb\" grid .*level set"):
        mi.load_dict({"type": "emissiveheterogeneous", "sigma_t": density,
                      "emission": {"type": "nanovdbvolume", "filename": ls}})
    vel = converted(tmp_path, "houdini_velocity_vec3s.vdb")
    with pytest.raises(RuntimeError, match=r"houdini_velocity_vec3s.nvdb\" grid .*3 channels"):
        mi.load_dict({"type": "emissiveheterogeneous", "sigma_t": density,
                      "temperature": {"type": "nanovdbvolume", "filename": vel}})


def test11_shared_density_heat_file_renders(variant_llvm_ad_rgb, tmp_path):
    # The shared multi-grid file: density and heat from one .nvdb, each its
    # own nanovdbvolume (use_grid_transform: the file's placement), heat as
    # a radiance; the image is finite and glows where heat is.
    fire = converted(tmp_path, "usd_density_heat_fog.vdb")
    grid = {"type": "nanovdbvolume", "filename": fire, "use_grid_transform": True}
    dens = mi.load_dict({**grid, "grid": "density"})
    heat = mi.load_dict({**grid, "grid": "heat"})
    facts = nanovdb_mitsuba.volume_facts(heat)
    assert facts["max"] > 0
    lo, hi = np.array(dens.bbox().min), np.array(dens.bbox().max)
    c, r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    scene = {"type": "scene", "integrator": {"type": "volpathlocal"},
             "sensor": {"type": "perspective", "fov": 40,
                        "to_world": T4().look_at(origin=(c + [0, 0, 3 * r]).tolist(),
                                                 target=c.tolist(), up=[0, 1, 0]),
                        "film": film(24), "sampler": {"type": "independent", "sample_count": 8}},
             "fire": {"type": "cube", "bsdf": {"type": "null"},
                      "to_world": T4().translate(c.tolist()).scale(((hi - lo) / 2 * 1.001).tolist()),
                      "interior": {"type": "emissiveheterogeneous", "sigma_t": dens,
                                   "scale": 4.0 / max(float(np.max(hi - lo)), 1e-6),
                                   "albedo": 0.5, "emission": heat,
                                   "emission_scale": 1.0 / facts["max"]}}}
    img = render_np(mi.load_dict(scene))
    assert np.all(np.isfinite(img)) and img.max() > 0.0
