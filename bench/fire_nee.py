"""What next-event estimation toward emissive media buys (issue 35):
volpathlocal's emission_sampling `collisions` (the emission the flights
collect, alone), `mis` (with next-event estimation, the default) and `nee`
(next-event estimation alone), on bench/emission.py's scenes: error against
time, by region.

    python3 bench/fire_nee.py --build BUILD                 # ~6 min -> bench/results/fire_nee.md, .json, .png
    python3 bench/fire_nee.py --build BUILD --quick         # harness check -> /tmp/fire_nee_quick/
    python3 bench/fire_nee.py --cases fireball --variants llvm_ad_rgb

Cases (bench/emission.py's `on` configuration: the medium on a floor under
a dim sky, temperature mode): `fireball` (`vdb2nvdb generate
fireball_<--n>`), `fireball_self_lit` (the same without floor and sky: smoke
lit only by its own fire) and `usd_heat`
(../shared/data/usd_density_heat_fog.vdb; skipped without it). Per case and variant, one child process
(bench/harness.py) renders, for each mode in turn, an spp sweep (each
point the minimum time of --repeats turntables, after an untimed render
at that spp that compiles its kernels), against one reference per case
(`mis`, --ref-variant, --ref-spp in --ref-passes passes, cached in --data
keyed by the settings, the grids and the plugins). Errors: relative RMSE,
noise-corrected, over the image and per region (bench/emission.py's
masks: the fire seen directly, the floor, the smoke), and at equal time
each mode's error against `collisions`' (bench/metrics.py's
error_at_equal_time: interpolated in log-log at the longest time both
sweeps reach). Also reported: the emission table's build time and bytes
against the grid's.

A measurement, not a test: nothing is asserted (tests/test_fire_nee.py
checks that the modes agree).
"""
import argparse
import datetime
import json
import os
import statistics
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import emission  # noqa: E402  (the scenes, files and region masks)
import harness  # noqa: E402
import report_common  # noqa: E402

MODES = ["collisions", "mis", "nee"]
# bench/emission.py's cases, and the fireball without floor and sky: smoke
# lit only by its own fire
CASES = ["fireball", "fireball_self_lit", "usd_heat"]


def log(msg):
    print(msg, flush=True)


def label(case):
    """A case's name in this benchmark's keys and report"""
    return case.get("label", case["name"])


def scene(mi, case, mode, res, spp, sensors):
    d = emission.scene_dict(mi, case, "on", res, spp, sensors)
    d["integrator"]["emission_sampling"] = mode
    if case.get("self_lit"):  # (smoke lit only by its own fire: no floor, no sky)
        del d["floor"], d["sky"]
    return d


def cases(a):
    """The cases a.cases names (files in a.data, made by a.build's vdb2nvdb
    where missing), and notes on those skipped"""
    case_list, notes = [], []
    for name in a.cases:
        if name == "fireball":
            case_list.append({"name": name, "file": emission.fireball_file(a.data, a.build, a.n)})
        elif name == "fireball_self_lit":
            case_list.append({"name": "fireball", "label": name, "self_lit": True,
                              "file": emission.fireball_file(a.data, a.build, a.n)})
        elif os.path.exists(emission.SHARED_USD):
            case_list.append({"name": name, "file": emission.usd_file(a.data, a.build)})
        else:
            notes.append("usd_heat skipped: ../shared/data/usd_density_heat_fog.vdb not found")
    return case_list, notes


