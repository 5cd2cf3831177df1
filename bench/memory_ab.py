"""Before/after measurement of a plugin change on the backend's memory and
render time: two builds of nanovdbvolume, the same grids, one fresh process
per (build, grid), interleaved (A B A B ...).

    python3 bench/memory_ab.py --builds OLD_BUILD NEW_BUILD --grids a.nvdb b.nvdb \
        --warmup tiny.nvdb [--variant cuda_ad_rgb] [--out table.md]

Per process: the device memory in use before/after mi.load_dict() of the
volume (CUDA: NVML, i.e. nvidia-smi's view; LLVM: RSS), Dr.Jit's allocator
watermark, and the warm median of 5 renders of the benchmark scene's first
sensor (128^2, 64 spp, trilinear). Prints a markdown table with the ratios
new/old.
"""
import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import harness  # noqa: E402


def measure(spec):
    """One process (bench/harness.py): a build's memory held by a grid's
    volume, its allocator watermark, and the render time"""
    import statistics
    import time
    import gpu
    from child_setup import mitsuba_for
    from scene import turntable_scene, volume_dict
    from worker import rss_bytes
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    jit_backend = dr.backend_v(mi.Float)
    # CUDA context and modules first, with another (tiny) grid: a block of
    # the measured grid's size must not be waiting in a pool when it is measured
    warm = mi.load_dict(volume_dict("nanovdbvolume", spec["warmup"], "trilinear"))
    del warm
    dr.sync_thread()
    dr.flush_malloc_cache()
    dr.detail.malloc_clear_statistics()
    cuda = spec["variant"].startswith("cuda")
    u0 = gpu.used_bytes() if cuda else rss_bytes()
    w0 = dr.detail.malloc_watermark(jit_backend)
    vol = mi.load_dict(volume_dict("nanovdbvolume", spec["grid"], "trilinear"))
    dr.sync_thread()
    held = (gpu.used_bytes() if cuda else rss_bytes()) - u0
    wm = dr.detail.malloc_watermark(jit_backend) - w0
    scene = mi.load_dict(turntable_scene(vol, 128, 64))
    ts = []
    for k in range(6):
        t0 = time.perf_counter()
        img = mi.render(scene, sensor=0, spp=64, seed=k)
        dr.eval(img)
        dr.sync_thread()
        ts.append(time.perf_counter() - t0)
    return {"held": held, "watermark": wm, "render_s": statistics.median(ts[1:])}


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--builds", nargs=2, required=True, metavar=("OLD", "NEW"))
    ap.add_argument("--grids", nargs="+", required=True)
    ap.add_argument("--variant", default="cuda_ad_rgb")
    ap.add_argument("--warmup", required=True, help="a tiny .nvdb loaded first (CUDA context)")
    ap.add_argument("--out")
    a = ap.parse_args()
    rows = []
    for g in a.grids:
        size = os.path.getsize(g)
        r = {}
        for tag, build in zip(("old", "new"), a.builds):
            spec = dict(variant=a.variant, build=os.path.abspath(build),
                        grid=os.path.abspath(g), warmup=os.path.abspath(a.warmup))
            try:
                r[tag] = harness.run_child("memory_ab:measure", spec)
            except harness.ChildFailed as e:
                sys.exit(f"{tag} on {g}: {e}")
        rows.append((os.path.basename(g), size, r))
    L = [f"{a.variant}: old = `{a.builds[0]}`, new = `{a.builds[1]}`; held = device memory "
         "in use after − before loading (NVML) on CUDA, RSS on LLVM; render: first sensor of "
         "the benchmark scene, 128², 64 spp, trilinear, warm median of 5.\n",
         "| grid | file bytes | held old | held new | old / file | new / file | allocator old | "
         "allocator new | render old [s] | render new [s] | new/old |",
         "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, size, r in rows:
        o, n = r["old"], r["new"]
        L.append(f"| {name} | {size:,} | {o['held']:,} | {n['held']:,} | {o['held'] / size:.3f} | "
                 f"{n['held'] / size:.3f} | {o['watermark']:,} | {n['watermark']:,} | "
                 f"{o['render_s']:.4f} | {n['render_s']:.4f} | "
                 f"{n['render_s'] / o['render_s']:.3f} |")
    text = "\n".join(L) + "\n"
    print(text)
    if a.out:
        open(a.out, "w").write(text)


if __name__ == "__main__":
    main()
