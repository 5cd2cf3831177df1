"""What an index grid's lookups cost (issue 20): the same grid rendered by
`nanovdbvolume` as it is (differentiable=false) and as an index grid
(differentiable=true: the tree with value indices, and a gather from the
values array per lookup), with `volpath` and `volpathlocal`, as ratios from
one run; and the bytes each holds.

    python3 bench/index_lookups.py --build BUILD --grids cloud.nvdb smoke.nvdb
        [--variant llvm_ad_rgb] [--res 96] [--spp 32] [--runs 3]
        [--filters trilinear stochastic_trilinear]

Times are the median of --runs renders after one warm-up render (JIT
compilation excluded); the scene is the benchmark's (bench/scene.py). A
measurement, not a test.
"""
import argparse
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="")
    ap.add_argument("--grids", nargs="+", required=True)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--filters", nargs="+", default=["trilinear", "stochastic_trilinear"])
    a = ap.parse_args()

    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(a.variant, a.build)
    from scene import turntable_scene

    def time_render(scene):
        mi.render(scene, seed=0)
        dr.sync_thread()
        times = []
        for r in range(a.runs):
            t0 = time.perf_counter()
            mi.render(scene, seed=1 + r)
            dr.sync_thread()
            times.append(time.perf_counter() - t0)
        return statistics.median(times)

    print(f"{a.variant}, {a.res}^2 x {a.spp} spp, median of {a.runs}")
    print("| grid | filter | integrator | grid time | index grid time | ratio | grid bytes "
          "| index grid bytes (tree + values) |")
    print("|---|---|---|---|---|---|---|---|")
    for path in a.grids:
        for filt in a.filters:
            for integrator in ("volpath", "volpathlocal"):
                times, sizes = [], []
                for diff in (False, True):
                    vol = mi.load_dict({"type": "nanovdbvolume", "filename": path,
                                        "filter_type": filt, "differentiable": diff})
                    p = mi.traverse(vol)
                    sizes.append((p["grid_bytes"], p["value_bytes"]))
                    desc = turntable_scene(vol, a.res, a.spp, integrator)
                    for i in range(1, 8):
                        del desc[f"sensor_{i}"]
                    times.append(time_render(mi.load_dict(desc)))
                print(f"| {os.path.basename(path)} | {filt} | {integrator} | {times[0]:.3f} s "
                      f"| {times[1]:.3f} s | {times[1] / times[0]:.3f} | {sizes[0][0]:,.0f} "
                      f"| {sizes[1][0]:,.0f} + {sizes[1][1]:,.0f} |", flush=True)


if __name__ == "__main__":
    main()
