"""
vdb2nvdb, the OpenVDB -> NanoVDB converter (tools/vdb2nvdb), checked against
independent references: OpenVDB's own reads (printed by --probe, and the
converter's --verify path), the nanovdbvolume plugin (its own PNanoVDB
translation, not NanoVDB's C++ reader), Mitsuba's gridvolume on the dense
export, hand-derived values, and the real files in ../shared/data.

The binary: $NVDB_VDB2NVDB, else $NVDB_BUILD_DIR/bin/vdb2nvdb (default
build/bin/vdb2nvdb). The plugin comes from $NVDB_BUILD_DIR (conftest.BUILD).
"""

import os
import re
import subprocess
import sysconfig
from pathlib import Path

import numpy as np
import pytest
import drjit as dr
import mitsuba as mi

from conftest import BUILD, need_shared_data, read_vol, shared_data_files
from conftest import assert_renders_match, eval_points, load_dense, load_nvdb
from test_nanovdbvolume import random_points, render

VDB2NVDB = Path(os.environ.get("NVDB_VDB2NVDB", BUILD / "bin" / "vdb2nvdb")).resolve()

# The generated cloud: index -> world is diag(0.01, 0.01, 0.0125) + (0.2, 1.0, -0.3)
CLOUD_SCALE = np.array([0.01, 0.01, 0.0125])
CLOUD_OFFSET = np.array([0.2, 1.0, -0.3])


# ---------------------------------------------------------------------------
#  Helpers
# ---------------------------------------------------------------------------

def run(*args, rc=0):
    """Runs vdb2nvdb; checks its exit status (rc=None: any)."""
    if not VDB2NVDB.exists():
        pytest.fail(f"{VDB2NVDB} is missing: build the vdb2nvdb target first")
    p = subprocess.run([str(VDB2NVDB), *map(str, args)], capture_output=True, text=True,
                       timeout=300)
    if rc is not None:
        assert p.returncode == rc, (
            f"exit {p.returncode}, expected {rc}\nstdout:\n{p.stdout}\nstderr:\n{p.stderr}")
    return p


def leftovers(directory):
    """Temporary files the converter failed to clean up."""
    return [p.name for p in Path(directory).iterdir() if ".tmp-" in p.name]


def parse_probes(stdout):
    """{(grid, (i, j, k)): (openvdb value, on, nanovdb value, on)} from --probe."""
    out = {}
    pat = re.compile(r'^probe "(.*)" (-?\d+),(-?\d+),(-?\d+) openvdb (\S+) (on|off) '
                     r'nanovdb (\S+) (on|off)$')
    for line in stdout.splitlines():
        m = pat.match(line)
        if m:
            g, i, j, k, a, aon, b, bon = m.groups()
            out[g, (int(i), int(j), int(k))] = (np.float32(a), aon == "on",
                                                 np.float32(b), bon == "on")
    return out


def parse_bbox(stats):
    """[(min), (max)] of the first 'active index bbox' line of --stats."""
    m = re.search(r"active index bbox\s+\[\((-?\d+), (-?\d+), (-?\d+)\), "
                  r"\((-?\d+), (-?\d+), (-?\d+)\)\]", stats)
    v = list(map(int, m.groups()))
    return np.array(v[:3]), np.array(v[3:])


def local_of_voxel(ijk, lo, hi):
    """nanovdbvolume's local point (use_grid_transform=false) at voxel centres."""
    d = (hi - lo + 1).astype(np.float64)
    return ((np.asarray(ijk, dtype=np.float64) - lo + 0.5) / d).astype(np.float32)


class Generated:
    """Generated .vdb files, once per session (vdb2nvdb generate CASE OUT.vdb)."""

    def __init__(self, directory):
        self.dir = Path(directory)
        self.cache = {}

    def __call__(self, case):
        if case not in self.cache:
            path = self.dir / f"{case}.vdb"
            run("generate", case, path, "--quiet")
            self.cache[case] = path
        return self.cache[case]


@pytest.fixture(scope="session")
def gen(tmp_path_factory):
    return Generated(tmp_path_factory.mktemp("vdb"))


@pytest.fixture(scope="session")
def cloud(gen, tmp_path_factory):
    """The cloud converted once: (.nvdb, dense .vol, --stats output)."""
    d = tmp_path_factory.mktemp("cloud")
    nvdb, vol = d / "cloud.nvdb", d / "cloud.vol"
    p = run(gen("cloud"), nvdb, "--dense", vol, "--stats")
    return nvdb, vol, p.stdout


# ---------------------------------------------------------------------------
#  Command line
# ---------------------------------------------------------------------------

