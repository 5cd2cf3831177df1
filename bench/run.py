"""Benchmarks of nanovdbvolume against Mitsuba's dense gridvolume, and of the
volpathlocal integrator against volpath.

    python3 bench/run.py                 # default run (~20-25 min on 2 cores) -> bench/results/
    python3 bench/run.py --full          # + the 934^3 cubes, larger images, more spp
    python3 bench/run.py --fast          # harness check (< 60 s): one tiny case -> bench/data/fast_results/
    python3 bench/run.py --gpu           # cuda_ad_rgb on a GPU -> bench/results/cuda/
    python3 bench/run.py --cases cloud sphere_fog --variants llvm_ad_rgb
    python3 bench/run.py --cases none --vdb smoke.vdb --nvdb other.nvdb:density
    python3 bench/run.py --integrators volpath      # the plugin comparison alone

Per case, variant, integrator + plugin and filter, a fresh worker process
(bench/worker.py's measure(), through bench/harness.py) measures the volume's memory, random-lookup throughput,
the render time of an 8-sensor turntable at equal spp (cold + >= 5 warm
runs) and an spp sweep. The integrator axis: volpath with both plugins
everywhere, and volpathlocal with nanovdbvolume on the integrator comparison's
cases (--local-cases, every --vdb/--nvdb file) and filters (--local-filters),
where the nanovdbvolume workers also count lookups and walk steps per path.
Converged references are rendered on llvm_ad_rgb (cached in
bench/data/refs/). Then CSV files, PNG plots and REPORT.md are written. See
bench/README.md for the methodology. Exits non-zero when any measurement
failed (never because of a timing target: those are reported, not asserted).
"""
import argparse
import datetime
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import cases as cases_mod  # noqa: E402
import harness  # noqa: E402
import metrics  # noqa: E402

PLUGINS = ["nanovdbvolume", "gridvolume"]
FILTERS = ["trilinear", "nearest"]
# volpath renders with every plugin; volpathlocal (src/integrators/) with
# nanovdbvolume, whose tree it walks (with gridvolume it would be volpath).
INTEGRATORS = ["volpath", "volpathlocal"]
# The integrator comparison's generated cases (user files always take part)
LOCAL_CASES = ["constant_300", "cloud", "sphere_fog_256", "cloudfield_400"]

# Settings per mode. Scalar settings apply to scalar_* variants.
MODES = {
    "fast": dict(cases=["cloud"], variants=["scalar_rgb", "llvm_ad_rgb"], res=16, spp=4, runs=3,
                 sweep=[1, 2, 4], ref_spp=32, ref_passes=2, lookups=1 << 16, scalar_lookups=2000,
                 scalar_res=16, scalar_spp=4, scalar_sweep=[1, 2, 4], lookup_runs=3,
                 sweep_repeats=1, scalar_filters=["trilinear"], local_cases=["cloud"],
                 integrators=INTEGRATORS, out=os.path.join(HERE, "data", "fast_results")),
    "default": dict(cases=cases_mod.DEFAULT_CASES, variants=["scalar_rgb", "llvm_ad_rgb"], res=32,
                    spp=16, runs=5, sweep=[1, 2, 4, 8, 16, 32], ref_spp=256, ref_passes=4,
                    lookups=1 << 22, scalar_lookups=1 << 14, scalar_res=32, scalar_spp=16,
                    scalar_sweep=[1, 2, 4, 8, 16, 32], lookup_runs=5, sweep_repeats=2,
                    integrators=INTEGRATORS, local_cases=LOCAL_CASES,
                    out=os.path.join(HERE, "results")),
    # Full: the scalar variant renders fewer spp (8, sweep to 16) at the same
    # image size, so that it shares the references with llvm_ad_rgb.
    # GPU: cuda_ad_rgb alone, larger images (a GPU needs >= 10^6 paths per
    # launch to fill), references on the GPU too; the integrator comparison
    # only when asked for (--integrators volpath volpathlocal).
    "gpu": dict(cases=cases_mod.GPU_CASES, variants=["cuda_ad_rgb"], res=128, spp=64, runs=5,
                sweep=[4, 16, 64, 256], ref_spp=1024, ref_passes=4, lookups=1 << 24,
                scalar_lookups=0, scalar_res=0, scalar_spp=0, scalar_sweep=[], lookup_runs=5,
                sweep_repeats=1, ref_variant="cuda_ad_rgb", integrators=["volpath"],
                local_cases=LOCAL_CASES, out=os.path.join(HERE, "results", "cuda")),
    "full": dict(cases=cases_mod.FULL_CASES, variants=["scalar_rgb", "llvm_ad_rgb"], res=48,
                 spp=16, runs=5, sweep=[1, 2, 4, 8, 16, 32, 64], ref_spp=512, ref_passes=4,
                 lookups=1 << 22, scalar_lookups=1 << 14, scalar_res=48, scalar_spp=8,
                 scalar_sweep=[1, 2, 4, 8, 16], lookup_runs=5, sweep_repeats=2,
                 integrators=INTEGRATORS, local_cases=LOCAL_CASES + ["constant_934"],
                 out=os.path.join(HERE, "results")),
}


