"""Index grids and differentiable volumes (issue 20).

nanovdbvolume with differentiable=true keeps its grid's tree as a NanoVDB
OnIndex grid and its active values (voxels and tiles) as one Float array,
exposed by mi.traverse as the differentiable "data"; OnIndex grids of files
(fVDB, Warp) read their values from a blind channel. The references:

* Warp's NanoVDB accessor (tools/warp_onindex_reference.py wrote what it
  reads in the shared Warp file to tests/data/warp_onindex_reference.json);
* the same grid read as a float grid (differentiable=false): every lookup
  equal, bit for bit;
* gridvolume on the grid's dense export, same scene and seed: prbvolpath's
  gradients of the active voxels equal, and a tile's gradient is the sum of
  its voxels';
* finite differences of prbvolpath renders, forward and reverse mode, with a
  tolerance from the spread of the estimates over seeds;
* after params.update(): max() bounds every lookup, and volpathlocal (which
  walks the per-node majorants) still renders what volpath renders.
"""

import json
import os

import numpy as np
import pytest

import drjit as dr
import mitsuba as mi

from conftest import eval_points, load_dense, load_nvdb, need_shared_data, _setup_variant

HERE = os.path.dirname(os.path.abspath(__file__))
WARP_FILE = "warp_onindex_2grids_zip_32.6.1.nvdb"


def data_key(params):
    keys = [k for k in params.keys() if k.endswith("data")]
    assert len(keys) == 1, keys
    return keys[0]


def voxel_centres(volume):
    """Local positions of every voxel centre of the volume's box, and the
    voxels (relative to the box minimum), x fastest"""
    res = np.array(mi.traverse(volume)["index_dims"])
    ijk = np.stack(np.meshgrid(*[np.arange(r) for r in res], indexing="ij"), -1).reshape(-1, 3)
    return (ijk + 0.5) / res, ijk


def data_coordinates(volume):
    """Which voxel each entry of "data" stands for (relative to the box
    minimum; -1: a tile's entry covers no single voxel), found by writing
    1..N into data and reading every voxel centre with nearest lookups"""
    params = mi.traverse(volume)
    key = data_key(params)
    saved = type(params[key])(params[key])
    n = dr.width(params[key])
    params[key] = mi.Float(np.arange(1, n + 1, dtype=np.float32))
    params.update()
    local, ijk = voxel_centres(volume)
    read = eval_points(volume, local).astype(np.int64)
    params[key] = saved
    params.update()
    owner = np.full((n, 3), -1)
    counts = np.bincount(read, minlength=n + 1)
    single = read[(read > 0)]
    for entry, voxel in zip(read, ijk):
        if entry > 0 and counts[entry] == 1:
            owner[entry - 1] = voxel
    return owner, read, counts[1:]


# ---------------------------------------------------------------------------
#  Index grids from files: the shared Warp file
# ---------------------------------------------------------------------------

def test01_warp_index_grids_read_as_warp(variants_rgb):
    path = str(need_shared_data(WARP_FILE) / WARP_FILE)
    with open(os.path.join(HERE, "data", "warp_onindex_reference.json")) as f:
        ref = json.load(f)
    for grid in ref["grids"]:
        for component in (0, 5):
            vol = load_nvdb(path, grid=grid["name"], filter_type="nearest",
                            blind_component=component)
            p = mi.traverse(vol)
            assert p["grid_type"] == 20  # OnIndex
            lo, res = np.array(p["index_min"]), np.array(p["index_dims"])
            voxels = np.array([v[:3] for v in grid["voxels"]], float)
            want = np.array([v[4 + component] for v in grid["voxels"]], np.float32)
            probes = np.array([v[:3] for v in grid["inactive_probes"]], float)
            inside = np.all((probes >= lo) & (probes < lo + res), axis=1)
            got = eval_points(vol, (voxels - lo + 0.5) / res)
            assert np.array_equal(got, want), (grid["name"], component)
            # inactive voxels in the box: index 0, the background (0)
            assert np.all(eval_points(vol, (probes[inside] - lo + 0.5) / res) == 0.0)
            assert vol.max() == pytest.approx(want.max())
            if dr.is_jit_v(mi.Float):
                assert dr.width(p[data_key(p)]) == len(voxels)
            # the tree without its blind data: no copy of the 6 floats per voxel
            assert p["value_bytes"] == 4 * len(voxels)


