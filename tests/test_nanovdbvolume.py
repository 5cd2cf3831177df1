"""
nanovdbvolume against independent references: Mitsuba's dense gridvolume on
a dense export of the same active box (written with NanoVDB's own C++
accessor), hand-derived values, and the NanoVDB files in ../shared/data.
"""

import re
import struct
from pathlib import Path

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from nanovdb_mitsuba import volume_facts
from conftest import (need_shared_data, shared_data_files, assert_renders_match,
                      eval_points, load_dense, load_nvdb, make_stability_grid, read_vol)
from test_stability import in_unit_range, render_transmittance


# ---------------------------------------------------------------------------
#  Helpers
# ---------------------------------------------------------------------------

def random_points(n, seed, lo=-0.05, hi=1.05):
    rng = np.random.default_rng(seed)
    return rng.uniform(lo, hi, size=(n, 3)).astype(np.float32)


def point_count():
    # The scalar path evaluates point by point in Python: fewer points there
    return 200_000 if dr.is_jit_v(mi.Float) else 4_000


def render(volume, spp=4, size=24, seed=0):
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": 16},
        "sensor": {
            "type": "perspective",
            "fov": 35,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[2.2, 1.6, 2.6], target=[0.5, 0.5, 0.5], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "emitter": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        "sun": {"type": "directional", "direction": [-1, -1, -0.5], "irradiance": 3.0},
        "cube": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().translate([0.5, 0.5, 0.5]).scale(0.5),
            "bsdf": {"type": "null"},
            "interior": {
                "type": "heterogeneous",
                "sigma_t": volume,
                "albedo": 0.8,
                "scale": 6.0,
            },
        },
    })
    return np.array(mi.render(scene, seed=seed))


# ---------------------------------------------------------------------------
#  Loading, layout and metadata
# ---------------------------------------------------------------------------

def test01_single_voxel_metadata(variants_all, make_grid):
    # A layout mismatch between this plugin and libmitsuba (wrong ABI flags)
    # shows up here first: resolution()/bbox() read back garbage.
    nvdb, _ = make_grid("single_voxel")
    vol = load_nvdb(nvdb, filter_type="nearest")
    assert list(vol.resolution()) == [1, 1, 1]
    bbox = vol.bbox()
    assert dr.allclose(bbox.min, mi.ScalarPoint3f(0, 0, 0))
    assert dr.allclose(bbox.max, mi.ScalarPoint3f(1, 1, 1))
    assert vol.max() == 3.0
    assert vol.channel_count() == 1
    # The one voxel, everywhere in the unit cube (nearest)
    v = eval_points(vol, [[0.5, 0.5, 0.5], [0.01, 0.99, 0.5]])
    assert np.all(v == 3.0)
    assert "single_voxel" in str(vol)


def test02_resolution_and_bbox_match_dense_export(variants_rgb, make_grid):
    nvdb, vol = make_grid("noisy_cloud")
    res, _, values = read_vol(vol)
    nano = load_nvdb(nvdb, to_world=mi.ScalarTransform4f().translate([1, 2, 3]).scale([2, 3, 4]))
    dense = load_dense(vol, to_world=mi.ScalarTransform4f().translate([1, 2, 3]).scale([2, 3, 4]))
    assert list(nano.resolution()) == list(res)
    assert list(nano.resolution()) == list(dense.resolution())
    assert dr.allclose(nano.bbox().min, dense.bbox().min)
    assert dr.allclose(nano.bbox().max, dense.bbox().max)
    assert dr.allclose(nano.bbox().min, [1, 2, 3]) and dr.allclose(nano.bbox().max, [3, 5, 7])
    # max() is a true upper bound of every value, at least the dense maximum
    assert nano.max() >= max(values)


@pytest.mark.parametrize("name", ["fog_sphere", "noisy_cloud", "constant_cube",
                                  "random_cube", "lower_tiles", "upper_tiles",
                                  "nonzero_background"])
