"""nanovdb-render: a user's .vdb or .nvdb, correctly proportioned, in one command.

    nanovdb-render smoke.vdb -o smoke.png
        [--grid NAME] [--spp 64] [--res 256] [--variant llvm_ad_rgb]
        [--integrator volpathlocal] [--scale S] [--filter trilinear]

A .vdb is converted first (vdb2nvdb, into a temporary file; level sets become
fog volumes). The volume stays in its own world space (use_grid_transform)
inside a null-BSDF box fitted to it, framed by a camera and lit by a sky and
a sun (scene.py). The density scale defaults to a mean optical depth of
about 8 across the box (from the plugin's per-node bounds), and is printed. The render runs in passes with a
progress bar; the image is written as PNG (sRGB, 8 bit) and EXR (linear).
`nanovdb-render` is the console script pip installs; from a clone without
installing: PYTHONPATH=python python3 -m nanovdb_mitsuba.render ...
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile
import time

if __package__ in (None, ""):  # run as a file: python3 python/nanovdb_mitsuba/render.py
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    __package__ = "nanovdb_mitsuba"

from nanovdb_mitsuba import setup, vdb2nvdb  # noqa: E402
from nanovdb_mitsuba.facts import volume_facts  # noqa: E402
from nanovdb_mitsuba.scene import framed_scene  # noqa: E402


def progress(done, total, started, out=sys.stderr):
    width = 30
    filled = int(width * done / total)
    elapsed = time.perf_counter() - started
    eta = elapsed / done * (total - done) if done else 0.0
    out.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{total} passes, "
              f"{elapsed:.1f} s elapsed, {eta:.1f} s left ")
    out.flush()
    if done == total:
        out.write("\n")


def convert(path, grid, tmpdir):
    """A .vdb through vdb2nvdb (only the chosen grid, or all of them)"""
    out = os.path.join(tmpdir, os.path.splitext(os.path.basename(path))[0] + ".nvdb")
    cmd = [vdb2nvdb(), path, out, "--verify", "0"]
    if grid:
        cmd += ["--grid", grid]
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        # vdb2nvdb's last line is its error; the notes before it go first
        lines = r.stdout.strip().splitlines() or [f"vdb2nvdb failed ({r.returncode})"]
        for note in lines[:-1]:
            print(note, file=sys.stderr)
        raise SystemExit(f"nanovdb-render: {lines[-1]}")
    return out


def grid_names(path):
    """The names of a .nvdb or .vdb file's grids, in file order (vdb2nvdb --list)"""
    r = subprocess.run([vdb2nvdb(), "--list", path], stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True)
    names = []
    for line in r.stdout.splitlines():
        m = re.match(r'^\s+(\d+)\s+"(.*)"\s', line)
        if m and int(m.group(1)) == len(names):
            names.append(m.group(2))
    return names


def volume_properties(volume, path):
    """A loaded nanovdbvolume's facts (nanovdb_mitsuba.volume_facts), with
    "grid", the name of its grid in `path`"""
    facts = volume_facts(volume)
    index = facts["grid_index"]
    names = grid_names(path) if index is not None else []
    facts["grid"] = names[index] if index is not None and index < len(names) else ""
    return facts