def test02_blind_channel_errors(variant_scalar_rgb):
    path = str(need_shared_data(WARP_FILE) / WARP_FILE)
    with pytest.raises(RuntimeError, match=r'blind channel "fvdb_jdatafloat32" holds 6 '
                                           r'float\(s\) per value; component 6 does not exist'):
        load_nvdb(path, grid="grid-0", blind_component=6)
    with pytest.raises(RuntimeError, match=r'has no blind channel "density" \(its channels: '
                                           r'"fvdb_jdatafloat32"\)'):
        load_nvdb(path, grid="grid-1", blind_channel="density")


# ---------------------------------------------------------------------------
#  Float grids made index grids: the same lookups
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["fog_sphere", "lower_tiles", "upper_tiles"])
@pytest.mark.parametrize("value_type", ["float", "fp8"])
def test03_index_grid_reads_equal_the_grid(variants_rgb, make_grid, name, value_type):
    nvdb, _ = make_grid(name, value_type=value_type)
    rng = np.random.default_rng(3)
    points = np.concatenate([rng.uniform(-0.1, 1.1, (20000, 3)), voxel_centres(load_nvdb(nvdb))[0]])
    for filter_type in ("nearest", "trilinear"):
        plain = load_nvdb(nvdb, filter_type=filter_type)
        diff = load_nvdb(nvdb, filter_type=filter_type, differentiable=True)
        assert mi.traverse(diff)["grid_type"] == 20
        assert diff.max() == plain.max()
        a, b = eval_points(plain, points), eval_points(diff, points)
        assert np.array_equal(a, b), (filter_type, np.abs(a - b).max())


def test04_data_holds_active_values_in_documented_order(variant_llvm_ad_rgb, make_grid):
    nvdb, _ = make_grid("lower_tiles")
    vol = load_nvdb(nvdb, filter_type="nearest", differentiable=True)
    owner, read, covered = data_coordinates(vol)
    # every entry is read somewhere; tiles (8^3 voxels each, active or not) come first,
    # then single voxels; no voxel reads the background inside the active leaves
    assert np.all(covered > 0)
    tiles = np.nonzero(covered > 1)[0]
    voxels = np.nonzero(covered == 1)[0]
    assert len(tiles) > 0 and np.all(covered[tiles] == 512)
    assert tiles.max() < voxels.min()
    # within a leaf, voxel offsets n = x << 6 | y << 3 | z ascend with the index
    lo = np.array(mi.traverse(vol)["index_min"])
    absolute = owner[voxels] + lo
    leaf = absolute >> 3
    n = (absolute[:, 0] & 7) << 6 | (absolute[:, 1] & 7) << 3 | (absolute[:, 2] & 7)
    for key in np.unique(leaf, axis=0):
        sel = np.all(leaf == key, axis=1)
        assert np.all(np.diff(n[sel]) > 0)
        assert np.all(np.diff(voxels[sel]) == 1)  # a leaf's values are contiguous


# ---------------------------------------------------------------------------
#  Gradients
# ---------------------------------------------------------------------------

