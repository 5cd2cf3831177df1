"""Per value type: what a precision costs and buys.

For the real smoke (../shared/data/openvdb_smoke1_fog.vdb) and the generated
cloud, vdb2nvdb writes the grid as float, Fp16, Fp8, Fp4 and FpN (NanoVDB's
own encoders) and a dense .vol for gridvolume. Each is rendered in the
benchmark scene (bench/scene.py: 8 turntable sensors, sky + sun, albedo 0.9,
max_depth 64), on llvm_ad_rgb, at several sample counts: nanovdbvolume with
volpathlocal, gridvolume with volpath (what volpathlocal does with it).

Measured per type: the .nvdb file's bytes, the bytes the backend holds (the
grid, padded to 64, + the majorant table), the render time per sample count,
and the error against the float grid's converged render (RMSE over every
sensor, pixel and channel; the reference's own noise is subtracted, see
metrics.rmse). The quantization error is what remains at high sample counts;
the chart shows error against time, one line per type, so that one can read
which precision gives the lowest error for the time and the memory.

    python3 bench/value_types.py [--res 48] [--spp 4 16 64] [--ref-spp 512]
                                 [--out bench/results/value_types]

Measurements, not tests: nothing here asserts a target.
"""
import argparse
import csv
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

TYPES = ["float", "fp16", "fp8", "fp4", "fpn", "dense"]


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed:\n{r.stdout}")
    return r.stdout