def test03_nearest_matches_dense(variants_rgb, make_grid, name):
    nvdb, vol = make_grid(name)
    nano = load_nvdb(nvdb, filter_type="nearest")
    dense = load_dense(vol, filter_type="nearest")
    # Inside the unit cube the two must pick the same voxel: exactly equal
    pts = random_points(point_count(), seed=3, lo=0.0, hi=0.999999)
    a, b = eval_points(nano, pts), eval_points(dense, pts)
    assert np.array_equal(a, b), f"{np.sum(a != b)} of {len(a)} lookups differ"


@pytest.mark.parametrize("name", ["fog_sphere", "noisy_cloud", "random_cube",
                                  "upper_tiles", "nonzero_background"])
def test04_trilinear_matches_dense_inside(variants_rgb, make_grid, name):
    nvdb, vol = make_grid(name)
    res, _, _ = read_vol(vol)
    nano = load_nvdb(nvdb)
    dense = load_dense(vol)
    # Away from the outer half voxel (where gridvolume clamps and a VDB blends
    # towards the background), both interpolate the same 8 voxels with the
    # same arithmetic: equal up to float rounding of the weights.
    margin = 0.5 / np.array(res, dtype=np.float32)
    rng = np.random.default_rng(4)
    pts = rng.uniform(margin, 1 - margin, size=(point_count(), 3)).astype(np.float32)
    a, b = eval_points(nano, pts), eval_points(dense, pts)
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


def test05_trilinear_blends_to_background_at_the_border(variants_rgb, make_grid):
    # constant_cube: 5.0 inside, background 0 outside. At the centre of a face
    # of the unit cube the sample sits half a voxel outside the box:
    # half 5.0, half background (VDB semantics); gridvolume clamps to 5.0.
    nvdb, vol = make_grid("constant_cube")
    nano, dense = load_nvdb(nvdb), load_dense(vol)
    face = [[0.0, 0.5, 0.5], [0.5, 1.0, 0.5]]
    assert np.allclose(eval_points(nano, face), 2.5)
    assert np.allclose(eval_points(dense, face), 5.0)
    assert np.allclose(eval_points(nano, [[0.5, 0.5, 0.5]]), 5.0)
    # Outside the box: the background
    assert np.allclose(eval_points(nano, [[-0.5, 0.5, 0.5], [2, 2, 2]]), 0.0)


def test06_outside_is_background(variants_rgb, make_grid):
    nvdb, _ = make_grid("nonzero_background")
    nano = load_nvdb(nvdb, filter_type="nearest")
    far = [[-3, 0.5, 0.5], [0.5, 7, 0.5], [1e4, -1e4, 1e4]]
    assert np.allclose(eval_points(nano, far), 0.25)


def test07_scalar_and_llvm_agree(make_grid):
    nvdb, _ = make_grid("noisy_cloud")
    pts = random_points(3000, seed=7)
    out = {}
    for variant in ["scalar_rgb", "llvm_ad_rgb"]:
        mi.set_variant(variant)
        from conftest import BUILD
        mi.file_resolver().prepend(str(BUILD))
        for filt in ["nearest", "trilinear"]:
            out[variant, filt] = eval_points(load_nvdb(nvdb, filter_type=filt), pts)
    for filt in ["nearest", "trilinear"]:
        np.testing.assert_allclose(out["scalar_rgb", filt], out["llvm_ad_rgb", filt],
                                   rtol=1e-6, atol=1e-7)


def test08_every_variant_is_single_channel(variants_all, make_grid):
    # Spectral, monochrome and polarized variants: eval() broadcasts the one
    # channel, as gridvolume does for single-channel data.
    nvdb, vol = make_grid("random_cube")
    nano, dense = load_nvdb(nvdb), load_dense(vol)
    it = dr.zeros(mi.Interaction3f)
    it.p = mi.Point3f(0.3, 0.6, 0.45)
    a, b = nano.eval(it), dense.eval(it)
    assert dr.allclose(a, b, rtol=1e-6)
    assert dr.allclose(nano.eval_1(it), dense.eval_1(it), rtol=1e-6)
    with pytest.raises(RuntimeError, match="single channel"):
        nano.eval_3(it)


