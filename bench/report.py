"""CSV files, PNG plots and REPORT.md from the measurements of bench/run.py.

This module puts the report together (header, summary, cases, references,
files, the performance log) from its parts: the plugin comparison (volpath
with nanovdbvolume and gridvolume) is bench/report_plugins.py's, the
integrator comparison's tables, plots and section are
bench/report_integrator.py's, the CUDA section is bench/report_cuda.py's;
helpers they share are in bench/report_common.py.
"""
import argparse
import csv
import dataclasses
import datetime
import functools
import os
import platform
import statistics
import subprocess
import sys

import report_integrator
from report_common import PLOT_DPI, integrator_of
from report_cuda import cuda_section
from report_plugins import (equal_time_rows, error_time_section, lookup_rows, lookups_section,
                            memory_rows, memory_section, plots, render_time_section,
                            target_rows, targets_section, time_rows)

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
PERF_LOG = os.path.join(HERE, "PERF_LOG.md")
PERF_LOG_HEADER = """# Performance log

The lead's before/after measurements of performance work on `nanovdbvolume`
(`src/volumes/grid_nanovdb.cpp`, `include/nanovdb_drjit/pnanovdb.h`).
`bench/run.py` copies this file verbatim into the section "Performance work"
of `bench/results/REPORT.md`. One entry per change: date, commit, what
changed, the command, and the numbers before and after (with the load).
"""


def write_csv(path, rows, fields=None):
    if not rows:
        open(path, "w").close()
        return
    fields = fields or list(dict.fromkeys(k for r in rows for k in r))  # in order of appearance
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def machine_info():
    cpu = platform.processor() or ""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        for line in open("/proc/meminfo"):
            if line.startswith("MemTotal"):
                mem = f"{int(line.split()[1]) / 2 ** 20:.1f} GiB"
    except OSError:
        pass
    vers = {}
    try:
        import importlib.metadata as md
        for p in ("mitsuba", "drjit", "numpy", "matplotlib"):
            try:
                vers[p] = md.version(p)
            except md.PackageNotFoundError:
                vers[p] = "not installed"
    except Exception:
        pass
    commit = ""
    try:
        commit = subprocess.run(["git", "-C", ROOT, "log", "-1", "--format=%h %s"],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "--untracked-files=no"],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                               text=True).stdout.rstrip()
        if dirty:
            commit += " (+ uncommitted changes: " + ", ".join(
                line[3:] for line in dirty.splitlines()) + ")"
    except Exception:
        pass
    if not commit:  # e.g. run from a GPU kit (scripts/gpu_kit_run.sh), which has no .git
        commit = os.environ.get("NVDB_KIT_COMMIT", "")
    return cpu, os.cpu_count(), mem, vers, commit


# ---------------------------------------------------------------------------
# REPORT.md

@dataclasses.dataclass
class Run:
    """What write_all writes about: one run's settings and measurements, as
    bench/run.py has them after measuring or reads them back from
    OUT/results.json (--report-only)."""
    args: argparse.Namespace  # bench/run.py's settings (mode, out, res, spp, ...)
    cases: list               # cases.Case (or cases.CaseRecord), in run order
    results: list             # one dict per worker (measure mode)
    errors: list              # one dict per sweep point
    refs_info: list           # one dict per reference, + the trilinear "difference" rows
    notes: list               # extra lines for the report's header
    failures: list            # (tag, output) per failed measurement; write_all appends
    #                           ("plots", note) when matplotlib is missing (not in fast mode)
    started: datetime.datetime
    elapsed: float            # seconds
    has_gpu: bool
    machine: dict = None      # machine_record() of the machine that measured (results.json
    #                           holds it: --report-only may run elsewhere); None: this one
    rewritten: bool = False   # --report-only (a None machine then is not this one)