def test01_help_explains_every_option():
    p = run("--help")
    for opt in ["--grid", "--list", "--keep-level-sets", "--quantize", "--tolerance",
                "--codec", "--verify", "--seed", "--verify-only", "--stats", "--dense",
                "--max-dense-bytes", "--probe", "--quiet", "--help", "generate",
                "constant_300", "constant_934", "random_300", "random_934", "sphere_ls",
                "cloud", "multi"]:
        assert opt in p.stdout, opt
    assert "--corrupt-for-test" not in p.stdout  # test-only, hidden
    p = run("--frobnicate", "a.vdb", "b.nvdb", rc=2)
    assert "unknown option" in p.stderr and "usage:" in p.stderr
    p = run("a.vdb", rc=2)
    assert "missing" in p.stderr


def test02_list_shows_grids_in_file_order(gen):
    p = run("--list", gen("multi"))
    rows = [l.split() for l in p.stdout.splitlines()[2:] if re.match(r"  \d", l)]
    assert [r[1] for r in rows] == ['"density"', '"vel"', '"ls_sphere"', '"flags"',
                                    '"temperature"']
    assert [r[2] for r in rows] == ["float", "vec3s", "float", "int32", "float"]
    text = p.stdout
    assert "level set" in text and "fog volume" in text
    # Hand-derived counts: 10^3 vel, 9^3 flags, 32 x 32 x 16 temperature
    assert re.search(r'"vel"\s+vec3s\s+unknown\s+1,000\s+\[\(0, 0, 0\), \(9, 9, 9\)\]', text)
    assert re.search(r'"flags"\s+int32\s+unknown\s+729\s', text)
    assert re.search(r'"temperature"\s+float\s+unknown\s+16,384\s+\[\(40, -8, 0\), \(71, 23, 15\)\]',
                     text)


