"""Error at equal time of the lookup filters (issue 19): which filter and
integrator give the lowest error per second, against the image users get
today (volpath + gridvolume, trilinear).

    python3 bench/filters.py --grids cloud=cloud.nvdb:cloud.vol smoke=smoke.nvdb:smoke.vol
        [--cases cloud cloudfield_400 ...] [--vdb smoke.vdb] [--data bench/data]
        [--variants llvm_ad_rgb scalar_rgb] [--res 64] [--spp 32] [--scalar-spp 8]
        [--ref-spp 4096]
        [--runs 3] [--out bench/results/filters.md] [--append]

A grid is NAME=FILE.nvdb:FILE.vol (the .vol: `vdb2nvdb --dense` of the same
grid, for gridvolume), a generated case of bench/cases.py (--cases: written
by BUILD/bin/vdb2nvdb into --data, as bench/run.py does) or a .vdb file
(--vdb FILE[:GRID], converted likewise; its name is the file's stem). The scene is the benchmark's (bench/scene.py, its
first sensor: albedo 0.9, sky + sun, max_depth 64, scale 40). Per variant, in
one process:

  - the reference: volpathlocal + nanovdbvolume, deterministic trilinear, at
    --ref-spp (rendered with the first variant, once per grid and resolution,
    cached in bench/data/filters_refs/, by grid name, resolution and spp);
  - per configuration (integrator, plugin, filter), at --spp: the warm render
    time (median of --runs, each with a new seed) and the RMSE of each of
    those renders against the reference (mean; the reference's own noise,
    estimated from two halves, is subtracted in quadrature);
  - the cost, RMSE^2 x time (equal-time error: lower is better), and the
    time and cost as ratios to volpath + gridvolume + trilinear.

stochastic_tricubic renders a smoother medium than trilinear: its RMSE
against the trilinear reference includes that difference (a bias, not
noise), and its row says how much (the RMSE of its own converged image is
not measured here). A measurement, not a test.

--append keeps the rows of other grids already in --out's .json (and their
commands), so that grids can be measured in several runs of one build.
"""
import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

CONFIGS = [  # (integrator, plugin, filter): the first is the baseline
    ("volpath", "gridvolume", "trilinear"),
    ("volpath", "nanovdbvolume", "trilinear"),
    ("volpath", "nanovdbvolume", "stochastic_trilinear"),
    ("volpathlocal", "nanovdbvolume", "trilinear"),
    ("volpathlocal", "nanovdbvolume", "nearest"),
    ("volpathlocal", "nanovdbvolume", "stochastic_trilinear"),
    ("volpathlocal", "nanovdbvolume", "stochastic_tricubic"),
]

sys.path.insert(0, HERE)
import harness  # noqa: E402


