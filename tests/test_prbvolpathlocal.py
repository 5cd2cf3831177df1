"""prbvolpathlocal (issue 36): Path Replay Backpropagation through the tree's
local majorants (python/nanovdb_mitsuba/prbvolpathlocal.py, its walk through
src/integrators/walk_bridge.cpp).

References: volpath's images (primal), prbvolpath's gradients on the same
scene (their expectations), central finite differences of renders with the
same seeds (single values, and a global scale of float, Vec3f, albedo and
emission grids), the primal pass itself (the adjoint pass must replay its
path: what it subtracts sums to what the primal pass added), and the
volume's own lookups (the rebuilt majorants bound them after an update, and
equal a fresh load's)."""
import re

import numpy as np
import pytest

import drjit as dr
import mitsuba as mi

from conftest import _setup_variant
from test_differentiable import data_key, fd_check, medium_scene


def ball(n=24, seed=1, lopsided=False):
    """A noisy ball in an n^3 box, zero outside it (a sparse tree);
    `lopsided`: five times denser at +x than at -x, so that an image tells
    the axes apart (a ray whose components are swapped sees another one)"""
    rng = np.random.default_rng(seed)
    x = np.linspace(-1, 1, n)
    z, y, x = np.meshgrid(x, x, x, indexing="ij")
    b = np.clip(1.0 - 1.4 * np.sqrt(x * x + y * y + z * z), 0, None)
    if lopsided:
        b = b * (1.0 + 0.667 * x) * 0.8
    return (2.5 * b * rng.uniform(0.5, 1.5, b.shape)).astype(np.float32)


def ball_volume(filter_type="trilinear", lopsided=False, **kw):
    return {"type": "nanovdbvolume", "data": mi.TensorXf(ball(lopsided=lopsided)[..., None]),
            "differentiable": True, "filter_type": filter_type, "max_value": 4.0, **kw}


@pytest.fixture
def ad_rgb():
    _setup_variant("llvm_ad_rgb")
    import nanovdb_mitsuba
    nanovdb_mitsuba.setup()  # (registers prbvolpathlocal in this variant)


def z_scores(a, b):
    """Per column: (mean a - mean b) / its standard error (rows: seeds)"""
    a, b = np.asarray(a), np.asarray(b)
    se = np.sqrt(a.var(axis=0, ddof=1) / len(a) + b.var(axis=0, ddof=1) / len(b))
    return (a.mean(axis=0) - b.mean(axis=0)) / np.maximum(se, 1e-12)


def test01_primal_equals_volpath(ad_rgb):
    """The image in expectation: 4x4 blocks of pixels over 12 seeds each"""
    blocks = {}
    for integrator in ("volpath", "prbvolpathlocal"):
        scene = medium_scene(ball_volume(lopsided=True), integrator, res=16, spp=32)
        rows = []
        for seed in range(12):
            img = np.array(mi.render(scene, seed=seed)).mean(axis=-1)
            rows.append(img.reshape(4, 4, 4, 4).mean(axis=(1, 3)).ravel())
        blocks[integrator] = rows
    z = z_scores(blocks["prbvolpathlocal"], blocks["volpath"])
    print("block z-scores:", np.round(z, 2))
    assert np.abs(z).max() < 4.0
    assert np.mean(blocks["prbvolpathlocal"]) > 0.05


def gradients(integrator, seeds, filter_type="trilinear", spp=16):
    """Per seed: the gradient of a weighted image mean (fixed random weights)
    with respect to "data", summed over 64 blocks of value indices"""
    scene = medium_scene(ball_volume(filter_type), integrator, res=16, spp=spp)
    params = mi.traverse(scene)
    key = data_key(params)
    weights = mi.TensorXf(np.random.default_rng(3).uniform(0, 2, (16, 16, 3)).astype(np.float32))
    n = dr.width(params[key])
    block = np.arange(n) * 64 // n
    rows = []
    for seed in seeds:
        dr.enable_grad(params[key])
        params.update()
        image = mi.render(scene, params, seed=seed)
        dr.backward(dr.mean(image * weights))
        g = np.array(dr.grad(params[key]))
        rows.append(np.bincount(block, weights=g, minlength=64))
        dr.disable_grad(params[key])
    return np.array(rows)


