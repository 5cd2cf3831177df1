"""nanovdb-render (python/nanovdb_mitsuba/render.py) on the real files in
../shared/data that hold a float fog volume or level set: each renders, at a
tiny size, to a finite, non-constant image in which the volume's world box
lies inside the frame and covers a fair share of it; a .vdb and the .nvdb
vdb2nvdb makes of it give the same image. The command reads files through
nanovdbvolume alone (test05: level sets, no vdb2nvdb process, no temporary
file), and lists their grids through a structured call (test06)."""
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from conftest import BUILD, ROOT, need_shared_data, shared_data_files

sys.path.insert(0, str(ROOT / "python"))
from nanovdb_mitsuba.render import render_file  # noqa: E402
from nanovdb_mitsuba.scene import _project  # noqa: E402

def float_grids(path):
    """[(name, class, active voxels)] of the float grids in `path`, as
    `vdb2nvdb --list` reads them (OpenVDB's reader for .vdb, NanoVDB's for
    .nvdb); None where it cannot read the file"""
    p = subprocess.run([str(BUILD / "bin" / "vdb2nvdb"), "--list", str(path)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        return None
    rows = []
    for line in p.stdout.splitlines():
        m = re.match(r'^\s+\d+\s+"(.*?)"\s+(.*)$', line)
        if m:
            cols = re.split(r"\s{2,}", m.group(2).strip())
            if cols[0] == "float":
                rows.append((m.group(1), cols[1], int(cols[2].replace(",", ""))))
    return rows


def renderable(path):
    """Why `path` has nothing for the render test, or None if it holds a
    float grid (fog volume, level set or unknown class) with active voxels"""
    rows = float_grids(path)
    if rows is None:
        return "vdb2nvdb --list cannot read it"
    if not any(n > 0 for _, _, n in rows):
        return "no float grid with active voxels" if rows else "no float grid"
    return None


def render(path, tmp_path, **kw):
    return render_file(str(path), str(tmp_path / (path.stem + ".png")), res=32, spp=4,
                       quiet=True, **kw)


@pytest.mark.parametrize("path", shared_data_files("*.*db"))
def test01_renders_framed(path, tmp_path):
    need_shared_data()
    why = renderable(path)
    if why:
        pytest.skip(f"{path.name}: {why} (test04 checks what the command says)")
    image, info = render(path, tmp_path)
    assert np.all(np.isfinite(image))
    assert image.std() > 1e-3, "constant image"
    assert (tmp_path / (path.stem + ".png")).exists() and (tmp_path / (path.stem + ".exr")).exists()
    # The world box projects inside the frame and covers at least 10 % of it
    cam = info["camera"]
    lo, hi = info["bbox_min"], info["bbox_max"]
    pts = [_project([hi[k] if (i >> k) & 1 else lo[k] for k in range(3)], cam["origin"],
                    cam["target"], cam["fov"]) for i in range(8)]
    assert all(p is not None and abs(p[0]) <= 1 and abs(p[1]) <= 1 for p in pts)
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    assert (max(xs) - min(xs)) * (max(ys) - min(ys)) / 4 > 0.1
    assert info["scale"] > 0
    # What was rendered is a density: level sets (.vdb by vdb2nvdb, .nvdb
    # by nanovdb-render itself) become fog volumes, never signed distances
    # (fvdb_batch4's "level set" has background 0, no inside: its fog is
    # empty, and the command says so and renders the values, documented)
    assert info["grid_class"] in ("fog volume", "unknown") or info.get("level_set_values"), \
        info["grid_class"]


def test02_vdb_and_its_nvdb_give_the_same_image(tmp_path):
    src = need_shared_data("openvdb_smoke1_fog.vdb") / "openvdb_smoke1_fog.vdb"
    nvdb = tmp_path / "smoke.nvdb"
    subprocess.run([str(BUILD / "bin" / "vdb2nvdb"), str(src), str(nvdb)], check=True,
                   capture_output=True)
    a, ia = render(src, tmp_path)
    b, ib = render(nvdb, tmp_path)
    assert ia["scale"] == ib["scale"]
    assert ia["bbox_min"] == ib["bbox_min"] and ia["bbox_max"] == ib["bbox_max"]
    # Same scene, same seeds: equal up to the order of the film's atomic
    # accumulation (Gaussian reconstruction filter)
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test03_command_line(tmp_path):
    src = need_shared_data("usd_density_heat_fog.vdb") / "usd_density_heat_fog.vdb"
    out = tmp_path / "heat.png"
    env = dict(os.environ, PYTHONPATH=str(ROOT / "python"))
    p = subprocess.run([sys.executable, "-m", "nanovdb_mitsuba.render", str(src), "-o", str(out),
                        "--res", "24", "--spp", "4", "--scale", "2"], env=env,
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert "density scale 2" in p.stdout and "wrote" in p.stdout
    assert out.exists() and out.with_suffix(".exr").exists()
    p = subprocess.run([sys.executable, "-m", "nanovdb_mitsuba.render", str(tmp_path / "no.vdb")],
                       env=env, capture_output=True, text=True)
    assert p.returncode != 0 and "no.vdb" in p.stderr


@pytest.mark.parametrize("path", shared_data_files("*.*db"))
def test04_files_without_a_density_get_one_clear_line(path, tmp_path):
    """The shared files test01 skips: the command either renders them while
    saying what it rendered (an empty grid, a Vec3f grid), or fails with one
    line that names the file and the problem, never with a traceback."""
    need_shared_data()
    if renderable(path) is None:
        pytest.skip(f"{path.name}: rendered by test01")
    env = dict(os.environ, PYTHONPATH=str(ROOT / "python"))
    p = subprocess.run([sys.executable, "-m", "nanovdb_mitsuba.render", str(path), "-o",
                        str(tmp_path / "x.png"), "--res", "16", "--spp", "1"], env=env,
                       capture_output=True, text=True)
    assert "Traceback" not in p.stderr, p.stderr
    if p.returncode == 0:
        # an empty grid says so; an index grid (OnIndex, its values in a
        # blind channel) is a density, rendered as one
        assert ("holds no active voxels" in p.stdout or
                ("onindex" in path.name and "wrote" in p.stdout)), p.stdout
    else:
        last = p.stderr.strip().splitlines()[-1]
        assert path.name in last and ("nanovdb-render:" in last), last


def test05_level_sets_render_without_a_converter(tmp_path):
    """A .vdb level set and the same level set kept in a .nvdb go straight
    to nanovdbvolume (level_set="fog"): no vdb2nvdb process (every way the
    package could find one fails and leaves a mark) and no temporary file
    (nothing is made in TMPDIR); both render as the same fog, so the same image"""
    trap_dir, tmp = tmp_path / "trap", tmp_path / "tmp"
    trap_dir.mkdir()
    tmp.mkdir()
    mark = tmp_path / "vdb2nvdb_ran"
    trap = trap_dir / "vdb2nvdb"
    trap.write_text(f"#!/bin/sh\necho ran >> '{mark}'\nexit 1\n")
    trap.chmod(0o755)
    exe = str(BUILD / "bin" / "vdb2nvdb")
    vdb, nvdb = tmp_path / "ball.vdb", tmp_path / "ball.nvdb"
    subprocess.run([exe, "generate", "sphere_ls_16", str(vdb)], check=True, capture_output=True)
    subprocess.run([exe, str(vdb), str(nvdb), "--keep-level-sets"], check=True,
                   capture_output=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT / "python"), NVDB_VDB2NVDB=str(trap),
               PATH=f"{trap_dir}:{os.environ.get('PATH', '')}", TMPDIR=str(tmp))
    images = []
    written = os.stat(tmp).st_mtime_ns  # (changes when a file is made in it, even if removed)
    for src in (vdb, nvdb):
        out = tmp_path / f"{src.suffix[1:]}.png"
        p = subprocess.run([sys.executable, "-m", "nanovdb_mitsuba.render", str(src), "-o",
                            str(out), "--res", "16", "--spp", "4", "--scale", "4"], env=env,
                           capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        assert f'{src}: grid "ls_sphere" is a level set: rendering it as a fog volume' in p.stdout
        assert not mark.exists(), "vdb2nvdb ran"
        assert os.stat(tmp).st_mtime_ns == written, f"a temporary file: {os.listdir(tmp)}"
        import mitsuba as mi
        mi.set_variant("scalar_rgb")
        images.append(np.array(mi.Bitmap(str(out.with_suffix(".exr")))))
    assert images[0].std() > 1e-3
    # The same fog (test_vdb_import test08 compares the grids bit for bit):
    # equal up to the order of the film's atomic accumulation
    np.testing.assert_allclose(images[0], images[1], rtol=1e-4, atol=1e-5)


def vdb2nvdb(*args):
    subprocess.run([str(BUILD / "bin" / "vdb2nvdb"), *map(str, args)], check=True,
                   capture_output=True)


def test06_grid_listing(tmp_path, monkeypatch):
    """nanovdb_mitsuba.files.list_grids: the grids' names, types and classes
    as fields (the generator's "multi": vdb2nvdb generate --list), from a
    .vdb through the reader process and from a .nvdb's headers; every
    failure a FileError that names the file"""
    from nanovdb_mitsuba import files
    multi_vdb = tmp_path / "multi.vdb"
    vdb2nvdb("generate", "multi", multi_vdb)
    want = [("density", "float", "fog volume"), ("vel", "vec3s", "unknown"),
            ("ls_sphere", "float", "level set"), ("flags", "int32", "unknown"),
            ("temperature", "float", "unknown")]
    got = files.list_grids(multi_vdb)
    assert [(g.name, g.type, g.grid_class) for g in got] == want
    assert [g.index for g in got] == list(range(5))
    # vdb2nvdb's .nvdb: float and vec3s grids, the level set made fog;
    # as an Fp16 file the scalar grids are still "float" (one channel)
    for quantize, stored in (("float", "float"), ("fp16", "Fp16")):
        nvdb = tmp_path / f"multi_{quantize}.nvdb"
        vdb2nvdb(multi_vdb, nvdb, "--quantize", quantize)
        got = files.list_grids(nvdb)
        assert [(g.name, g.type, g.grid_class) for g in got] == [
            ("density", "float", "fog volume"), ("vel", "vec3s", "unknown"),
            ("ls_sphere", "float", "fog volume"), ("temperature", "float", "unknown")]
        assert [g.stored_type for g in got] == [stored, "Vec3f", stored, stored]
    assert files.grid_rows(multi_vdb)[1] == ("vel", "vec3s")
    # Damaged, missing, not a volume: an error that names the file
    data = multi_vdb.read_bytes()
    cases = {"truncated.vdb": data[:200], "garbage.vdb": bytes(range(256)) * 40,
             "garbage.nvdb": bytes(range(256)) * 40, "empty.nvdb": b""}
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(files.FileError, match=name):
            files.list_grids(tmp_path / name)
    with pytest.raises(files.FileError, match=r'missing.vdb": no such file'):
        files.list_grids(tmp_path / "missing.vdb")
    # A reader that crashes: the caller gets an error, and lives on
    crash = tmp_path / "crash.sh"
    crash.write_text("#!/bin/sh\nkill -SEGV $$\n")
    crash.chmod(0o755)
    monkeypatch.setenv("NVDB_VDB_READER", str(crash))
    copy = tmp_path / "copy.vdb"
    copy.write_bytes(data)
    with pytest.raises(files.FileError, match=r'copy.vdb": damaged: .*crashed on it with '
                                              r'SIGSEGV'):
        files.list_grids(copy)


def trilinear_box_mean(values):
    """The mean over the box of the voxels' cells ([-1/2, n - 1/2] per axis)
    of the trilinear interpolant of `values` (numpy (z, y, x)), zero outside:
    along an axis each voxel's hat function integrates to 1 inside the box,
    an end voxel's to 1/2 + 3/8 (the box ends half a voxel beyond its
    centre, where the hat is down to 1/2), 3/4 for a single voxel"""
    weights = []
    for n in values.shape:
        w = np.ones(n)
        w[0] = w[-1] = (0.875 if n > 1 else 0.75)
        weights.append(w)
    total = np.einsum("zyx,z,y,x->", values.astype(np.float64), *weights)
    return total / values.size


@pytest.mark.parametrize("case", ["constant_24", "random_32", "cloud_32"])
def test07_the_printed_optical_depth_is_the_real_one(case, tmp_path, capsys):
    """The command prints the density scale and the mean optical depth
    across the box that it gives: scale x the density's mean over the box x
    the box's mean extent (the mean, over the lines through the box parallel
    to an axis, of scale x the density's integral, averaged over the axes).
    The mean density here from numpy on the grid's dense export,
    independently of the plugin's lookups: constant_24, 5.0 in a 24^3 cube,
    has it in closed form, 5 x (23.75 / 24)^3; random_32 (values in [4.5,
    5.5]) is a case where the scale's bound of the mean, from the maximum
    (5.5), is 10 % high; cloud_32 (voxels of 0.01 x 0.01 x 0.0125) a box
    that is not a cube."""
    vdb, vol = tmp_path / f"{case}.vdb", tmp_path / f"{case}.vol"
    vdb2nvdb("generate", case, vdb)
    vdb2nvdb(vdb, tmp_path / "x.nvdb", "--dense", vol, "--verify", "0", "--quiet")
    raw = vol.read_bytes()
    assert raw[:4] == b"VOL\x03"
    nx, ny, nz = np.frombuffer(raw[8:20], dtype="<i4")
    bbox = np.frombuffer(raw[24:48], dtype="<f4").astype(np.float64)  # the cells' world box
    extent = (bbox[3:] - bbox[:3]).mean()
    values = np.frombuffer(raw[48:], dtype="<f4").reshape(nz, ny, nx)
    mean = trilinear_box_mean(values)
    n = int(case.split("_")[1])
    if case.startswith("constant"):
        assert mean == pytest.approx(5.0 * ((n - 0.25) / n) ** 3, rel=1e-12)
        assert extent == n  # voxel size 1
    render_file(str(vdb), str(tmp_path / "x.png"), res=8, spp=1)
    out = capsys.readouterr().out
    m = re.search(r"density scale ([0-9.e+-]+) \(default, from the density bounds; change it "
                  r"with --scale\); mean optical depth across the box ([0-9.e+-]+)\n", out)
    assert m, out
    scale, printed = float(m.group(1)), float(m.group(2))
    # printed with 6 and 4 digits
    assert printed == pytest.approx(scale * mean * extent, rel=1e-3)
    if case == "random_32":
        assert printed < 0.92 * 8  # the bound's 8 is not the real depth here
    # scalar_rgb: exact where its lattice (scene.LATTICE_POINTS_SCALAR,
    # 2^17 cells) still has 2 cells per voxel (24^3); a coarser one at 32^3
    # (about 50^3 cells): a midpoint estimate, which misses part of the
    # trilinear falloff in the half voxel at the box's faces (1.8 % of
    # random_32's mass; the estimate is 0.19 % high)
    import mitsuba as mi
    from nanovdb_mitsuba import files, setup
    from nanovdb_mitsuba.scene import mean_optical_depth
    mi.set_variant("scalar_rgb")
    setup(mi)
    depth = mean_optical_depth(files.load_volume(mi, vdb), scale)
    assert depth == pytest.approx(scale * mean * extent, rel=1e-5 if n == 24 else 5e-3)


def test08_shadow_rays_go_to_the_sun(tmp_path):
    """framed_scene gives the sky a sampling_weight of 0: next-event
    estimation samples the sun alone, and phase sampling finds the sky (MIS
    weight 1 there, the sky's emitter pdf being 0). Against Mitsuba's
    default choice, where half the shadow rays go to the sky: the same mean
    (a z-test on the image means of independent renders) and a lower
    variance per sample (1.8-1.9x on the shared smoke and the generator's cloud
    at 128²; bench/INTEGRATOR_LOG.md, 2026-11-27). llvm_ad_rgb, cloud_32."""
    import mitsuba as mi
    from nanovdb_mitsuba import setup
    from nanovdb_mitsuba.scene import framed_scene
    vdb = tmp_path / "cloud_32.vdb"
    vdb2nvdb("generate", "cloud_32", vdb)
    mi.set_variant("llvm_ad_rgb")
    setup(mi)
    renders, sky = {}, None
    for name, sky_weight in (("framed", None), ("mitsuba's default", 1.0)):
        desc, _ = framed_scene(mi, str(vdb), res=24, spp=8, filter_type="trilinear")
        if sky_weight is not None:
            desc["sky"]["sampling_weight"] = sky_weight
        desc["sensor"]["film"]["rfilter"] = {"type": "box"}  # (independent pixels)
        sky = np.array(desc["sky"]["radiance"]["value"])  # (the background's pixels)
        scene = mi.load_dict(desc)
        base = 1000 if sky_weight is None else 2000
        renders[name] = np.stack([np.array(mi.render(scene, seed=base + s))[..., :3]
                                  for s in range(24)]).astype(np.float64)
    mask = np.any(np.abs(renders["mitsuba's default"].mean(0) - sky) > 0.02, axis=-1)
    assert mask.sum() > 50, "the volume covers too few pixels to compare"
    means = {k: v[:, mask].mean(axis=(1, 2)) for k, v in renders.items()}
    a, b = means["framed"], means["mitsuba's default"]
    se = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    assert abs(a.mean() - b.mean()) < 4 * se, (a.mean(), b.mean(), se)
    var = {k: v.var(axis=0, ddof=1)[mask].mean() for k, v in renders.items()}
    assert var["mitsuba's default"] > 1.3 * var["framed"], var
