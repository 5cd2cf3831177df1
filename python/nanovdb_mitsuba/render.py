"""nanovdb-render: a user's .vdb or .nvdb, correctly proportioned, in one command.

    nanovdb-render smoke.vdb -o smoke.png
        [--grid NAME] [--spp 64] [--res 256] [--variant llvm_ad_rgb]
        [--integrator volpathlocal] [--scale S] [--filter trilinear]

The file goes straight to nanovdbvolume (files.py): only the grids rendered
are read, a .vdb through the plugin's reader process, and a level set
(.vdb or .nvdb) becomes a fog volume (level_set="fog"); no converter runs
and no temporary file is written. The volume stays in its own world space (use_grid_transform)
inside a null-BSDF box fitted to it, framed by a camera and lit by a sky and
a sun (scene.py). The density scale defaults to one from the plugin's
per-node density bounds (scene.default_scale: a mean optical depth of 8
across the box if the density were as high as its bounds); it is printed
with the mean optical depth across the box that it really gives (scale x
the density's mean over the box x the box's mean extent:
scene.mean_optical_depth). The render runs in passes with a progress bar;
the image is written as PNG (sRGB, 8 bit) and EXR (linear).
`nanovdb-render` is the console script pip installs; from a clone without
installing: PYTHONPATH=python python3 -m nanovdb_mitsuba.render ...
"""
import argparse
import os
import sys
import time

if __package__ in (None, ""):  # run as a file: python3 python/nanovdb_mitsuba/render.py
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    __package__ = "nanovdb_mitsuba"

from nanovdb_mitsuba import files, fire, sequence, setup  # noqa: E402
from nanovdb_mitsuba.scene import framed_scene, mean_optical_depth  # noqa: E402


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


def render_file(path, out, grid="", spp=64, res=256, variant="llvm_ad_rgb",
                integrator="volpathlocal", scale=None, filter_type="trilinear", passes=None,
                quiet=False, emission_grid=None, emission_mode=None, temperature_scale=None,
                temperature_offset=None, emission_scale=None):
    """Renders `path` (.vdb or .nvdb); writes `out` (.png; an .exr beside it).
    emission_grid: None finds one by name (fire.py), "none" renders none, a
    name that grid; the other emission_* / temperature_* None: fire.py's
    defaults. Returns (image as numpy array, info)."""
    import numpy as np
    import mitsuba as mi
    import drjit as dr
    mi.set_variant(variant)
    setup(mi)
    # The density: --grid, else a grid named "density", else the
    # first float grid (nanovdbvolume's choice without a name)
    rows = files.grid_rows(path)
    density = fire.default_density(rows)
    if grid:
        density = rows[int(grid)][0] if grid.isdigit() and int(grid) < len(rows) else grid
    by_name = grid or (density if density.lower() == "density" else "")
    found = fire.emission_candidates([n for n, _ in rows], exclude=density)
    chosen, mode = fire.choose(path, rows, density, emission_grid, emission_mode)
    if chosen and integrator != "volpathlocal":
        raise SystemExit(f"nanovdb-render: {path}: grid \"{chosen}\" emits light, which "
                         f"only the volpathlocal integrator renders, not {integrator}; "
                         "leave --integrator out, or add --no-emission")
    if chosen:
        by_name = density
    # The file itself, to nanovdbvolume: only this grid is read, a level
    # set made a fog volume (level_set="fog", .vdb and .nvdb alike)
    volume = files.load_volume(mi, path, by_name, filter_type)
    props = files.volume_properties(volume, path)
    level_set_values = False
    if props["level_set_fogged"]:
        if not quiet:
            print(f"{path}: grid \"{props.get('grid')}\" is a level set: rendering it as a "
                  "fog volume (nanovdbvolume's level_set=\"fog\")")
        if props["max"] == 0:
            # No inside: e.g. a "level set" whose background (the band's
            # width) is 0. Its values as densities, negative ones as 0
            distances = files.load_volume(mi, path, by_name, filter_type,
                                          level_set="distance", invalid_values="clamp")
            dprops = files.volume_properties(distances, path)
            if dprops["max"] != 0:
                print(f"{path}: the level set's fog volume is empty (background "
                      f"{dprops['background']:g}: no inside to fill); rendering its values "
                      "as densities instead, negative ones as 0")
                volume, props, level_set_values = distances, dprops, True
            del distances
    kw = dict(scale=scale, res=res, spp=spp, integrator=integrator, filter_type=filter_type)
    scene_dict, info = framed_scene(mi, path, grid=by_name, volume=volume, **kw)
    del volume
    if level_set_values:
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
    info["emission"] = None
    if chosen or found:
        # A fire's smoke: the same albedo with its emission or without
        # it (--no-emission), so that the two differ only by the glow
        interior = scene_dict["box"]["interior"]
        interior["albedo"] = {"type": "rgb", "value": [fire.FIRE_ALBEDO] * 3}
    if found and not quiet and not chosen:
        listed = ", ".join(f'"{n}"' for n in found)
        print(f"{path}: emission grids {listed}: not rendered (--no-emission); albedo "
              f"{fire.FIRE_ALBEDO:g}")
    if chosen:
        info["emission"] = add_emission(
            mi, scene_dict, path, chosen, mode, found, filter_type,
            dict(temperature_scale=temperature_scale, temperature_offset=temperature_offset,
                 emission_scale=emission_scale), quiet)
    if not quiet:
        bmin, bmax = info["bbox_min"], info["bbox_max"]
        depth = mean_optical_depth(info["volume"], info["scale"])
        print(f"{path}: world bbox [{', '.join(f'{v:g}' for v in bmin)}] .. "
              f"[{', '.join(f'{v:g}' for v in bmax)}]; density scale {info['scale']:.6g}"
              f"{' (default, from the density bounds; change it with --scale)' if scale is None else ''}"
              f"; mean optical depth across the box {depth:.4g}")
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
    info["grid"] = props.get("grid")
    info.pop("volume", None)
    if not quiet:
        print(f"wrote {out} and {exr} ({res}x{res}, {spp} spp, {variant}, {integrator}) "
              f"in {info['seconds']:.1f} s")
    return image, info