@pytest.mark.parametrize("filter_type", ["trilinear", "stochastic_trilinear"])
def test02_gradients_equal_prbvolpath(ad_rgb, filter_type):
    """In expectation, block by block: prbvolpath's global majorant and the
    walk's local ones give different paths, the same derivative"""
    ours = gradients("prbvolpathlocal", range(16), filter_type)
    ref = gradients("prbvolpath", range(100, 116), filter_type)
    z = z_scores(ours, ref)
    big = np.abs(ref.mean(axis=0)) > 0.05 * np.abs(ref.mean(axis=0)).max()
    print(f"{filter_type}: {big.sum()} blocks, max |z| {np.abs(z).max():.2f}, "
          f"total {ours.mean(axis=0).sum():.4g} vs {ref.mean(axis=0).sum():.4g}")
    assert np.abs(z).max() < 4.5
    # and the total: the same sign and, within its standard error, size
    assert abs(z_scores(ours.sum(axis=1, keepdims=True), ref.sum(axis=1, keepdims=True))[0]) < 4
    assert np.sign(ours.sum(axis=1).mean()) == np.sign(ref.sum(axis=1).mean())


def test03_gradients_match_finite_differences(ad_rgb, make_grid):
    """Single values, the image mean and one pixel (test_differentiable's
    check, through prbvolpathlocal, with the filter optimization uses).
    Weaker than prbvolpath's: a value's change changes its nodes' majorants,
    so the renders of a finite difference track other collisions and agree
    less (standard errors 2-5x prbvolpath's); test04's global scales are the
    sharper check"""
    fd_check("llvm_ad_rgb", make_grid, "voxels", filter_type="stochastic_trilinear",
             integrator="prbvolpathlocal")


def scaled_medium_scene(kind, integrator, spp=32, res=12):
    """The ball with one grid of the kind to scale: sigma_t float, sigma_t
    Vec3f, an albedo grid, or (emissiveheterogeneous) an emission grid;
    "constant": sigma_t one value wherever the ball is (where an
    optimization starts: each node's values at its majorant)"""
    d = ball()
    if kind == "constant":
        d = np.where(d > 0, 1.2, 0).astype(np.float32)
    sigma = {"type": "nanovdbvolume", "data": mi.TensorXf(d[..., None]), "max_value": 4.0,
             "differentiable": kind in ("float", "constant")}
    if kind == "vec3f":
        rgb = np.stack([d, 0.6 * d, 0.3 * d], axis=-1)
        sigma = {"type": "nanovdbvolume", "data": mi.TensorXf(rgb), "max_value": 4.0,
                 "differentiable": True}
    medium = {"type": "heterogeneous", "sigma_t": sigma, "scale": 3.0, "albedo": 0.7}
    if kind == "albedo":
        a = np.where(d > 0, 0.6, 0.0).astype(np.float32)
        medium["albedo"] = {"type": "nanovdbvolume", "data": mi.TensorXf(a[..., None]),
                            "differentiable": True}
    if kind == "emission":
        e = np.where(d > 0, 2.0, 0.0).astype(np.float32)
        medium = {"type": "emissiveheterogeneous", "sigma_t": sigma, "scale": 3.0,
                  "albedo": 0.5,
                  "emission": {"type": "nanovdbvolume", "data": mi.TensorXf(e[..., None]),
                               "differentiable": True}}
    return medium_scene(None, integrator, res=res, spp=spp, medium=medium, point_light=False)


