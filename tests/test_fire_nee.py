"""
Next-event estimation toward emissive media (issue 35: volpathlocal's
emission_sampling; the table: src/media/emission_distribution.h, tested
on its own in tests/test_emission_table.cpp), against independent
references:

- analytic: a uniform emitting, absorbing box (albedo 0) above a diffuse
  floor; the floor's radiance is reflectance / pi x the irradiance
  E(p) = int_box sigma_a Le exp(-sigma_a l(p, x)) cos / r^2 dV, l the
  length of p -> x inside the box, integrated here in numpy (midpoint rule
  on 40^3 points); every mode (collisions only, NEE with MIS, NEE alone)
  per pixel and over the image, z-tests;
- unbiased: a scattering fireball over a floor (a hot core in smoke, the
  smoke lit by its own fire, the floor lit by both), NEE + MIS against the
  collision estimator alone, per region (fire, floor, smoke) and per 8 x 8
  block, z-tests over independent renders;
- bad input: an emission of zero power turns NEE off for that medium and
  says so, and the render is the collision estimator's.
"""

import numpy as np
import pytest
import mitsuba as mi

from conftest import TEST_VARIANTS, _setup_variant, make_stability_grid as make_stab

Z_MAX = 5.0


def T4():
    return mi.ScalarTransform4f()


# The analytic test's variants: two RGB and one spectral (NVDB_TEST_VARIANTS
# replaces them)
@pytest.fixture(params=TEST_VARIANTS or ["scalar_rgb", "llvm_ad_rgb", "scalar_spectral"])
def variants_nee(request):
    _setup_variant(request.param)
    return request.param


LUMA = np.array([0.2126, 0.7152, 0.0722])


def dense(values, filter_type="nearest", to_world=None):
    v = {"type": "nanovdbvolume", "data": mi.TensorXf(np.asarray(values, np.float32)),
         "filter_type": filter_type}
    if to_world is not None:
        v["to_world"] = to_world
    return v


def film(size):
    return {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
            "pixel_format": "rgb"}


def renders(scene, k, spp, seed0=0):
    """k independent renders [k, H, W, 3]"""
    return np.stack([np.array(mi.render(scene, seed=seed0 + 1000 * i, spp=spp),
                              dtype=np.float64)[..., :3] for i in range(k)])


# ---------------------------------------------------------------------------
#  A uniform emitting box over a floor: analytic irradiance
# ---------------------------------------------------------------------------

BOX_LO, BOX_HI = np.array([0.0, 0.1, 0.0]), np.array([1.0, 1.1, 1.0])
SIGMA_A, LE, REFLECTANCE = 2.0, 1.5, 0.5


@pytest.fixture(scope="module")
def box_grids(tmp_path_factory):
    """Constant 16^3 grids of voxels in leaves, density 1, emission LE and
    0; and "tiles": emission LE as OpenVDB's fill makes it, eight active
    tiles of 8^3 voxels in a lower node (no leaf)"""
    d = tmp_path_factory.mktemp("fire_nee")
    box = ("--min", 0, 0, 0, "--max", 15, 15, 15)
    grids = {v: make_stab(d, f"c{i}", *box, "--value", v, dense=False)[0]
             for i, v in enumerate((1.0, LE, 0.0))}
    grids["tiles"], _, summary = make_stab(d, "c_tiles", *box, "--value", LE, "--tiles",
                                           dense=False)
    assert summary["leaves"] == 0, summary
    return grids


def box_scene(grids, mode, size, spp, emission=LE):
    place = T4().translate(BOX_LO.tolist())  # (the box's cells onto the unit cube, then here)
    medium = {"type": "emissiveheterogeneous", "albedo": 0.0, "scale": SIGMA_A,
              "sigma_t": {"type": "nanovdbvolume", "filename": grids[1.0],
                          "filter_type": "nearest", "to_world": place},
              "emission": {"type": "nanovdbvolume", "filename": grids[emission],
                           "filter_type": "nearest", "to_world": place}}
    return {
        "type": "scene",
        "integrator": {"type": "volpathlocal", "emission_sampling": mode},
        "box": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
                "to_world": T4().translate((0.5 * (BOX_LO + BOX_HI)).tolist()).scale(0.5)},
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": REFLECTANCE},
                  "to_world": T4().rotate([1, 0, 0], -90).scale(3.0)},
        "sensor": {"type": "orthographic", "film": film(size),
                   "to_world": T4().look_at(origin=[0.5, 4.0, 0.5], target=[0.5, 0.0, 0.5],
                                            up=[0, 0, 1]) @ T4().scale([1.5, 1.5, 1]),
                   "sampler": {"type": "independent", "sample_count": spp}},
    }


