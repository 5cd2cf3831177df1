"""What one optimization step holds in memory, measured in a process of its
own: the largest volume that optimizes on this machine (issue 20).

    python3 bench/step_memory.py --volume cf.nvdb [--build build] [--variant llvm_ad_rgb]
    python3 bench/step_memory.py --volume cf.vol              (gridvolume)
    python3 bench/step_memory.py --sweep A.nvdb B.vol ... --out bench/results/optimize
    python3 bench/step_memory.py --integrator prbvolpathlocal --sweep A.nvdb ... --out DIR

One run loads the volume (nanovdbvolume with differentiable=true for a
.nvdb, gridvolume for a .vol), sets up bench/optimize.py's problem at its
smallest (one view of the benchmark scene, 32 x 32 at 4 spp, prbvolpath
or --integrator prbvolpathlocal, Adam on the values) and takes two steps: render, loss against a constant
image, backward, Adam step, params.update(). It prints one JSON line: the
values optimized, the process's peak RSS (ru_maxrss: loading and the steps
together, what the machine must hold) and its RSS after loading, and the
time of the second step. --sweep runs each volume in a child process
(bench/harness.py; one at a time; a child killed or out of memory is
reported, not fatal) and
writes step_memory.json and step_memory.md to --out: bytes per value of
the peak, and from the slope over the volumes of each plugin, the largest
volume whose peak fits in --memory-gb. A child whose RSS passes --stop-gb
is stopped and reported as such.

A measurement, not a test.
"""
import argparse
import json
import os
import resource
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import harness  # noqa: E402


def rss_now():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def peak_rss():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def measure(spec):
    """One run (in a child of its own: bench/harness.py): spec "volume",
    "variant", "build"; returns the row"""
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    from scene import turntable_scene
    import numpy as np

    rss0 = rss_now()
    t0 = time.perf_counter()
    path = spec["volume"]
    if path.endswith(".vol"):
        volume = mi.load_dict({"type": "gridvolume", "filename": path})
    else:
        volume = mi.load_dict({"type": "nanovdbvolume", "filename": path,
                               "differentiable": True,
                               "majorant_rebuild": spec.get("majorant_rebuild", "backend")})
    desc = turntable_scene(volume, 32, 4, spec.get("integrator", "prbvolpath"))
    desc["integrator"]["max_depth"] = 4
    for i in range(1, 8):
        desc.pop(f"sensor_{i}", None)
    scene = mi.load_dict(desc)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("sigma_t.data"))
    dr.eval()
    load_s = time.perf_counter() - t0
    rss_loaded = rss_now()
    values = dr.width(params[key].array if isinstance(params[key], mi.TensorXf) else params[key])
    optimizer = mi.ad.Adam(lr=0.01)
    optimizer[key] = params[key]
    params.update(optimizer)
    step_s = 0.0
    for it in range(2):
        t = time.perf_counter()
        img = mi.render(scene, params, sensor=0, seed=it, spp=4)
        loss = dr.mean(dr.square(img - 0.5))
        dr.backward(loss)
        optimizer.step()
        optimizer[key] = dr.maximum(optimizer[key], 0.0)
        params.update(optimizer)
        dr.eval()
        step_s = time.perf_counter() - t
    return dict(volume=os.path.abspath(path), integrator=spec.get("integrator", "prbvolpath"),
                majorant_rebuild=spec.get("majorant_rebuild", "backend"),
                plugin="gridvolume" if path.endswith(".vol") else "nanovdbvolume",
                values=int(values), file_bytes=os.path.getsize(path),
                rss_start=rss0, rss_loaded=rss_loaded, peak_rss=peak_rss(),
                load_s=load_s, step_s=step_s)


