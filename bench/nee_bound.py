"""How much of an emissive scene's variance next-event estimation toward the
fire can remove (issue 35): paired renders (the same seeds) of
bench/fire_nee.py's scenes, per region, with volpathlocal's
`emission_samples` raised until the estimate of the fire's light at each
vertex is nearly exact.

    python3 bench/nee_bound.py --build BUILD        # ~4 min -> bench/results/nee_bound.md
    python3 bench/nee_bound.py --build BUILD --quick

Configurations (llvm_ad_rgb by default), each --renders renders at --spp
with seeds 1..renders:
  collisions     emission_sampling collisions: the emission the flights collect
  mis            the default: next-event estimation with MIS, one point per vertex
  mis x4, x16    the same, 4 and 16 points (and shadow rays) per vertex, averaged

Every configuration samples the same path vertices (delta tracking's
collisions, phase and BSDF directions) and differs only in how it estimates
the fire's light arriving at them (and, mis: the camera segment's emission
by ratio tracking, emission_rate 1). With N points per vertex, next-event
estimation's own variance falls as 1/N; what stays is the variance of
where the vertices are, and of the share of the emission that MIS leaves to
the flights. Per region (bench/emission.py's masks: the fire seen directly,
the floor, the smoke), the report gives each configuration's pixel
variance and time against collisions', and V_inf: the variance
extrapolated to N -> infinity from x4 and x16 (V(N) = A + B/N). 1 / V_inf
bounds the variance ratio that a better estimate of the fire's light at
the same vertices can reach, at any cost; at equal time it bounds the
efficiency by 1 / V_inf (that estimate costing nothing, and the rest of
the path what collisions' costs), so the relative RMSE ratio at equal time
by sqrt(1 / V_inf). (Next-event estimation alone, `nee`, is no basis for
the bound: at vertices inside the fire its variance is unbounded, 1/r^2,
and 16 renders of it measure fireflies. The points per vertex are unrolled
in the kernel: 16 cost about 8x collisions' time per render.)

A measurement, not a test: nothing is asserted.
"""
import argparse
import datetime
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import emission  # noqa: E402  (the scenes, files and region masks)
import fire_nee  # noqa: E402  (the cases)

CONFIGS = [("collisions", "collisions", 1), ("mis", "mis", 1), ("mis x4", "mis", 4),
           ("mis x16", "mis", 16)]


def measure(mi, dr, case, a):
    """{config: (seconds per render, images [renders, H, W, 3])} and the region masks"""
    out = {}
    for name, mode, n in CONFIGS:
        d = fire_nee.scene(mi, case, mode, a.res, a.spp, 1)
        d["integrator"]["emission_samples"] = n
        s = mi.load_dict(d)
        dr.eval(mi.render(s, spp=a.spp, seed=0))  # (compiles)
        imgs, t0 = [], time.perf_counter()
        for k in range(a.renders):
            img = mi.render(s, spp=a.spp, seed=1 + k)
            dr.eval(img)
            dr.sync_thread()
            imgs.append(np.asarray(img, dtype=np.float64)[..., :3])
        out[name] = ((time.perf_counter() - t0) / a.renders, np.stack(imgs))
        print(f"  {fire_nee.label(case)} {name}: {out[name][0]:.3f} s per render", flush=True)
    ids = emission.region_ids(mi, case, {"res": a.res, "sensors": 1})
    masks = emission.region_masks(ids, out["collisions"][1].mean(0)[None])
    return out, {r: m[0] for r, m in masks.items()}


def table(case, out, masks):
    t0, a0 = out["collisions"]
    rows = []
    for region, m in masks.items():
        v0 = a0.var(0, ddof=1)[m].mean() if m.any() else 0.0
        if not v0 > 0:  # (no such region: the self-lit case's floor)
            continue
        v = {name: out[name][1].var(0, ddof=1)[m].mean() / v0 for name, _, _ in CONFIGS}
        v_inf = max((16 * v["mis x16"] - 4 * v["mis x4"]) / 12, 0.0)
        cells = [f"{v[n]:.3f} ({out[n][0] / t0:.2f}x)" for n, _, _ in CONFIGS[1:]]
        bound = f"{v_inf:.3f}, {1 / v_inf:.1f}x, {np.sqrt(1 / v_inf):.2f}" if v_inf > 0 else "-"
        eff = 1 / (v["mis"] * out["mis"][0] / t0)
        rows.append(f"| {fire_nee.label(case)} | {region} | " + " | ".join(cells) +
                    f" | {eff:.1f}x, {np.sqrt(eff):.2f} | {bound} |")
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--cases", nargs="+", default=["fireball", "fireball_self_lit"])
    ap.add_argument("--n", type=int, default=128)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--renders", type=int, default=16)
    ap.add_argument("--data", default=os.path.join(HERE, "data", "emission"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out")
    a = ap.parse_args()
    if a.quick:
        a.n, a.res, a.spp, a.renders = 32, 16, 4, 4
        a.out = a.out or "/tmp/nee_bound_quick/nee_bound.md"
    a.out = a.out or os.path.join(HERE, "results", "nee_bound.md")
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(a.variant, a.build)
    a.build, a.data = os.path.abspath(a.build), os.path.abspath(a.data)
    case_list, notes = fire_nee.cases(a)
    cases = {fire_nee.label(c): c for c in case_list}
    started = datetime.datetime.now(datetime.timezone.utc)
    t_run = time.perf_counter()
    rows = []
    for name in cases:
        out, masks = measure(mi, dr, cases[name], a)
        rows += table(cases[name], out, masks)
    head = ("| case | region | " + " | ".join(n for n, _, _ in CONFIGS[1:]) +
            " | mis: efficiency, RMSE ratio at equal time | V_inf, its bounds: efficiency, "
            "RMSE ratio |")
    text = "\n".join([
        "# What next-event estimation toward the fire can remove (bench/nee_bound.py)", "",
        f"`python3 bench/nee_bound.py --build BUILD --res {a.res} --spp {a.spp} "
        f"--renders {a.renders}`", "",
        f"Run {started:%Y-%m-%d %H:%M} UTC, {time.perf_counter() - t_run:.0f} s, {a.variant}, "
        f"one sensor at {a.res}^2, {a.spp} spp, {a.renders} renders per configuration "
        "(seeds 1..renders, the same for every configuration). Each cell: the region's "
        "mean pixel variance over the renders / collisions' (its time / collisions'). "
        "V_inf: nee's variance extrapolated to infinitely many points per vertex "
        "(bench/nee_bound.py's docstring); its bounds hold for any estimate of the fire's "
        "light at the vertices the path samples.", "",
        head, "|" + "---|" * (head.count("|") - 1), *rows, "", *notes])
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()
