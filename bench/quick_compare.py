"""Quick one-scene comparison: nanovdbvolume vs gridvolume (same scene, same spp).

    python3 bench/quick_compare.py [--case noisy_cloud] [--scale 2]
                                   [--variant llvm_ad_rgb] [--spp 32] [--res 256]
                                   [--runs 5]

Writes the test grid with build/bin/nvdb_make_test_grid (as .nvdb and as the
dense .vol export of the same active box), then renders scenes/cloud.xml's
scene with each plugin. It reports the first-render time (incl. JIT
compilation), the median of --runs warm renders, the bytes Dr.Jit's allocator
reserved for the volume while loading it (watermark difference; Dr.Jit rounds
every allocation up to a power of two), the grid's own bytes, and the RMSE
between the two images. A measurement, not a test.
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
import drjit as dr
import mitsuba as mi

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "scenes"))
from render_cloud import cloud_scene  # noqa: E402


def backend_bytes(load):
    """Bytes the JIT allocator newly reserves while `load()` runs."""
    if not dr.is_jit_v(mi.Float):
        return load(), None
    backend = dr.backend_v(mi.Float)
    dr.sync_thread()
    dr.flush_malloc_cache()
    dr.detail.malloc_clear_statistics()
    before = dr.detail.malloc_watermark(backend)
    obj = load()
    dr.eval()
    dr.sync_thread()
    return obj, dr.detail.malloc_watermark(backend) - before


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="noisy_cloud")
    ap.add_argument("--scale", type=int, default=2)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--filter", default="trilinear")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    args = ap.parse_args()

    mi.set_variant(args.variant)
    mi.file_resolver().prepend(os.path.abspath(args.build))
    tmp = tempfile.mkdtemp()
    nvdb, vol = os.path.join(tmp, "grid.nvdb"), os.path.join(tmp, "grid.vol")
    subprocess.run([os.path.join(args.build, "bin", "nvdb_make_test_grid"), args.case, nvdb,
                    "--dense", vol, "--scale", str(args.scale)], check=True)

    images = {}
    for plugin, path in [("nanovdbvolume", nvdb), ("gridvolume", vol)]:
        # volpath: the plugins compared under Mitsuba's own integrator
        desc = cloud_scene(path, filter_type=args.filter, spp=args.spp, res=args.res,
                           integrator="volpath")
        desc["cube"]["interior"]["sigma_t"]["type"] = plugin
        volume, nbytes = backend_bytes(
            lambda: mi.load_dict(desc["cube"]["interior"]["sigma_t"]))
        desc["cube"]["interior"]["sigma_t"] = volume
        scene = mi.load_dict(desc)
        t0 = time.perf_counter()
        img = mi.render(scene, seed=0)
        dr.eval(img)
        dr.sync_thread()
        first = time.perf_counter() - t0
        times = []
        for i in range(args.runs):
            t0 = time.perf_counter()
            img = mi.render(scene, seed=i + 1)
            dr.eval(img)
            dr.sync_thread()
            times.append(time.perf_counter() - t0)
        images[plugin] = np.array(img)
        print(f"{plugin:14s} first {first:7.3f} s  warm median {statistics.median(times):7.3f} s"
              f"  ({args.runs} runs: {', '.join(f'{t:.3f}' for t in times)})"
              f"  backend bytes {nbytes}  file {os.path.getsize(path)} B")
    a, b = images["nanovdbvolume"], images["gridvolume"]
    print(f"RMSE between the two images: {np.sqrt(np.mean((a - b) ** 2)):.5f}"
          f" (image mean {b.mean():.4f})")


if __name__ == "__main__":
    main()
