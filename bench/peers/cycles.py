"""Issue 34's peer benchmark: nanovdb-render's scene of a .vdb in Blender
Cycles and in volpathlocal, error against time for each.

    bash bench/peers/setup.sh          # Debian's blender (3.4.1), once
    python3 bench/peers/cycles.py [FILE.vdb ...] [--grid density] [--res 128]
        [--spp 1 2 4 8 16 32] [--ref-spp 1024] [--step-rates 1 0.1]
        [--filter stochastic_trilinear] [--variant llvm_ad_rgb] [--threads 2]
        [--transmittance residual|ratio] [--build build]
        [--out bench/results/peers]

Without files: the shared smoke and the generator's cloud. Both renderers
get one scene: nanovdb_mitsuba.scene.framed_scene's camera,
sun, sky and default density scale, albedo 0.9, an isotropic phase,
max_depth 64, a 1 px box filter. bench/peers/cycles_render.py builds it in
Cycles and says what it changes from Cycles' defaults. Per file:

- **Agreement.** Each renderer's own reference (--ref-spp, its own seed):
  their means over the volume's pixels and the relative RMSE between them,
  with Cycles' volume where OpenVDB puts it (shifted by -1/2 voxel, which
  Cycles' convention needs) and unshifted.
- **Error against time.** Renders at --spp (two seeds each), each against
  its own renderer's reference: relative RMSE over the volume's pixels
  (those the reference shows other than the sky). The time is the render's
  wall time: mi.render with its kernel compiled (a warm-up render first);
  Cycles' bpy.ops.render.render after a warm-up render, which includes its
  scene sync and the grid's upload each time (Blender 3.4 does not render
  again with persistent data in background mode). Both run on --threads
  cores.
- **Time to a relative RMSE of 0.05 and 0.02**, from each renderer's
  efficiency at its two highest spp counts (the median of error^2 x time:
  error ~ time^-1/2; there a render's fixed cost, Cycles' sync, weighs
  least), and its ratio: ours / Cycles'.

A measurement, not a test: the targets (issue 34: <= 0.7x Cycles' time at
its default step rate) are read from the table, not asserted. Results:
OUT/peers.json, OUT/peers.md and a figure per file.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
BENCH = os.path.dirname(HERE)
ROOT = os.path.dirname(BENCH)
sys.path.insert(0, BENCH)
import harness  # noqa: E402

SHARED = os.path.join(os.path.dirname(ROOT), "shared", "data")


def scene_and_renders(spec):
    """The child (bench/harness.py): framed_scene's parameters for the file,
    and our renders of it (spec["renders"]: spp, seed, npy), timed"""
    import time
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(spec["variant"], spec.get("build", ""))
    if spec.get("threads"):
        dr.set_thread_count(int(spec["threads"]))
    from nanovdb_mitsuba.scene import framed_scene
    desc, info = framed_scene(mi, spec["file"], grid=spec["grid"], res=spec["res"], spp=1,
                              filter_type=spec["filter"])
    desc["integrator"]["max_depth"] = spec["max_depth"]
    desc["integrator"]["transmittance"] = spec.get("transmittance", "residual")
    desc["sensor"]["film"]["rfilter"] = {"type": "box"}
    sun, sky = desc["sun"], desc["sky"]
    out = dict(camera=dict(origin=info["camera"]["origin"], target=info["camera"]["target"],
                           fov=info["camera"]["fov"]),
               scale=info["scale"], albedo=0.9,
               sun=dict(direction=list(sun["direction"]),
                        irradiance=list(sun["irradiance"]["value"])),
               sky=list(sky["radiance"]["value"]), renders=[])
    scene = mi.load_dict(desc)
    dr.eval(mi.render(scene, seed=999_999, spp=1))  # (the kernel's compile)
    dr.sync_thread()
    for r in spec["renders"]:
        t0 = time.perf_counter()
        img = mi.render(scene, seed=int(r["seed"]), spp=int(r["spp"]))
        dr.eval(img)
        dr.sync_thread()
        seconds = time.perf_counter() - t0
        np.save(r["npy"], np.array(img, dtype=np.float32)[..., :3])
        out["renders"].append(dict(r, time_s=seconds))
    return out


def cycles(spec, workdir):
    """Runs cycles_render.py in Blender on `spec`; returns its result"""
    blender = shutil.which("blender")
    if not blender:
        raise SystemExit("cycles.py: no blender on PATH: run bash bench/peers/setup.sh")
    spec_path = os.path.join(workdir, "cycles_spec.json")
    out_path = os.path.join(workdir, "cycles_out.json")
    with open(spec_path, "w") as f:
        json.dump(spec, f)
    proc = subprocess.run([blender, "-b", "--factory-startup", "-noaudio", "-P",
                           os.path.join(HERE, "cycles_render.py"), "--", spec_path, out_path],
                          capture_output=True, text=True)
    if proc.returncode != 0 or not os.path.exists(out_path):
        raise RuntimeError(f"blender failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n"
                           f"{proc.stderr[-3000:]}")
    with open(out_path) as f:
        return json.load(f)


def read_exr(path):
    import mitsuba as mi
    if not mi.variant():
        mi.set_variant("scalar_rgb")
    return np.array(mi.Bitmap(path), dtype=np.float32)[..., :3]


def volume_mask(ref, sky):
    """The pixels where the reference shows something other than the sky"""
    return np.any(np.abs(ref - np.asarray(sky, dtype=np.float32)) > 1e-3 * max(sky), axis=-1)


def rel_rmse(img, ref, mask):
    d = (img - ref)[mask].astype(np.float64)
    return math.sqrt(float(np.mean(d * d))) / float(np.mean(ref[mask]))


def time_to(errors, target):
    """The time a renderer needs for a relative RMSE of `target`, from the
    median of error^2 x time over its renders (error ~ time^-1/2)"""
    top = sorted({e["spp"] for e in errors})[-2:]
    cost = float(np.median([e["rel_rmse"] ** 2 * e["time_s"] for e in errors if e["spp"] in top]))
    return cost / target ** 2


def default_files(workdir):
    """The shared smoke (where ../shared/data is) and the generator's cloud
    (vdb2nvdb generate cloud: 456,712 voxels, 1.6 MB), written to workdir"""
    files = []
    smoke = os.path.join(SHARED, "openvdb_smoke1_fog.vdb")
    if os.path.exists(smoke):
        files.append(smoke)
    else:
        print(f"cycles.py: {smoke} is missing: the generated cloud only")
    tool = os.path.join(ROOT, "build", "bin", "vdb2nvdb")
    tool = tool if os.path.exists(tool) else shutil.which("vdb2nvdb")
    cloud = os.path.join(workdir, "cloud.vdb")
    subprocess.run([tool, "generate", "cloud", cloud], check=True, capture_output=True)
    return files + [cloud]


def run_file(path, args, workdir):
    name = os.path.splitext(os.path.basename(path))[0]
    d = os.path.join(workdir, name)
    os.makedirs(d, exist_ok=True)
    seeds = (1, 2)
    # Ours: the reference and the sweep in one child (one compile)
    ours_renders = [dict(spp=args.ref_spp, seed=10_000, npy=os.path.join(d, "ours_ref.npy"))]
    ours_renders += [dict(spp=s, seed=k, npy=os.path.join(d, f"ours_{s}_{k}.npy"))
                     for s in args.spp for k in seeds]
    ours = harness.run_child("peers.cycles:scene_and_renders", dict(
        file=os.path.abspath(path), grid=args.grid, res=args.res, filter=args.filter,
        variant=args.variant, max_depth=args.max_depth, threads=args.threads,
        build=args.build, transmittance=args.transmittance,
        renders=ours_renders), home=os.path.join(workdir, "home"))
    base = dict(file=os.path.abspath(path), grid=args.grid, scale=ours["scale"],
                albedo=ours["albedo"], camera=ours["camera"], sun=ours["sun"], sky=ours["sky"],
                res=args.res, max_depth=args.max_depth, threads=args.threads)
    ref = np.load(os.path.join(d, "ours_ref.npy"))
    mask = volume_mask(ref, ours["sky"])
    row = dict(file=name, res=args.res, scale=ours["scale"], pixels=int(mask.sum()),
               ours=[], cycles={}, agreement={})
    for r in ours["renders"][1:]:
        row["ours"].append(dict(spp=r["spp"], seed=r["seed"], time_s=r["time_s"],
                                rel_rmse=rel_rmse(np.load(r["npy"]), ref, mask)))
    row["ours_mean"] = float(np.mean(ref[mask]))
    for rate in args.step_rates:
        renders = [dict(spp=1, seed=99, exr=os.path.join(d, f"cy{rate}_warm.exr")),
                   dict(spp=args.ref_spp, seed=10_000, exr=os.path.join(d, f"cy{rate}_ref.exr"))]
        renders += [dict(spp=s, seed=k, exr=os.path.join(d, f"cy{rate}_{s}_{k}.exr"))
                    for s in args.spp for k in seeds]
        cy = cycles(dict(base, step_rate=rate, shift_voxels=-0.5, renders=renders), d)
        cref = read_exr(renders[1]["exr"])
        errs = [dict(spp=r["spp"], seed=r["seed"], time_s=r["time_s"],
                     rel_rmse=rel_rmse(read_exr(r["exr"]), cref, mask))
                for r in cy["renders"][2:]]
        row["cycles"][str(rate)] = dict(errors=errs, ref_time_s=cy["renders"][1]["time_s"],
                                        mean=float(np.mean(cref[mask])), blender=cy["blender"])
        row["agreement"][f"step_rate {rate}, shifted -1/2 voxel"] = dict(
            mean_ratio=float(np.mean(cref[mask])) / row["ours_mean"],
            rel_rmse=rel_rmse(cref, ref, mask))
    # The half voxel: the default step rate's reference once more, unshifted
    rate = args.step_rates[0]
    r0 = dict(spp=args.ref_spp, seed=10_000, exr=os.path.join(d, f"cy{rate}_ref_unshifted.exr"))
    cycles(dict(base, step_rate=rate, shift_voxels=0.0, renders=[r0]), d)
    c0 = read_exr(r0["exr"])
    row["agreement"][f"step_rate {rate}, unshifted"] = dict(
        mean_ratio=float(np.mean(c0[mask])) / row["ours_mean"], rel_rmse=rel_rmse(c0, ref, mask))
    # What two independent references differ by from their noise alone
    # (each render's relative variance per sample, over ref_spp samples)
    def per_sample(errs):
        return float(np.median([e["rel_rmse"] ** 2 * e["spp"] for e in errs]))
    for key, a in row["agreement"].items():
        rate = key.split(",")[0].split()[1]
        a["noise_alone"] = math.sqrt((per_sample(row["ours"]) +
                                      per_sample(row["cycles"][rate]["errors"])) / args.ref_spp)
    row["time_to"] = {}
    for target in (0.05, 0.02):
        t_ours = time_to(row["ours"], target)
        row["time_to"][str(target)] = dict(
            ours=t_ours, **{f"cycles {rate}": time_to(c["errors"], target)
                            for rate, c in row["cycles"].items()})
    return row


def figure(row, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(4.6, 3.6))
    curves = [("volpathlocal", row["ours"], "C0")]
    curves += [(f"Cycles, step rate {rate}", c["errors"], f"C{i + 1}")
               for i, (rate, c) in enumerate(row["cycles"].items())]
    for label, errs, color in curves:
        by_spp = {}
        for e in errs:
            by_spp.setdefault(e["spp"], []).append(e)
        pts = sorted((np.mean([e["time_s"] for e in v]),
                      np.sqrt(np.mean([e["rel_rmse"] ** 2 for e in v])))
                     for v in by_spp.values())
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", ms=3, color=color, label=label)
    for target in (0.05, 0.02):
        ax.axhline(target, color="grey", lw=0.5, ls=":")
    ax.set_xlabel("render time [s]")
    ax.set_ylabel("relative RMSE (volume's pixels)")
    ax.set_title(f"{row['file']}, {row['res']}²", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    name = f"peers_{row['file']}.png"
    fig.savefig(os.path.join(out, name), dpi=110)
    plt.close(fig)
    return name


def report(rows, args, out):
    lines = ["# Peer benchmark: Blender Cycles and volpathlocal (issue 34)", "",
             f"`python3 bench/peers/cycles.py {' '.join(sys.argv[1:])}`", "",
             f"{args.variant}, `{args.filter}`, transmittance `{args.transmittance}`, "
             f"{args.threads} threads, {args.res}², max_depth "
             f"{args.max_depth}; references at {args.ref_spp} spp; bench/peers/cycles.py says "
             "how.", ""]
    for row in rows:
        lines += [f"## {row['file']}", "",
                  f"density scale {row['scale']:.4g}; {row['pixels']} volume pixels", "",
                  "| agreement with our reference | mean ratio (Cycles / ours) | relative RMSE "
                  "| from noise alone |",
                  "|---|---|---|---|"]
        for k, a in row["agreement"].items():
            lines.append(f"| {k} | {a['mean_ratio']:.4f} | {a['rel_rmse']:.4f} "
                         f"| {a['noise_alone']:.4f} |")
        lines += ["", "| renderer | time per spp (s) | rel. RMSE x sqrt(spp) | to 0.05 (s) "
                  "| to 0.02 (s) | ratio to Cycles (0.05) |",
                  "|---|---|---|---|---|---|"]
        tt = row["time_to"]
        cy_first = f"cycles {args.step_rates[0]}"

        def line(label, errs, key):
            per_spp = np.median([e["time_s"] / e["spp"] for e in errs
                                 if e["spp"] == max(args.spp)])
            noise = np.median([e["rel_rmse"] * math.sqrt(e["spp"]) for e in errs])
            return (f"| {label} | {per_spp:.4f} | {noise:.3f} | {tt['0.05'][key]:.2f} | "
                    f"{tt['0.02'][key]:.2f} | {tt['0.05'][key] / tt['0.05'][cy_first]:.2f}x |")
        lines.append(line("volpathlocal", row["ours"], "ours"))
        for rate, c in row["cycles"].items():
            lines.append(line(f"Cycles, step rate {rate}", c["errors"], f"cycles {rate}"))
        lines += ["", f"![]({figure(row, out)})", ""]
    with open(os.path.join(out, "peers.md"), "w") as f:
        f.write("\n".join(lines))
    with open(os.path.join(out, "peers.json"), "w") as f:
        json.dump(rows, f, indent=1)
    print("\n".join(lines))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*")
    ap.add_argument("--grid", default="density")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--step-rates", type=float, nargs="+", default=[1.0, 0.1])
    ap.add_argument("--filter", default="stochastic_trilinear")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--max-depth", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--transmittance", default="residual", choices=["residual", "ratio"],
                    help="volpathlocal's shadow-ray estimator")
    ap.add_argument("--build", default=os.path.join(ROOT, "build"),
                    help="the build whose plugins render ours")
    ap.add_argument("--out", default=os.path.join(BENCH, "results", "peers"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="nvdb-peers-") as workdir:
        files = args.files or default_files(workdir)
        rows = [run_file(f, args, workdir) for f in files]
    report(rows, args, args.out)


if __name__ == "__main__":
    main()
