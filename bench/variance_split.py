"""Where volpathlocal's variance comes from (issue 34): the shadow rays'
ratio-tracked transmittance, or the rest of the path (delta-tracked free
flights, phase and light sampling).

    python3 bench/variance_split.py [FILE.vdb|.nvdb ...] [--variant llvm_ad_rgb]
        [--filter stochastic_trilinear] [--res 128] [--spp 4] [--renders 24]
        [--estimates 1 16] [--transmittance ratio residual] [--max-depth 64] [--build build]
        [--out bench/results/variance_split.md]

The scene is nanovdb-render's for the file (nanovdb_mitsuba.scene.framed_scene:
its camera, sky and sun, albedo 0.9, max_depth 64 or --max-depth, the default density
scale). Per volpathlocal shadow_estimates M (each shadow ray averages M
independent ratio-tracking estimates of each tracked medium's
transmittance, the rest of the path unchanged), --renders independent
renders at --spp: the per-pixel variance of one sample, from the spread of
the renders, summed over the image relative to the image's squared mean
(a relative variance per sample, V(M)), and the warm time per sample.

With independent estimates, V(M) = V_rest + V_shadow / M, so two values of
M give both parts: V_shadow = (V(1) - V(M)) M / (M - 1). Each of
--transmittance (volpathlocal's shadow-ray estimator: ratio tracking or
residual ratio tracking) gets its own rows and split. The cost of an
estimator at equal error is V x time (lower is better). A measurement, not
a test: no target is asserted.
"""
import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import harness  # noqa: E402


def measure(spec):
    """One process (bench/harness.py): per shadow_estimates, the renders'
    relative variance per sample and the warm time per sample"""
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    from nanovdb_mitsuba.scene import framed_scene
    rows = []
    for estimator, m in [(e, m) for e in spec["transmittance"] for m in spec["estimates"]]:
        desc, info = framed_scene(mi, spec["file"], res=spec["res"], spp=spec["spp"],
                                  filter_type=spec["filter"])
        desc["integrator"]["shadow_estimates"] = m
        desc["integrator"]["transmittance"] = estimator
        desc["integrator"]["max_depth"] = spec["max_depth"]
        desc["sensor"]["film"]["rfilter"] = {"type": "box"}  # (pixels independent)
        scene = mi.load_dict(desc)
        mi.render(scene, seed=10_000)  # (the kernel's compile, not timed)
        images, seconds = [], []
        for seed in range(spec["renders"]):
            t0 = time.perf_counter()
            img = mi.render(scene, seed=seed)
            dr.eval(img)
            dr.sync_thread()
            seconds.append(time.perf_counter() - t0)
            images.append(np.array(img, dtype=np.float64)[..., :3])
        a = np.stack(images)                         # renders x H x W x 3
        mean = a.mean(axis=0)
        var_sample = a.var(axis=0, ddof=1) * spec["spp"]  # of one sample
        rel_var = float(var_sample.sum() / max(np.square(mean).sum(), 1e-30))
        t_spp = float(np.median(seconds)) / spec["spp"]
        rows.append(dict(transmittance=estimator, estimates=m, rel_var=rel_var,
                         seconds_per_spp=t_spp,
                         mean=float(mean.mean()), scale=info["scale"]))
    return dict(rows=rows)


def split(rows):
    """V_shadow and V_rest from the rows of M = 1 and the largest M"""
    by = {r["estimates"]: r for r in rows}
    if 1 not in by or len(by) < 2:
        return None
    m = max(by)
    v1, vm = by[1]["rel_var"], by[m]["rel_var"]
    shadow = (v1 - vm) * m / (m - 1)
    return dict(shadow=shadow, rest=v1 - shadow, share=shadow / v1 if v1 > 0 else 0.0, m=m)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="*",
                    default=[os.path.join(ROOT, "..", "shared", "data", "openvdb_smoke1_fog.vdb")])
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--filter", default="stochastic_trilinear")
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--renders", type=int, default=24)
    ap.add_argument("--estimates", type=int, nargs="+", default=[1, 16])
    ap.add_argument("--transmittance", nargs="+", default=["ratio", "residual"],
                    choices=["ratio", "residual"])
    ap.add_argument("--max-depth", type=int, default=64,
                    help="the integrator's max_depth (1: what the camera ray sees through "
                         "the medium alone; 2: and single scattering)")
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    lines = [f"`python3 bench/variance_split.py {' '.join(sys.argv[1:])}`", "",
             "| file | transmittance | shadow_estimates | relative variance per sample | "
             "s per spp | cost (V x s) | mean |", "|---|---|---|---|---|---|---|"]
    summary = []
    for f in args.files:
        spec = dict(file=os.path.abspath(f), variant=args.variant, filter=args.filter,
                    res=args.res, spp=args.spp, renders=args.renders,
                    estimates=args.estimates, build=args.build, max_depth=args.max_depth,
                    transmittance=args.transmittance)
        rows = harness.run_child("variance_split:measure", spec)["rows"]
        name = os.path.basename(f)
        for r in rows:
            lines.append(f"| {name} | {r['transmittance']} | {r['estimates']} | {r['rel_var']:.4g} | "
                         f"{r['seconds_per_spp']:.4g} | {r['rel_var'] * r['seconds_per_spp']:.4g} "
                         f"| {r['mean']:.4g} |")
        for estimator in args.transmittance:
            s = split([r for r in rows if r["transmittance"] == estimator])
            if s:
                summary.append(f"- {name}, {estimator}: shadow rays {s['shadow']:.4g} "
                               f"({100 * s['share']:.0f} % of the variance at M = 1), the rest "
                               f"{s['rest']:.4g} (from M = 1 and {s['m']})")
    text = "\n".join(lines + [""] + summary) + "\n"
    print(text)
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as fh:
            fh.write(text)


if __name__ == "__main__":
    main()