@pytest.mark.parametrize("kind", ["float", "constant", "vec3f", "albedo", "emission"])
def test04_global_scale_matches_finite_differences(ad_rgb, kind):
    """d(image mean)/ds with every value of the grid times (1 + s): the
    gradient's dot product with the values against central differences of
    renders with the same seeds (s = +-0.05), over 12 seeds"""
    scene = scaled_medium_scene(kind, "prbvolpathlocal")
    params = mi.traverse(scene)
    suffix = {"float": "sigma_t.data", "constant": "sigma_t.data", "vec3f": "sigma_t.data", "albedo": "albedo.data",
              "emission": "emission.data"}[kind]
    key = next(k for k in params.keys() if k.endswith(suffix))
    base = np.array(params[key])
    h = 0.05
    ad, fd = [], []
    for seed in range(12):
        params[key] = mi.Float(base)
        dr.enable_grad(params[key])
        params.update()
        dr.backward(dr.mean(mi.render(scene, params, seed=seed)))
        ad.append(float(np.dot(np.array(dr.grad(params[key])), base)))
        dr.disable_grad(params[key])
        values = []
        for s in (1 + h, 1 - h):
            params[key] = mi.Float(base * s)
            params.update()
            values.append(float(np.array(mi.render(scene, params, seed=seed)).mean()))
        fd.append((values[0] - values[1]) / (2 * h))
    params[key] = mi.Float(base)
    params.update()
    ad, fd = np.array(ad), np.array(fd)
    se = np.std(ad - fd, ddof=1) / np.sqrt(len(ad))
    print(f"{kind}: AD {ad.mean():.5g} FD {fd.mean():.5g} (standard error {se:.2g})")
    assert abs(fd.mean()) > 5 * se  # the derivative is measured, not noise
    assert abs(ad.mean() - fd.mean()) <= 4 * se + 0.03 * abs(fd.mean())


@pytest.mark.parametrize("emissive", [False, True])
def test05_adjoint_pass_replays_the_primal_path(ad_rgb, emissive):
    """The adjoint pass starts from the primal pass's radiance and subtracts
    every contribution as it meets it again: where it sees the same
    collisions, voxels and shadow rays, what is left at the end is 0 to
    float rounding, lane by lane"""
    if emissive:
        scene = scaled_medium_scene("emission", "prbvolpathlocal", spp=4, res=16)
    else:
        scene = medium_scene(ball_volume("stochastic_trilinear"), "prbvolpathlocal",
                             res=16, spp=4)
    integrator, sensor = scene.integrator(), scene.sensors()[0]
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith(".data"))
    dr.enable_grad(params[key])
    params.update()

    def pass_(mode, state_in=None):
        sampler, _ = integrator.prepare(sensor, 5, 4)
        ray, _, _ = integrator.sample_rays(scene, sensor, sampler)
        with dr.suspend_grad(when=mode == dr.ADMode.Primal), \
                dr.resume_grad(when=mode != dr.ADMode.Primal):
            return integrator.sample(mode, scene, sampler, ray,
                                     None if mode == dr.ADMode.Primal else mi.Spectrum(1.0),
                                     state_in, mi.Bool(True))

    L, valid, _, _ = pass_(dr.ADMode.Primal)
    L = dr.detach(L)
    dr.eval(L)
    _, _, _, left = pass_(dr.ADMode.Backward, L)
    L, left = np.array(L).T, np.array(left).T  # (lanes, channels)
    assert L.shape[0] == 16 * 16 * 4 and L.max() > 0.1
    worst = np.abs(left).max(axis=-1) / np.maximum(np.abs(L).max(axis=-1), 1e-3)
    print(f"emissive={emissive}: {L.shape[0]} lanes, radiance left after the replay: "
          f"largest {np.abs(left).max():.2e} ({worst.max():.2e} of its lane's)")
    assert worst.max() < 1e-4
    assert np.count_nonzero(np.array(dr.grad(params[key]))) > 0