def medium_scene(volume, integrator="prbvolpath", res=24, spp=16, scale=3.0, max_depth=6):
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": max_depth},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at([0.4, 0.3, 3.2], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "emitter": {"type": "constant"},
        "light": {"type": "point", "position": [2, 2, 2], "intensity": {"type": "rgb", "value": 8}},
        "cube": {"type": "cube", "bsdf": {"type": "null"},
                 "interior": {"type": "heterogeneous", "sigma_t": volume, "scale": scale,
                              "albedo": 0.7}},
    })


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_mono"])
@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
def test05_gradients_equal_gridvolume(make_grid, variant, filter_type):
    _setup_variant(variant)
    nvdb, vol = make_grid("lower_tiles")
    sparse = load_nvdb(nvdb, filter_type=filter_type, differentiable=True, wrap_mode="clamp")
    dense = load_dense(vol, filter_type=filter_type)
    owner, read, covered = data_coordinates(sparse)
    grads = []
    for volume in (sparse, dense):
        scene = medium_scene(volume)
        params = mi.traverse(scene)
        key = data_key(params)
        dr.enable_grad(params[key])
        params.update()
        image = mi.render(scene, params, seed=7)
        dr.backward(dr.mean(image))
        grads.append(np.array(dr.grad(params[key])).ravel())
    g_sparse, g_dense = grads
    res = np.array(mi.traverse(sparse)["index_dims"])
    dense_grid = g_dense.reshape(res[2], res[1], res[0])  # z, y, x
    flat = dense_grid.transpose(2, 1, 0).ravel()           # x-major like voxel_centres' order
    scale = np.abs(g_dense).max()
    assert scale > 0
    single = covered == 1
    want = flat[np.ravel_multi_index(owner[single].T, res)]
    np.testing.assert_allclose(g_sparse[single], want, rtol=0, atol=2e-4 * scale)
    # a tile's one value gets the sum of its voxels' gradients
    tiles = np.nonzero(covered > 1)[0]
    for t in tiles[:8]:
        assert g_sparse[t] == pytest.approx(flat[read == t + 1].sum(), abs=2e-3 * scale)
    # and voxels outside the active values (the background) have none here
    assert np.count_nonzero(g_sparse) > 0.5 * len(g_sparse)