def child(spec):
    """One variant: the references (mode "reference") or the sweeps"""
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    out, images = {"cases": {}}, {}
    for case in spec["cases"]:
        n = label(case)
        res = out["cases"][n] = {}
        if spec["mode"] == "reference":
            s = mi.load_dict(scene(mi, case, "mis", spec["res"], spec["ref_spp"], spec["sensors"]))
            passes = []
            t0 = time.perf_counter()
            for k in range(spec["ref_passes"]):
                _, im = emission.render_turntable(mi, dr, s, spec["ref_spp"] // spec["ref_passes"],
                                                  2_000_000 + k)
                passes.append(im.astype(np.float64))
            p = np.stack(passes)
            images[f"{n}__mean"] = p.mean(0).astype(np.float32)
            images[f"{n}__var_of_mean"] = (p.var(0, ddof=1) / len(passes)).astype(np.float32)
            images[f"{n}__regions"] = emission.region_ids(mi, case, spec)
            res["ref_s"] = time.perf_counter() - t0
            continue
        res["sweep"] = {}
        for mode in spec["modes"]:
            t0 = time.perf_counter()
            s = mi.load_dict(scene(mi, case, mode, spec["res"], 1, spec["sensors"]))
            res.setdefault("load_s", {})[mode] = time.perf_counter() - t0
            pts = []
            for j, spp in enumerate(spec["sweep"]):
                img = mi.render(s, sensor=0, spp=spp, seed=7)  # (compiles)
                if dr.is_jit_v(mi.Float):
                    dr.eval(img)
                    dr.sync_thread()
                ts = []
                for r in range(spec["repeats"]):
                    t, im = emission.render_turntable(mi, dr, s, spp, 100 + 31 * j + r)
                    ts.append(t)
                images[f"{n}__{mode}__{spp}"] = im
                pts.append({"spp": spp, "time_s": min(ts), "times_s": ts})
            res["sweep"][mode] = pts
            if mode != "collisions" and "table" not in res:  # (built by the first render)
                params = mi.traverse(s)
                key = next((k for k in params.keys() if k.endswith("emission_table_bytes")), None)
                if key:
                    from nanovdb_mitsuba import volume_facts
                    temp = mi.load_dict(emission.volumes(mi, case)[1])
                    res["table"] = {"bytes": float(params[key]),
                                    "seconds": float(params[key.replace("bytes", "seconds")]),
                                    "grid_bytes": float(volume_facts(temp)["grid_bytes"]),
                                    "scene_load_s": res["load_s"][mode]}
            log(f"    {spec['variant']} {n} {mode}: " +
                ", ".join(f"{p['spp']} spp {p['time_s']:.2f} s" for p in pts))
    np.savez(spec["out_npz"], **images)
    return out


