"""Before/after measurement of a plugin change on the CPU variants: two builds
of nanovdbvolume, the same grids, one fresh process per (round, build, grid,
variant), interleaved (A B A B ...), so that both builds see the same machine.

    python3 bench/ab.py --builds OLD_BUILD NEW_BUILD --grids a.nvdb b.nvdb \
        [--variants llvm_ad_rgb scalar_rgb] [--rounds 3] [--out table.md]
        [--load-only] [--volume-args '{"invalid_values": "clamp"}']
        [--integrator volpathlocal] [--filters trilinear]

A build is a directory holding plugins/nanovdbvolume.so. Per process and
filter (nearest, trilinear): the load time (mi.load_dict of the volume: read,
validate, upload), the lookup throughput (llvm: one vectorized eval_1 over
2^20 random points of the unit cube, warm median of 5; scalar variants have
no vectorized lookup, so none), and the render time of the benchmark scene's
first sensor (llvm: 128^2, 16 spp; scalar: 64^2, 16 spp; warm median of 3).
The table gives the median over the rounds of each build and new/old.
--load-only measures the load time alone (median of 7 loads per process);
--volume-args adds plugin parameters (JSON) to every volume; --integrator
renders with another integrator (volpathlocal: both builds need
plugins/volpathlocal.so); --filters limits the filters (any filter_type:
nearest, trilinear, stochastic_trilinear, stochastic_tricubic).
A measurement, not a test.
"""
import argparse
import json
import os
import statistics
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import harness  # noqa: E402


def measure(spec):
    """One process (bench/harness.py): a build's load time, lookup
    throughput and render time on a grid, per filter"""
    import time
    import numpy as np
    from child_setup import mitsuba_for
    from scene import turntable_scene, volume_dict
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    jit = dr.is_jit_v(mi.Float)

    def sync():
        if jit:
            dr.sync_thread()

    out = {}
    for filt in spec["filters"]:
        loads = []
        desc = dict(volume_dict("nanovdbvolume", spec["grid"], filt), **spec["extra"])
        for k in range(7 if spec["load_only"] else 3):
            t0 = time.perf_counter()
            vol = mi.load_dict(desc)
            sync()
            loads.append(time.perf_counter() - t0)
        r = {"load_s": statistics.median(loads)}
        if spec["load_only"]:
            out[filt] = r
            continue
        if jit:
            n = 1 << 20
            pts = np.random.default_rng(1).random((3, n), dtype=np.float32)
            it = dr.zeros(mi.Interaction3f, n)
            it.p = mi.Point3f(mi.Float(pts[0]), mi.Float(pts[1]), mi.Float(pts[2]))
            dr.eval(it.p)
            sync()
            ts = []
            for k in range(6):
                t0 = time.perf_counter()
                v = vol.eval_1(it)
                dr.eval(v)
                sync()
                ts.append(time.perf_counter() - t0)
            r["lookups_per_s"] = n / statistics.median(ts[1:])
        res, spp = (128, 16) if jit else (64, 16)
        scene = mi.load_dict(turntable_scene(vol, res, spp, integrator=spec["integrator"]))
        ts = []
        for k in range(4):
            t0 = time.perf_counter()
            img = mi.render(scene, sensor=0, spp=spp, seed=k)
            if jit:
                dr.eval(img)
                sync()
            ts.append(time.perf_counter() - t0)
        r["render_s"] = statistics.median(ts[1:])
        out[filt] = r
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--builds", nargs=2, required=True, metavar=("OLD", "NEW"))
    ap.add_argument("--grids", nargs="+", required=True)
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out")
    ap.add_argument("--load-only", action="store_true")
    ap.add_argument("--volume-args", default="{}", help="JSON: extra plugin parameters")
    ap.add_argument("--integrator", default="volpath", choices=["volpath", "volpathlocal"])
    ap.add_argument("--filters", nargs="+", default=["nearest", "trilinear"],
                    choices=["nearest", "trilinear", "stochastic_trilinear",
                             "stochastic_tricubic"])
    a = ap.parse_args()
    extra = json.loads(a.volume_args)
    for b in a.builds:
        if not os.path.isfile(os.path.join(b, "plugins", "nanovdbvolume.so")):
            sys.exit(f"{b}: no plugins/nanovdbvolume.so")

    # results[(variant, grid)][tag] = list of per-round dicts
    results = {}
    for r in range(a.rounds):
        for variant in a.variants:
            for g in a.grids:
                for tag, build in zip(("old", "new"), a.builds):
                    spec = dict(variant=variant, build=os.path.abspath(build),
                                grid=os.path.abspath(g), extra=extra, load_only=a.load_only,
                                filters=a.filters, integrator=a.integrator)
                    try:
                        d = harness.run_child("ab:measure", spec)
                    except harness.ChildFailed as e:
                        sys.exit(f"{tag} {variant} {g}: {e}")
                    results.setdefault((variant, g), {}).setdefault(tag, []).append(d)
                    print(f"round {r} {variant} {os.path.basename(g)} {tag}: {d}",
                          file=sys.stderr, flush=True)

    def med(runs, filt, key):
        vals = [x[filt][key] for x in runs if key in x[filt]]
        return statistics.median(vals) if vals else None

    L = [f"old = `{a.builds[0]}`, new = `{a.builds[1]}`; {a.rounds} rounds, interleaved; "
         f"volume parameters {extra or 'default'}{'; load only' if a.load_only else ''}; "
         f"integrator {a.integrator}; "
         "medians over the rounds. load: mi.load_dict of the volume; lookups: llvm, one "
         "eval_1 over 2^20 points; render: first sensor of the benchmark scene (llvm 128² "
         "16 spp, scalar 64² 16 spp).\n",
         "| variant | grid | filter | load old [s] | load new/old | lookups old [M/s] | "
         "lookups new/old | render old [s] | render new/old |",
         "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for (variant, g), runs in results.items():
        for filt in a.filters:
            row = [variant, os.path.basename(g), filt]
            for key, scale, inverse in (("load_s", 1, False), ("lookups_per_s", 1e-6, False),
                                        ("render_s", 1, False)):
                o, n = med(runs["old"], filt, key), med(runs["new"], filt, key)
                if o is None:
                    row += ["—", "—"]
                else:
                    row += [f"{o * scale:.4g}", f"{n / o:.3f}"]
            L.append("| " + " | ".join(row) + " |")
    text = "\n".join(L) + "\n"
    print(text)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text)


if __name__ == "__main__":
    main()