@pytest.mark.parametrize("codec", ["zip", "blosc"])
def test09_codecs_read_the_same_grid(variant_llvm_ad_rgb, make_grid, codec):
    plain, _ = make_grid("noisy_cloud", "none", dense=False)
    packed, _ = make_grid("noisy_cloud", codec, dense=False)
    assert Path(packed).stat().st_size < Path(plain).stat().st_size
    pts = random_points(50_000, seed=9)
    assert np.array_equal(eval_points(load_nvdb(plain), pts),
                          eval_points(load_nvdb(packed), pts))


def test10_grid_transform(variants_rgb, make_grid):
    # noisy_cloud has voxel size 0.5 and is translated by (1, 2, 3): with
    # use_grid_transform, voxel ijk sits at world 0.5 * ijk + (1, 2, 3).
    nvdb, vol = make_grid("noisy_cloud")
    res, bbox, values = read_vol(vol)
    lo = np.array(bbox[:3], dtype=np.int64)  # index box minimum (written as floats)
    values = np.array(values, dtype=np.float32).reshape(res[2], res[1], res[0])
    nano = load_nvdb(nvdb, filter_type="nearest", use_grid_transform=True)
    rng = np.random.default_rng(10)
    idx = np.stack([rng.integers(0, res[k], 500) for k in range(3)], axis=1)
    world = 0.5 * (idx + lo) + np.array([1.0, 2.0, 3.0])
    got = eval_points(nano, world)
    expected = values[idx[:, 2], idx[:, 1], idx[:, 0]]
    assert np.array_equal(got, expected)
    # Bounds: the voxels' cells, in world space
    b = nano.bbox()
    assert dr.allclose(b.min, 0.5 * (lo - 0.5) + np.array([1, 2, 3]), atol=1e-5)
    assert dr.allclose(b.max, 0.5 * (lo + np.array(res) - 0.5) + np.array([1, 2, 3]), atol=1e-5)
    # Trilinear at a voxel centre returns that voxel's value
    tri = load_nvdb(nvdb, use_grid_transform=True)
    np.testing.assert_allclose(eval_points(tri, world[:50]), expected[:50], rtol=1e-5, atol=1e-6)


def test11_grid_selection(variant_scalar_rgb, make_grid):
    nvdb, _ = make_grid("single_voxel")
    assert load_nvdb(nvdb, grid="single_voxel").max() == 3.0
    assert load_nvdb(nvdb, grid="0").max() == 3.0
    with pytest.raises(RuntimeError, match=r'(?s)single_voxel.*not found|not found.*single_voxel'):
        load_nvdb(nvdb, grid="density")


def test12_empty_grid_is_background(variants_rgb, make_grid):
    nvdb, _ = make_grid("empty", dense=False)
    vol = load_nvdb(nvdb)
    assert list(vol.resolution()) == [1, 1, 1]
    assert vol.max() == 0.0
    assert np.all(eval_points(vol, random_points(100, 12)) == 0.0)



# ---------------------------------------------------------------------------
#  Invalid voxel values: NaN, Inf, negative (parameter invalid_values)
#
#   invalid_values = "error" (default): a NaN or +-Inf anywhere a lookup can
#       reach -> load error naming file, grid, counts and the first offending
#       coordinate; negative values load, with a warning, as they are.
#   invalid_values = "clamp": NaN -> 0, +Inf -> the grid's largest finite
#       value, -Inf and negatives -> 0, in place before upload; max() is
#       recomputed afterwards.
# ---------------------------------------------------------------------------

