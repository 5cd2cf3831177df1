"""nanovdb-render (python/nanovdb_mitsuba/render.py) on the real files in
../shared/data that hold a float fog volume or level set: each renders, at a
tiny size, to a finite, non-constant image in which the volume's world box
lies inside the frame and covers a fair share of it; a .vdb and the .nvdb
vdb2nvdb makes of it give the same image."""
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
