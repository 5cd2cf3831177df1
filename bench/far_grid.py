"""Render time on a grid whose root tiles lie far apart (issue 19's target
for `far_coords`-like grids: volpathlocal <= 2 x volpath + nanovdbvolume).

    python3 bench/far_grid.py [--build BUILD] [--variants llvm_ad_rgb scalar_rgb]
        [--sizes 8x4 128x16] [--runs 5]

The grid is the test suite's `far_coords` (tests/make_test_grid.cpp: 111
voxels in root tiles up to |ijk| = 1e9), written by BUILD/bin/
nvdb_make_test_grid, in the benchmark scene (bench/scene.py, first sensor).
Its unit cube spans 2e9 voxels: the walk crosses almost only empty root
space (walk_far). Per variant and size RESxSPP: the warm render time (median
of --runs) of volpath + nanovdbvolume and of volpathlocal, and their ratio.
A measurement, not a test.
"""
import argparse
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

sys.path.insert(0, HERE)
import harness  # noqa: E402


def measure(spec):
    """One process (bench/harness.py): the warm render times of volpath and
    volpathlocal per size on the grid"""
    import statistics
    import time
    from child_setup import mitsuba_for
    from scene import turntable_scene, volume_dict
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    out = {}
    for res, spp in spec["sizes"]:
        for integrator in ("volpath", "volpathlocal"):
            vol = mi.load_dict(volume_dict("nanovdbvolume", spec["nvdb"], "trilinear"))
            scene = mi.load_dict(turntable_scene(vol, res, spp, integrator))
            times = []
            for r in range(spec["runs"] + 1):
                t0 = time.perf_counter()
                img = mi.render(scene, seed=r, sensor=0)
                dr.eval(img)
                dr.sync_thread()
                times.append(time.perf_counter() - t0)
            out[f"{res}x{spp}|{integrator}"] = statistics.median(times[1:])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"),
                    help="a build folder holding bin/ and plugins/")
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--sizes", nargs="+", default=["8x4", "128x16"], help="RESxSPP")
    ap.add_argument("--runs", type=int, default=5)
    a = ap.parse_args()
    sizes = [tuple(int(v) for v in s.split("x")) for s in a.sizes]
    with tempfile.TemporaryDirectory() as tmp:
        nvdb = os.path.join(tmp, "far_coords.nvdb")
        subprocess.run([os.path.join(a.build, "bin", "nvdb_make_test_grid"), "far_coords", nvdb],
                       check=True, capture_output=True)
        print("| variant | size | volpath + nanovdbvolume [s] | volpathlocal [s] | ratio |")
        print("|---|---|---:|---:|---:|")
        for variant in a.variants:
            r = harness.run_child("far_grid:measure", dict(variant=variant, build=a.build,
                                                            nvdb=nvdb, sizes=sizes, runs=a.runs))
            for res, spp in sizes:
                t0, t1 = r[f"{res}x{spp}|volpath"], r[f"{res}x{spp}|volpathlocal"]
                print(f"| {variant} | {res}^2 x {spp} spp | {t0:.4f} | {t1:.4f} | {t1 / t0:.2f} |",
                      flush=True)


if __name__ == "__main__":
    main()