def _single_voxel_with(make_grid, tmp_path, value, name):
    """single_voxel (3.0 at (7, -3, 12)) with every stored 3.0 replaced: the
    voxel's value and the statistics that repeat it."""
    nvdb, _ = make_grid("single_voxel", dense=False)
    data = bytearray(Path(nvdb).read_bytes())
    three, new = struct.pack("<f", 3.0), struct.pack("<f", value)
    i = data.find(three, 200)
    while i >= 0:
        data[i:i + 4] = new
        i = data.find(three, i + 4)
    path = tmp_path / name
    path.write_bytes(bytes(data))
    return str(path)


def _invalid_grid(tmp_path):
    """Box 0..7 of 1.0 with a 7.0 at (5, 5, 5), the largest finite value, and,
    in the same leaf (so that "first" is fixed by the leaf's value order
    i*64 + j*8 + k): NaN at (1, 2, 3), +Inf at (4, 2, 3), -Inf at (6, 0, 0)
    and -0.5 at (2, 2, 2)."""
    nvdb, _, _ = make_stability_grid(tmp_path, "invalid", "--value", 1.0,
                                     "--set", 5, 5, 5, 7.0, "--set", 1, 2, 3, "nan",
                                     "--set", 4, 2, 3, "inf", "--set", 6, 0, 0, "-inf",
                                     "--set", 2, 2, 2, -0.5, dense=False)
    return nvdb


def _at_index(vol, ijk):
    """Lookup with use_grid_transform on an identity map: world = index."""
    return eval_points(vol, np.asarray(ijk, dtype=np.float32))


def test13_non_finite_values_rejected_at_the_first_voxel(variants_rgb, make_grid, tmp_path):
    # One kind at a time: the message names the file, the grid, the count of
    # that kind, its voxel and the way out.
    for value, word in [(float("nan"), "NaN"), (float("inf"), "+Inf"), (float("-inf"), "-Inf")]:
        path = _single_voxel_with(make_grid, tmp_path, value, "bad_value.nvdb")
        with pytest.raises(RuntimeError, match=r"(?s)bad_value\.nvdb.*single_voxel.*1 " +
                           re.escape(word) + r".*\(7, -3, 12\).*invalid_values"):
            load_nvdb(path)
    # Every kind in one grid: the counts, the first NaN and the first infinite
    # value; "error" is the default.
    nvdb = _invalid_grid(tmp_path)
    for kwargs in [{}, {"invalid_values": "error"}]:
        with pytest.raises(RuntimeError, match=r'(?s)invalid\.nvdb.*"stability".*1 NaN '
                           r'\(first: voxel \(1, 2, 3\)\), 1 \+Inf and 1 -Inf values '
                           r'\(first infinite: voxel \(4, 2, 3\)\).*invalid_values="clamp"'):
            load_nvdb(nvdb, **kwargs)


def test14_clamp_replaces_invalid_values(variants_rgb, make_grid, tmp_path):
    # The single voxel alone: NaN, -Inf and negatives become 0; the only
    # finite value left is the background 0, which +Inf becomes too.
    for value in [float("nan"), float("-inf"), -2.5, float("inf")]:
        path = _single_voxel_with(make_grid, tmp_path, value, "clamp_me.nvdb")
        vol = load_nvdb(path, invalid_values="clamp", filter_type="nearest")
        assert np.all(eval_points(vol, [[0.5, 0.5, 0.5]]) == 0.0), value
        assert vol.max() == 0.0, value
    # Every kind in one grid: +Inf becomes the largest finite value (7.0),
    # the other voxels keep theirs, max() is recomputed, and trilinear
    # lookups and a render see only finite values.
    nvdb = _invalid_grid(tmp_path)
    vol = load_nvdb(nvdb, invalid_values="clamp", filter_type="nearest", use_grid_transform=True)
    v = _at_index(vol, [[1, 2, 3], [4, 2, 3], [6, 0, 0], [2, 2, 2], [5, 5, 5], [0, 0, 0]])
    assert v.tolist() == [0.0, 7.0, 0.0, 0.0, 7.0, 1.0]
    assert vol.max() == 7.0
    tri = load_nvdb(nvdb, invalid_values="clamp")
    assert np.all(np.isfinite(eval_points(tri, random_points(500, 31, 0, 1))))
    img = render_transmittance(tri, size=8, spp=4)   # asserts finite pixels
    assert in_unit_range(img)


