"""
.vdb files straight into nanovdbvolume (src/loader/vdb_import.cpp): the
grid is read and converted at load with vdb2nvdb's own steps, so a .vdb
load must equal the load of the .nvdb that vdb2nvdb writes from it:

- the same facts (type, class, index box, world box, max) and nearest
  reads bit for bit at random points and every active voxel's centre, on
  scalar_rgb and llvm_ad_rgb, for the generated multi-grid file (fog, vec3s,
  level set, an unknown class) and every shared .vdb (smoke, three level
  sets, multi-grid USD, Blender's empty frame, Houdini's vec3s);
- level sets come out as the same fog (vdb2nvdb's default);
- renders at the same seed are equal;
- bad input (points, integer grids, a truncated file, a missing grid name,
  no file) gives one error that names the file.
"""

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from conftest import BUILD, SHARED_DATA, eval_points, need_shared_data
from nanovdb_mitsuba import volume_facts

VDB2NVDB = BUILD / "bin" / "vdb2nvdb"


def vdb2nvdb(*args):
    if not VDB2NVDB.exists():
        pytest.fail(f"{VDB2NVDB} is missing: build the project first")
    return subprocess.run([str(VDB2NVDB), *map(str, args)], check=True, capture_output=True,
                          text=True)


@pytest.fixture(scope="module")
def multi_vdb(tmp_path_factory):
    """vdb2nvdb generate multi: density (fog), vel (vec3s), ls_sphere (level
    set), flags (int32), temperature (float, class unknown)"""
    out = tmp_path_factory.mktemp("vdb") / "multi.vdb"
    vdb2nvdb("generate", "multi", out)
    return out


def shared_vdbs():
    if not SHARED_DATA.is_dir():
        return [pytest.param(None, id="no_shared_data")]
    return [pytest.param(p, id=p.name) for p in sorted(SHARED_DATA.glob("*.vdb"))
            if "points" not in p.name]


def grid_names(vdb):
    """(name, type) of every grid of a .vdb, from vdb2nvdb --list"""
    rows = []
    for line in vdb2nvdb("--list", vdb).stdout.splitlines():
        parts = line.split()
        if len(parts) >= 3 and parts[0].isdigit() and parts[1].startswith('"'):
            rows.append((parts[1].strip('"'), parts[2]))
    return rows


def compare_loads(vdb, grid, tmp_path, **kwargs):
    """The .vdb grid and vdb2nvdb's .nvdb of it: same facts, same nearest
    reads (bit for bit). Returns the .vdb volume's facts."""
    nvdb = tmp_path / f"{Path(vdb).stem}.{grid or 'first'}.nvdb"
    vdb2nvdb(vdb, nvdb, "--grid", grid)
    args = {"filter_type": "nearest", **kwargs}
    a = mi.load_dict({"type": "nanovdbvolume", "filename": str(vdb), "grid": grid, **args})
    b = mi.load_dict({"type": "nanovdbvolume", "filename": str(nvdb), "grid": grid, **args})
    fa, fb = volume_facts(a), volume_facts(b)
    for key in ["grid_type", "grid_class", "channels", "index_min", "index_dims",
                "world_bbox_min", "world_bbox_max", "max", "grid_max", "background",
                "grid_bytes", "local_majorant_ratio"]:
        assert fa[key] == fb[key], (key, fa[key], fb[key])
    assert mi.traverse(a)["vdb_imported"] and not mi.traverse(b)["vdb_imported"]
    # Random local points (the unit cube and a margin) and every voxel centre
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.05, 1.05, (4000, 3))
    dims = np.array(fa["index_dims"], dtype=np.float64)
    if dims.prod() <= 64 ** 3:
        idx = np.stack(np.meshgrid(*[np.arange(int(d)) for d in dims], indexing="ij"), -1)
        pts = np.concatenate([pts, ((idx.reshape(-1, 3) + 0.5) / dims)])
    if fa["channels"] == 1:
        va, vb = eval_points(a, pts), eval_points(b, pts)
        assert np.array_equal(va, vb)
    return fa


def test01_multi_grid_file_every_grid(variants_rgb, multi_vdb, tmp_path):
    facts = {g: compare_loads(multi_vdb, g, tmp_path) for g in ["density", "temperature"]}
    assert facts["density"]["grid_class"] == "fog volume"
    # The level set, made a fog volume as vdb2nvdb makes it
    ls = compare_loads(multi_vdb, "ls_sphere", tmp_path)
    assert ls["grid_class"] == "fog volume" and ls["max"] <= 1.0
    vol = mi.load_dict({"type": "nanovdbvolume", "filename": str(multi_vdb),
                        "grid": "ls_sphere"})
    params = mi.traverse(vol)
    assert params["vdb_fogged"] and params["vdb_source_class"] == 1
    assert "a level set made a fog volume" in str(vol)
    # The vec3s grid as Vec3f, placed by its own transform
    vel = compare_loads(multi_vdb, "vel", tmp_path, use_grid_transform=True)
    assert vel["grid_type"] == "Vec3f" and vel["channels"] == 3


