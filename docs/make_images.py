"""Makes the pictures of README.md and the guides (docs/images/), with the installed package:

1. `nanovdb-render FILE -o ...` (the console script, defaults: 256², 64 spp,
   llvm_ad_rgb, volpathlocal) on every .vdb/.nvdb in ../shared/data, timed
   from the shell's side (conversion, kernel compilation and render), with
   what the command printed; a table in docs/images/README.md. Files it
   cannot render are listed with its message.
2. The two placement modes on the OpenVDB smoke (docs/placement.md).

    python3 docs/make_images.py [--shared ../shared/data] [--only shared|placement]
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
IMAGES = os.path.join(HERE, "images")


def render_shared(shared):
    rows = []
    for old in os.listdir(os.path.join(IMAGES, "shared")):  # no stale pictures
        os.remove(os.path.join(IMAGES, "shared", old))
    with tempfile.TemporaryDirectory() as tmp:
        for name in sorted(os.listdir(shared)):
            if not name.endswith((".vdb", ".nvdb")):
                continue
            stem = os.path.splitext(name)[0]
            out = os.path.join(tmp, stem + ".png")
            src = os.path.relpath(os.path.join(shared, name), ROOT)
            cmd = ["nanovdb-render", src, "-o", out]
            t0 = time.perf_counter()
            p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               cwd=ROOT)
            seconds = time.perf_counter() - t0
            said = [re.sub(r"\x1b\[[0-9;]*m", "", l.split("\r")[-1])  # no ANSI colours
                    for l in p.stdout.splitlines() if l.strip()]
            if p.returncode == 0:
                shutil.copy(out, os.path.join(IMAGES, "shared", stem + ".png"))
                scale = next((l.split("density scale ")[1].split(" ")[0].rstrip(";")
                              for l in said if "density scale" in l), "?")
                # what the command said about the grid, beyond the box and scale
                notes = [l.split(": ", 1)[1] for l in said
                         if l.startswith(src + ":") and "world bbox" not in l]
                rows.append((name, f"![](shared/{stem}.png)", f"{seconds:.1f} s",
                             "; ".join([f"scale {scale}"] + notes)))
            else:
                rows.append((name, "not rendered", f"{seconds:.1f} s", said[-1] if said else ""))
            print(f"{name}: {rows[-1][2]}, {rows[-1][3]}", flush=True)
    with open(os.path.join(IMAGES, "README.md"), "w") as f:
        f.write("# `nanovdb-render` on the files in `../shared/data`\n\n"
                "Made by `python3 docs/make_images.py` with the installed package: for each\n"
                "file, `nanovdb-render ../shared/data/FILE -o FILE.png` with its defaults\n"
                "(256², 64 spp, `llvm_ad_rgb`, `volpathlocal`, the default density scale).\n"
                "The time is the whole command, from the shell: Python start, the `.vdb`\n"
                "conversion, loading, Dr.Jit's kernel compilation and the render, on a\n"
                "2-core machine. Files without a float-like grid to render are listed with\n"
                "the command's message.\n\n"
                "| file | image | time | what the command said |\n|---|---|---|---|\n")
        for r in rows:
            f.write("| " + " | ".join(x.replace("|", "\\|") for x in r) + " |\n")


def render_placement(shared, res=192, spp=32):
    import mitsuba as mi
    import nanovdb_mitsuba
    from nanovdb_mitsuba.scene import camera
    mi.set_variant("llvm_ad_rgb")
    with tempfile.TemporaryDirectory() as tmp:
        nvdb = os.path.join(tmp, "smoke.nvdb")
        subprocess.run([nanovdb_mitsuba.vdb2nvdb(), os.path.join(shared, "openvdb_smoke1_fog.vdb"),
                        nvdb, "--verify", "0"], check=True, stdout=subprocess.DEVNULL)
        T = mi.ScalarTransform4f
        unit = mi.load_dict({"type": "nanovdbvolume", "filename": nvdb})
        world = mi.load_dict({"type": "nanovdbvolume", "filename": nvdb, "use_grid_transform": True})
        res3 = unit.resolution()
        s = [r / max(res3) for r in res3]
        cube01 = T().translate([0.5, 0.5, 0.5]).scale(0.5)
        wb = world.bbox()
        wbox = ([float(x) for x in wb.min], [float(x) for x in wb.max])
        cases = {
            # name: (the shape's to_world, volume parameters, the box the camera frames: the shape)
            "unit_cube": (cube01, {}, ([0, 0, 0], [1, 1, 1])),
            "unit_cube_scaled": (T().scale(s) @ cube01, {"to_world": T().scale(s)}, ([0, 0, 0], s)),
            "grid_transform_clipped": (cube01, {"use_grid_transform": True}, ([0, 0, 0], [1, 1, 1])),
            "grid_transform_fitted": (nanovdb_mitsuba.enclosing_cube(mi, world),
                                      {"use_grid_transform": True}, wbox),
        }
        for name, (to_world, extra, frame) in cases.items():
            vdict = dict({"type": "nanovdbvolume", "filename": nvdb}, **extra)
            # the same mean optical depth in each (the clipped one: as the fitted one)
            scale = nanovdb_mitsuba.default_scale(mi.load_dict(vdict))
            box = mi.ScalarBoundingBox3f(frame[0], frame[1])
            cam = camera(box)
            scene = mi.load_dict({
                "type": "scene",
                "integrator": {"type": "volpathlocal", "max_depth": 64},
                "sensor": {"type": "perspective", "fov": cam["fov"],
                           "to_world": T().look_at(origin=cam["origin"], target=cam["target"],
                                                   up=[0, 1, 0]),
                           "film": {"type": "hdrfilm", "width": res, "height": res}},
                "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.15, 0.18, 0.25]}},
                "sun": {"type": "directional", "direction": [-1, -1, -0.5],
                        "irradiance": {"type": "rgb", "value": [6, 5.7, 5.1]}},
                "box": {"type": "cube", "to_world": to_world, "bsdf": {"type": "null"},
                        "interior": {"type": "heterogeneous", "sigma_t": vdict, "scale": scale,
                                     "albedo": {"type": "rgb", "value": [0.9, 0.9, 0.9]}}},
            })
            image = mi.render(scene, spp=spp)
            out = os.path.join(IMAGES, f"placement_{name}.png")
            mi.util.write_bitmap(out, image)
            print("wrote", out, flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shared", default=os.path.join(ROOT, "..", "shared", "data"))
    ap.add_argument("--only", choices=["shared", "placement"])
    a = ap.parse_args()
    if not os.path.isdir(a.shared):
        sys.exit(f"make_images.py: no folder {a.shared} (--shared)")
    os.makedirs(os.path.join(IMAGES, "shared"), exist_ok=True)
    if a.only in (None, "shared"):
        render_shared(a.shared)
    if a.only in (None, "placement"):
        render_placement(a.shared)


if __name__ == "__main__":
    main()