def test15_negative_values_load_by_default(variants_rgb, make_grid, tmp_path):
    # A volume is not always a density: negatives load (with a warning) as
    # they are; "clamp" sets them to 0 and leaves the other voxels alone.
    path = _single_voxel_with(make_grid, tmp_path, -2.5, "negative.nvdb")
    vol = load_nvdb(path, filter_type="nearest")
    assert np.all(eval_points(vol, [[0.5, 0.5, 0.5]]) == -2.5)
    # max() is what lookups inside the volume return: here its one voxel (the
    # background, 0, lies outside; see test19)
    assert vol.max() == -2.5
    nvdb, _, _ = make_stability_grid(tmp_path, "negative", "--value", 1.0,
                                     "--set", 2, 2, 2, -0.5, dense=False)
    vol = load_nvdb(nvdb, filter_type="nearest", use_grid_transform=True)
    assert _at_index(vol, [[2, 2, 2], [3, 3, 3]]).tolist() == [-0.5, 1.0]
    vol = load_nvdb(nvdb, filter_type="nearest", use_grid_transform=True, invalid_values="clamp")
    assert _at_index(vol, [[2, 2, 2], [3, 3, 3]]).tolist() == [0.0, 1.0]


def test16_invalid_values_choices(variant_scalar_rgb, make_grid, tmp_path):
    # Anything but "error" and "clamp" is refused, naming the choices, on a
    # clean grid and on one that has a value to clamp.
    clean, _ = make_grid("single_voxel", dense=False)
    negative = _single_voxel_with(make_grid, tmp_path, -2.5, "negative.nvdb")
    for path, choice in [(clean, "bogus"), (negative, "ignore")]:
        with pytest.raises(RuntimeError, match=rf'(?s)(?=.*invalid_values)(?=.*"{choice}")'
                                               r'(?=.*"error")(?=.*"clamp")'):
            load_nvdb(path, invalid_values=choice)


# ---------------------------------------------------------------------------
#  Renders: nanovdbvolume vs gridvolume, same scene, same seed
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
@pytest.mark.parametrize("name", ["fog_sphere", "noisy_cloud"])
def test17_render_matches_gridvolume(variants_rgb, make_grid, name, filter_type):
    nvdb, vol = make_grid(name)
    nano = load_nvdb(nvdb, filter_type=filter_type)
    dense = load_dense(vol, filter_type=filter_type)
    # Equal majorants are a precondition for equal random decisions
    assert nano.max() == dense.max()
    spp = 4 if dr.is_jit_v(mi.Float) else 1
    a, b = render(nano, spp=spp), render(dense, spp=spp)
    assert np.all(np.isfinite(a))
    assert np.mean(a) > 0.01
    assert_renders_match(a, b, filter_type)


@pytest.mark.parametrize("name", ["fog_sphere", "constant_cube"])
def test18_trilinear_never_exceeds_max(variants_rgb, make_grid, name):
    # max() must bound every value the medium sees (it is the majorant), also
    # after float rounding of the interpolation weights.
    nvdb, _ = make_grid(name, dense=False)
    vol = load_nvdb(nvdb)
    v = eval_points(vol, random_points(point_count(), 14, 0, 1))
    assert v.max() <= vol.max()
    assert v.max() == vol.max()   # the plateau reaches it


