"""How long the per-node majorants take to follow an update (issue 36): a
differentiable nanovdbvolume's values changed, params.update(), then the
rebuild the walk asks for (mi.traverse asks too), on the host
(majorant_rebuild="host") and on the backend ("backend"), the two volumes
loaded side by side in one process and updated in turn.

    python3 bench/rebuild_time.py cf.nvdb smoke.nvdb [--build build]
           [--variant llvm_ad_rgb] [--rounds 10]

Prints, per file, the medians of --rounds rebuilds (after two untimed
ones: Dr.Jit compiles the backend's kernels once) and their ratio. A
measurement, not a test.
"""
import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from child_setup import mitsuba_for  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--build", default="")
    ap.add_argument("--rounds", type=int, default=10)
    a = ap.parse_args()
    dr, mi = mitsuba_for(a.variant, a.build)
    for path in a.files:
        volumes = {where: mi.load_dict({
            "type": "nanovdbvolume", "filename": path, "differentiable": True,
            "filter_type": "stochastic_trilinear", "majorant_rebuild": where})
            for where in ("host", "backend")}
        base = mi.Float(mi.traverse(volumes["host"])["data"])
        dr.eval(base)
        times = {where: [] for where in volumes}
        for r in range(a.rounds + 2):
            for where, volume in volumes.items():
                params = mi.traverse(volume)
                params["data"] = base * (1.0 + 1e-3 * (r + 1))  # (new values: an update)
                dr.eval(params["data"])
                params.update()
                dr.sync_thread()
                t0 = time.perf_counter()
                mi.traverse(volume)  # (the walk's question: the rebuild)
                dr.sync_thread()
                if r >= 2:
                    times[where].append(time.perf_counter() - t0)
        host, backend = (statistics.median(times[w]) for w in ("host", "backend"))
        print(f"{os.path.basename(path)}: {dr.width(base)} values, rebuild (median of "
              f"{a.rounds}): host {1e3 * host:.1f} ms, backend {1e3 * backend:.1f} ms, "
              f"backend / host {backend / host:.3f}", flush=True)


if __name__ == "__main__":
    main()