def test06_rebuilt_majorants_bound_lookups(ad_rgb):
    """After an update that raises some values 100x and sets others to 0,
    the walk's majorant at a tentative collision bounds the lookup there
    (10^6 rays through the box): the per-node majorants follow the values"""
    from nanovdb_mitsuba.walk_bridge import WalkBridge, medium_index
    rng = np.random.default_rng(4)
    m = mi.load_dict({"type": "heterogeneous", "scale": 2.0, "sigma_t": {
        "type": "nanovdbvolume", "data": mi.TensorXf(ball()[..., None]),
        "differentiable": True, "filter_type": "trilinear"}})
    params = mi.traverse(m)
    key = data_key(params)
    values = np.array(params[key])
    change = rng.uniform(0, 1, values.shape)
    values = np.where(change < 0.1, values * 100, np.where(change < 0.4, 0, values))
    params[key] = mi.Float(values.astype(np.float32))
    params.update()

    bridge = WalkBridge.for_variant()
    assert bridge.tracked(m) == 1
    n = 1_000_000
    o = rng.uniform(-0.2, 1.2, (n, 3)).astype(np.float32)
    dirs = rng.uniform(0, 1, (n, 3)).astype(np.float32) - o
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*dirs.T))
    u = mi.Float(rng.uniform(0, 1, n).astype(np.float32))
    for coarse in (0.0, 2.0):  # every leaf; thin nodes crossed whole
        t, majorant = bridge.next_collision(medium_index(m), ray, mi.Float(dr.inf), u,
                                            mi.Bool(True), coarse_depth=coarse)
        hit = dr.isfinite(t)
        mei = dr.zeros(mi.MediumInteraction3f, n)
        mei.p = ray(dr.select(hit, t, 0))
        _, _, sigma_t = m.get_scattering_coefficients(mei, hit)
        majorant, sigma_t, hit = (np.array(majorant), np.array(sigma_t[0]), np.array(hit))
        print(f"coarse {coarse}: {hit.sum()} tentative collisions; lookup / majorant at "
              f"most {(sigma_t[hit] / majorant[hit]).max():.4f}; largest majorant "
              f"{majorant.max():.1f}")
        assert hit.sum() > 100_000
        assert np.all(sigma_t[hit] <= majorant[hit] * (1 + 1e-5))
        assert majorant.max() >= 2.0 * 0.9 * values.max()


@pytest.mark.parametrize("policy", ["clamp", "error"])
def test07_update_with_bad_values_follows_the_policy(ad_rgb, policy):
    """NaN and negative values from an optimizer step: invalid_values="clamp"
    renders them as 0 (the same image, same seed, as zeros put there), and
    "error" refuses the update, naming the volume and the problem"""
    scene = medium_scene(ball_volume(invalid_values=policy), "prbvolpathlocal", res=12, spp=8)
    params = mi.traverse(scene)
    key = data_key(params)
    values = np.array(params[key])
    bad = values.copy()
    bad[::7] = np.nan
    bad[3::7] = -1.0
    zeros = values.copy()
    zeros[::7] = 0
    zeros[3::7] = 0
    params[key] = mi.Float(bad)
    if policy == "error":
        with pytest.raises(RuntimeError, match=r"nanovdbvolume.*NaN"):
            params.update()
        return
    params.update()
    image = np.array(mi.render(scene, params, seed=3))
    params[key] = mi.Float(zeros)
    params.update()
    assert np.all(np.isfinite(image))
    np.testing.assert_array_equal(image, np.array(mi.render(scene, params, seed=3)))


def test08_non_differentiable_volume_names_the_parameter(ad_rgb, make_grid):
    """A nanovdbvolume loaded without differentiable=true has no `data`
    parameter: asking for it (to read, or to set from an optimizer) raises a
    KeyError that names the key, the volume's file and the fix
    (nanovdb_mitsuba/params.py); other missing keys keep Mitsuba's error"""
    path, _ = make_grid("lower_tiles")
    scene = medium_scene({"type": "nanovdbvolume", "filename": path}, "prbvolpathlocal",
                         res=8, spp=1)
    params = mi.traverse(scene)
    key = "cube.interior_medium.sigma_t.data"
    assert key.replace(".data", ".grid_type") in params
    for access in (lambda: params[key], lambda: params.__setitem__(key, mi.Float(1.0))):
        with pytest.raises(KeyError) as e:
            access()
        message = str(e.value)
        assert key in message and path in message and "differentiable=true" in message
        assert "\"differentiable\": True" in message
    with pytest.raises(KeyError) as e:
        params["cube.interior_medium.sigma_t.no_such_key"]
    assert "differentiable" not in str(e.value)
    # loaded with differentiable=true, the same key is the values
    scene = medium_scene(ball_volume(), "prbvolpathlocal", res=8, spp=1)
    assert dr.width(mi.traverse(scene)[key]) > 0


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "cuda_ad_rgb"])
@pytest.mark.parametrize("name", ["openvdb_smoke1_fog.vdb", "usd_density_heat_fog.vdb",
                                  "warp_vec3f_zip_32.3.3.nvdb", "warp_onindex_2grids_zip_32.6.1.nvdb"])