@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
def test19_max_is_what_lookups_in_the_volume_return(variants_rgb, tmp_path, filter_type):
    # Voxels of 1 in the box [0, 7]^3, background 3 (as a fog volume made
    # from a level set keeps it): nearest lookups inside the volume read only
    # the voxels, so max() = 1, not the grid's maximum 3; trilinear stencils
    # reach the one-voxel ring, which holds the background, so max() = 3.
    nvdb, _, _ = make_stability_grid(tmp_path, "bg3", "--max", 7, 7, 7, "--value", 1,
                                     "--background", 3, dense=False)
    vol = load_nvdb(nvdb, filter_type=filter_type)
    want = 1.0 if filter_type == "nearest" else 3.0
    assert vol.max() == want
    assert volume_facts(vol)["grid_max"] == 3
    v = eval_points(vol, random_points(point_count(), 19, 0, 1))
    assert v.max() <= want
    # Outside the volume the tree holds the background, 3: lookups there
    # are clamped to max(), so that it bounds every lookup
    outside = eval_points(vol, [[1.5, 0.5, 0.5], [-2.0, 0.5, 0.5], [0.5, 0.5, 9.0]])
    assert np.all(outside == want)


# ---------------------------------------------------------------------------
#  Bad input: each a clear error naming the file, never a crash
# ---------------------------------------------------------------------------

def test20_missing_file(variant_scalar_rgb, tmp_path):
    path = tmp_path / "does_not_exist.nvdb"
    with pytest.raises(RuntimeError, match="does_not_exist.nvdb"):
        load_nvdb(str(path))


def test21_not_a_nanovdb_file(variant_scalar_rgb, tmp_path):
    path = tmp_path / "text.nvdb"
    path.write_text("this is not a NanoVDB file, just some text\n" * 10)
    with pytest.raises(RuntimeError, match=r"(?s)text\.nvdb.*NanoVDB"):
        load_nvdb(str(path))