def log(msg):
    print(msg, flush=True)


def gpu_present():
    """Whether Dr.Jit's CUDA backend initialises (asked in a subprocess)."""
    code = "import drjit as dr, sys; sys.exit(0 if dr.has_backend(dr.JitBackend.CUDA) else 1)"
    try:
        return subprocess.run([sys.executable, "-c", code], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, timeout=120).returncode == 0
    except Exception:
        return False


def file_key(*paths):
    h = hashlib.sha1()
    for p in paths:
        st = os.stat(p)
        h.update(f"{os.path.abspath(p)}|{st.st_size}|{st.st_mtime_ns}".encode())
    return h.hexdigest()[:12]


class Runner:
    def __init__(self, args):
        self.args = args
        self.work = os.path.join(args.data, "runs", args.mode)
        os.makedirs(self.work, exist_ok=True)
        self.failures = []
        self.n_workers = 0

    def worker(self, spec, tag, timeout):
        """Runs one worker (worker.measure, through harness.py) with an empty
        Dr.Jit kernel cache (HOME of its own), so the first render's JIT
        compilation is really measured."""
        spec = dict(spec, build=self.args.build, out_npz=os.path.join(self.work, tag + ".npz"))
        home = tempfile.mkdtemp(prefix="jit_home_", dir=self.work)
        t0 = time.perf_counter()
        self.n_workers += 1
        res, output = None, ""
        try:
            res = harness.run_child("worker:measure", spec, home=home, timeout=timeout)
        except harness.ChildFailed as e:
            output = str(e)
        except subprocess.TimeoutExpired:
            output = f"timed out after {timeout} s"
        finally:
            shutil.rmtree(home, ignore_errors=True)
        dt = time.perf_counter() - t0
        if res is None:
            self.failures.append((tag, output[-3000:]))
            log(f"    FAILED {tag} ({dt:.1f} s):\n{output[-3000:]}")
            return None, None
        with open(os.path.join(self.work, tag + ".json"), "w") as f:
            json.dump(res, f, indent=1)  # (kept beside the images, as before)
        res["worker_wall_s"] = dt
        npz = dict(np.load(spec["out_npz"])) if os.path.exists(spec["out_npz"]) else {}
        return res, npz


def reference(runner, case, plugin, filt, res, a):
    """Converged reference on llvm_ad_rgb, cached in bench/data/refs/."""
    files = [case.nvdb if plugin == "nanovdbvolume" else case.vol]
    if plugin == "nanovdbvolume":
        files.append(os.path.join(a.build, "plugins", "nanovdbvolume.so"))
    key = (f"{case.name.replace(':', '_').replace('/', '_')}__{plugin}__{filt}__r{res}"
           f"__s{a.ref_spp}x{a.ref_passes}__{file_key(*files)}")
    path = os.path.join(a.data, "refs", key + ".npz")
    if os.path.exists(path) and not a.no_cache:
        d = np.load(path)
        return {"mean": d["mean"], "var_of_mean": d["var_of_mean"],
                "time_s": float(d["time_s"]), "plugin": plugin, "cached": True}
    spec = {"mode": "reference", "variant": a.ref_variant, "plugin": plugin,
            "volume": files[0], "grid": case.grid, "filter": filt, "res": res, "spp": a.ref_spp,
            "ref_spp": a.ref_spp, "ref_passes": a.ref_passes}
    tag = f"ref__{key}"
    out, npz = runner.worker(spec, tag, a.timeout)
    if out is None:
        return None
    os.makedirs(os.path.dirname(path), exist_ok=True)
    np.savez(path, mean=npz["mean"], var_of_mean=npz["var_of_mean"], time_s=out["ref_time_s"])
    return {"mean": npz["mean"], "var_of_mean": npz["var_of_mean"], "time_s": out["ref_time_s"],
            "plugin": plugin, "cached": False}