def test10_backend_rebuild_equals_the_host_one(variant, name):
    """After updates (values raised 100x, set to 0, scaled at random; then
    the same reversed), the majorants rebuilt on the backend
    (majorant_rebuild="backend", the default; the second rebuild a replay
    of the first's kernels) equal those the loader builds on the host
    ("host") from the same values: real files (float, Vec3f, an index
    grid's blind data), the walk's first tentative collision and its
    majorant the same, bit for bit, on 2 x 10^5 rays after the second; the
    mean bound (local_majorant_ratio) to 1e-5 after each.
    (test_majorant_walk checks the table itself, word for word, on LLVM.)
    LLVM, and CUDA where a GPU is (the offline GPU kit)."""
    from conftest import need_shared_data
    _setup_variant(variant)
    import nanovdb_mitsuba
    nanovdb_mitsuba.setup()
    from nanovdb_mitsuba.walk_bridge import WalkBridge, medium_index
    path = need_shared_data(name) / name
    volumes = [mi.load_dict({
        "type": "nanovdbvolume", "filename": str(path), "differentiable": True,
        "filter_type": "trilinear", "invalid_values": "clamp", "max_value": 1e6,
        "majorant_rebuild": where}) for where in ("backend", "host")]
    from nanovdb_mitsuba.facts import volume_facts
    # (the plan took the tree: else both would rebuild on the host)
    assert [volume_facts(v)["majorant_rebuild"] for v in volumes] == ["backend", "host"]
    rng = np.random.default_rng(11)
    values = np.array(mi.traverse(volumes[0])["data"])
    # (a scale that gives the rays an optical depth of about 20)
    box = volumes[0].bbox()
    lo, hi = np.array(box.min), np.array(box.max)
    scale = 20.0 / (np.linalg.norm(hi - lo) * max(values.mean(), 1e-6))
    media = [mi.load_dict({"type": "heterogeneous", "sigma_t": v, "scale": scale})
             for v in volumes]
    change = rng.uniform(0, 1, values.shape)
    values = np.where(change < 0.1, np.abs(values) * 100,
                      np.where(change < 0.4, 0, values * rng.uniform(0, 3, values.shape)))
    # Two updates: the backend records its rebuild's kernels at the first
    # and replays them at the second (kernel_replay.h), whose values are
    # the first's swapped around: other nodes raised and zeroed
    for update in (values, values[::-1].copy()):
        for v in volumes:
            params = mi.traverse(v)
            params["data"] = mi.Float(update.astype(np.float32))
            params.update()
        ratios = [float(mi.traverse(v)["local_majorant_ratio"]) for v in volumes]
        assert ratios[0] == pytest.approx(ratios[1], rel=1e-5)
    assert volume_facts(volumes[0])["majorant_rebuild_replays"] == 1
    bridge = WalkBridge.for_variant()
    assert all(bridge.tracked(m) == 1 for m in media)
    n = 200_000
    o = lo + (hi - lo) * rng.uniform(-0.2, 1.2, (n, 3))
    d = lo + (hi - lo) * rng.uniform(0, 1, (n, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*o.astype(np.float32).T), mi.Vector3f(*d.astype(np.float32).T))
    u = mi.Float(rng.uniform(0, 1, n).astype(np.float32))
    for coarse in (0.0, 2.0):
        out = [[np.array(x) for x in bridge.next_collision(medium_index(m), ray, mi.Float(dr.inf),
                                                           u, mi.Bool(True), coarse_depth=coarse)]
               for m in media]
        hit = np.isfinite(out[0][0])
        assert hit.sum() > n // 10
        np.testing.assert_array_equal(out[0][0], out[1][0])
        np.testing.assert_array_equal(out[0][1], out[1][1])