def test22_truncated_file(variant_scalar_rgb, make_grid, tmp_path):
    nvdb, _ = make_grid("fog_sphere", dense=False)
    data = Path(nvdb).read_bytes()
    for cut in [10, 100, 300, len(data) // 2, len(data) - 1]:
        path = tmp_path / f"cut_{cut}.nvdb"
        path.write_bytes(data[:cut])
        with pytest.raises(RuntimeError, match=f"cut_{cut}.nvdb"):
            load_nvdb(str(path))


def _grid_payload_offset(data):
    # Uncompressed file written by NanoVDB 32.4: 16-byte header, 176-byte
    # metadata record per grid, the names, then the grid itself.
    count = struct.unpack_from("<H", data, 12)[0]
    assert count == 1
    name_size = struct.unpack_from("<I", data, 16 + 136)[0]
    return 16 + 176 + name_size


def test23_node_offset_outside_buffer(variant_scalar_rgb, make_grid, tmp_path):
    nvdb, _ = make_grid("fog_sphere", dense=False)
    data = bytearray(Path(nvdb).read_bytes())
    grid = _grid_payload_offset(data)
    tree = grid + 672
    root = tree + struct.unpack_from("<Q", data, tree + 24)[0]
    tile0 = root + 64
    # Point the first root tile's child far beyond the end of the grid
    struct.pack_into("<q", data, tile0 + 8, 1 << 40)
    path = tmp_path / "bad_child.nvdb"
    path.write_bytes(bytes(data))
    with pytest.raises(RuntimeError, match=r"bad_child\.nvdb"):
        load_nvdb(str(path))
    # The root node itself outside the buffer
    data2 = bytearray(Path(nvdb).read_bytes())
    struct.pack_into("<Q", data2, tree + 24, 1 << 33)
    path2 = tmp_path / "bad_root.nvdb"
    path2.write_bytes(bytes(data2))
    with pytest.raises(RuntimeError, match=r"bad_root\.nvdb"):
        load_nvdb(str(path2))


def test24_unsupported_grid_type(variant_scalar_rgb):
    data = need_shared_data("warp_int32_zip_32.3.3.nvdb", "warp_vec3f_zip_32.3.3.nvdb")
    path = data / "warp_int32_zip_32.3.3.nvdb"
    with pytest.raises(RuntimeError, match=r"(?s)warp_int32_zip_32\.3\.3\.nvdb.*"
                                           r"supported types: float, Half, Fp4, Fp8, Fp16, FpN, "
                                           r"Vec3f.*int32"):
        load_nvdb(str(path))
    # Warp's Vec3f grid is a supported type: a 3-channel volume
    vol = load_nvdb(str(data / "warp_vec3f_zip_32.3.3.nvdb"))
    assert volume_facts(vol)["grid_type"] == "Vec3f"
    it = mi.Interaction3f()
    it.p = mi.ScalarPoint3f(0.5, 0.5, 0.5)
    assert np.all(np.isfinite(np.array(vol.eval_3(it))))


def test25_grid_not_found_lists_grids(variant_scalar_rgb):
    path = need_shared_data("warp_torus_ls_zip_32.3.3.nvdb") / "warp_torus_ls_zip_32.3.3.nvdb"
    with pytest.raises(RuntimeError, match=r'(?s)warp_torus.*"nope".*surface'):
        load_nvdb(str(path), grid="nope")


def test26_invalid_filter_type(variant_scalar_rgb, make_grid):
    nvdb, _ = make_grid("single_voxel", dense=False)
    with pytest.raises(RuntimeError, match="cubic"):
        load_nvdb(nvdb, filter_type="cubic")


def test27_directory_and_empty_file(variant_scalar_rgb, tmp_path):
    empty = tmp_path / "empty.nvdb"
    empty.write_bytes(b"")
    with pytest.raises(RuntimeError, match="empty.nvdb"):
        load_nvdb(str(empty))
    with pytest.raises(RuntimeError):
        load_nvdb(str(tmp_path))


# ---------------------------------------------------------------------------
#  The real files in ../shared/data
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("path", shared_data_files("*.nvdb"))
def test28_shared_data_files(variants_rgb, path):
    need_shared_data()
    name = path.name
    if name.startswith("warp_torus_ls"):
        # A float level set: loads, values are finite, max is a bound
        vol = load_nvdb(str(path))
        v = eval_points(vol, random_points(2000, 30, 0, 1))
        assert np.all(np.isfinite(v))
        assert np.all(v <= vol.max())
        assert vol.resolution()[0] > 1
    elif name.startswith("fvdb_batch4"):
        # Metadata declares one grid but the payload holds four: the loader
        # reads the declared grid (the first one of the payload) or fails
        # with a message that says what is inconsistent; never a crash.
        try:
            vol = load_nvdb(str(path))
            v = eval_points(vol, random_points(2000, 31, 0, 1))
            assert np.all(np.isfinite(v))
        except RuntimeError as e:
            assert name in str(e)
    elif name.startswith("warp_vec3f"):
        # A Vec3f grid: eval_1 (the luminance) finite and within max()
        vol = load_nvdb(str(path))
        v = eval_points(vol, random_points(2000, 31, 0, 1))
        assert volume_facts(vol)["grid_type"] == "Vec3f"
        assert np.all(np.isfinite(v)) and np.all(v <= vol.max() * (1 + 1e-6))
    elif name.startswith("warp_onindex"):
        # Index grids (OnIndex) with their values in a blind channel: both
        # load, within max() (tests/test_differentiable.py reads them
        # against Warp's own accessor)
        for grid in ("grid-0", "grid-1"):
            vol = load_nvdb(str(path), grid=grid)
            v = eval_points(vol, random_points(2000, 32, 0, 1))
            assert volume_facts(vol)["grid_type"] == "OnIndex"
            assert np.all(np.isfinite(v)) and np.all(v <= vol.max()) and v.max() > 0
    else:
        # int32 grids: a clear "unsupported type" error
        with pytest.raises(RuntimeError, match=r"(?s)" + name.replace(".", r"\.") +
                           r".*(int32|float)"):
            load_nvdb(str(path))


# ---------------------------------------------------------------------------
#  Install step
# ---------------------------------------------------------------------------

# (test29, `cmake --install` into Mitsuba's plugin directory, is gone:
# installation is pip's, tested by tests/test_pip_install.py)