def make_files(case, source, data_dir, vdb2nvdb):
    """The case's .nvdb per type and its dense .vol; returns {type: path}."""
    os.makedirs(data_dir, exist_ok=True)
    files = {}
    vdb = source
    if source is None:  # the generated cloud
        vdb = os.path.join(data_dir, f"{case}.vdb")
        if not os.path.exists(vdb):
            run([vdb2nvdb, "generate", "cloud", vdb])
    for t in TYPES[:-1]:
        out = os.path.join(data_dir, f"{case}_{t}.nvdb")
        if not os.path.exists(out):
            cmd = [vdb2nvdb, vdb, out, "--grid", "density", "--verify", "20000"]
            if t != "float":
                cmd += ["--quantize", t]
            if t == "float":
                cmd += ["--dense", os.path.join(data_dir, f"{case}.vol")]
            run(cmd)
        files[t] = out
    files["dense"] = os.path.join(data_dir, f"{case}.vol")
    return files


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", type=int, default=48)
    ap.add_argument("--spp", type=int, nargs="+", default=[4, 16, 64])
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--vdb", default=os.path.join(ROOT, "..", "shared", "data",
                                                 "openvdb_smoke1_fog.vdb"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(HERE, "results", "value_types"))
    a = ap.parse_args()

    import drjit as dr
    import mitsuba as mi
    mi.set_variant(a.variant)
    mi.file_resolver().prepend(a.build)
    from scene import turntable_scene
    from metrics import rmse
    sys.path.insert(0, os.path.join(ROOT, "python"))
    from nanovdb_mitsuba.facts import volume_facts

    vdb2nvdb = os.path.join(a.build, "bin", "vdb2nvdb")
    data_dir = os.path.join(HERE, "data", "value_types")
    cases = [("cloud", None)]
    if os.path.exists(a.vdb):
        cases.insert(0, ("smoke", a.vdb))
    else:
        print(f"no {a.vdb}: the smoke case is left out")
    os.makedirs(a.out, exist_ok=True)

    def render(volume, integrator, spp, seed):
        scene = mi.load_dict(turntable_scene(volume, a.res, spp, integrator))
        imgs = []
        t0 = time.perf_counter()
        for i in range(len(scene.sensors())):
            img = mi.render(scene, sensor=i, spp=spp, seed=seed * 1009 + i)
            dr.eval(img)
            dr.sync_thread()
            imgs.append(img)
        return time.perf_counter() - t0, np.stack([np.asarray(im)[..., :3] for im in imgs])

    def load(t, path):
        if t == "dense":
            return mi.load_dict({"type": "gridvolume", "filename": path,
                                 "filter_type": "trilinear"}), "volpath"
        return mi.load_dict({"type": "nanovdbvolume", "filename": path,
                             "filter_type": "trilinear"}), "volpathlocal"

    rows, lines = [], []
    for case, source in cases:
        files = make_files(case, source, data_dir, vdb2nvdb)
        # The reference: the float grid, converged (two halves: their
        # difference estimates the reference's own noise)
        ref_vol, ref_int = load("float", files["float"])
        _, r1 = render(ref_vol, ref_int, a.ref_spp // 2, 101)
        _, r2 = render(ref_vol, ref_int, a.ref_spp // 2, 202)
        ref = 0.5 * (r1 + r2)
        ref_var_of_mean = ((r1 - r2) ** 2) / 4.0
        for t in TYPES:
            vol, integrator = load(t, files[t])
            file_bytes = os.path.getsize(files[t])
            if t == "dense":
                backend = file_bytes - 48  # the dense floats
            else:
                facts = volume_facts(vol)
                backend = facts["backend_bytes"] + facts["majorant_bytes"]
            render(vol, integrator, a.spp[0], 7)  # compiles the kernels
            for spp in a.spp:
                secs, img = render(vol, integrator, spp, 11)
                raw, err = rmse(img, ref, ref_var_of_mean)
                rows.append(dict(case=case, type=t, file_bytes=file_bytes,
                                 backend_bytes=backend, spp=spp, seconds=round(secs, 4),
                                 rmse=err, rmse_raw=raw))
                print(f"{case:6s} {t:6s} spp {spp:4d}: {secs:7.3f} s, RMSE {err:.5f} "
                      f"(raw {raw:.5f}), file {file_bytes:,} B, backend {backend:,} B",
                      flush=True)
            del vol

    with open(os.path.join(a.out, "value_types.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)

    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        for case, _ in cases:
            fig, ax = plt.subplots(figsize=(6, 4.2))
            for t in TYPES:
                pts = [(r["seconds"], r["rmse"]) for r in rows if r["case"] == case and r["type"] == t]
                if pts:
                    xs, ys = zip(*pts)
                    ax.loglog(xs, ys, "o-", label=t)
            ax.set_xlabel("render time [s] (8 sensors, %d^2, %s)" % (a.res, a.variant))
            ax.set_ylabel("RMSE vs the float grid's converged render")
            ax.set_title(f"{case}: error against time per value type")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
            fig.tight_layout()
            fig.savefig(os.path.join(a.out, f"error_time_{case}.png"), dpi=110)
            plt.close(fig)
    except ImportError:
        print("matplotlib is missing: no chart")

    with open(os.path.join(a.out, "REPORT.md"), "w") as f:
        f.write("# Value types: bytes, time and error\n\n")
        f.write(f"`python3 bench/value_types.py --res {a.res} --spp {' '.join(map(str, a.spp))} "
                f"--ref-spp {a.ref_spp}` on {a.variant}; nanovdbvolume with volpathlocal, "
                "gridvolume (dense) with volpath; trilinear. RMSE against the float grid's "
                f"render at {a.ref_spp} spp (its own noise subtracted).\n\n")
        for case, _ in cases:
            f.write(f"## {case}\n\n![error against time](error_time_{case}.png)\n\n")
            f.write("| type | file bytes | backend bytes | vs float | " +
                    " | ".join(f"time {s} spp" for s in a.spp) + " | " +
                    " | ".join(f"RMSE {s} spp" for s in a.spp) + " |\n")
            f.write("|---|---|---|---|" + "---|" * (2 * len(a.spp)) + "\n")
            fb = [r for r in rows if r["case"] == case and r["type"] == "float"][0]["backend_bytes"]
            for t in TYPES:
                rs = [r for r in rows if r["case"] == case and r["type"] == t]
                if not rs:
                    continue
                f.write(f"| {t} | {rs[0]['file_bytes']:,} | {rs[0]['backend_bytes']:,} | "
                        f"{rs[0]['backend_bytes'] / fb:.3f} | " +
                        " | ".join(f"{r['seconds']:.2f} s" for r in rs) + " | " +
                        " | ".join(f"{r['rmse']:.4f}" for r in rs) + " |\n")
            f.write("\n")
    print("wrote", os.path.join(a.out, "REPORT.md"))


if __name__ == "__main__":
    main()