def test02_grid_by_index_and_default(variant_scalar_rgb, multi_vdb):
    # No grid: the first float or vec3s grid; "2": the third grid of the file
    first = mi.load_dict({"type": "nanovdbvolume", "filename": str(multi_vdb)})
    by_name = mi.load_dict({"type": "nanovdbvolume", "filename": str(multi_vdb),
                            "grid": "density"})
    assert volume_facts(first)["grid_max"] == volume_facts(by_name)["grid_max"]
    names = [n for n, _ in grid_names(multi_vdb)]
    third = mi.load_dict({"type": "nanovdbvolume", "filename": str(multi_vdb), "grid": "2"})
    assert volume_facts(third)["grid_index"] == 2, names


@pytest.mark.parametrize("vdb", shared_vdbs())
def test03_shared_files_equal_their_nvdb(variants_rgb, vdb, tmp_path):
    need_shared_data()
    for name, type_ in grid_names(vdb):
        if type_ not in ("float", "vec3s"):
            continue
        try:
            compare_loads(vdb, name, tmp_path, use_grid_transform=True)
        except RuntimeError as e:
            # A grid the plugin refuses (e.g. an empty one): the .nvdb of it
            # must be refused alike
            nvdb = tmp_path / f"{vdb.stem}.{name or 'first'}.nvdb"
            with pytest.raises(RuntimeError):
                mi.load_dict({"type": "nanovdbvolume", "filename": str(nvdb), "grid": name})
            assert str(vdb) in str(e), e