def test02b_list_shows_world_bbox_transform_and_values(gen, tmp_path):
    # The generated cloud: index -> world is diag(0.01, 0.01, 0.0125) + (0.2, 1.0, -0.3)
    p = run("--list", gen("cloud"))
    lines = p.stdout.splitlines()
    row = [l for l in lines if re.match(r"  0 ", l)][0]
    lo, hi = [np.array(list(map(int, m))) for m in
              re.findall(r"\((-?\d+), (-?\d+), (-?\d+)\)", row)[:2]]
    world = [l for l in lines if "world bbox" in l][0]
    nums = list(map(float, re.findall(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", world.split("size")[0])))
    np.testing.assert_allclose(nums[:3], CLOUD_SCALE * (lo - 0.5) + CLOUD_OFFSET, rtol=1e-5)
    np.testing.assert_allclose(nums[3:6], CLOUD_SCALE * (hi + 0.5) + CLOUD_OFFSET, rtol=1e-5)
    xf = [l for l in lines if "transform" in l][0]
    assert "translation (0.2, 1, -0.3)" in xf and "voxel size (0.01, 0.01, 0.0125)" in xf
    assert "no rotation" in xf
    values = [l for l in lines if "active values" in l][0]
    lo_v, hi_v = map(float, re.search(r"\[(\S+), (\S+)\]", values).groups())
    assert 0 <= lo_v < hi_v
    # A vec3s grid: the range of its largest channel
    p = run("--list", gen("multi"))
    assert "active values' largest channel in" in p.stdout
    # --stats shows the same three lines for the grid as written
    stats = run(gen("cloud"), tmp_path / "c.nvdb", "--stats").stdout
    for want in (world.split("world bbox")[1].strip(), xf.split("transform")[1].strip(),
                 values.split("active values")[1].strip()):
        assert want in stats, (want, stats)
    # ... and for a level set: those of the fog volume it became
    fog = run(gen("sphere_ls"), tmp_path / "s.nvdb", "--stats").stdout
    assert re.search(r"active values\s+in \[\S+, 1\]", fog), fog
    # and .nvdb input (NanoVDB's reader): the same listing as the .vdb's
    nv = run("--list", tmp_path / "c.nvdb").stdout
    assert world in nv.splitlines() and xf in nv.splitlines(), nv


def list_roles(stdout):
    """{grid name: its last --list column (what nanovdb-render makes of it)}"""
    roles = {}
    for line in stdout.splitlines():
        m = re.match(r'^  \d+\s+"(.*)"\s+(.*)$', line)
        if m:
            cols = re.split(r"\s{2,}", m.group(2).strip())
            roles[m.group(1)] = cols[5] if len(cols) > 5 else ""
    return roles


def test02c_list_marks_density_and_emission_grids(gen, tmp_path):
    # The column nanovdb-render's rule fills (python/nanovdb_mitsuba/fire.py):
    # density by name, else the first float grid; the first of emission,
    # flame, temperature, heat as the emission, temperature/heat in kelvin
    p = run("--list", gen("multi"))
    assert "nanovdb-render" in p.stdout.splitlines()[1]
    assert list_roles(p.stdout) == {"density": "density", "vel": "", "ls_sphere": "",
                                    "flags": "", "temperature": "emission (temperature)"}
    src = need_shared_data("usd_density_heat_fog.vdb") / "usd_density_heat_fog.vdb"
    want = {"density": "density", "heat": "emission (temperature)"}
    assert list_roles(run("--list", src).stdout) == want
    # The conversion keeps both float grids, and the .nvdb lists the same
    run(src, tmp_path / "h.nvdb")
    assert list_roles(run("--list", tmp_path / "h.nvdb").stdout) == want


# ---------------------------------------------------------------------------
#  Conversion: grids, order, names, values
# ---------------------------------------------------------------------------

def plugin_grid_names(nvdb):
    """Grid names in file order, as the nanovdbvolume plugin reads them."""
    mi.set_variant("scalar_rgb")
    mi.file_resolver().prepend(str(BUILD))
    with pytest.raises(RuntimeError) as e:
        load_nvdb(str(nvdb), grid="999")
    return re.findall(r'\d+: "([^"]*)" \((?:float|Vec3f)\)', str(e.value))


def test03_every_float_and_vec3s_grid_in_file_order(gen, tmp_path):
    out = tmp_path / "multi.nvdb"
    p = run(gen("multi"), out)
    # one notice per skipped grid, naming it and its type
    notes = [l for l in p.stderr.splitlines() if "skipping" in l]
    assert len(notes) == 1
    assert '"flags" (int32' in notes[0] and "only float and vec3s" in notes[0]
    assert plugin_grid_names(out) == ["density", "vel", "ls_sphere", "temperature"]
    assert p.stdout.count("verified") == 4 and p.stdout.count("identical") == 4
    assert 'converted "vel": 1,000 active voxels, Vec3f' in p.stdout


def test03b_vec3s_becomes_a_vec3f_grid_that_renders(gen, tmp_path):
    # vel (vec3s, 10^3 voxels) -> Vec3f: nanovdbvolume's 3-vector equals
    # gridvolume's on the converter's 3-channel dense export, and a --quantize
    # choice leaves it unquantized (with a note)
    out = tmp_path / "v.nvdb"
    p = run(gen("multi"), out, "--grid", "vel", "--dense", tmp_path / "v.vol",
            "--quantize", "fp8")
    assert '"vel" (vec3s) is written as Vec3f' in p.stderr
    mi.set_variant("llvm_ad_rgb")
    mi.file_resolver().prepend(str(BUILD))
    nano = load_nvdb(str(out), filter_type="nearest")
    dense = load_dense(str(tmp_path / "v.vol"), filter_type="nearest")
    assert "grid_type = Vec3f," in str(nano)
    assert nano.max() == dense.max()
    pts = random_points(5000, 41, 0.0, 0.999999)
    it = dr.zeros(mi.Interaction3f, len(pts))
    it.p = mi.Point3f(pts[:, 0], pts[:, 1], pts[:, 2])
    a, b = np.array(nano.eval_3(it)), np.array(dense.eval_3(it))
    assert np.array_equal(a, b) and np.abs(a).max() > 0


def test04_grid_selection_keeps_file_order(gen, tmp_path):
    out = tmp_path / "sel.nvdb"
    p = run(gen("multi"), out, "--grid", "temperature", "--grid", "density")
    assert "skipping" not in p.stderr
    assert plugin_grid_names(out) == ["density", "temperature"]


def test05_values_match_openvdb_through_the_plugin(variants_rgb, cloud, tmp_path, gen):
    # --probe prints what OpenVDB reads (after the conversion's own pipeline)
    # and what NanoVDB's reader reads back; the plugin is a third reader.
    nvdb, _, stats = cloud
    lo, hi = parse_bbox(stats)
    rng = np.random.default_rng(5)
    ijk = np.stack([rng.integers(lo[k], hi[k] + 1, 150) for k in range(3)], axis=1)
    args = []
    for c in ijk:
        args += ["--probe", f"{c[0]},{c[1]},{c[2]}"]
    p = run(gen("cloud"), tmp_path / "probe.nvdb", "--verify", "0", *args)
    probes = parse_probes(p.stdout)
    assert len(probes) == len({tuple(c) for c in ijk})
    expected = np.array([probes["density", tuple(map(int, c))][0] for c in ijk], dtype=np.float32)
    assert all(a == b and aon == bon for a, aon, b, bon in probes.values())
    assert np.count_nonzero(expected) > 20  # the samples hit the cloud, not only empty space
    vol = load_nvdb(str(nvdb), filter_type="nearest")
    got = eval_points(vol, local_of_voxel(ijk, lo, hi))
    assert np.array_equal(got, expected)


def test06_level_set_becomes_fog(gen, tmp_path):
    # sphere_ls: radius 1, centre (0.1, -0.2, 0.3) = index (5, -10, 15), voxel
    # size 0.02, band 3 voxels (background 0.06). sdfToFogVolume: inside the
    # band fog = -sdf / 0.06, interior 1 (active), exterior 0 (inactive).
    ks = list(range(0, 60, 3)) + list(range(44, 56))
    probes = [f"{5 + k},-10,15" for k in ks] + ["5,-10,15", "300,0,0", "-2000,5,5"]
    args = sum((["--probe", c] for c in probes), [])
    p = run(gen("sphere_ls"), tmp_path / "fog.nvdb", "--stats", *args)
    assert "level set -> fog volume" in p.stdout and "(float, fog volume)" in p.stdout
    pr = parse_probes(p.stdout)
    for k in ks:
        fog, on, nano, nano_on = pr["ls_sphere", (5 + k, -10, 15)]
        assert fog == nano and on == nano_on
        expected = np.clip((1.0 - 0.02 * k) / 0.06, 0.0, 1.0)
        assert abs(fog - expected) < 2e-4, (k, fog, expected)
        assert 0.0 <= fog <= 1.0
        assert on == (fog > 0)   # exterior inactive, interior and inner band active
    for far in [(300, 0, 0), (-2000, 5, 5)]:
        assert pr["ls_sphere", far][:2] == (0.0, False)
    # Monotonic ramp from the centre outwards
    ramp = [pr["ls_sphere", (5 + k, -10, 15)][0] for k in range(44, 56)]
    assert all(a >= b for a, b in zip(ramp, ramp[1:]))
    # The plugin sees a fog volume: max 1, background 0
    mi.set_variant("scalar_rgb")
    mi.file_resolver().prepend(str(BUILD))
    vol = load_nvdb(str(tmp_path / "fog.nvdb"), filter_type="nearest")
    assert vol.max() == 1.0
    assert eval_points(vol, [[0.5, 0.5, 0.5]])[0] == 1.0


def test07_keep_level_sets(tmp_path):
    # The icosahedron's background is 0.15 (README of shared/data)
    src = need_shared_data("openvdb_icosahedron_ls.vdb") / "openvdb_icosahedron_ls.vdb"
    out = tmp_path / "ls.nvdb"
    p = run(src, out, "--keep-level-sets", "--probe", "0,0,0", "--probe", "500,0,0", "--stats")
    assert "(float, level set)" in p.stdout and "fog" not in p.stdout
    pr = parse_probes(p.stdout)
    # (stored as half floats: 0.15002441)
    assert pr["ls_icosahedron", (500, 0, 0)][0] == pytest.approx(0.15, abs=1e-4)
    assert pr["ls_icosahedron", (0, 0, 0)][0] == -pr["ls_icosahedron", (500, 0, 0)][0]
    mi.set_variant("scalar_rgb")
    mi.file_resolver().prepend(str(BUILD))
    vol = load_nvdb(str(out), filter_type="nearest")
    assert np.allclose(eval_points(vol, [[-3, 0.5, 0.5]]), 0.15, atol=1e-4)
    # ... and the default turns it into fog: background 0, values in [0, 1]
    out2 = tmp_path / "fog.nvdb"
    run(src, out2)
    vol = load_nvdb(str(out2), filter_type="nearest")
    assert vol.max() == 1.0
    v = eval_points(vol, random_points(2000, 7))
    assert v.min() >= 0.0 and v.max() <= 1.0
    assert np.allclose(eval_points(vol, [[-3, 0.5, 0.5]]), 0.0)


# ---------------------------------------------------------------------------
#  Dense export and renders
# ---------------------------------------------------------------------------

def test08_dense_one_file_per_grid(gen, tmp_path):
    run(gen("multi"), tmp_path / "m.nvdb", "--dense", tmp_path / "m.vol")
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["m.nvdb", "m_density.vol", "m_ls_sphere.vol", "m_temperature.vol",
                     "m_vel.vol"]
    res, _, values = read_vol(tmp_path / "m_vel.vol")   # 3 channels
    assert res == (10, 10, 10) and len(values) == 3 * 1000
    res, _, values = read_vol(tmp_path / "m_temperature.vol")
    assert res == (32, 32, 16)
    assert 300.0 <= min(values) and max(values) <= 400.0
    # With one grid the name is taken as given
    run(gen("multi"), tmp_path / "t.nvdb", "--grid", "temperature", "--dense", tmp_path / "t.vol")
    assert (tmp_path / "t.vol").exists()


def test09_dense_bbox_is_the_cells_world_extent(cloud):
    nvdb, vol, stats = cloud
    lo, hi = parse_bbox(stats)
    res, bbox, _ = read_vol(vol)
    assert list(res) == list(hi - lo + 1)
    np.testing.assert_allclose(bbox[:3], CLOUD_SCALE * (lo - 0.5) + CLOUD_OFFSET, rtol=1e-6)
    np.testing.assert_allclose(bbox[3:], CLOUD_SCALE * (hi + 0.5) + CLOUD_OFFSET, rtol=1e-6)


def test10_dense_nearest_equals_nvdb(variants_rgb, cloud):
    nvdb, vol, _ = cloud
    nano = load_nvdb(str(nvdb), filter_type="nearest")
    dense = load_dense(str(vol), filter_type="nearest")
    assert list(nano.resolution()) == list(dense.resolution())
    pts = random_points(100_000 if dr.is_jit_v(mi.Float) else 3000, 10, 0.0, 0.999999)
    a, b = eval_points(nano, pts), eval_points(dense, pts)
    assert np.array_equal(a, b), f"{np.sum(a != b)} of {len(a)} lookups differ"


def test11_grid_bbox_lines_up_with_grid_transform(variants_rgb, cloud):
    # gridvolume(use_grid_bbox) spans the .vol's bbox (the cells' world
    # extent); nanovdbvolume(use_grid_transform) uses the grid's own map:
    # the same voxel at every world point (axis-aligned transform)
    nvdb, vol, stats = cloud
    lo, hi = parse_bbox(stats)
    nano = load_nvdb(str(nvdb), filter_type="nearest", use_grid_transform=True)
    dense = load_dense(str(vol), filter_type="nearest", use_grid_bbox=True)
    assert dr.allclose(nano.bbox().min, dense.bbox().min, rtol=1e-5)
    assert dr.allclose(nano.bbox().max, dense.bbox().max, rtol=1e-5)
    # world points at random positions inside cells, away from cell faces
    # (where float rounding of the two maps may pick the neighbour)
    rng = np.random.default_rng(11)
    n = 50_000 if dr.is_jit_v(mi.Float) else 2000
    ijk = np.stack([rng.integers(lo[k], hi[k] + 1, n) for k in range(3)], axis=1)
    frac = rng.uniform(-0.4, 0.4, size=(n, 3))
    world = (CLOUD_SCALE * (ijk + frac) + CLOUD_OFFSET).astype(np.float32)
    a, b = eval_points(nano, world), eval_points(dense, world)
    assert np.array_equal(a, b), f"{np.sum(a != b)} of {len(a)} lookups differ"


@pytest.mark.parametrize("filter_type", ["nearest", "trilinear"])
def test12_render_dense_equals_nvdb(variants_rgb, cloud, filter_type):
    nvdb, vol, _ = cloud
    nano = load_nvdb(str(nvdb), filter_type=filter_type)
    dense = load_dense(str(vol), filter_type=filter_type)
    assert nano.max() == dense.max()   # equal majorants: equal random decisions
    spp = 4 if dr.is_jit_v(mi.Float) else 1
    a, b = render(nano, spp=spp), render(dense, spp=spp)
    assert np.all(np.isfinite(a)) and np.mean(a) > 0.01
    assert_renders_match(a, b, filter_type)


def test13_stats_of_a_small_cube(gen, tmp_path):
    # constant_40: 40^3 voxels at [0, 39]^3 -> 5^3 leaves, 1 lower, 1 upper
    out = tmp_path / "c.nvdb"
    p = run(gen("constant_40"), out, "--stats", "--probe", "0,0,0", "--probe", "39,39,39",
            "--probe", "40,0,0")
    s = p.stdout
    assert re.search(r"voxel dimensions\s+40 x 40 x 40", s)
    assert re.search(r"nodes upper / lower / leaf\s+1 / 1 / 125\n", s)
    assert re.search(r"active voxels\s+64,000\n", s)
    assert re.search(r"dense equivalent \(voxels x 4 B\)\s+256,000 B", s)
    size = out.stat().st_size
    assert re.search(rf"\.nvdb file size\s+{size:,} B", s)
    # 125 leaves of 2,144 B (NanoVDB 32.4 float leaf: 96 B header + 512 x 4 B)
    m = re.search(r"grid size in memory\s+([\d,]+) B", s)
    grid_bytes = int(m.group(1).replace(",", ""))
    m = re.search(r"leaf nodes\s+268,000 B.*\(([\d.]+) % of the grid\)", s)
    assert float(m.group(1)) == pytest.approx(100 * 268000 / grid_bytes, abs=0.05)
    pr = parse_probes(s)
    assert pr["density", (0, 0, 0)][:2] == (5.0, True)
    assert pr["density", (39, 39, 39)][:2] == (5.0, True)
    assert pr["density", (40, 0, 0)][:2] == (0.0, False)


def test14_generator_is_deterministic(gen, tmp_path):
    for i in range(2):
        run("generate", "random_24", tmp_path / f"r{i}.vdb", tmp_path / f"r{i}.nvdb", "--quiet")
    assert (tmp_path / "r0.nvdb").read_bytes() == (tmp_path / "r1.nvdb").read_bytes()
    p = run(tmp_path / "r0.vdb", tmp_path / "x.nvdb", "--dense", tmp_path / "r.vol")
    _, _, values = read_vol(tmp_path / "r.vol")
    values = np.array(values)
    assert values.size == 24 ** 3 and 4.5 <= values.min() and values.max() <= 5.5
    assert len(np.unique(values)) > 0.99 * values.size
    assert abs(values.mean() - 5.0) < 0.01
    p = run("generate", "--list")
    assert "constant_934" in p.stdout and "cloud" in p.stdout
    p = run("generate", "nonsense", tmp_path / "n.vdb", rc=2)
    assert "random_300" in p.stderr and not (tmp_path / "n.vdb").exists()


def test14b_fireball_case(tmp_path):
    # fireball_<N>: density and temperature with the same active voxels (so
    # the same dense box), temperature 0 where there is no smoke, at most 2.8
    # kK and hot in the core, density in (0, 1]; in the unit cube
    vdb = tmp_path / "f.vdb"
    run("generate", "fireball_32", vdb, "--quiet")
    grids = {}
    for g in ("density", "temperature"):
        p = run(vdb, tmp_path / f"{g}.nvdb", "--grid", g, "--dense", tmp_path / f"{g}.vol",
                "--stats")
        assert "voxel size (0.03125, 0.03125, 0.03125)" in p.stdout, p.stdout
        grids[g] = read_vol(tmp_path / f"{g}.vol")
    (res_d, box_d, d), (res_t, box_t, t) = grids["density"], grids["temperature"]
    assert res_d == res_t and box_d == box_t
    d, t = np.array(d).reshape(res_d[::-1]), np.array(t).reshape(res_d[::-1])
    assert 0.0 < d.max() <= 1.0 and d.min() >= 0.0
    assert np.all(t[d == 0] == 0) and 0.0 <= t.min() and t.max() <= 2.8 + 1e-6
    assert 0.25 < (t > 0.1).sum() / (d > 0).sum() < 0.95   # a core that glows, a cold shell
    assert all(0.0 <= v <= 1.0 for v in box_d)
    # the heat centred on the ball's centre (0.5, 0.47, 0.5); the rim cold:
    # the shell's outer voxels (density only) hold no heat
    kk, jj, ii = np.indices(t.shape)
    xyz = np.array(box_d[:3]) + (np.stack([ii, jj, kk], -1) + 0.5) / 32
    centroid = (xyz * t[..., None]).sum((0, 1, 2)) / t.sum()
    assert np.linalg.norm(centroid - [0.5, 0.47, 0.5]) < 0.05, centroid
    r = np.linalg.norm(xyz - [0.5, 0.47, 0.5], axis=-1)
    assert t[(d > 0) & (r > 0.4)].max(initial=0.0) == 0.0


# ---------------------------------------------------------------------------
#  Verification
# ---------------------------------------------------------------------------

def test15_verify_catches_a_conversion_bug(gen, tmp_path):
    # --corrupt-for-test adds 1 to the first value of every leaf and fixes
    # the checksum: only the value comparison can notice
    out = tmp_path / "bad.nvdb"
    p = run(gen("cloud"), out, "--corrupt-for-test", "--dense", tmp_path / "bad.vol", rc=3)
    m = re.search(r"mismatch at \((-?\d+), (-?\d+), (-?\d+)\): OpenVDB (\S+) \((in)?active\), "
                  r"written file (\S+)", p.stderr)
    assert m, p.stderr
    assert float(m.group(6)) == pytest.approx(float(m.group(4)) + 1.0, abs=1e-5)
    assert "not written" in p.stderr
    assert list(tmp_path.iterdir()) == []


def test16_verify_only_on_a_corrupted_file(gen, tmp_path):
    out = tmp_path / "ok.nvdb"
    run(gen("cloud"), out, "--verify", "0")
    p = run("--verify-only", gen("cloud"), out)
    assert "matches" in p.stdout
    # Overwrite 4 KiB of leaf values near the end of the (uncompressed) file
    data = bytearray(out.read_bytes())
    data[-20000:-16000] = b"\x7f" * 4000
    out.write_bytes(bytes(data))
    p = run("--verify-only", gen("cloud"), out, rc=3)
    assert "does not validate" in p.stderr or "mismatch" in p.stderr
    assert "does not match" in p.stderr
    # A file from other options or another source does not match either
    p = run("--verify-only", gen("sphere_ls"), out, rc=3)


@pytest.mark.parametrize("q", ["fp4", "fp8", "fp16", "fpn"])
def test17_quantized_output_within_bound(gen, tmp_path, q):
    out = tmp_path / f"{q}.nvdb"
    p = run(gen("multi"), out, "--quantize", q, "--verify", "30000")
    assert p.stdout.count("within the quantization bound") == 3
    errs = [float(x) for x in re.findall(r"largest error (\S+)\)", p.stdout)]
    assert max(errs) > 0.0   # quantized for real
    float_size = (tmp_path / "f.nvdb")
    if not float_size.exists():
        run(gen("multi"), float_size, "--verify", "0")
    assert out.stat().st_size < float_size.stat().st_size
    # The file renders: nanovdbvolume reads every quantized grid, and its
    # values lie within half a quantization step of the float file's: the
    # grid's value range / (2^bits - 1) / 2, for FpN at most its tolerance
    # (0.01 for the fog volumes, 0 for "temperature", class unknown), plus
    # the float rounding of code * quantum + minimum (the converter's bound)
    mi.set_variant("llvm_ad_rgb")
    mi.file_resolver().prepend(str(BUILD))
    rng = np.random.default_rng(17)
    pts = rng.uniform(0, 1, size=(50_000, 3)).astype(np.float32)
    for grid in ["density", "ls_sphere", "temperature"]:
        qv = load_nvdb(str(out), grid=grid, filter_type="nearest")
        fv = load_nvdb(str(float_size), grid=grid, filter_type="nearest")
        name = {"fp4": "Fp4", "fp8": "Fp8", "fp16": "Fp16", "fpn": "FpN"}[q]
        assert f"grid_type = {name}," in str(qv)
        f = eval_points(fv, pts)
        diff = np.abs(eval_points(qv, pts) - f)
        value_range = float(fv.max() - f.min())
        if q == "fpn":
            bound = max(0.0 if grid == "temperature" else 0.01, 0.5 * value_range / 65535)
        else:
            bound = 0.5 * value_range / (2 ** int(q[2:]) - 1)
        bound += 8 * np.finfo(np.float32).eps * (max(abs(f.min()), fv.max()) + value_range)
        assert 0 < diff.max() <= bound, (grid, diff.max(), bound)


def test18_quantize_options(gen, tmp_path):
    p = run(gen("multi"), tmp_path / "t.nvdb", "--quantize", "fpn", "--tolerance", "0.5",
            "--grid", "temperature")
    err = float(re.search(r"largest error (\S+)\)", p.stdout).group(1))
    assert 0.0 < err <= 0.5
    p = run(gen("multi"), tmp_path / "h.nvdb", "--quantize", "half", rc=2)
    assert "fp16" in p.stderr
    p = run(gen("multi"), tmp_path / "h.nvdb", "--tolerance", "0.5", rc=2)
    assert "fpn" in p.stderr
    assert leftovers(tmp_path) == [] and not (tmp_path / "h.nvdb").exists()


# ---------------------------------------------------------------------------
#  Bad input: a clear message, a non-zero exit, nothing left behind
# ---------------------------------------------------------------------------

def test19_missing_input(tmp_path):
    p = run(tmp_path / "nope.vdb", tmp_path / "o.nvdb", rc=1)
    assert "nope.vdb" in p.stderr and "no such file" in p.stderr
    assert list(tmp_path.iterdir()) == []


def test20_corrupt_and_truncated_input(gen, tmp_path):
    (tmp_path / "garbage.vdb").write_bytes(b"this is not a vdb file at all" * 10)
    cloud = gen("cloud").read_bytes()
    (tmp_path / "trunc.vdb").write_bytes(cloud[: len(cloud) // 2])
    (tmp_path / "empty.vdb").write_bytes(b"")
    for name in ["garbage.vdb", "trunc.vdb", "empty.vdb"]:
        p = run(tmp_path / name, tmp_path / "o.nvdb", rc=1)
        # (a file cut inside a grid: its descriptor's end lies past the
        # file's, found before OpenVDB reads it: src/loader/vdb_read.h)
        assert name in p.stderr and ("cannot read as an OpenVDB file" in p.stderr or
                                     "truncated: grid" in p.stderr), p.stderr
    assert not (tmp_path / "o.nvdb").exists() and leftovers(tmp_path) == []


def test21_unknown_grid_lists_the_grids(gen, tmp_path):
    p = run(gen("multi"), tmp_path / "o.nvdb", "--grid", "smoke", rc=1)
    assert 'no grid named "smoke"' in p.stderr
    for name in ["density", "vel", "ls_sphere", "flags", "temperature"]:
        assert f'"{name}"' in p.stderr
    p = run(gen("multi"), tmp_path / "o.nvdb", "--grid", "flags", rc=1)
    assert '"flags" (int32' in p.stderr and "only float and vec3s" in p.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name,kind", [("openvdb_sphere_points.vdb", "ptdataidx32")])
def test22_no_convertible_grid(tmp_path, name, kind):
    p = run(need_shared_data(name) / name, tmp_path / "o.nvdb", rc=1)
    assert "no float or vec3s grid" in p.stderr and kind in p.stderr and name in p.stderr
    assert list(tmp_path.iterdir()) == []


def test23_unwritable_output(gen, tmp_path):
    (tmp_path / "file").write_text("x")
    cases = [tmp_path / "no" / "such" / "dir" / "o.nvdb",   # missing directory
             tmp_path / "file" / "o.nvdb",                   # a file as directory
             tmp_path]                                       # a directory as output
    for out in cases:
        p = run(gen("cloud"), out, rc=1)
        assert "vdb2nvdb: error:" in p.stderr and str(out) in p.stderr
    # --dense to an unwritable place: no .nvdb either
    p = run(gen("cloud"), tmp_path / "o.nvdb", "--dense", tmp_path / "no" / "o.vol", rc=1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test24_dense_too_large_is_refused(gen, tmp_path):
    p = run(gen("cloud"), tmp_path / "o.nvdb", "--dense", tmp_path / "o.vol",
            "--max-dense-bytes", "1M", rc=1)
    # cloud: 121 x 129 x 119 voxels = 7,429,884 B + 48 B of header
    assert "7,429,932 B" in p.stderr and "--max-dense-bytes" in p.stderr
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------
#  Real files (../shared/data, used in place)
# ---------------------------------------------------------------------------

# file -> grids written (None: rejected with a clear message)
EXPECTED = {
    "houdini_velocity_vec3s.vdb": ["vel"],
    "openvdb_sphere_points.vdb": None,
    "openvdb_icosahedron_ls.vdb": ["ls_icosahedron"],
    "openvdb_smoke1_fog.vdb": ["density"],
    "openvdb_sphere_ls.vdb": ["ls_sphere"],
    "usd_blender_smoke_empty.vdb": ["density", "shadow", "velocity"],
    "usd_density_heat_fog.vdb": ["density", "heat"],
    "zeno_unnamed_ls.vdb": [""],
}


@pytest.mark.parametrize("path", shared_data_files("*.vdb"))
def test25_shared_data_files(path, tmp_path):
    need_shared_data()
    assert path.name in EXPECTED, f"new file in shared/data: add {path.name} to EXPECTED"
    want = EXPECTED[path.name]
    out = tmp_path / "o.nvdb"
    p = run(path, out, "--dense", tmp_path / "o.vol", "--stats", rc=None)
    if want is None:
        assert p.returncode == 1 and "no float or vec3s grid" in p.stderr
        assert list(tmp_path.iterdir()) == []
        return
    assert p.returncode == 0, p.stderr
    assert p.stdout.count("identical") == len(want)   # --verify, exact
    assert plugin_grid_names(out) == want
    for i in range(len(want)):
        vol = load_nvdb(str(out), grid=str(i), filter_type="nearest")
        vols = sorted(tmp_path.glob("o*.vol"))
        res, _, values = read_vol(vols[i])
        assert list(vol.resolution()) == list(res)
        assert vol.max() >= max(values)
        dense = load_dense(str(vols[i]), filter_type="nearest")
        pts = random_points(2000, 30 + i, 0.0, 0.999999)
        assert np.array_equal(eval_points(vol, pts), eval_points(dense, pts))


# Installation (pip install .: the binary inside the package, the console
# script vdb2nvdb): tests/test_pip_install.py