def render_file(path, out, grid="", spp=64, res=256, variant="llvm_ad_rgb",
                integrator="volpathlocal", scale=None, filter_type="trilinear", passes=None,
                quiet=False):
    """Renders `path` (.vdb or .nvdb); writes `out` (.png; an .exr beside it).
    Returns (image as numpy array, info)."""
    import numpy as np
    import mitsuba as mi
    import drjit as dr
    mi.set_variant(variant)
    setup(mi)
    with tempfile.TemporaryDirectory() as tmp:
        nvdb = convert(path, grid, tmp) if path.lower().endswith(".vdb") else path
        kw = dict(scale=scale, res=res, spp=spp, integrator=integrator, filter_type=filter_type)
        scene_dict, info = framed_scene(mi, nvdb, grid=grid if nvdb == path else "", **kw)
        props = volume_properties(info["volume"], nvdb)
        if nvdb == path and props.get("grid_class") == "level set":
            # A .nvdb level set: signed distances, not a density. Made a fog
            # volume as a .vdb's level set is (vdb2nvdb reads .nvdb too)
            if not quiet:
                print(f"{path}: grid \"{props.get('grid')}\" is a level set: rendering it as a "
                      "fog volume (vdb2nvdb, into a temporary file)")
            del scene_dict, info
            level_set = props
            nvdb = convert(path, props.get("grid"), tmp)
            scene_dict, info = framed_scene(mi, nvdb, **kw)
            props = volume_properties(info["volume"], nvdb)
            if props["max"] == 0 and level_set["max"] != 0:
                # No inside: e.g. a "level set" whose background (the band's
                # width) is 0. Its values as densities, negative ones as 0
                print(f"{path}: the level set's fog volume is empty (background "
                      f"{level_set['background']:g}: no inside to fill); rendering its values "
                      "as densities instead, negative ones as 0")
                del scene_dict, info
                nvdb = path
                scene_dict, info = framed_scene(mi, path, grid=level_set.get("grid"),
                                                invalid_values="clamp", **kw)
                props = volume_properties(info["volume"], nvdb)
                info["level_set_values"] = True
        if not quiet and props["index_dims"] == [1, 1, 1] and props["max"] == 0:
            print(f"{path}: grid \"{props.get('grid')}\" holds no active voxels and a zero "
                  "background: the image shows only the lights")
        if props.get("grid_type") == "Vec3f":
            if not grid:  # the file's first renderable grid, not the user's choice
                raise SystemExit(
                    f"nanovdb-render: {path}: its first grid, \"{props.get('grid')}\", is a Vec3f "
                    "grid (a colour or a vector), not a density; choose a scalar grid with "
                    f"--grid, or --grid {props.get('grid') or 0} to render this one as a colour "
                    "extinction (one density per RGB channel)")
            if not quiet:
                print(f"{path}: grid \"{props.get('grid')}\" is a Vec3f grid: rendered as a "
                      "colour extinction (one density per RGB channel)")
        if not quiet:
            bmin, bmax = info["bbox_min"], info["bbox_max"]
            print(f"{path}: world bbox [{', '.join(f'{v:g}' for v in bmin)}] .. "
                  f"[{', '.join(f'{v:g}' for v in bmax)}]; density scale {info['scale']:.6g}"
                  f"{' (default: mean optical depth ~8; change it with --scale)' if scale is None else ''}")
        scene = mi.load_dict(scene_dict)
        # Passes of a few samples each: a progress bar, and the same image
        # as one render of `spp` samples per pixel in expectation
        passes = passes or max(1, min(16, spp // 4))
        per = [spp // passes + (1 if i < spp % passes else 0) for i in range(passes)]
        acc = None
        started = time.perf_counter()
        for i, n in enumerate(per):
            img = mi.render(scene, spp=n, seed=i)
            dr.eval(img)
            a = np.array(img) * n
            acc = a if acc is None else acc + a
            if not quiet:
                progress(i + 1, passes, started)
        image = (acc / spp).astype(np.float32)
        bitmap = mi.Bitmap(image)
        exr = os.path.splitext(out)[0] + ".exr"
        bitmap.write(exr)
        bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True).write(out)
        info["seconds"] = time.perf_counter() - started
        info["grid_class"] = props.get("grid_class")
        info.pop("volume", None)
        if not quiet:
            print(f"wrote {out} and {exr} ({res}x{res}, {spp} spp, {variant}, {integrator}) "
                  f"in {info['seconds']:.1f} s")
        return image, info


def main(argv=None):
    ap = argparse.ArgumentParser(prog="nanovdb-render", description=__doc__.split("\n\n")[0])
    ap.add_argument("input", help=".vdb or .nvdb file")
    ap.add_argument("-o", "--output", help="PNG to write (default: INPUT's name + .png); "
                                           "an EXR is written beside it")
    ap.add_argument("--grid", default="", help="grid name or index (default: the first one)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--integrator", default="volpathlocal")
    ap.add_argument("--scale", type=float, default=None,
                    help="density scale (default: a mean optical depth of about 8)")
    ap.add_argument("--filter", default="trilinear", choices=["trilinear", "nearest"])
    a = ap.parse_args(argv)
    if not os.path.exists(a.input):
        raise SystemExit(f"nanovdb-render: \"{a.input}\": no such file")
    out = a.output or os.path.splitext(os.path.basename(a.input))[0] + ".png"
    try:
        render_file(a.input, out, grid=a.grid, spp=a.spp, res=a.res, variant=a.variant,
                    integrator=a.integrator, scale=a.scale, filter_type=a.filter)
    except RuntimeError as e:
        # Mitsuba's messages already name the file and the problem; drop
        # its source location prefix ("[parser.cpp:1718] ...")
        msg = str(e)
        inner = msg.rsplit("[NanoVDBVolume] ", 1)[-1]
        raise SystemExit(f"nanovdb-render: {inner.strip()}")


if __name__ == "__main__":
    main()