@dataclasses.dataclass
class Tables:
    """The tables derived from a run's measurements (the rows of the CSV files)."""
    times: list       # render time per case, variant, filter (both plugins)
    memory: list      # memory per case, variant, plugin
    lookups: list     # lookup throughput per case, variant, filter
    equal_time: list  # error at equal time per case, variant, filter
    targets: list     # the targets, measured
    volpath_errors: list  # the plugin comparison's sweep points (volpath)
    integrator_times: list       # per case, variant, filter of the integrator comparison
    integrator_equal_time: list  # ... volpathlocal's error at equal time
    integrator_targets: list     # ... its targets (llvm_ad_rgb)

    @classmethod
    def of(cls, run):
        case_by_name = {c.name: c for c in run.cases}
        case_names = [c.name for c in run.cases]
        # The plugin comparison: volpath's workers (volpathlocal's are the
        # integrator comparison's)
        volpath = [r for r in run.results if integrator_of(r) == "volpath"]
        volpath_errors = [e for e in run.errors if integrator_of(e) == "volpath"]
        times = time_rows(volpath)
        memory = memory_rows(volpath, case_by_name)
        itimes = report_integrator.time_rows(run.results, case_names)
        return cls(times=times, memory=memory, lookups=lookup_rows(volpath),
                   equal_time=equal_time_rows(volpath_errors),
                   targets=target_rows(times, memory, case_by_name),
                   volpath_errors=volpath_errors, integrator_times=itimes,
                   integrator_equal_time=report_integrator.equal_time_rows(run.errors,
                                                                           case_names),
                   integrator_targets=report_integrator.target_rows(itimes, case_by_name))


def write_all(run):
    """Replaces OUT's CSV files, plots and REPORT.md with those of `run` (a Run)."""
    out = run.args.out
    clear_outputs(out)
    case_names = [c.name for c in run.cases]
    # The variant the summary and the targets are about
    main_variant = "cuda_ad_rgb" if run.args.mode == "gpu" else "llvm_ad_rgb"
    t = Tables.of(run)
    write_csvs(out, run, t)
    pngs, plot_note = make_plots(run, t, case_names, main_variant)
    if not os.path.exists(PERF_LOG):
        with open(PERF_LOG, "w") as f:
            f.write(PERF_LOG_HEADER)
    L = (header_section(run, plot_note)
         + summary_section(t, main_variant)
         + cases_section(run.cases)
         + targets_section(t.targets, main_variant)
         + render_time_section(t.times, pngs)
         + memory_section(t.memory, case_names, pngs)
         + error_time_section(t.equal_time, run.refs_info, pngs)
         + lookups_section(t.lookups, pngs)
         + report_integrator.section(t.integrator_times, t.integrator_equal_time,
                                     t.integrator_targets, pngs)
         + references_section(run.refs_info)
         + files_section(pngs)
         + (cuda_section(out) if run.args.mode != "gpu" else [])
         + perf_log_section())
    with open(os.path.join(out, "REPORT.md"), "w") as f:
        f.write("\n".join(L) + "\n")


def clear_outputs(out):
    os.makedirs(out, exist_ok=True)
    for f in os.listdir(out):  # a run replaces the previous one's files
        if f.startswith("huge_sparse."):
            continue  # bench/huge_sparse.py's, not the report's
        if f.endswith((".png", ".csv")) or f == "REPORT.md":
            os.remove(os.path.join(out, f))


def write_csvs(out, run, t):
    write_csv(os.path.join(out, "cases.csv"), [c.row() for c in run.cases])
    write_csv(os.path.join(out, "render_time.csv"), t.times,
              sorted({k for r in t.times for k in r}, key=lambda k: list(t.times[0]).index(k)
                     if k in t.times[0] else 99) if t.times else None)
    write_csv(os.path.join(out, "memory.csv"), t.memory)
    write_csv(os.path.join(out, "lookups.csv"), t.lookups)
    write_csv(os.path.join(out, "error_sweep.csv"), run.errors)
    write_csv(os.path.join(out, "error_equal_time.csv"), t.equal_time)
    write_csv(os.path.join(out, "references.csv"), run.refs_info,
              ["case", "filter", "plugin", "res", "spp", "passes", "time_s", "cached",
               "noise_rmse", "rmse_between"])
    write_csv(os.path.join(out, "targets.csv"), t.targets)
    write_csv(os.path.join(out, "integrator_render_time.csv"), t.integrator_times)
    write_csv(os.path.join(out, "integrator_error_equal_time.csv"), t.integrator_equal_time)
    write_csv(os.path.join(out, "integrator_targets.csv"), t.integrator_targets)