def settings_for(variant, a):
    if variant.startswith("scalar"):
        return dict(res=a.scalar_res, spp=a.scalar_spp, sweep=a.scalar_sweep,
                    lookups=a.scalar_lookups)
    return dict(res=a.res, spp=a.spp, sweep=a.sweep, lookups=a.lookups)


def in_local_comparison(case, filt, a):
    """Whether (case, filter) is a cell of the integrator comparison."""
    return ("volpathlocal" in a.integrators and filt in a.local_filters
            and (case.source != "generated" or case.name in a.local_cases))


def configs_for(case, filt, a):
    """The (integrator, plugin) pairs measured on (case, filter), in run order."""
    configs = [("volpath", p) for p in a.plugins] if "volpath" in a.integrators else []
    if in_local_comparison(case, filt, a):
        configs.append(("volpathlocal", "nanovdbvolume"))
    return configs


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--full", action="store_true", help="all cases incl. 934^3, larger images")
    mode.add_argument("--fast", action="store_true", help="harness check: one tiny case, < 60 s")
    mode.add_argument("--gpu", action="store_true", help="cuda_ad_rgb, GPU-sized images")
    ap.add_argument("--cases", nargs="+", help="generated cases (%s; 'none' for only --vdb/--nvdb)"
                    % ", ".join(cases_mod.GENERATED))
    ap.add_argument("--vdb", nargs="+", default=[], metavar="FILE[:GRID]",
                    help=".vdb files (converted with vdb2nvdb; default grid: the first float grid)")
    ap.add_argument("--nvdb", nargs="+", default=[], metavar="FILE[:GRID]",
                    help=".nvdb files (dense baseline read back through nanovdbvolume)")
    ap.add_argument("--variants", nargs="+")
    ap.add_argument("--filters", nargs="+", choices=FILTERS, default=FILTERS)
    ap.add_argument("--scalar-filters", nargs="+", choices=FILTERS,
                    help="filters for scalar variants (default: --filters; fast: trilinear)")
    ap.add_argument("--plugins", nargs="+", choices=PLUGINS, default=PLUGINS,
                    help="volume plugins rendered with volpath")
    ap.add_argument("--integrators", nargs="+", choices=INTEGRATORS,
                    help="volpath: the plugins in --plugins; volpathlocal: nanovdbvolume on the "
                    "--local-cases and user files (default both; gpu: volpath)")
    ap.add_argument("--local-cases", nargs="+", metavar="CASE",
                    help="generated cases of the integrator comparison ('all', 'none'; default "
                    "%s; full: + constant_934; fast: cloud). --vdb/--nvdb files always take "
                    "part" % " ".join(LOCAL_CASES))
    ap.add_argument("--local-filters", nargs="+", choices=FILTERS, default=["trilinear"],
                    help="filters of the integrator comparison (default trilinear)")
    ap.add_argument("--res", type=int, help="image width = height (JIT variants)")
    ap.add_argument("--spp", type=int, help="spp of the timed renders (JIT variants)")
    ap.add_argument("--sweep", type=int, nargs="+", help="spp sweep (JIT variants)")
    ap.add_argument("--scalar-res", type=int)
    ap.add_argument("--scalar-spp", type=int)
    ap.add_argument("--scalar-sweep", type=int, nargs="+")
    ap.add_argument("--runs", type=int, help="warm timed renders (>= 5 recommended)")
    ap.add_argument("--sweep-repeats", type=int,
                    help="timed renders per sweep point (the minimum is kept)")
    ap.add_argument("--ref-spp", type=int, help="spp of the converged references")
    ap.add_argument("--ref-passes", type=int, help="independent passes of a reference")
    ap.add_argument("--ref-variant", help="variant of the references (default llvm_ad_rgb; "
                    "gpu: cuda_ad_rgb)")
    ap.add_argument("--lookups", type=int, help="random eval_1 points (JIT variants)")
    ap.add_argument("--scalar-lookups", type=int, help="random eval_1 calls (scalar)")
    ap.add_argument("--out", help="results directory (default bench/results/, "
                    "fast: bench/data/fast_results/)")
    ap.add_argument("--data", default=os.path.join(HERE, "data"),
                    help="cache of generated grids and references (default bench/data/)")
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--no-cache", action="store_true", help="re-render cached references")
    ap.add_argument("--max-dense-bytes", type=int, default=8 << 30)
    ap.add_argument("--timeout", type=int, default=1800, help="per worker, seconds")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite REPORT.md, CSVs and plots from OUT/results.json (e.g. after "
                    "bench/PERF_LOG.md changed), without measuring")
    a = ap.parse_args()
    if a.report_only:
        return report_only(a)
    a.mode = "full" if a.full else "fast" if a.fast else "gpu" if a.gpu else "default"
    for k, v in MODES[a.mode].items():
        if getattr(a, k, None) is None:
            setattr(a, k, v)
    if a.local_cases == ["none"]:
        a.local_cases = []
    elif a.local_cases == ["all"]:
        a.local_cases = list(cases_mod.GENERATED)
    for name in a.local_cases:
        if name not in cases_mod.GENERATED:
            sys.exit(f"unknown case {name!r} in --local-cases; known: "
                     f"{', '.join(cases_mod.GENERATED)}")
    if a.scalar_filters is None:
        a.scalar_filters = a.filters
    if a.cases == ["none"]:
        a.cases = []
    a.build = os.path.abspath(a.build)
    a.data = os.path.abspath(a.data)
    a.out = os.path.abspath(a.out)
    a.ref_variant = a.ref_variant or "llvm_ad_rgb"
    # The project's plugins this run loads, and their builds (a rebuild during
    # the run is reported)
    sos = [os.path.join(a.build, "plugins", f"{p}.so") for p in
           ["nanovdbvolume"] + (["volpathlocal"] if "volpathlocal" in a.integrators else [])]
    for so in sos:
        if not os.path.exists(so):
            sys.exit(f"{so} not found: build the project first")
    t_start = time.perf_counter()
    started = datetime.datetime.now().astimezone()
    so_stats = {so: (os.stat(so).st_size, os.stat(so).st_mtime_ns) for so in sos}

    notes = []
    cuda_requested = [v for v in a.variants if v.startswith("cuda")]
    has_gpu = gpu_present()
    if not has_gpu:
        notes.append("cuda_ad_rgb: no GPU, not measured.")
        a.variants = [v for v in a.variants if not v.startswith("cuda")]
    elif a.mode not in ("fast", "gpu") and not cuda_requested and "--variants" not in sys.argv:
        a.variants.append("cuda_ad_rgb")

    log(f"== bench/run.py ({a.mode}): cases {a.cases + a.vdb + a.nvdb}, variants {a.variants}, "
        f"filters {a.filters}, integrators {a.integrators}")
    log("== preparing cases")
    case_list = []
    for name in a.cases:
        if name not in cases_mod.GENERATED:
            sys.exit(f"unknown case {name!r}; known: {', '.join(cases_mod.GENERATED)}")
        case_list.append(cases_mod.generated_case(name, a.data, a.build))
    for f in a.vdb:
        case_list.append(cases_mod.vdb_case(f, a.data, a.build))
    for f in a.nvdb:
        case_list.append(cases_mod.nvdb_case(f, a.data, a.build, a.max_dense_bytes))
    seen = set()
    for c in case_list:  # user files may share a name with a case or each other
        base, k = c.name, 2
        while c.name in seen:
            c.name, k = f"{base}#{k}", k + 1
        seen.add(c.name)
    for c in case_list:
        log(f"   {c.name}: grid {c.grid_bytes:,} B, dense {c.dense_bytes:,} B "
            f"({'x'.join(map(str, c.dense_res))}), border all zero: {c.border_background}")

    runner = Runner(a)
    results = []   # one dict per worker (measure mode)
    errors = []    # one dict per sweep point
    refs_info = []
    def variants_for(filt):
        return [v for v in a.variants if not v.startswith("scalar") or filt in a.scalar_filters]
    total = sum(len(variants_for(f)) * len(configs_for(c, f, a))
                for c in case_list for f in a.filters)
    done = 0
    for c in case_list:
        for filt in a.filters:
            # References: nearest looks up the same voxels in both plugins, so
            # one reference (gridvolume's) serves both; trilinear differs in
            # the outer half voxel, so each plugin has its own.
            ref_cache = {}
            for variant in variants_for(filt):
                st = settings_for(variant, a)
                for integrator, plugin in configs_for(c, filt, a):
                    # volpathlocal's expectation is volpath's: it is compared
                    # with volpath's reference of its plugin
                    ref_plugin = "gridvolume" if filt == "nearest" else plugin
                    rk = (ref_plugin, st["res"])
                    if rk not in ref_cache:
                        log(f"   reference {c.name} {filt} {ref_plugin} {st['res']}^2 x8, "
                            f"{a.ref_spp} spp")
                        ref_cache[rk] = reference(runner, c, ref_plugin, filt, st["res"], a)
                    done += 1
                    config = plugin if integrator == "volpath" else f"{integrator}_{plugin}"
                    tag = f"{c.name}__{variant}__{config}__{filt}".replace(":", "_").replace("/", "_")
                    log(f"[{done}/{total}] {tag}  (elapsed {time.perf_counter() - t_start:.0f} s, "
                        f"load {os.getloadavg()[0]:.2f})")
                    spec = {"mode": "measure", "variant": variant, "plugin": plugin,
                            "integrator": integrator,
                            "volume": c.nvdb if plugin == "nanovdbvolume" else c.vol,
                            "grid": c.grid, "filter": filt, "res": st["res"], "spp": st["spp"],
                            "runs": a.runs, "sweep": st["sweep"],
                            # the volume's lookups do not depend on the integrator
                            "lookups": st["lookups"] if integrator == "volpath" else 0,
                            "sweep_repeats": a.sweep_repeats,
                            "lookup_runs": a.lookup_runs,
                            "count_lookups": plugin == "nanovdbvolume"
                            and in_local_comparison(c, filt, a)}
                    out, npz = runner.worker(spec, tag, a.timeout)
                    if out is None:
                        continue
                    out.update(case=c.name, variant=variant, plugin=plugin, filter=filt,
                               integrator=integrator)
                    results.append(out)
                    ref = ref_cache[rk]
                    if ref is None:
                        continue
                    for pt in out["sweep"]:
                        img = npz[f"sweep_{pt['spp']}"]
                        raw, corr = metrics.rmse(img, ref["mean"], ref["var_of_mean"])
                        errors.append({"case": c.name, "variant": variant, "plugin": plugin,
                                       "integrator": integrator, "filter": filt,
                                       "res": st["res"], "spp": pt["spp"],
                                       "time_s": pt["time_s"], "rmse": corr, "rmse_raw": raw,
                                       "ssim": metrics.ssim(img, ref["mean"]),
                                       "reference": ref_plugin})
                    log(f"      warm median {out['warm_median_s']:.3f} s, first "
                        f"{out['first_s']:.3f} s, lookups {out.get('lookups_per_s', 0):.3g}/s, "
                        + (f"per path {out['counts']['lookup_count'] / out['count_paths']:.2f} "
                           f"lookups, {out['counts']['walk_step_count'] / out['count_paths']:.2f}"
                           " walk steps, " if "counts" in out else "")
                        + f"worker {out['worker_wall_s']:.1f} s")
            # Trilinear: how far apart the two plugins' references are (the
            # border convention), against the references' own noise.
            for (rp, res), ref in ref_cache.items():
                if ref is not None:
                    refs_info.append({"case": c.name, "filter": filt, "plugin": rp, "res": res,
                                      "spp": a.ref_spp, "passes": a.ref_passes,
                                      "time_s": ref["time_s"], "cached": ref["cached"],
                                      "noise_rmse": float(np.sqrt(np.mean(ref["var_of_mean"])))})
            # What is measured so far survives an interrupted run
            # (--report-only writes the report from it)
            save(a, case_list, results, errors, refs_info,
                 notes + ["**partial run: interrupted before its end**"], runner.failures,
                 started, time.perf_counter() - t_start, has_gpu)
            for res in sorted({r for (_, r) in ref_cache}):
                ra, rb = ref_cache.get(("nanovdbvolume", res)), ref_cache.get(("gridvolume", res))
                if filt == "trilinear" and ra is not None and rb is not None:
                    d = float(np.sqrt(np.mean((ra["mean"].astype(np.float64) - rb["mean"]) ** 2)))
                    noise = float(np.sqrt(np.mean(ra["var_of_mean"]) + np.mean(rb["var_of_mean"])))
                    refs_info.append({"case": c.name, "filter": filt, "plugin": "difference",
                                      "res": res, "spp": a.ref_spp, "passes": a.ref_passes,
                                      "time_s": 0.0, "cached": True,
                                      "noise_rmse": noise, "rmse_between": d})

    elapsed = time.perf_counter() - t_start
    for so, (size, mtime) in so_stats.items():
        name = os.path.basename(so)
        if (os.stat(so).st_size, os.stat(so).st_mtime_ns) != (size, mtime):
            notes.append(f"**build/plugins/{name} was rebuilt during this run**: "
                         "measurements before and after may mix two builds.")
        else:
            built = datetime.datetime.fromtimestamp(mtime / 1e9).astimezone()
            notes.append(f"{name}: built {built:%Y-%m-%d %H:%M:%S %Z}, {size:,} B, unchanged "
                         "during the run.")
    import report
    save(a, case_list, results, errors, refs_info, notes, runner.failures, started, elapsed,
         has_gpu)
    # runner.failures itself: write_all may add the plots' failure to it
    report.write_all(report.Run(args=a, cases=case_list, results=results, errors=errors,
                                refs_info=refs_info, notes=notes, failures=runner.failures,
                                started=started, elapsed=elapsed, has_gpu=has_gpu))
    log(f"== done in {elapsed:.0f} s ({runner.n_workers} worker processes); results in {a.out}")
    if runner.failures:
        log(f"== {len(runner.failures)} measurement(s) FAILED: "
            + ", ".join(t for t, _ in runner.failures))
        sys.exit(1)


