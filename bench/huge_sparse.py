"""The use case the project exists for: a sparse volume whose dense form does
not fit in GPU memory at all, rendered on the GPU.

    python3 bench/huge_sparse.py [--n 3200] [--variant cuda_ad_rgb] [--out bench/results/cuda]

Generates `cloudfield_N` with vdb2nvdb (24 frayed cloud puffs in an N^3 box,
1-2 % occupied; N = 3200: its active box holds 2.3e10 voxels, 91 GB as a
dense float grid, more than an 80 GB GPU has), then in this
process: loads it with nanovdbvolume (device memory before/after, as the
driver reports it), shows that the dense grid cannot even be allocated on
this device (a dense float tensor of the active box), measures random-lookup
throughput, the render time of the benchmark turntable at equal spp and the
error against run time (RMSE against a converged render of its own), and
saves one view. Results: huge_sparse.json, huge_sparse.md (a report section)
and huge_sparse.png in --out.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)


def generate(n, data, build):
    base = os.path.join(data, f"cloudfield_{n}")
    nvdb, stats = base + ".nvdb", base + ".stats.txt"
    t0 = time.perf_counter()
    if not (os.path.exists(nvdb) and os.path.exists(stats)):
        os.makedirs(data, exist_ok=True)
        r = subprocess.run([os.path.join(build, "bin", "vdb2nvdb"), "generate", f"cloudfield_{n}",
                            base + ".vdb", nvdb, "--stats"], capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"vdb2nvdb generate cloudfield_{n} failed:\n{r.stdout}\n{r.stderr}")
        open(stats, "w").write(r.stdout)
        os.remove(base + ".vdb")  # only the .nvdb is rendered
    text = open(stats).read()
    dims = [int(x) for x in re.search(r"voxel dimensions\s+(\d+) x (\d+) x (\d+)", text).groups()]
    grid = int(re.search(r"grid size in memory\s+([\d,]+) B", text).group(1).replace(",", ""))
    active = int(re.search(r"active voxels\s+([\d,]+)", text).group(1).replace(",", ""))
    return nvdb, {"n": n, "dims": dims, "grid_bytes": grid, "active_voxels": active,
                  "dense_bytes": 4 * int(np.prod(dims, dtype=np.int64)),
                  "nvdb_file_bytes": os.path.getsize(nvdb),
                  "generate_s": time.perf_counter() - t0, "stats": text}


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3200)
    ap.add_argument("--variant", default="cuda_ad_rgb")
    ap.add_argument("--filter", default="trilinear", choices=["trilinear", "nearest"])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--sweep", type=int, nargs="+", default=[4, 16, 64, 256])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--ref-passes", type=int, default=4)
    ap.add_argument("--lookups", type=int, default=1 << 24)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--data", default=os.path.join(HERE, "data"))
    ap.add_argument("--out", default=os.path.join(HERE, "results", "cuda"))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)

    nvdb, info = generate(a.n, a.data, a.build)
    print(f"cloudfield_{a.n}: grid {info['grid_bytes']:,} B, dense {info['dense_bytes']:,} B "
          f"({'x'.join(map(str, info['dims']))}), generated in {info['generate_s']:.1f} s",
          flush=True)

    import drjit as dr
    import mitsuba as mi
    import gpu
    import metrics
    from scene import turntable_scene, volume_dict
    from worker import lookup_throughput, render_turntable
    mi.set_variant(a.variant)
    mi.file_resolver().prepend(a.build)
    out = dict(info, variant=a.variant, filter=a.filter, res=a.res, spp=a.spp,
               device=gpu.device_name())
    del out["stats"]

    # Memory: the device's view before and after loading
    dr.sync_thread()
    dr.flush_malloc_cache()
    g0 = gpu.used_bytes()
    t0 = time.perf_counter()
    vol = mi.load_dict(volume_dict("nanovdbvolume", nvdb, a.filter))
    dr.sync_thread()
    out["load_s"] = time.perf_counter() - t0
    out["gpu_used"] = (gpu.used_bytes() - g0) if g0 is not None else None
    print(f"loaded in {out['load_s']:.2f} s; device memory: {held(out)}", flush=True)

    # The dense alternative: a float tensor of the active box on this device
    try:
        dense = dr.zeros(mi.TensorXf, shape=tuple(info["dims"][::-1]) + (1,))
        dr.eval(dense)
        dr.sync_thread()
        out["dense_alloc"] = "succeeded (unexpected: the device holds the dense grid)"
        del dense
    except Exception as e:
        while e.__cause__ is not None:  # the reason is in the innermost exception
            e = e.__cause__
        out["dense_alloc"] = f"failed: {' '.join(str(e).split())[:300]}"
    dr.flush_malloc_cache()
    print(f"dense tensor of the box ({info['dense_bytes']:,} B): {out['dense_alloc']}", flush=True)

    out.update(lookup_throughput(mi, dr, vol, a.lookups, 5))
    print(f"lookups: {out['lookups_per_s']:.3g}/s", flush=True)

    scene = mi.load_dict(turntable_scene(vol, a.res, a.spp))
    out["first_s"], _ = render_turntable(mi, dr, scene, a.spp, 0)
    times = [render_turntable(mi, dr, scene, a.spp, 1 + r)[0] for r in range(a.runs)]
    out["warm_s"] = times
    out["warm_median_s"] = float(np.median(times))
    print(f"turntable {a.res}^2 x 8 sensors x {a.spp} spp: warm median "
          f"{out['warm_median_s']:.3f} s (first {out['first_s']:.2f} s)", flush=True)

    passes = []
    t_ref = 0.0
    for k in range(a.ref_passes):
        t, im = render_turntable(mi, dr, scene, a.ref_spp // a.ref_passes, 1_000_000 + k)
        passes.append(im.astype(np.float64))
        t_ref += t
    p = np.stack(passes)
    ref, var = p.mean(axis=0), p.var(axis=0, ddof=1) / len(passes)
    out["ref_spp"], out["ref_time_s"] = a.ref_spp, t_ref
    sweep = []
    for j, s in enumerate(a.sweep):
        # Twice, keeping the faster: a new spp count compiles new kernels
        t, im = min((render_turntable(mi, dr, scene, s, 100 + j) for _ in range(2)),
                    key=lambda r: r[0])
        raw, corr = metrics.rmse(im, ref, var)
        sweep.append({"spp": s, "time_s": t, "rmse": corr, "rmse_raw": raw,
                      "ssim": metrics.ssim(im, ref)})
        print(f"  {s:4d} spp: {t:.3f} s, RMSE {corr:.5f}", flush=True)
    out["sweep"] = sweep
    out["image_mean"] = float(ref.mean())
    out["image_finite"] = bool(np.all(np.isfinite(ref)))

    # One view, larger, for the report
    view = mi.load_dict(turntable_scene(vol, 4 * a.res, a.spp))
    img = np.asarray(mi.render(view, sensor=0, spp=4 * a.spp, seed=7), dtype=np.float32)[..., :3]
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        plt.imsave(os.path.join(a.out, "huge_sparse.png"), np.clip(img, 0, 1) ** (1 / 2.2))
    except ImportError:
        pass

    json.dump(out, open(os.path.join(a.out, "huge_sparse.json"), "w"), indent=1)
    write_section(out, os.path.join(a.out, "huge_sparse.md"))
    print(open(os.path.join(a.out, "huge_sparse.md")).read())


def held(o):
    if o.get("gpu_used") is None:
        return "not measured (no GPU)"
    return f"{o['gpu_used']:,} B ({o['gpu_used'] / o['grid_bytes']:.4f} × the grid)"


def write_section(o, path):
    gib = 2 ** 30
    L = [f"### A grid whose dense form does not fit on the GPU: cloudfield_{o['n']}\n",
         f"Device: {o['device']}. `vdb2nvdb generate cloudfield_{o['n']}`: 24 frayed cloud "
         f"puffs in a {o['n']}³ box, {o['active_voxels']:,} active voxels; active box "
         f"{' × '.join(map(str, o['dims']))}. Command: `python3 bench/huge_sparse.py --n {o['n']}`.\n",
         "| | value |", "|---|---:|",
         f"| dense float grid of the active box | {o['dense_bytes']:,} B ({o['dense_bytes'] / gib:.1f} GiB) |",
         f"| NanoVDB grid | {o['grid_bytes']:,} B ({o['grid_bytes'] / gib:.2f} GiB) |",
         f"| device memory held by `nanovdbvolume` (NVML, after − before load) | {held(o)} |",
         f"| dense tensor of the box on this device (`dr.zeros(TensorXf)`) | {o['dense_alloc']} |",
         f"| generate + convert + verify (vdb2nvdb) | {o['generate_s']:.1f} s |",
         f"| load (read, validate, upload) | {o['load_s']:.2f} s |",
         f"| random `eval_1` lookups ({o['filter']}, {o['lookup_n']:,} points) | "
         f"{o['lookups_per_s'] / 1e6:,.0f} M/s |",
         f"| turntable {o['res']}² × 8 sensors × {o['spp']} spp, warm median ({o['filter']}) | "
         f"{o['warm_median_s']:.3f} s (first, with JIT: {o['first_s']:.2f} s) |",
         "", "Error against run time (RMSE against its own "
         f"{o['ref_spp']}-spp render, reference noise subtracted):\n",
         "| spp | time [s] | RMSE | SSIM |", "|---:|---:|---:|---:|"]
    for s in o["sweep"]:
        L.append(f"| {s['spp']} | {s['time_s']:.3f} | {s['rmse']:.5f} | {s['ssim']:.4f} |")
    L.append("\n![cloudfield view](huge_sparse.png)\n")
    open(path, "w").write("\n".join(L) + "\n")


if __name__ == "__main__":
    main()