def test11_majorant_rebuild_names_a_bad_choice(ad_rgb):
    """majorant_rebuild takes "backend" or "host"; another value is refused,
    named with the choices"""
    with pytest.raises(RuntimeError, match=r'invalid value "gpu" for majorant_rebuild.*'
                                           r'"backend" or "host"'):
        mi.load_dict(dict(ball_volume(), majorant_rebuild="gpu"))


@pytest.mark.parametrize("variant, majorant_rebuild", [("llvm_ad_rgb", "backend"),
                                                       ("llvm_ad_rgb", "host"),
                                                       ("cuda_ad_rgb", "backend")])
def test12_frozen_step_follows_updates(variant, majorant_rebuild):
    """A step (render + backward) frozen with dr.freeze, Mitsuba's way of
    leaving out the Python tracing of the PRB loops, replayed after updates
    that move the values (100x, half the box 0, scaled at random: the
    majorants and max() all change): its image and gradient equal an
    unfrozen step's with the same seed on a twin scene, and it was
    replayed, not re-recorded. Recorded at small values, then replayed at
    100x: a replay that kept the recording's table or loop bounds differs.
    LLVM, and CUDA where a GPU is (the offline GPU kit)"""
    _setup_variant(variant)
    import nanovdb_mitsuba
    nanovdb_mitsuba.setup()
    volume = dict(ball_volume("stochastic_trilinear"), majorant_rebuild=majorant_rebuild)
    del volume["max_value"]  # (max() follows the values)
    scenes = [medium_scene(volume, "prbvolpathlocal", res=16, spp=4) for _ in range(2)]
    key = data_key(mi.traverse(scenes[0]))
    weights = mi.TensorXf(np.random.default_rng(3).uniform(0, 2, (16, 16, 3)).astype(np.float32))

    def step(scene, seed):
        params = mi.traverse(scene)
        params.keep(key)
        image = mi.render(scene, params, seed=seed)
        dr.backward(dr.mean(image * weights))
        return image

    frozen = dr.freeze(step)
    # (the values in the index grid's order: its first half is a part of the box)
    d = np.array(mi.traverse(scenes[0])[key])
    rng = np.random.default_rng(5)
    half = np.arange(len(d)) < len(d) // 2
    # Recorded at the first four, replayed at the others but at most one:
    # 100x, then up to 300x the values. (Dr.Jit records the first step,
    # again once the sampler's arrays exist, and now and then once more
    # with no change in the inputs' variables: upstream prbvolpath with
    # gridvolume too, 2 or 3 recordings in 12 steps)
    first = [0.5 * d, np.where(half, 0, d), d * rng.uniform(0, 3, len(d)), 0.8 * d]
    then = [100 * d, np.where(half, d, 0), 0 * d, 100 * d * rng.uniform(0, 3, len(d))]
    steps = first + then * 2
    out, recordings = {}, []
    # (the frozen steps first, then the unfrozen ones on the twin: steps of
    # another scene in between make Dr.Jit record more often)
    for scene, f in zip(scenes, (frozen, step)):
        params = mi.traverse(scene)
        for i, values in enumerate(steps):
            params[key] = mi.Float(values.astype(np.float32))
            params.update()
            dr.enable_grad(params[key])
            params.update()
            image = f(scene, dr.opaque(mi.UInt32, 7 * i))
            out.setdefault(i, []).append((np.array(image), np.array(dr.grad(params[key]))))
            dr.disable_grad(params[key])
            if f is frozen:
                recordings.append(frozen.n_recordings)
    for i in range(len(steps)):
        (img_f, g_f), (img, g) = out[i]
        assert np.abs(img).max() > 0
        np.testing.assert_allclose(img_f, img, rtol=1e-5, atol=1e-6 * np.abs(img).max())
        np.testing.assert_allclose(g_f, g, rtol=0, atol=1e-5 * np.abs(g).max())
    print("recordings after each step:", recordings)
    assert recordings[-1] <= 3 and recordings[-1] - recordings[3] <= 1