def add_emission(mi, scene_dict, path, name, mode, found, filter_type, overrides, quiet):
    """Makes scene_dict's medium glow with grid `name` of `path` (fire.py
    picks the scales from the loaded grid's max()); says what it chose.
    Returns what it rendered (a dict), or None where the grid cannot emit
    (empty, or never hot enough): then the scene stays as it was."""
    rendered, summary, why_not = fire.add_emission(mi, scene_dict, path, name, mode, filter_type,
                                                   **overrides)
    listed = ", ".join(f'"{n}"' for n in found) or "none by name"
    if rendered is None:
        if not quiet:
            print(f"{path}: emission grid \"{name}\" is empty ({why_not}): rendering without "
                  "emission")
        return None
    if not quiet:
        print(f"{path}: emission grids: {listed}; \"{name}\" glows: {summary}; albedo "
              f"{fire.FIRE_ALBEDO:g}; {fire.LIGHTING}")
    return rendered


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
                    help="density scale (default: 8 / (the mean of the plugin's per-node "
                         "density bounds x the box's mean extent); the command prints the "
                         "mean optical depth across the box that the scale gives)")
    ap.add_argument("--filter", default="trilinear", choices=["trilinear", "nearest"])
    fire_args = ap.add_argument_group(
        "fire", "A grid named emission, flame, temperature or heat (case-insensitive; the "
        "first of these present, in this order) beside the density makes the medium glow "
        "(emissiveheterogeneous, rendered by volpathlocal; the density's albedo becomes "
        f"{fire.FIRE_ALBEDO:g}). temperature/heat: blackbody emission, the grid's max mapped "
        f"to {fire.HOTTEST_KELVIN:.0f} K; emission/flame: radiance in a "
        f"{fire.FIRE_KELVIN:.0f} K blackbody's colour. Either way the brightest value has "
        f"luminance {fire.BRIGHTNESS:g} (twice the brightest sunlit smoke).")
    fire_args.add_argument("--emission-grid", metavar="NAME", default=None,
                           help="the emission grid (default: found by name), or none")
    fire_args.add_argument("--no-emission", action="store_true",
                           help="render the density only (same as --emission-grid none)")
    fire_args.add_argument("--emission-mode", choices=list(fire.MODES), default=None,
                           help="default: temperature for temperature/heat, else radiance")
    fire_args.add_argument("--temperature-scale", type=float, default=None, metavar="S",
                           help="kelvin = (value - offset) x S (default: the grid's max -> "
                                f"{fire.HOTTEST_KELVIN:.0f} K)")
    fire_args.add_argument("--temperature-offset", type=float, default=None, metavar="O",
                           help="see --temperature-scale (default 0)")
    fire_args.add_argument("--emission-scale", type=float, default=None, metavar="E",
                           help="multiplies the emitted radiance (default: the brightest "
                                f"value's luminance -> {fire.BRIGHTNESS:g})")
    sequence.add_arguments(ap)
    a = ap.parse_args(argv)
    if a.no_emission:
        if a.emission_grid not in (None, "none"):
            ap.error("--no-emission and --emission-grid contradict each other")
        a.emission_grid = "none"
    emission_options = [o for o, v in (("--emission-mode", a.emission_mode),
                                       ("--temperature-scale", a.temperature_scale),
                                       ("--temperature-offset", a.temperature_offset),
                                       ("--emission-scale", a.emission_scale)) if v is not None]
    if a.emission_grid == "none" and emission_options:
        ap.error(f"{emission_options[0]} needs an emission grid, not --no-emission")
    if a.emission_mode == "radiance" and (a.temperature_scale is not None or
                                          a.temperature_offset is not None):
        ap.error("--temperature-scale and --temperature-offset apply to --emission-mode "
                 "temperature")
    if sequence.handles(a, ap):  # 'smoke.####.vdb', 'smoke.%04d.vdb' or a folder (sequence.py)
        return
    if not os.path.exists(a.input):
        raise SystemExit(f"nanovdb-render: \"{a.input}\": no such file")
    out = a.output or os.path.splitext(os.path.basename(a.input))[0] + ".png"
    try:
        render_file(a.input, out, grid=a.grid, spp=a.spp, res=a.res, variant=a.variant,
                    integrator=a.integrator, scale=a.scale, filter_type=a.filter,
                    emission_grid=a.emission_grid, emission_mode=a.emission_mode,
                    temperature_scale=a.temperature_scale,
                    temperature_offset=a.temperature_offset, emission_scale=a.emission_scale)
    except RuntimeError as e:  # (files.FileError too)
        # The messages already name the file and the problem; Mitsuba's
        # lose their source location prefix ("[parser.cpp:1718] ...")
        raise SystemExit(f"nanovdb-render: {files.plugin_message(e)}")


if __name__ == "__main__":
    main()