def make_plots(run, t, case_names, main_variant):
    """(PNG file names, None), or ([], a note for the report) without
    matplotlib -- then a failure of the run, except in fast mode."""
    try:
        return (plots(run.args.out, t.volpath_errors, t.times, t.memory, t.lookups, case_names,
                      main_variant)
                + report_integrator.plots(run.args.out, run.errors, t.integrator_times,
                                          t.integrator_targets, case_names, PLOT_DPI)), None
    except ImportError as e:
        plot_note = (f"matplotlib is not installed ({e}): no plots. "
                     "`pip install matplotlib==3.11.2` (scripts/install.sh pins it).")
        print("WARNING: " + plot_note, file=sys.stderr)
        if run.args.mode != "fast":
            run.failures.append(("plots", plot_note))
        return [], plot_note


@functools.lru_cache(maxsize=None)
def machine_record(has_gpu):
    """The header's machine, GPU, software and commit lines, as measured here
    (bench/run.py stores them in results.json with the measurements)."""
    cpu, ncpu, mem, vers, commit = machine_info()
    rec = {"machine": f"{cpu}, {ncpu} cores, {mem} RAM; {platform.platform()}",
           "software": f"Python {platform.python_version()}, "
                       + ", ".join(f"{k} {v}" for k, v in vers.items()),
           "commit": commit}
    if has_gpu:
        import gpu
        rec["gpu"] = gpu.device_name() or "unknown (nvidia-smi not found)"
    return rec


def header_section(run, plot_note):
    """Title, command, machine, software and settings, then notes and failures."""
    a = run.args
    m = run.machine
    if m is None and run.rewritten:
        # results.json from before the record existed: not this machine's
        m = {k: "not recorded in results.json (a run before 2026-11-27; this report was "
                "rewritten from it elsewhere)" for k in ("machine", "gpu", "software", "commit")}
    m = m or machine_record(run.has_gpu)
    L = []
    w = L.append
    w("# nanovdbvolume vs gridvolume, volpathlocal vs volpath: benchmark report\n")
    w(f"Generated by `{' '.join(['python3', 'bench/run.py'] + sys.argv[1:])}` "
      f"({a.mode} mode) on {run.started:%Y-%m-%d %H:%M %Z}, in {run.elapsed / 60:.1f} min. "
      "Methodology and caveats: [bench/README.md](../README.md). Benchmarks are "
      "measurements: the ✓/✗ below are reported, not asserted.\n")
    w(f"- Machine: {m['machine']}.")
    if run.has_gpu:
        w(f"- GPU: {m.get('gpu', 'unknown')}.")
    w(f"- Software: {m['software']}.")
    w("- Plugins: `build/plugins/nanovdbvolume.so` (and `volpathlocal.so`) as built at the time "
      f"of the run; repository at {m['commit'] or 'unknown commit'}.")
    L += settings_lines(run)
    for n in run.notes:
        w(f"- {n}")
    if plot_note:
        w(f"- {plot_note}")
    if run.failures:
        w(f"- **{len(run.failures)} measurement(s) failed:** "
          + ", ".join(f"`{t}`" for t, _ in run.failures))
    w("")
    return L


def settings_lines(run):
    """The header's scene, settings, variants and machine load."""
    a = run.args
    L = []
    w = L.append
    w(f"- Scene: the volume in the unit cube (null BSDF, `heterogeneous` medium, scale 40, "
      "albedo 0.9), `volpath` max_depth 64, constant sky + sun (as `scenes/cloud.xml`), "
      "a turntable of 8 sensors (35° fov, elevation 22°, distance 2.92). The same scene for "
      "both plugins; `gridvolume` reads the aligned dense `.vol` export of the same active box.")
    integrators = getattr(a, "integrators", ["volpath"])
    if "volpathlocal" in integrators:
        w(f"- Integrators: {', '.join(integrators)}; `volpathlocal` (in place of `volpath`, "
          f"same parameters) with nanovdbvolume on the cases "
          f"{', '.join(a.local_cases) or 'none'} and every `--vdb`/`--nvdb` file, filters "
          f"{', '.join(a.local_filters)} (section \"Integrator\").")
    w(f"- JIT variants: {a.res}² pixels per sensor, {a.spp} spp for the timings, "
      f"{a.runs} warm runs, sweep {a.sweep} spp. Scalar: {a.scalar_res}², {a.scalar_spp} spp, "
      f"sweep {a.scalar_sweep}. References: {getattr(a, 'ref_variant', 'llvm_ad_rgb')}, "
      f"{a.ref_spp} spp in "
      f"{a.ref_passes} passes.")
    w(f"- Variants measured: {', '.join(sorted({r['variant'] for r in run.results})) or 'none'}. "
      + ("GPU present." if run.has_gpu else "**cuda_ad_rgb: no GPU, not measured.**"))
    loads = [r["loadavg_start"][0] for r in run.results]
    if loads:
        w(f"- Machine load (1-min load average at each worker's start): min {min(loads):.2f}, "
          f"median {statistics.median(loads):.2f}, max {max(loads):.2f} "
          "(per measurement in the CSV files).")
    return L