def box_irradiance(p, n=40):
    """E at floor points p [N, 3] (normal +y) from the box, midpoint rule"""
    g = (np.arange(n) + 0.5) / n
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) * (BOX_HI - BOX_LO) + BOX_LO
    dv = np.prod(BOX_HI - BOX_LO) / n ** 3
    out = np.empty(len(p))
    for i, q in enumerate(p):
        d = x - q
        r2 = (d * d).sum(1)
        r = np.sqrt(r2)
        # where the segment q -> x enters the box (slabs; x is inside)
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (BOX_LO - q) / d
            t1 = (BOX_HI - q) / d
        t_in = np.nanmax(np.where(np.isfinite(t0), np.minimum(t0, t1), -np.inf), axis=1)
        t_in = np.clip(t_in, 0.0, 1.0)
        length = r * (1.0 - t_in)
        out[i] = (SIGMA_A * LE * np.exp(-SIGMA_A * length) * d[:, 1] / r / r2).sum() * dv
    return out


def floor_points(scene, size):
    """Per pixel: 2 x 2 points of the floor its footprint covers (the
    sensor's own rays), and whether the pixel's rays miss the box"""
    sensor = scene.sensors()[0]
    pts, clear = [], []
    for j in range(size):
        for i in range(size):
            sub = []
            for (a, b) in ((0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)):
                ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((i + a) / size, (j + b) / size),
                                           mi.Point2f(0.5, 0.5))
                o = np.array(ray.o, dtype=np.float64).ravel()
                dd = np.array(ray.d, dtype=np.float64).ravel()
                sub.append(o + dd * (-o[1] / dd[1]))
            sub = np.array(sub)
            pts.append(sub)
            lo, hi = sub.min(0), sub.max(0)
            # (half a pixel beyond the footprint: no ray of the pixel meets the box)
            clear.append(hi[0] < BOX_LO[0] - 0.1 or lo[0] > BOX_HI[0] + 0.1 or
                         hi[2] < BOX_LO[2] - 0.1 or lo[2] > BOX_HI[2] + 0.1)
    return np.array(pts), np.array(clear)


@pytest.mark.parametrize("mode", ["collisions", "mis", "nee"])
def test01_box_lights_floor_analytic(variants_nee, box_grids, mode):
    check_box_analytic(box_grids, mode, LE)