def test13_update_inside_a_frozen_function_is_refused(ad_rgb):
    """params.update() of "data" inside dr.freeze: the bounds of new values
    are read back on the host, which a recording cannot replay; the error
    names the file and says to update before the call"""
    volume = dict(ball_volume("stochastic_trilinear"))
    scene = medium_scene(volume, "prbvolpathlocal", res=8, spp=1)
    key = data_key(mi.traverse(scene))

    def step(scene, values):
        params = mi.traverse(scene)
        params[key] = values
        params.update()
        return mi.render(scene, params, seed=0)

    values = mi.traverse(scene)[key] * 2.0
    with pytest.raises(RuntimeError) as e:
        dr.freeze(step)(scene, values)
    # (Dr.Jit raises its own error, caused by ours)
    chain, err = [], e.value
    while err is not None:
        chain.append(str(err))
        err = err.__cause__
    assert any(re.search(r'"data: a 24 x 24 x 24 tensor.*": "data" was updated inside a frozen '
                         r'function.*Call params.update\(\) before the frozen function', m)
               for m in chain), chain


@pytest.mark.parametrize("variant", ["llvm_ad_mono", "llvm_ad_spectral"])
def test14_mono_and_spectral(variant):
    """The other colour variants: the image in expectation equals volpath's
    (4x4 blocks of pixels, 8 seeds each), and the gradient of the image
    mean with respect to "data", summed over the values, equals
    prbvolpath's within its standard error"""
    _setup_variant(variant)
    import nanovdb_mitsuba
    nanovdb_mitsuba.setup()
    blocks, totals = {}, {}
    for integrator, reference in (("prbvolpathlocal", "volpath"), ("prbvolpath", None)):
        scene = medium_scene(ball_volume(lopsided=True), integrator, res=16, spp=16)
        params = mi.traverse(scene)
        key = data_key(params)
        rows, grads = [], []
        for seed in range(8):
            dr.enable_grad(params[key])
            params.update()
            image = mi.render(scene, params, seed=seed)
            dr.backward(dr.mean(image))
            img = np.array(image).mean(axis=-1)
            rows.append(img.reshape(4, 4, 4, 4).mean(axis=(1, 3)).ravel())
            grads.append([float(np.sum(np.array(dr.grad(params[key]))))])
            dr.disable_grad(params[key])
        totals[integrator] = grads
        if reference:
            ref = medium_scene(ball_volume(lopsided=True), reference, res=16, spp=16)
            blocks[reference] = [np.array(mi.render(ref, seed=100 + s)).mean(axis=-1)
                                 .reshape(4, 4, 4, 4).mean(axis=(1, 3)).ravel() for s in range(8)]
            blocks[integrator] = rows
    z = z_scores(blocks["prbvolpathlocal"], blocks["volpath"])
    zg = z_scores(totals["prbvolpathlocal"], totals["prbvolpath"])[0]
    print(f"{variant}: block z max {np.abs(z).max():.2f}, gradient total z {zg:.2f} "
          f"({np.mean(totals['prbvolpathlocal']):.4g} vs {np.mean(totals['prbvolpath']):.4g})")
    assert np.abs(z).max() < 4.0
    assert np.mean(blocks["prbvolpathlocal"]) > 0.05
    assert abs(zg) < 4.0 and np.mean(totals["prbvolpath"]) != 0


def test15_registered_in_every_ad_variant_switched_to():
    """mi.set_variant from one *_ad_* variant to another: prbvolpathlocal
    derives from the new variant's integrator (planted, the module reloaded
    before Mitsuba's own AD integrators: scenes in llvm_ad_spectral and
    llvm_ad_mono loaded it as no integrator at all)"""
    import nanovdb_mitsuba  # noqa: F401 (registers it on every switch)
    seen = []
    for variant in ("llvm_ad_rgb", "llvm_ad_spectral", "llvm_ad_rgb", "scalar_rgb",
                    "llvm_ad_mono", "llvm_ad_rgb"):
        if variant not in mi.variants():
            continue
        mi.set_variant(variant)
        if variant.startswith("scalar"):
            continue
        scene = mi.load_dict({"type": "scene", "integrator": {"type": "prbvolpathlocal"}})
        assert scene.integrator() is not None, f"{variant}: prbvolpathlocal loaded as None"
        assert type(scene.integrator()).__name__ == "PRBVolpathLocalIntegrator"
        seen.append(variant)
    assert len(seen) >= 2, seen