def summary_section(t, main_variant):
    """Render time ratios per variant and filter; main_variant's memory and
    error at equal time; the integrator comparison's targets."""
    L = ["## Summary\n"]
    w = L.append
    for v in sorted({r["variant"] for r in t.times}):
        for filt in ("trilinear", "nearest"):
            rs = [(r["case"], r["ratio_median"]) for r in t.times
                  if r["variant"] == v and r["filter"] == filt and "ratio_median" in r]
            if rs:
                w(f"- {v}, {filt}: render time nano/grid at equal spp "
                  + ", ".join(f"{c} {r:.2f}" for c, r in rs) + ".")
    for m in t.memory:
        if m["variant"] == main_variant and m["plugin"] == "nanovdbvolume" and m["backend_bytes"]:
            g = next((x for x in t.memory if x["case"] == m["case"]
                      and x["variant"] == m["variant"] and x["plugin"] == "gridvolume"), None)
            w(f"- {m['case']}, {main_variant} memory: nano holds {m['backend_over_grid']:.4f} × the "
              f"grid's bytes" + (f"; gridvolume holds {g['backend_bytes'] / m['backend_bytes']:.2f}"
                                 " × what nano holds" if g and g["backend_bytes"] else "") + ".")
    for e in t.equal_time:
        if e["ratio"] is not None and e["variant"] == main_variant:
            w(f"- {e['case']}, {e['variant']}, {e['filter']}: at equal time "
              f"({e['t_s']:.2f} s) {e['lower']} has the lower RMSE "
              f"(nano/grid {e['ratio']:.2f}; cost ratio {e['cost_ratio']:.2f}).")
    L += report_integrator.summary_lines(t.integrator_times, t.integrator_targets)
    w("")
    return L


def cases_section(case_list):
    L = ["## Cases\n"]
    w = L.append
    w("| case | grid | dense box | grid bytes | .nvdb file | dense bytes | grid / dense | "
      "border voxels all 0 |")
    w("|---|---|---|---:|---:|---:|---:|:-:|")
    for c in case_list:
        w(f"| {c.name} | {c.grid_name or '—'} | {'×'.join(map(str, c.dense_res))} | "
          f"{c.grid_bytes:,} | {c.nvdb_file_bytes:,} | {c.dense_bytes:,} | "
          f"{c.grid_bytes / c.dense_bytes:.3f} | {'yes' if c.border_background else 'no'} |")
    w("")
    w("Descriptions: " + "; ".join(f"**{c.name}**: {c.description}" for c in case_list) + ".\n")
    return L


def references_section(refs_info):
    L = ["## References\n"]
    w = L.append
    w("| case | filter | plugin | res | spp | time [s] | noise RMSE | cached |")
    w("|---|---|---|---:|---:|---:|---:|:-:|")
    for r in refs_info:
        if r["plugin"] != "difference":
            w(f"| {r['case']} | {r['filter']} | {r['plugin']} | {r['res']} | {r['spp']} | "
              f"{r['time_s']:.1f} | {r['noise_rmse']:.3g} | {'yes' if r['cached'] else 'no'} |")
    w("")
    return L


def files_section(pngs):
    return ["## Files\n",
            "CSV: " + ", ".join(f"`{f}`" for f in ("cases.csv", "render_time.csv", "memory.csv",
                                                   "lookups.csv", "error_sweep.csv",
                                                   "error_equal_time.csv", "references.csv",
                                                   "targets.csv", "integrator_render_time.csv",
                                                   "integrator_error_equal_time.csv",
                                                   "integrator_targets.csv")) + ". Plots: "
            + (", ".join(f"`{p}`" for p in pngs) or "none") + ".\n"]


def perf_log_section():
    return ["## Performance work\n",
            "The contents of `bench/PERF_LOG.md`, verbatim:\n",
            open(PERF_LOG).read().rstrip("\n"),
            ""]