def check_box_analytic(box_grids, mode, emission):
    # The collision estimator is heavy-tailed here (a floor point sees the
    # box through few of its samples): its pixels are checked in 2 x 2
    # groups, over 16 renders; NEE's per pixel. Spectral variants: the
    # luminance (a flat spectrum's Y is its value; its sRGB is not grey)
    size, k = 12, 16
    spp = 32 if mode == "collisions" else 16
    scene = mi.load_dict(box_scene(box_grids, mode, size, spp, emission=emission))
    pts, clear = floor_points(scene, size)
    expect = (REFLECTANCE / np.pi * box_irradiance(pts.reshape(-1, 3))).reshape(-1, 4).mean(1)
    imgs = renders(scene, k, spp).reshape(k, size * size, 3)
    if mi.is_spectral:
        imgs = (imgs @ LUMA)[..., None]
    if mode == "collisions":  # 2 x 2 groups of clear pixels
        group = (np.arange(size)[:, None] // 2 * (size // 2) + np.arange(size)[None, :] // 2).ravel()
        keep = np.array([clear[group == g].all() for g in range(group.max() + 1)])
        imgs = np.stack([imgs[:, group == g].mean(1) for g in range(group.max() + 1)], 1)[:, keep]
        e = np.array([expect[group == g].mean() for g in range(group.max() + 1)])[keep][:, None]
    else:
        imgs, e = imgs[:, clear], expect[clear][:, None]
    mean = imgs.mean(0)
    se = imgs.std(0, ddof=1) / np.sqrt(k)
    # per pixel (group): within Z_MAX standard errors (and 1e-3 for the quadrature)
    bad = np.abs(mean - e) > Z_MAX * se + 1e-3 * e
    assert not bad.any(), (mode, np.argwhere(bad)[:4], mean[bad.any(1)][:4], e[bad.any(1)][:4])
    # the image: per channel, its mean within Z_MAX standard errors
    whole = imgs.mean(1)
    tol = Z_MAX * whole.std(0, ddof=1) / np.sqrt(k) + 1e-3 * e.mean()
    assert np.all(np.abs(whole.mean(0) - e.mean()) <= tol), (mode, whole.mean(0), e.mean(), tol)


def test02_nee_lowers_the_floors_variance(variant_llvm_ad_rgb, box_grids):
    # The point of NEE (and a check that it runs): on the box's floor, the
    # variance per pixel against the collision estimator's, same spp
    size, spp, k = 12, 16, 4
    var = {}
    for mode in ("collisions", "mis"):
        scene = mi.load_dict(box_scene(box_grids, mode, size, spp))
        _, clear = floor_points(scene, size)
        var[mode] = renders(scene, k, spp).reshape(k, -1, 3)[:, clear].var(0, ddof=1).mean()
    assert var["mis"] < 0.25 * var["collisions"], var  # (measured: 0.13)


# ---------------------------------------------------------------------------
#  A scattering fireball over a floor: NEE + MIS = collisions
# ---------------------------------------------------------------------------

def fireball_grids(n=24):
    g = (np.arange(n) + 0.5) / n - 0.5
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    r = np.sqrt(x * x + y * y + z * z)
    rng = np.random.default_rng(7)
    density = np.clip(1.0 - r / 0.5, 0.0, None) * (0.6 + 0.4 * rng.random(r.shape))
    temperature = np.clip(1.0 - r / 0.3, 0.0, None) * 2.8   # kK: 2800 K at the core
    return density, temperature


def fireball_scene(mode, size, spp, filter_type="trilinear"):
    density, temperature = fireball_grids()
    medium = {"type": "emissiveheterogeneous", "albedo": 0.6, "scale": 8.0,
              "sigma_t": dense(density.transpose(2, 1, 0), filter_type),
              "temperature": dense(temperature.transpose(2, 1, 0), filter_type),
              "temperature_scale": 1000.0, "emission_scale": 0.05}
    return {
        "type": "scene",
        "integrator": {"type": "volpathlocal", "emission_sampling": mode, "max_depth": 16},
        "sky": {"type": "constant", "radiance": 0.02},
        "cube": {"type": "cube", "bsdf": {"type": "null"}, "interior": medium,
                 "to_world": T4().translate([0.5, 0.5, 0.5]).scale(0.5)},
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 0.5},
                  "to_world": T4().translate([0.5, -0.02, 0.5]).rotate([1, 0, 0], -90).scale(3.0)},
        "sensor": {"type": "perspective", "fov": 45, "film": film(size),
                   "to_world": T4().look_at(origin=[0.5, 1.2, 2.6], target=[0.5, 0.3, 0.5],
                                            up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": spp}},
    }


def test03_fireball_mis_equals_collisions(variants_rgb):
    size, spp, k = 16, 32, 8
    ref = renders(mi.load_dict(fireball_scene("collisions", size, spp)), k, spp, seed0=1)
    new = renders(mi.load_dict(fireball_scene("mis", size, spp)), k, spp, seed0=2)
    # regions: the fire (the brightest 5 % of the reference), the rest
    luma = ref.mean(0) @ np.array([0.2126, 0.7152, 0.0722])
    fire = luma >= np.quantile(luma, 0.95)
    def z(a, b):
        return (a.mean() - b.mean()) / np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    for name, m in (("fire", fire), ("rest", ~fire), ("image", np.ones_like(fire))):
        zz = z(new[:, m].mean(1), ref[:, m].mean(1))
        assert abs(zz) < Z_MAX, (name, zz, new[:, m].mean(), ref[:, m].mean())
    # 8 x 8 blocks
    blocks = lambda a: a.reshape(k, size // 8, 8, size // 8, 8, 3).mean((2, 4))
    bn, br = blocks(new), blocks(ref)
    zb = (bn.mean(0) - br.mean(0)) / np.sqrt(bn.var(0, ddof=1) / k + br.var(0, ddof=1) / k + 1e-30)
    assert np.abs(zb).max() < Z_MAX, zb


def two_boxes_scene(grids, mode, size, spp, between):
    """Two emitting boxes of different brightness (NEE picks one by its
    power) over the floor; `between` "fog": the whole scene inside a grey
    homogeneous fog (emission reached through another medium: NEE's shadow
    rays cross it, and a shadow ray that does not end in its target's
    medium counts nothing); "glass": a glass slab between the boxes and the
    floor (emission reached through glass: NEE's shadow rays stop there,
    and the flights after it, a specular chain, keep all they collect)"""
    scene = box_scene(grids, mode, size, spp)
    scene["integrator"]["max_depth"] = 8
    place2 = T4().translate([1.3, 0.1, 0.0])
    second = dict(scene["box"]["interior"], emission_scale=0.3)
    second["sigma_t"] = dict(second["sigma_t"], to_world=place2)
    second["emission"] = dict(second["emission"], to_world=place2)
    scene["box2"] = {"type": "cube", "bsdf": {"type": "null"}, "interior": second,
                     "to_world": T4().translate([1.8, 0.6, 0.5]).scale(0.5)}
    if between == "glass":
        scene["glass"] = {"type": "cube", "bsdf": {"type": "dielectric", "int_ior": 1.5},
                          "to_world": T4().translate([0.9, 0.05, 0.5]).scale([2.0, 0.02, 2.0])}
    if between == "fog":
        scene["fog"] = {"type": "homogeneous", "sigma_t": 0.4, "albedo": 0.7}
        ref = {"type": "ref", "id": "fog"}
        scene["fog_box"] = {"type": "cube", "bsdf": {"type": "null"}, "interior": ref,
                            "to_world": T4().translate([0.9, 1.0, 0.5]).scale([2.0, 1.2, 2.0])}
        for k in ("box", "box2", "floor"):
            scene[k]["exterior"] = ref
    return scene


@pytest.mark.parametrize("between", ["nothing", "fog", "glass"])
def test05_two_media_through_fog_and_glass_mis_equals_collisions(variant_llvm_ad_rgb, box_grids,
                                                                  between):
    size, spp, k = 12, 32, 16
    ref = renders(mi.load_dict(two_boxes_scene(box_grids, "collisions", size, 4 * spp, between)),
                  k, 4 * spp, seed0=3)
    new = renders(mi.load_dict(two_boxes_scene(box_grids, "mis", size, spp, between)), k, spp,
                  seed0=4)
    # both boxes' floors and the whole image: z-tests over the renders
    for name, sl in (("left", np.s_[:, :, : size // 2]), ("right", np.s_[:, :, size // 2:]),
                     ("image", np.s_[:])):
        a, b = new[sl].reshape(k, -1).mean(1), ref[sl].reshape(k, -1).mean(1)
        z = (a.mean() - b.mean()) / np.sqrt(a.var(ddof=1) / k + b.var(ddof=1) / k)
        assert abs(z) < Z_MAX, (between, name, z, a.mean(), b.mean())
    # and NEE does its job: lower variance per pixel at a quarter of the spp
    # (not through glass: its shadow rays stop there)
    if between != "glass":
        assert new.var(0, ddof=1).mean() < ref.var(0, ddof=1).mean() * 4


# ---------------------------------------------------------------------------
#  Bad input
# ---------------------------------------------------------------------------

def warnings_of(fn):
    """Runs fn() with Mitsuba's log caught: (its result, the lines)"""
    seen = []

    class Catch(mi.Appender):
        def append(self, level, text):
            seen.append(text)

        def log_progress(self, *args):
            pass

    catch = Catch()
    mi.logger().add_appender(catch)
    try:
        return fn(), seen
    finally:
        mi.logger().remove_appender(catch)


def test04_zero_power_turns_nee_off_and_says_so(variant_scalar_rgb, box_grids):
    scene = mi.load_dict(box_scene(box_grids, "mis", 8, 4, emission=0.0))
    img, seen = warnings_of(lambda: np.array(mi.render(scene, spp=4)))
    assert np.all(img == 0.0)
    msgs = [t for t in seen if "next-event estimation is off" in t]
    assert len(msgs) == 1 and "zero power" in msgs[0] and "c2.nvdb" in msgs[0], seen


def test06_bad_emission_values_say_so(variant_scalar_rgb, box_grids, tmp_path):
    """NaN and negative emission follow the emission grid's invalid_values;
    a temperature under the cutoff everywhere is zero power. Each names the
    file, and none is silently wrong."""
    box = ("--min", 0, 0, 0, "--max", 15, 15, 15, "--value", LE)
    nan = make_stab(tmp_path, "nan_le", *box, "--set", 3, 4, 5, "nan", dense=False)[0]
    neg = make_stab(tmp_path, "neg_le", *box, "--set", 3, 4, 5, -2.0, dense=False)[0]
    zero = make_stab(tmp_path, "zero_le", *box, "--set", 3, 4, 5, 0.0, dense=False)[0]

    def scene(path, **emission):
        d = box_scene({**box_grids, LE: path}, "mis", 8, 4)
        d["box"]["interior"]["emission"].update(emission)
        return mi.load_dict(d)

    # NaN under "error" (the default): refused, naming the file and the voxel
    with pytest.raises(RuntimeError, match=r"(?s)nan_le\.nvdb.*1 NaN.*\(3, 4, 5\)"):
        scene(nan)
    # ... under "clamp": 0 there, with a warning; the table and the render are
    # those of the grid holding 0 there (same seed: the same image)
    loaded, seen = warnings_of(lambda: scene(nan, invalid_values="clamp"))
    assert any("nan_le.nvdb" in t for t in seen), seen
    clamped, seen = warnings_of(lambda: np.array(mi.render(loaded, seed=3)))
    assert not any("next-event estimation is off" in t for t in seen), seen
    assert np.isfinite(clamped).all() and clamped.max() > 0.0
    assert np.array_equal(clamped, np.array(mi.render(scene(zero), seed=3)))
    # Negative under "error": loads with a warning that names the file, and
    # renders what the grid holds (the table weighs that voxel 0, the
    # collision estimator and NEE's other points carry it); under "clamp":
    # the grid with 0 there, image for image
    loaded, seen = warnings_of(lambda: scene(neg))
    assert any("neg_le.nvdb" in t and "negative" in t for t in seen), seen
    assert np.isfinite(np.array(mi.render(loaded, seed=3))).all()
    assert np.array_equal(np.array(mi.render(scene(neg, invalid_values="clamp"), seed=3)),
                          np.array(mi.render(scene(zero), seed=3)))
    # A temperature under temperature_cutoff everywhere: zero power
    d = box_scene(box_grids, "mis", 8, 4)
    medium = d["box"]["interior"]
    medium["temperature"] = medium.pop("emission")
    medium["temperature_scale"] = 1000.0 / LE  # (every voxel at 1000 K: it would glow)
    medium["temperature_cutoff"] = 2000.0
    img, seen = warnings_of(lambda: np.array(mi.render(mi.load_dict(d), spp=4)))
    off = [t for t in seen if "next-event estimation is off" in t]
    assert len(off) == 1 and "zero power" in off[0] and "c1.nvdb" in off[0], seen
    assert np.all(img == 0.0)


# ---------------------------------------------------------------------------
#  An emission grid in tiles (nanovdb_loader/active_tiles.h)
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("mode", ["mis", "nee"])
def test07_emission_in_tiles_analytic(variants_rgb, box_grids, mode):
    # NEE alone is unbiased only where its table holds every emitting point:
    # here every point is in a tile, so a tile left out of the table fails
    # it (and mis then has nothing but collisions')
    check_box_analytic(box_grids, mode, "tiles")


def test08_emission_in_leaves_and_tiles_equals_collisions(variant_llvm_ad_rgb, box_grids,
                                                          tmp_path):
    # A leaf (the octant at the origin) and seven active tiles of 8^3 voxels
    # of different values beside it (units: the leaf, then the tiles, whose
    # pdfs differ, so that one read for another shows). Against the
    # collision estimator, over the image and per half: NEE alone (its
    # sampling; every emitting point is in its table, nearest filter) on the
    # absorbing box, and NEE with MIS (the pdf of points the flights find)
    # on a scattering one, where the vertices inside the box give MIS weights
    # between 0 and 1. Planted: a tile's unit without the leaves' offset
    # (mis: z 8.6 at these settings; 0.5 without it)
    tiles = []
    for n in range(1, 8):
        tiles += ["--tile", 1, 8 * (n >> 2), 8 * ((n >> 1) & 1), 8 * (n & 1), 0.5 * n * LE]
    mixed, _, summary = make_stab(tmp_path, "mixed", "--min", 0, 0, 0, "--max", 7, 7, 7,
                                  "--value", LE, *tiles, dense=False)
    assert summary["leaves"] == 1 and summary["bbox"] == [0, 0, 0, 15, 15, 15], summary
    grids = dict(box_grids, mixed=mixed)
    size, k = 12, 160

    def scene(mode, spp, albedo):
        d = box_scene(grids, mode, size, spp, "mixed")
        d["box"]["interior"]["albedo"] = albedo
        return mi.load_dict(d)

    for mode, albedo in (("nee", 0.0), ("mis", 0.8)):
        ref = renders(scene("collisions", 64, albedo), k, 64, 1)
        new = renders(scene(mode, 16, albedo), k, 16, 2)
        for name, sl in (("left", np.s_[:, :, : size // 2]), ("right", np.s_[:, :, size // 2:]),
                         ("image", np.s_[:])):
            a, b = new[sl].reshape(k, -1).mean(1), ref[sl].reshape(k, -1).mean(1)
            z = (a.mean() - b.mean()) / np.sqrt(a.var(ddof=1) / k + b.var(ddof=1) / k)
            assert abs(z) < Z_MAX, (mode, name, z, a.mean(), b.mean())