def save(a, case_list, results, errors, refs_info, notes, failures, started, elapsed, has_gpu):
    import report
    saved = {"settings": {k: v for k, v in vars(a).items()}, "argv": sys.argv[1:],
             "cases": [c.row() for c in case_list], "results": results, "errors": errors,
             "refs_info": refs_info, "notes": notes, "failures": failures,
             "started": started.isoformat(), "elapsed": elapsed, "has_gpu": has_gpu,
             "machine": report.machine_record(has_gpu)}
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "results.json.tmp"), "w") as f:
        json.dump(saved, f, indent=1, default=str)
    os.replace(os.path.join(a.out, "results.json.tmp"), os.path.join(a.out, "results.json"))


def report_only(args):
    import report
    out = os.path.abspath(args.out or MODES["full" if args.full else "fast" if args.fast
                                              else "gpu" if args.gpu else "default"]["out"])
    saved = json.load(open(os.path.join(out, "results.json")))
    a = argparse.Namespace(**saved["settings"])
    a.out = out
    sys.argv = [sys.argv[0]] + saved["argv"]
    case_list = [cases_mod.CaseRecord(r) for r in saved["cases"]]
    failures = [tuple(f) for f in saved["failures"]]
    report.write_all(report.Run(args=a, cases=case_list, results=saved["results"],
                                errors=saved["errors"], refs_info=saved["refs_info"],
                                notes=saved["notes"], failures=failures,
                                started=datetime.datetime.fromisoformat(saved["started"]),
                                elapsed=saved["elapsed"], has_gpu=saved["has_gpu"],
                                machine=saved.get("machine"), rewritten=True))
    log(f"== report rewritten from {out}/results.json")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