def sweep(a):
    rows = []
    for path in a.sweep:
        print("measuring", path, flush=True)
        t = time.perf_counter()
        try:
            row = harness.run_child("step_memory:measure", dict(
                volume=os.path.abspath(path), variant=a.variant, build=a.build,
                integrator=a.integrator),
                stop_rss_gb=a.stop_gb)
        except harness.ChildFailed as e:
            rows.append(dict(volume=os.path.abspath(path), failed=True, returncode=e.returncode,
                             stopped_at_gb=a.stop_gb if e.stopped else None,
                             stderr=e.stderr, wall_s=time.perf_counter() - t))
            print(f"  failed (exit {e.returncode}" +
                  (f", stopped at {a.stop_gb:g} GB of RSS)" if e.stopped else ")"), flush=True)
            continue
        row["wall_s"] = time.perf_counter() - t
        rows.append(row)
        print(f"  {row['plugin']}: {row['values']:,} values, peak RSS {row['peak_rss'] / 1e9:.2f} GB "
              f"({(row['peak_rss'] - row['rss_start']) / row['values']:.1f} B a value above the "
              f"start), step {row['step_s']:.2f} s", flush=True)
    budget = a.memory_gb * 1e9
    fits = {}
    for plugin in ("gridvolume", "nanovdbvolume"):
        ok = sorted((r for r in rows if not r.get("failed") and r["plugin"] == plugin),
                    key=lambda r: r["values"])
        if len(ok) >= 2:
            # peak = base + slope x values, through the two largest runs
            x0, x1 = ok[-2]["values"], ok[-1]["values"]
            y0, y1 = ok[-2]["peak_rss"], ok[-1]["peak_rss"]
            slope = (y1 - y0) / (x1 - x0)
            base = y1 - slope * x1
            fits[plugin] = dict(bytes_per_value=slope, base_bytes=base,
                                values_in_budget=(budget - base) / slope,
                                largest_measured=x1)
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "step_memory.json"), "w") as f:
        json.dump(dict(rows=rows, fits=fits, memory_gb=a.memory_gb, variant=a.variant), f, indent=1)
    lines = [f"| volume | plugin | values | file | RSS after load | peak RSS | peak B / value | step |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        name = os.path.basename(r["volume"])
        if r.get("failed"):
            why = (f"stopped at {r['stopped_at_gb']:g} GB" if r.get("stopped_at_gb")
                   else f"failed (exit {r['returncode']})")
            lines.append(f"| {name} | | | | | {why} | | |")
            continue
        lines.append(f"| {name} | {r['plugin']} | {r['values']:,} | {r['file_bytes'] / 1e9:.2f} GB | "
                     f"{r['rss_loaded'] / 1e9:.2f} GB | {r['peak_rss'] / 1e9:.2f} GB | "
                     f"{r['peak_rss'] / r['values']:.1f} | {r['step_s']:.2f} s |")
    lines.append("")
    for plugin, f in fits.items():
        lines.append(f"- {plugin}: {f['bytes_per_value']:.1f} bytes a value (slope between the two "
                     f"largest runs), {f['base_bytes'] / 1e9:.2f} GB fixed: "
                     f"{f['values_in_budget']:.3g} values in {a.memory_gb:g} GB "
                     f"(largest measured: {f['largest_measured']:,})")
    with open(os.path.join(a.out, "step_memory.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--volume", help="one run: a .nvdb (nanovdbvolume) or .vol (gridvolume)")
    ap.add_argument("--sweep", nargs="+", help="volumes, each run in a child process")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--integrator", default="prbvolpath", choices=["prbvolpath", "prbvolpathlocal"],
                    help="the differentiable integrator of the step")
    ap.add_argument("--majorant-rebuild", default="backend", choices=["backend", "host"],
                    help="nanovdbvolume's majorant_rebuild (where prbvolpathlocal's "
                         "majorants follow the update)")
    ap.add_argument("--build", default="", help="a build folder holding plugins/")
    ap.add_argument("--memory-gb", type=float, default=24.0)
    ap.add_argument("--stop-gb", type=float, default=21.0,
                    help="--sweep: a child whose RSS passes this is stopped (and reported)")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "optimize"))
    a = ap.parse_args()
    if a.sweep:
        sweep(a)
    elif a.volume:  # (in this process)
        print(json.dumps(measure(dict(volume=a.volume, variant=a.variant, build=a.build,
                                      integrator=a.integrator,
                                      majorant_rebuild=a.majorant_rebuild))))
    else:
        ap.error("give --volume or --sweep")


if __name__ == "__main__":
    main()