def run(spec, work, tag):
    spec = dict(spec, out_npz=os.path.join(work, tag + ".npz"))
    home = tempfile.mkdtemp(prefix="jit_home_", dir=work)
    out = harness.run_child("fire_nee:child", spec, home=home, echo=True)
    with np.load(spec["out_npz"]) as z:
        return out, {k: z[k] for k in z.files}


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cases", nargs="+", choices=CASES, default=CASES)
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--modes", nargs="+", choices=MODES, default=MODES)
    ap.add_argument("--n", type=int, default=128)
    ap.add_argument("--res", type=int, default=48)
    ap.add_argument("--sensors", type=int, default=4)
    ap.add_argument("--sweep", type=int, nargs="+", default=[4, 8, 16, 32])
    ap.add_argument("--scalar-sweep", type=int, nargs="+", default=[2, 4, 8])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--ref-passes", type=int, default=8)
    ap.add_argument("--ref-variant", default="llvm_ad_rgb")
    ap.add_argument("--data", default=os.path.join(HERE, "data", "emission"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out")
    a = ap.parse_args()
    if a.quick:
        a.n, a.res, a.sensors, a.sweep, a.scalar_sweep = 64, 24, 2, [2, 4], [1, 2]
        a.repeats, a.ref_spp, a.ref_passes = 1, 128, 2
    a.out = os.path.abspath(a.out or (os.path.join("/tmp", "fire_nee_quick", "fire_nee.md")
                                      if a.quick else os.path.join(HERE, "results", "fire_nee.md")))
    a.build, a.data = os.path.abspath(a.build), os.path.abspath(a.data)
    started = datetime.datetime.now().astimezone()
    t_start = time.perf_counter()
    case_list, notes = cases(a)
    work = os.path.join(a.data, "runs")
    os.makedirs(work, exist_ok=True)
    # References (cached): keyed by the settings, the grids, the plugins
    sos = [os.path.join(a.build, "plugins", p + ".so") for p in emission.PLUGINS]
    refs, missing = {}, []
    for case in case_list:
        key = (f"nee_{label(case)}__r{a.res}x{a.sensors}__s{a.ref_spp}x{a.ref_passes}__{a.ref_variant}__"
               f"{emission.source_key(emission.volumes, emission.sensor, emission.scene_dict, scene, emission.region_ids, emission.MEDIUM, emission.FIRE)}__"
               f"{emission.file_key([case['file']] + sos)}")
        case["ref"] = os.path.join(a.data, "refs", key + ".npz")
        if os.path.exists(case["ref"]):
            with np.load(case["ref"]) as z:
                refs[label(case)] = {k: z[k] for k in z.files}
        else:
            missing.append(case)
    if missing:
        log(f"== references (mis, {a.ref_variant}, {a.ref_spp} spp): " +
            ", ".join(label(c) for c in missing))
        spec = {"mode": "reference", "variant": a.ref_variant, "build": a.build,
                "cases": [{k: c[k] for k in c if k != "ref"} for c in missing],
                "res": a.res, "sensors": a.sensors, "ref_spp": a.ref_spp,
                "ref_passes": a.ref_passes}
        _, imgs = run(spec, work, "nee_reference")
        for c in missing:
            n = label(c)
            d = {"mean": imgs[f"{n}__mean"], "var_of_mean": imgs[f"{n}__var_of_mean"],
                 "regions": imgs[f"{n}__regions"]}
            os.makedirs(os.path.dirname(c["ref"]), exist_ok=True)
            np.savez(c["ref"], **d)
            refs[n] = d
    import metrics
    errors, measured = [], {}
    for variant in a.variants:
        sweep = a.scalar_sweep if variant.startswith("scalar") else a.sweep
        spec = {"mode": "sweep", "variant": variant, "build": a.build, "modes": a.modes,
                "cases": [{k: c[k] for k in c if k != "ref"} for c in case_list],
                "res": a.res, "sensors": a.sensors, "sweep": sweep, "repeats": a.repeats}
        log(f"== {variant}: sweep {sweep}")
        out, imgs = run(spec, work, f"nee_{variant}")
        measured[variant] = out
        for c in case_list:
            n = label(c)
            ref = refs[n]
            masks = emission.region_masks(ref["regions"], ref["mean"])
            level = float(ref["mean"].mean())
            for mode in a.modes:
                for pt in out["cases"][n]["sweep"][mode]:
                    img = imgs[f"{n}__{mode}__{pt['spp']}"]
                    _, corr = metrics.rmse(img, ref["mean"], ref["var_of_mean"])
                    errors.append({"case": n, "variant": variant, "mode": mode, "spp": pt["spp"],
                                   "time_s": pt["time_s"], "rel_rmse": corr / level,
                                   "regions": metrics.region_errors(img, ref["mean"],
                                                                    ref["var_of_mean"], masks)})
    elapsed = time.perf_counter() - t_start
    write_report(a, case_list, errors, measured, notes, started, elapsed)
    log(f"== done in {elapsed:.0f} s; {a.out}")


def write_report(a, case_list, errors, measured, notes, started, elapsed):
    import metrics
    base = os.path.splitext(a.out)[0]
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    png = os.path.basename(base) + "_error_time.png"
    plot(errors, os.path.join(os.path.dirname(a.out), png))
    with open(base + ".json", "w") as f:
        json.dump({"settings": vars(a), "started": started.isoformat(), "elapsed_s": elapsed,
                   "errors": errors, "measured": measured, "notes": notes}, f, indent=1,
                  default=str)
    regions = ["image"] + emission.REGIONS
    L = ["# Next-event estimation toward emissive media (bench/fire_nee.py)", "",
         "`python3 bench/fire_nee.py " + " ".join(sys.argv[1:]) + "`", "",
         f"Run {started:%Y-%m-%d %H:%M %Z}, {elapsed:.0f} s, {os.cpu_count()} cores. "
         f"bench/emission.py's `on` scenes ({a.sensors} sensors at {a.res}²); modes of "
         "volpathlocal's `emission_sampling`; errors against one `mis` reference per case "
         f"({a.ref_variant}, {a.ref_spp} spp), noise-corrected, relative to the reference's mean "
         "(image) or to its mean over the region.", "",
         f"![error against time]({png})", "",
         "## At equal time, against `collisions`", "",
         "Relative RMSE of `collisions` / the mode's, interpolated at the longest time both "
         "sweeps reach (above 1: the mode is better), and the efficiency ratio (error² × "
         "time, median over the sweep points).", "",
         "| case | variant | mode | " + " | ".join(f"{r}: RMSE ratio, efficiency" for r in regions)
         + " |", "|---|---|---|" + "---|" * len(regions)]
    for c in case_list:
        for v in a.variants:
            def series(mode, region):
                out = []
                for e in errors:
                    if (e["case"], e["variant"], e["mode"]) == (label(c), v, mode):
                        err = e["rel_rmse"] if region == "image" else \
                            e["regions"][region]["rel_rmse"]
                        if err:
                            out.append((e["time_s"], err))
                return out
            for mode in a.modes:
                if mode == "collisions":
                    continue
                cells = []
                for r in regions:
                    res = metrics.error_at_equal_time(series("collisions", r), series(mode, r))
                    cells.append("–" if res["ratio"] is None else
                                 f"{res['ratio']:.2f}, {res['cost_ratio']:.1f}×")
                L.append(f"| {label(c)} | {v} | {mode} | " + " | ".join(cells) + " |")
    L += ["", "## The emission table", "",
          "Bytes and build time (at the first render) against the emission grid's bytes and "
          "the scene's load time (both grids, llvm_ad_rgb: the first variant).", "",
          "| case | table bytes | emission grid bytes | share | build [s] | scene load [s] |",
          "|---|---:|---:|---:|---:|---:|"]
    for c in case_list:
        t = next((m["cases"][label(c)].get("table") for m in measured.values()
                  if m["cases"][label(c)].get("table")), None)
        if t:
            L.append(f"| {label(c)} | {t['bytes']:.0f} | {t['grid_bytes']:.0f} | "
                     f"{100 * t['bytes'] / t['grid_bytes']:.2f} % | {t['seconds']:.3f} | "
                     f"{t['scene_load_s']:.3f} |")
    L += ["", "## Every point", "",
          "| case | variant | mode | spp | time [s] | " + " | ".join(
              f"{r} rel. RMSE" for r in regions) + " |",
          "|---|---|---|---:|---:|" + "---:|" * len(regions)]
    for e in errors:
        cells = [f"{e['rel_rmse']:.4f}"] + [
            "–" if e["regions"][r]["rel_rmse"] is None else f"{e['regions'][r]['rel_rmse']:.4f}"
            for r in emission.REGIONS]
        L.append(f"| {e['case']} | {e['variant']} | {e['mode']} | {e['spp']} | "
                 f"{e['time_s']:.3f} | " + " | ".join(cells) + " |")
    report_common.write_markdown(a.out, L, notes)


def plot(errors, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    keys = sorted({(e["case"], e["variant"]) for e in errors})
    regions = ["image"] + emission.REGIONS
    fig, axes = plt.subplots(len(keys), len(regions), figsize=(3.2 * len(regions), 2.8 * len(keys)),
                             squeeze=False)
    colors = {"collisions": "tab:blue", "mis": "tab:red", "nee": "tab:green"}
    for i, (c, v) in enumerate(keys):
        for j, r in enumerate(regions):
            ax = axes[i, j]
            for mode in MODES:
                pts = sorted((e for e in errors if (e["case"], e["variant"], e["mode"]) ==
                              (c, v, mode)), key=lambda e: e["spp"])
                xs = [e["time_s"] for e in pts]
                ys = [e["rel_rmse"] if r == "image" else e["regions"][r]["rel_rmse"] for e in pts]
                if pts and all(y for y in ys):
                    ax.loglog(xs, ys, "o-", ms=3, color=colors[mode], label=mode)
            ax.set_title(f"{c}, {v}: {r}", fontsize=8)
            ax.set_xlabel("time [s]", fontsize=7)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=6)
    report_common.save_figure(fig, *os.path.split(path), 80)


if __name__ == "__main__":
    main()