def measure(spec):
    """One process (bench/harness.py): the reference (if asked) and each
    configuration's images and warm render time, on one variant"""
    from child_setup import mitsuba_for
    from scene import turntable_scene
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    jit = dr.is_jit_v(mi.Float)

    def scene_for(integrator, plugin, filt, spp):
        path = spec["nvdb"] if plugin == "nanovdbvolume" else spec["vol"]
        vol = {"type": plugin, "filename": path, "filter_type": filt}
        desc = turntable_scene(vol, spec["res"], spp, integrator)
        for i in range(1, 8):
            del desc[f"sensor_{i}"]
        return mi.load_dict(desc)

    def render(scene, seed):
        t0 = time.perf_counter()
        img = mi.render(scene, seed=seed)
        if jit:
            dr.sync_thread()
        return np.array(img, dtype=np.float64)[..., :3], time.perf_counter() - t0

    out = {}
    if spec["ref_spp"]:
        scene = scene_for("volpathlocal", "nanovdbvolume", "trilinear", spec["ref_spp"] // 2)
        halves = [render(scene, 1000 + k) for k in range(2)]
        out["ref"] = ((halves[0][0] + halves[1][0]) / 2).tolist()
        out["ref_half_diff"] = (halves[0][0] - halves[1][0]).tolist()
        out["ref_time_s"] = sum(h[1] for h in halves)
    for integrator, plugin, filt in spec["configs"]:
        scene = scene_for(integrator, plugin, filt, spec["spp"])
        render(scene, 0)  # (compiles the kernels)
        imgs, times = [], []
        for k in range(spec["runs"]):
            img, t = render(scene, 1 + k)
            imgs.append(img.tolist())
            times.append(t)
        out["|".join((integrator, plugin, filt))] = {"time_s": statistics.median(times),
                                                     "imgs": imgs}
    return out


def run_child(a, variant, nvdb, vol, ref_spp):
    spp = a.spp if not variant.startswith("scalar") else a.scalar_spp
    return harness.run_child("filters:measure", dict(
        variant=variant, build=a.build, nvdb=nvdb, vol=vol, res=a.res, spp=spp,
        ref_spp=ref_spp, runs=a.runs, configs=CONFIGS))


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grids", nargs="+", default=[], help="NAME=FILE.nvdb:FILE.vol")
    ap.add_argument("--cases", nargs="+", default=[], metavar="CASE",
                    help="generated cases of bench/cases.py")
    ap.add_argument("--vdb", nargs="+", default=[], metavar="FILE[:GRID]",
                    help=".vdb files (converted with BUILD/bin/vdb2nvdb)")
    ap.add_argument("--data", default=os.path.join(HERE, "data"),
                    help="where --cases and --vdb grids are written (default bench/data/)")
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--scalar-spp", type=int, default=8)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--build", default="", help="a build folder holding plugins/ (default: "
                    "the installed package's)")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "filters.md"))
    ap.add_argument("--append", action="store_true",
                    help="keep the other grids' rows of --out's .json")
    a = ap.parse_args()
    if a.cases or a.vdb:
        import cases as cases_mod
        if not a.build:
            ap.error("--cases and --vdb need --build (its bin/vdb2nvdb writes the grids)")
        made = [cases_mod.generated_case(c, a.data, a.build) for c in a.cases]
        made += [cases_mod.vdb_case(v, a.data, a.build) for v in a.vdb]
        a.grids += [f"{c.name}={c.nvdb}:{c.vol}" for c in made]
    if not a.grids:
        ap.error("no grid: give --grids, --cases or --vdb")

    json_out = os.path.splitext(a.out)[0] + ".json"
    command = (f"python3 bench/filters.py --grids {' '.join(a.grids)} --variants "
               f"{' '.join(a.variants)} --res {a.res} --spp {a.spp} "
               f"--scalar-spp {a.scalar_spp} --ref-spp {a.ref_spp} --runs {a.runs}"
               + (" --append" if a.append else ""))
    commands, kept = [command], []
    if a.append and os.path.exists(json_out):
        with open(json_out) as f:
            old = json.load(f)
        if isinstance(old, list):  # (before --append: the rows alone)
            old = dict(commands=[], rows=old)
        names = {spec.split("=", 1)[0] for spec in a.grids}
        kept = [r for r in old["rows"] if r["grid"] not in names]
        commands = old["commands"] + commands
    rows = []
    for spec in a.grids:
        name, files = spec.split("=", 1)
        nvdb, vol = files.split(":", 1)
        ref = None
        cache = os.path.join(HERE, "data", "filters_refs", f"{name}__r{a.res}__s{a.ref_spp}.npz")
        if os.path.exists(cache):
            with np.load(cache) as z:
                ref, ref_var = z["ref"], float(z["ref_var"])
            print(f"{name}: reference from {cache}", flush=True)
        for variant in a.variants:
            t0 = time.time()
            need_ref = ref is None
            r = run_child(a, variant, nvdb, vol, a.ref_spp if need_ref else 0)
            if need_ref:
                ref = np.array(r["ref"])
                # Noise of the reference (per pixel variance of the mean of
                # two halves = (half difference)^2 / 4)
                ref_var = np.mean(np.array(r["ref_half_diff"]) ** 2) / 4
                print(f"{name}: reference {a.ref_spp} spp in {r['ref_time_s']:.1f} s, "
                      f"its RMSE ~{np.sqrt(ref_var):.4f}", flush=True)
                os.makedirs(os.path.dirname(cache), exist_ok=True)
                np.savez_compressed(cache, ref=ref, ref_var=ref_var)
            rf, rf_var = ref, ref_var
            base = None
            for cfg in CONFIGS:
                c = r["|".join(cfg)]
                mses = [max(np.mean((np.array(img) - rf) ** 2) - rf_var, 0.0)
                        for img in c["imgs"]]
                rmse = float(np.sqrt(np.mean(mses)))
                cost = rmse ** 2 * c["time_s"]
                if base is None:
                    base = (c["time_s"], cost)
                rows.append(dict(grid=name, variant=variant, integrator=cfg[0], plugin=cfg[1],
                                 filter=cfg[2], time_s=c["time_s"], rmse=rmse, cost=cost,
                                 time_ratio=c["time_s"] / base[0], cost_ratio=cost / base[1]))
                print(f"  {variant} {cfg}: {c['time_s']:.3f} s, RMSE {rmse:.4f}, "
                      f"time x{c['time_s'] / base[0]:.3g}, cost x{cost / base[1]:.3g}",
                      flush=True)
            print(f"  ({variant}: {time.time() - t0:.0f} s)", flush=True)

    lines = [
        "# Lookup filters: render time and error at equal time (bench/filters.py)", "",
        *[f"`{c}`" for c in commands], "",
        "Reference: volpathlocal + nanovdbvolume, trilinear, at the reference spp "
        "(llvm_ad_rgb). Ratios against volpath + gridvolume + trilinear, same variant, same "
        "spp. cost = RMSE^2 x time: below 1, the configuration reaches a given error in "
        "less time. stochastic_tricubic's RMSE includes its difference from the trilinear "
        "medium.", "",
        "| grid | variant | integrator | plugin | filter | time [s] | RMSE | time ratio | "
        "cost ratio |",
        "|---|---|---|---|---|---:|---:|---:|---:|",
    ]
    rows = kept + rows
    for r in rows:
        lines.append(f"| {r['grid']} | {r['variant']} | {r['integrator']} | {r['plugin']} | "
                     f"{r['filter']} | {r['time_s']:.3f} | {r['rmse']:.4f} | "
                     f"{r['time_ratio']:.3g} | {r['cost_ratio']:.3g} |")
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    with open(a.out, "w") as f:
        f.write("\n".join(lines) + "\n")
    with open(json_out, "w") as f:
        json.dump(dict(commands=commands, rows=rows), f, indent=1)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
