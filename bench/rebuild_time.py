"""How long the per-node majorants take to follow an update (issue 36): a
differentiable nanovdbvolume's values changed, params.update(), then the
rebuild the walk asks for (mi.traverse asks too), on the host
(majorant_rebuild="host") and on the backend ("backend"), the two volumes
loaded side by side in one process and updated in turn.

    python3 bench/rebuild_time.py cf.nvdb smoke.nvdb [--build build]
           [--variant llvm_ad_rgb] [--rounds 10]

Prints, per file, the medians of --rounds rebuilds (after two untimed
ones: Dr.Jit compiles the backend's kernels once, then records them for
its replays) and their ratio.

    python3 bench/rebuild_time.py FILES --compare-builds OLD NEW [--runs 3]

The backend's rebuild of two builds (before and after a change), a child
process of each in turn, --runs times: per file the first quartile of 60
rebuilds (less noisy than the median on a shared machine), the median of
those over the runs, and NEW / OLD. A measurement, not a test.
"""
import argparse
import os
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from child_setup import mitsuba_for  # noqa: E402


def load(mi, path, where):
    return mi.load_dict({
        "type": "nanovdbvolume", "filename": path, "differentiable": True,
        "filter_type": "stochastic_trilinear", "majorant_rebuild": where})


def rebuild_times(dr, mi, volumes, rounds):
    """Per (name, volume): the times of `rounds` rebuilds after 2 untimed"""
    bases = {k: mi.Float(mi.traverse(v)["data"]) for k, v in volumes.items()}
    dr.eval(*bases.values())
    times = {k: [] for k in volumes}
    for r in range(rounds + 2):
        for k, volume in volumes.items():
            params = mi.traverse(volume)
            params["data"] = bases[k] * (1.0 + 1e-3 * (r + 1))  # (new values: an update)
            dr.eval(params["data"])
            params.update()
            dr.sync_thread()
            t0 = time.perf_counter()
            mi.traverse(volume)  # (the walk's question: the rebuild)
            dr.sync_thread()
            if r >= 2:
                times[k].append(time.perf_counter() - t0)
    return times


def compare_builds(a):
    p25 = {}
    me = os.path.abspath(__file__)
    for run in range(a.runs):
        for build in a.compare_builds:
            out = subprocess.run(
                [sys.executable, me, *a.files, "--backend-only", "--rounds", "60", "--build", build,
                 "--variant", a.variant], check=True, capture_output=True, text=True).stdout
            for line in out.splitlines():
                name, q = line.split()
                p25.setdefault(name, {}).setdefault(build, []).append(float(q))
    old, new = a.compare_builds
    for name, by in p25.items():
        o, n = statistics.median(by[old]), statistics.median(by[new])
        runs = [round(y / x, 2) for x, y in zip(by[old], by[new])]
        print(f"{name}: backend rebuild (first quartile, median of {a.runs} runs): "
              f"{os.path.basename(old.rstrip('/'))} {1e3 * o:.2f} ms, "
              f"{os.path.basename(new.rstrip('/'))} {1e3 * n:.2f} ms, new / old {n / o:.3f} "
              f"(per run {runs})", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--build", default="")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--compare-builds", nargs=2, metavar=("OLD", "NEW"))
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--backend-only", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.compare_builds:
        return compare_builds(a)
    dr, mi = mitsuba_for(a.variant, a.build)
    if a.backend_only:  # (a child of --compare-builds: each file's first quartile)
        volumes = {os.path.basename(p): load(mi, p, "backend") for p in a.files}
        for name, t in rebuild_times(dr, mi, volumes, a.rounds).items():
            print(name, sorted(t)[len(t) // 4], flush=True)
        return
    for path in a.files:
        volumes = {where: load(mi, path, where) for where in ("host", "backend")}
        times = rebuild_times(dr, mi, volumes, a.rounds)
        host, backend = (statistics.median(times[w]) for w in ("host", "backend"))
        values = dr.width(mi.traverse(volumes["host"])["data"])
        print(f"{os.path.basename(path)}: {values} values, rebuild (median of "
              f"{a.rounds}): host {1e3 * host:.1f} ms, backend {1e3 * backend:.1f} ms, "
              f"backend / host {backend / host:.3f}", flush=True)


if __name__ == "__main__":
    main()