def fd_check(variant, mode, make_grid, filter_type="trilinear"):
    _setup_variant(variant)
    nvdb, _ = make_grid("lower_tiles")
    volume = load_nvdb(nvdb, filter_type=filter_type, differentiable=True, wrap_mode="clamp")
    owner, read, covered = data_coordinates(volume)
    scene = medium_scene(volume, res=16, spp=32)
    params = mi.traverse(scene)
    key = data_key(params)
    base = np.array(params[key])
    # entries: a tile and voxels below max() (a change of max() changes the
    # majorant, and the FD estimate's paths with it)
    tile = int(np.nonzero(covered > 1)[0][0])
    middle = np.nonzero((covered == 1) & (base < 0.6 * base.max()) & (base > 0.1 * base.max()))[0]
    entries = [tile] + list(middle[:: max(1, len(middle) // 3)][:3])
    seeds = range(6)
    pixel = (8, 8)

    def render(values, seed, grad_entry=None):
        params[key] = mi.Float(values)
        if grad_entry is not None:
            dr.enable_grad(params[key])
        params.update()
        if grad_entry is not None and mode == "forward":
            onehot = np.zeros_like(values)
            onehot[grad_entry] = 1
            dr.set_grad(params[key], mi.Float(onehot))
        image = mi.render(scene, params, seed=seed)
        return image

    failures = []
    for e in entries:
        h = 0.05 * max(base[e], 0.2)
        ad_mean, ad_pixel, fd_mean, fd_pixel = [], [], [], []
        for seed in seeds:
            image = render(base, seed, e)
            if mode == "forward":
                dr.forward_to(image)
                gi = np.array(dr.grad(image))
                ad_mean.append(gi.mean())
                ad_pixel.append(gi[pixel].mean())
            else:
                dr.backward(dr.mean(image))
                ad_mean.append(np.array(dr.grad(params[key]))[e])
                params[key] = mi.Float(base)
                dr.enable_grad(params[key])
                params.update()
                image = render(base, seed, e)
                dr.backward(dr.mean(image[pixel[0], pixel[1]]))
                ad_pixel.append(np.array(dr.grad(params[key]))[e])
            plus, minus = base.copy(), base.copy()
            plus[e] += h
            minus[e] -= h
            ip = np.array(render(plus, seed))
            im = np.array(render(minus, seed))
            fd_mean.append((ip.mean() - im.mean()) / (2 * h))
            fd_pixel.append((ip[pixel].mean() - im[pixel].mean()) / (2 * h))
        for what, a, f in (("mean", ad_mean, fd_mean), ("pixel", ad_pixel, fd_pixel)):
            a, f = np.array(a), np.array(f)
            sigma = np.sqrt(a.var(ddof=1) / len(a) + f.var(ddof=1) / len(f))
            tol = 4 * sigma + 0.02 * max(abs(a.mean()), abs(f.mean())) + 1e-6
            rel = abs(a.mean() - f.mean()) / max(abs(f.mean()), 1e-12)
            print(f"{variant} {mode} entry {e} ({'tile' if e == tile else 'voxel'}) {what}: "
                  f"AD {a.mean():.5g} FD {f.mean():.5g} (sigma {sigma:.2g}, rel {rel:.3f})")
            if not abs(a.mean() - f.mean()) <= tol:
                failures.append((e, what, a.mean(), f.mean(), tol))
    params[key] = mi.Float(base)
    params.update()
    assert not failures, failures


@pytest.mark.parametrize("variant", ["llvm_ad_rgb", "llvm_ad_mono"])
@pytest.mark.parametrize("mode", ["reverse", "forward"])
def test06_gradients_match_finite_differences(make_grid, variant, mode):
    fd_check(variant, mode, make_grid)


# ---------------------------------------------------------------------------
#  parameters_changed: bounds after an update
# ---------------------------------------------------------------------------

def test07_update_recomputes_max_and_majorants(variant_llvm_ad_rgb, make_grid):
    nvdb, _ = make_grid("fog_sphere")
    rng = np.random.default_rng(11)
    for filter_type in ("nearest", "trilinear"):
        vol = load_nvdb(nvdb, filter_type=filter_type, differentiable=True)
        params = mi.traverse(vol)
        key = data_key(params)
        old_max = vol.max()
        values = np.array(params[key]) * rng.uniform(0.2, 3.0, dr.width(params[key])).astype(np.float32)
        hot = int(np.argmin(values))
        values[hot] = 100 * old_max
        params[key] = mi.Float(values)
        params.update()
        assert vol.max() == pytest.approx(float(values.max()), rel=1e-6)
        assert vol.max() >= 100 * old_max
        points = rng.uniform(-0.05, 1.05, (1_000_000, 3))
        got = eval_points(vol, points)
        assert got.max() <= vol.max()
        assert mi.traverse(vol)["max"] == vol.max()


def test08_volpathlocal_unbiased_after_update(variant_llvm_ad_rgb, make_grid):
    """The per-node majorants after an update bound the new values: volpathlocal
    (walked) renders what volpath renders; with the table of the old values
    (not recomputed), a voxel raised far above them would be under-sampled"""
    nvdb, _ = make_grid("noisy_cloud")
    vol_dict = {"type": "nanovdbvolume", "filename": nvdb, "differentiable": True}
    images = {}
    for integrator in ("volpath", "volpathlocal"):
        d = {"type": integrator, "max_depth": 16}
        if integrator == "volpathlocal":
            d["max_majorant_ratio"] = 1.0  # walk always
        scene = mi.load_dict({
            "type": "scene", "integrator": d,
            "sensor": {"type": "perspective", "fov": 35,
                       "to_world": mi.ScalarTransform4f().look_at([0, 0, 3.2], [0, 0, 0], [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 24, "height": 24,
                                "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": 256}},
            "emitter": {"type": "constant"},
            "cube": {"type": "cube", "bsdf": {"type": "null"},
                     "interior": {"type": "heterogeneous", "sigma_t": vol_dict, "scale": 20.0,
                                  "albedo": 0.5}}})
        params = mi.traverse(scene)
        key = data_key(params)
        values = np.array(params[key])
        # a slab of the cloud's voxels raised 30x above the old maximum
        values[: len(values) // 3] = 30 * values.max()
        params[key] = mi.Float(values)
        params.update()
        images[integrator] = np.array(mi.render(scene, params, seed=1, spp=256))
    a, b = images["volpath"], images["volpathlocal"]
    diff = a.mean() - b.mean()
    assert abs(diff) < 0.01 * a.mean(), (a.mean(), b.mean())