def test16_frozen_step_of_an_emissive_medium(ad_rgb):
    """The emission grid's values updated between frozen steps: the same
    check as test12, for emissiveheterogeneous (emission at collisions).
    Planted, its box left out of Dr.Jit's traversal (BoundingBox is no
    Dr.Jit structure, and MI_TRAVERSE_CB skipped it silently): the
    recording refused ("was read ... but it had not yet been initialized")"""
    scenes = [scaled_medium_scene("emission", "prbvolpathlocal", spp=4, res=12) for _ in range(2)]
    key = next(k for k in mi.traverse(scenes[0]).keys() if k.endswith("emission.data"))

    def step(scene, seed):
        params = mi.traverse(scene)
        params.keep(key)
        image = mi.render(scene, params, seed=seed)
        dr.backward(dr.mean(image))
        return image

    frozen = dr.freeze(step)
    d = np.array(mi.traverse(scenes[0])[key])
    out = {}
    for scene, f in zip(scenes, (frozen, step)):
        params = mi.traverse(scene)
        for i, factor in enumerate((0.5, 0.8, 100.0, 0.0)):
            params[key] = mi.Float((d * factor).astype(np.float32))
            params.update()
            dr.enable_grad(params[key])
            params.update()
            image = f(scene, dr.opaque(mi.UInt32, i))
            out.setdefault(i, []).append((np.array(image), np.array(dr.grad(params[key]))))
            dr.disable_grad(params[key])
    for (img_f, g_f), (img, g) in out.values():
        np.testing.assert_allclose(img_f, img, rtol=1e-5, atol=1e-6 * np.abs(img).max())
        np.testing.assert_allclose(g_f, g, rtol=0, atol=1e-5 * np.abs(g).max())


def test17_frozen_render_with_emission_sampling(ad_rgb):
    """volpathlocal's next-event estimation toward an emissive medium in a
    frozen render, the emission grid updated between calls (0.5x, up to
    300x at random, 0, 2x): from the second call on, each render equals an
    unfrozen one with the same seed. (The first call records without the
    emission table, whose build reads numbers back: its emission comes by
    collisions. The second builds the table first, and records again.)
    Planted: the table not rebuilt before a replay (the images differ);
    the volume's table of active tiles left out of the traversal (Dr.Jit
    refused the recording)"""
    scenes = [scaled_medium_scene("emission", "volpathlocal", spp=4, res=12) for _ in range(2)]
    key = next(k for k in mi.traverse(scenes[0]).keys() if k.endswith("emission.data"))
    frozen = dr.freeze(lambda scene, seed: mi.render(scene, seed=seed))
    d = np.array(mi.traverse(scenes[0])[key])
    rng = np.random.default_rng(4)
    factors = [1.0, 0.5, 0.8, 100 * rng.uniform(0, 3, len(d)), 0.0, 2.0, 1.5, 0.7]
    images = {}
    for scene, f in zip(scenes, (frozen, lambda scene, seed: mi.render(scene, seed=seed))):
        params = mi.traverse(scene)
        for i, factor in enumerate(factors):
            params[key] = mi.Float((d * factor).astype(np.float32))
            params.update()
            images.setdefault(i, []).append(np.array(f(scene, dr.opaque(mi.UInt32, i))))
    for i in range(1, len(factors)):
        img_f, img = images[i]
        assert np.abs(img).max() > 0
        np.testing.assert_allclose(img_f, img, rtol=1e-5, atol=1e-6 * np.abs(img).max(),
                                   err_msg=f"call {i}")
    # (recorded: the first call, the second (the table now exists), the
    # call after the emission went to 0 (no table: nothing to sample) and
    # now and then once more, as Dr.Jit does; the others replayed)
    print("recordings:", frozen.n_recordings)
    assert frozen.n_recordings <= 5