def test04_renders_equal_at_the_same_seed(variants_rgb, multi_vdb, tmp_path):
    nvdb = tmp_path / "multi.nvdb"
    vdb2nvdb(multi_vdb, nvdb)

    def render(path):
        return np.array(mi.render(mi.load_dict({
            "type": "scene", "integrator": {"type": "volpathlocal"},
            "sensor": {"type": "perspective", "fov": 40,
                       "to_world": mi.ScalarTransform4f().look_at(origin=[2, 1.5, 2.5],
                                                                  target=[0.5, 0.5, 0.5],
                                                                  up=[0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": 16, "height": 16},
                       "sampler": {"type": "independent", "sample_count": 8}},
            "sky": {"type": "constant"},
            "cube": {"type": "cube", "bsdf": {"type": "null"},
                     "to_world": mi.ScalarTransform4f().translate([0.5, 0.5, 0.5]).scale(0.5),
                     "interior": {"type": "heterogeneous", "scale": 10.0,
                                  "sigma_t": {"type": "nanovdbvolume", "filename": str(path),
                                              "grid": "density"}}}}), seed=3))
    # Equal up to the order of the film's float sums, which varies between
    # two renders of one scene on LLVM (measured: 1.8e-7 either way)
    a, b = render(multi_vdb), render(nvdb)
    assert np.allclose(a, b, rtol=1e-6, atol=1e-6), np.abs(a - b).max()


def test05_bad_input_names_the_file(variant_scalar_rgb, multi_vdb, tmp_path):
    def load(path, grid=None):
        d = {"type": "nanovdbvolume", "filename": str(path)}
        if grid is not None:
            d["grid"] = grid
        return mi.load_dict(d)

    with pytest.raises(RuntimeError, match=r"multi.vdb.*grid \"flags\".*only float and vec3s"):
        load(multi_vdb, "flags")
    with pytest.raises(RuntimeError, match=r"multi.vdb.*no grid named \"nope\"; the file "
                                           r"holds:.*density"):
        load(multi_vdb, "nope")
    # A truncated file: a grid cut off is an error naming the file; a grid
    # stored before the cut may load, and then reads as the intact file's
    # (temperature is the last grid of the file, density the first)
    truncated = tmp_path / "truncated.vdb"
    data = multi_vdb.read_bytes()
    intact = volume_facts(load(multi_vdb, "density"))
    for n in (16, 200, len(data) // 3, len(data) // 2, len(data) - 100):
        truncated.write_bytes(data[:n])
        with pytest.raises(RuntimeError, match=r"truncated.vdb"):
            load(truncated, "temperature")
        try:
            facts = volume_facts(load(truncated, "density"))
        except RuntimeError as e:
            assert "truncated.vdb" in str(e), e
        else:
            assert facts == intact, n
    garbage = tmp_path / "garbage.vdb"
    garbage.write_bytes(bytes(range(256)) * 40)
    with pytest.raises(RuntimeError, match=r"garbage.vdb.*cannot read as an OpenVDB file"):
        load(garbage)
    with pytest.raises(RuntimeError, match=r"missing.vdb.*no such file"):
        load(tmp_path / "missing.vdb")


def test06_points_file(variant_scalar_rgb):
    points = need_shared_data("openvdb_sphere_points.vdb") / "openvdb_sphere_points.vdb"
    with pytest.raises(RuntimeError, match=r"openvdb_sphere_points.vdb.*points.*only float "
                                           r"and vec3s"):
        mi.load_dict({"type": "nanovdbvolume", "filename": str(points), "grid": "points"})
    with pytest.raises(RuntimeError, match=r"openvdb_sphere_points.vdb.*no float or vec3s grid"):
        mi.load_dict({"type": "nanovdbvolume", "filename": str(points)})


# level_set (issue 33): what a file's level set becomes, validated in the
# constructor; "fog" must give exactly vdb2nvdb's fog of the same file, for
# .nvdb files too (the reader process makes it), and "distance" exactly the
# distances vdb2nvdb --keep-level-sets writes.

def nearest_reads(volume, facts):
    rng = np.random.default_rng(7)
    pts = rng.uniform(-0.05, 1.05, (3000, 3))
    dims = np.array(facts["index_dims"], dtype=np.float64)
    idx = np.stack(np.meshgrid(*[np.arange(int(d)) for d in dims], indexing="ij"), -1)
    return eval_points(volume, np.concatenate([pts, (idx.reshape(-1, 3) + 0.5) / dims]))


def assert_same_volume(a, b):
    fa, fb = volume_facts(a), volume_facts(b)
    for key in ["grid_type", "grid_class", "index_min", "index_dims", "world_bbox_min",
                "world_bbox_max", "max", "grid_max", "background", "grid_bytes"]:
        assert fa[key] == fb[key], (key, fa[key], fb[key])
    va, vb = nearest_reads(a, fa), nearest_reads(b, fb)
    assert np.array_equal(va, vb), np.abs(va - vb).max()
    assert va.max() > 0  # (something was compared)
    return fa


def test07_level_set_is_validated(variant_scalar_rgb, multi_vdb):
    load = lambda **kw: mi.load_dict({"type": "nanovdbvolume", **kw})  # noqa: E731
    with pytest.raises(RuntimeError, match=r'multi.vdb": invalid level_set "sdf", must be one '
                                           r'of: "fog" or "distance"'):
        load(filename=str(multi_vdb), grid="ls_sphere", level_set="sdf")
    with pytest.raises(RuntimeError, match=r"level_set applies to the level sets of .nvdb and "
                                           r".vdb files; this volume comes from memory"):
        load(data=mi.TensorXf(np.ones((2, 2, 2), dtype=np.float32)), level_set="fog")


def test08_level_set_fog_and_distance_equal_vdb2nvdb(variants_rgb, multi_vdb, tmp_path):
    # The level set kept in a .nvdb, and vdb2nvdb's fog and distances of it
    kept = tmp_path / "kept.nvdb"
    vdb2nvdb(multi_vdb, kept, "--grid", "ls_sphere", "--keep-level-sets")
    fogged = tmp_path / "fogged.nvdb"
    vdb2nvdb(kept, fogged)  # (vdb2nvdb reads .nvdb input: a level set becomes fog)
    args = {"grid": "ls_sphere", "filter_type": "nearest"}

    def load(path, **kw):
        return mi.load_dict({"type": "nanovdbvolume", "filename": str(path), **args, **kw})
    # .nvdb: distances by default, fog on request, equal to vdb2nvdb's fog
    plain = load(kept)
    assert volume_facts(plain)["grid_class"] == "level set"
    assert not mi.traverse(plain)["level_set_fogged"]
    fog = load(kept, level_set="fog")
    assert mi.traverse(fog)["level_set_fogged"]
    facts = assert_same_volume(fog, load(fogged))
    assert facts["grid_class"] == "fog volume" and facts["max"] <= 1.0
    assert_same_volume(load(kept, level_set="distance", invalid_values="clamp"),
                       load(kept, invalid_values="clamp"))
    # .vdb: fog by default (as before), distances on request, equal to
    # vdb2nvdb --keep-level-sets
    assert_same_volume(load(multi_vdb), load(fogged))
    distances = load(multi_vdb, level_set="distance", invalid_values="clamp")
    assert volume_facts(distances)["grid_class"] == "level set"
    assert not mi.traverse(distances)["level_set_fogged"]
    assert_same_volume(distances, load(kept, invalid_values="clamp"))
    # Other grids are read as they are whatever level_set says
    assert_same_volume(load(multi_vdb, grid="density", level_set="fog"),
                       load(multi_vdb, grid="density", level_set="distance"))
