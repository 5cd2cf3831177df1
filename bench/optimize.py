"""Inverse rendering benchmark (issue 20): recover a volume's densities from
rendered views with Mitsuba's differentiable volumetric path tracer, and
measure what one optimization step costs.

    python3 bench/optimize.py --target cloud.vol [--plugin gridvolume]
        [--reference cloud.vol] [--variant llvm_ad_rgb] [--views 8] [--res 64]
        [--spp 8] [--ref-spp 512] [--iters 60] [--lr 0.05] [--max-depth 8]
        [--filter trilinear] [--out bench/results/optimize]
    python3 bench/optimize.py --target cloud.nvdb --plugin nanovdbvolume --reference cloud.vol
    python3 bench/optimize.py --compare bench/results/optimize   (the runs there, one plot a case)

The scene is the benchmark's (bench/scene.py: the volume in a unit cube,
albedo 0.9, sky + sun, scale 40) with `prbvolpath` (max_depth --max-depth)
and the turntable's first --views sensors. The target images are `volpath`
renders of --reference (default: the target) through gridvolume for a .vol,
nanovdbvolume for a .nvdb, at --ref-spp: give both plugins the same .vol and
they fit the same images. The optimized volume starts as a constant (a tenth
of the target's mean) in the target's box and resolution -- gridvolume: every
voxel of the box; nanovdbvolume (differentiable=true): the target's active
voxels and tiles, its tree kept (the sparse case: where the medium may be is
known, e.g. from a coarse reconstruction) -- and takes one view per
iteration, in turn: render, L2 loss against that view's target, backward,
Adam step, values clamped at 0, params.update().

Per iteration: the wall time (render + backward + step + update), the
loss, and the RMSE of the volume's values against the target's over the
whole box (the target is known here, so the recovery itself is measured,
not only the images; a voxel outside nanovdbvolume's tree is 0, as the
target's). Per run: the bytes of an optimization step, counted from the
arrays (values, gradient, Adam's two moments: 16 bytes per value; for
nanovdbvolume also its tree and majorant table) and as the process's peak
RSS above its level after loading, and the time per iteration (median of
the warm ones). A step's time grows with the densities (longer paths), and
two runs' volumes differ at the same iteration, so the plugins are also
timed at one volume, the target's values: render + backward of every view,
--timing-rounds times after an untimed round (step_at_target_s).

--freeze: render + loss + backward run as one frozen function (dr.freeze,
Mitsuba's way of leaving out Python's tracing of the integrator once it is
recorded), for every integrator alike; the update (params.update(), the
majorant rebuild) and Adam's step stay outside it. The runs' names end
in _frozen.

A measurement, not a test; results: OUT/PLUGIN_TARGET.{json,csv,png}.
"""
import argparse
import json
import os
import resource
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def peak_rss_bytes():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", required=True,
                    help="the target volume (.vol for gridvolume, .nvdb for nanovdbvolume)")
    ap.add_argument("--reference", default="",
                    help="the volume the target images are rendered from (default: --target)")
    ap.add_argument("--plugin", default="gridvolume", choices=["gridvolume", "nanovdbvolume"])
    ap.add_argument("--integrator", default="prbvolpath", choices=["prbvolpath", "prbvolpathlocal"],
                    help="the differentiable integrator (prbvolpathlocal: through the tree's "
                         "local majorants, issue 36; with nanovdbvolume)")
    ap.add_argument("--headroom", type=float, default=None,
                    help="prbvolpathlocal's majorant_headroom (default: the integrator's)")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--build", default="", help="a build folder holding plugins/")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--iters", type=int, default=60)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--timing-rounds", type=int, default=3,
                    help="rounds over the views timing render + backward at the target's values")
    ap.add_argument("--filter", default="trilinear",
                    choices=["nearest", "trilinear", "stochastic_trilinear"],
                    help="nanovdbvolume's filter_type while optimizing (gridvolume: trilinear "
                         "always; the target images are rendered with trilinear)")
    ap.add_argument("--freeze", action="store_true",
                    help="render + loss + backward as one frozen function (dr.freeze)")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "optimize"))
    a = ap.parse_args()

    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(a.variant, a.build)
    from scene import turntable_scene

    def scene_with(volume, integrator, spp):
        desc = turntable_scene(volume, a.res, spp, integrator)
        desc["integrator"]["max_depth"] = a.max_depth
        if a.headroom is not None and integrator == "prbvolpathlocal":
            desc["integrator"]["majorant_headroom"] = a.headroom
        for i in range(a.views, 8):
            del desc[f"sensor_{i}"]
        return mi.load_dict(desc)

    def load(path, optimized=False, **kw):
        plugin = "gridvolume" if path.endswith(".vol") else "nanovdbvolume"
        if plugin == "nanovdbvolume":
            kw["differentiable"] = True
            if optimized:
                kw["filter_type"] = a.filter
        return mi.load_dict({"type": plugin, "filename": path, **kw})

    # The target images
    ref_scene = scene_with(load(a.reference or a.target), "volpath", a.ref_spp)
    t0 = time.perf_counter()
    refs = [mi.render(ref_scene, sensor=v, seed=1000 + v) for v in range(a.views)]
    dr.eval(refs)
    print(f"target images: {a.views} views, {a.ref_spp} spp, {time.perf_counter() - t0:.1f} s",
          flush=True)

    key_suffix = "data"
    target = load(a.target)
    target_values = mi.traverse(target)
    truth = np.array(target_values["data"]).ravel()
    box_voxels = int(np.prod(target.resolution()))
    del target_values, target, ref_scene

    # The volume to optimize: the same box and resolution (nanovdbvolume:
    # the same tree), one constant value
    opt = load(a.target, optimized=True)
    scene = scene_with(opt, a.integrator, a.spp)
    params = mi.traverse(scene)
    pkey = next(k for k in params.keys() if k.endswith("sigma_t." + key_suffix))
    start = float(truth.mean()) * 0.1
    if isinstance(params[pkey], mi.TensorXf):
        params[pkey] = dr.full(mi.TensorXf, start, params[pkey].shape)
    else:
        params[pkey] = dr.full(mi.Float, start, dr.width(params[pkey]))
    params.update()
    n_values = dr.width(params[pkey].array if isinstance(params[pkey], mi.TensorXf) else params[pkey])
    facts = {k.split(".")[-1]: params[k] for k in params.keys()
             if k.endswith(("sigma_t.grid_bytes", "sigma_t.majorant_bytes"))}
    tree_bytes = int(facts.get("grid_bytes", 0) + facts.get("majorant_bytes", 0))
    dr.eval()
    rss_loaded = peak_rss_bytes()

    def box_rmse(values):
        # over the whole box: a voxel outside the sparse tree is 0 in both
        return float(np.sqrt(np.sum((values - truth) ** 2) / box_voxels))

    # A step: render one view, its L2 loss against the view's target,
    # backward. --freeze: as one frozen function of the scene, the sensor,
    # the seed (opaque: one recording for every seed) and the target image
    sensors = scene.sensors()

    def step(scene, sensor, seed, ref):
        params = mi.traverse(scene)
        params.keep(pkey)
        img = mi.render(scene, params, sensor=sensor, seed=seed, spp=a.spp)
        loss = dr.mean(dr.square(img - ref))
        dr.backward(loss)
        return loss

    frozen = dr.freeze(step) if a.freeze else None

    def run_step(v, seed):
        if frozen is not None:
            return frozen(scene, sensors[v], dr.opaque(mi.UInt32, seed), refs[v])
        img = mi.render(scene, params, sensor=v, seed=seed, spp=a.spp)
        loss = dr.mean(dr.square(img - refs[v]))
        dr.backward(loss)
        return loss

    # The time of a step at the same volume for both plugins: the target's
    # values (a step's time grows with the densities, so iterations of two
    # runs, whose volumes differ, do not compare): render + backward of
    # each view, after one untimed pass, median over --timing-rounds
    start_values = type(params[pkey])(params[pkey])
    if isinstance(params[pkey], mi.TensorXf):
        params[pkey] = mi.TensorXf(truth.astype(np.float32).reshape(params[pkey].shape))
    else:
        params[pkey] = mi.Float(truth.astype(np.float32))
    params.update()
    timed = []
    # (--freeze: two untimed rounds; Dr.Jit records each view's step twice,
    # before and after its sensor's sampler has arrays)
    warm_rounds = 2 if a.freeze else 1
    for r in range(a.timing_rounds + warm_rounds):
        for v in range(a.views):
            dr.enable_grad(params[pkey])
            params.update()
            t0 = time.perf_counter()
            run_step(v, r * a.views + v)
            g = dr.grad(params[pkey])
            dr.eval(g)
            dr.sync_thread()
            if r >= warm_rounds:
                timed.append(time.perf_counter() - t0)
            dr.disable_grad(params[pkey])
    step_at_target = statistics.median(timed)
    print(f"render + backward at the target's values: {step_at_target:.3f} s (median of "
          f"{len(timed)})" + (f", {frozen.n_recordings} recordings" if frozen else ""), flush=True)
    # nanovdbvolume: what an update costs (issue 36): params.update() (the
    # value policy and max() on the backend), then the per-node majorants
    # rebuilt as the next step asks for them: unfrozen, the walk asks for
    # them and for their mean (local_majorant_ratio; mi.traverse asks the
    # same); frozen, Dr.Jit's traversal of the inputs asks for the table
    # alone. Medians of 10 at the target's values, after 2 untimed (the
    # backend's rebuild records its kernels at the first, replays after)
    update_s, rebuild_s = [], []
    if a.plugin == "nanovdbvolume":
        for r in range(12):
            params[pkey] = params[pkey] * (1.0 + 1e-6 * (r + 1))  # (a new value: an equal one is no update)
            dr.eval(params[pkey])
            dr.sync_thread()
            t0 = time.perf_counter()
            params.update()
            dr.sync_thread()
            t1 = time.perf_counter()
            if a.freeze:
                with dr.scoped_set_flag(dr.JitFlag.EnableObjectTraversal, True):
                    dr.detail.collect_indices(opt)  # (as dr.freeze collects its inputs)
            else:
                mi.traverse(opt)
            dr.sync_thread()
            if r >= 2:
                update_s.append(t1 - t0)
                rebuild_s.append(time.perf_counter() - t1)
        print(f"update {statistics.median(update_s) * 1e3:.1f} ms, majorants rebuilt "
              f"{statistics.median(rebuild_s) * 1e3:.1f} ms", flush=True)
    params[pkey] = start_values
    params.update()

    optimizer = mi.ad.Adam(lr=a.lr)
    optimizer[pkey] = params[pkey]
    params.update(optimizer)

    rows = []
    t_start = time.perf_counter()
    for it in range(a.iters):
        v = it % a.views
        t0 = time.perf_counter()
        loss = run_step(v, it)
        optimizer.step()
        optimizer[pkey] = dr.maximum(optimizer[pkey], 0.0)
        params.update(optimizer)
        dr.eval()
        loss_value = float(np.array(loss).ravel()[0])
        dt = time.perf_counter() - t0
        values = np.array(params[pkey]).ravel()
        vol_rmse = box_rmse(values)
        rows.append(dict(iter=it, view=v, time_s=dt, elapsed_s=time.perf_counter() - t_start,
                         loss=loss_value, volume_rmse=vol_rmse))
        print(f"  iter {it:3d} view {v}: loss {loss_value:.5f}, volume RMSE {vol_rmse:.4f}, "
              f"{dt:.2f} s", flush=True)

    warm = [r["time_s"] for r in rows[min(a.views, len(rows) - 1):]] or [rows[-1]["time_s"]]
    summary = dict(
        plugin=a.plugin, integrator=a.integrator, headroom=a.headroom, target=os.path.abspath(a.target), variant=a.variant,
        filter=a.filter if a.plugin == "nanovdbvolume" else "trilinear",
        views=a.views, res=a.res, spp=a.spp, max_depth=a.max_depth, iters=a.iters, lr=a.lr,
        values=n_values, box_voxels=box_voxels, tree_and_table_bytes=tree_bytes,
        step_bytes_counted=16 * n_values + tree_bytes,
        peak_rss_above_loaded=max(peak_rss_bytes() - rss_loaded, 0),
        time_per_iter_s=statistics.median(warm),
        step_at_target_s=step_at_target,
        update_s=statistics.median(update_s) if update_s else None,
        majorant_rebuild_s=statistics.median(rebuild_s) if rebuild_s else None,
        volume_rmse_start=box_rmse(np.full_like(truth, truth.mean() * 0.1)),
        volume_rmse_end=rows[-1]["volume_rmse"], loss_end=rows[-1]["loss"],
        frozen=a.freeze, recordings=frozen.n_recordings if frozen is not None else None)
    print(json.dumps(summary, indent=1))

    os.makedirs(a.out, exist_ok=True)
    stem = os.path.join(a.out, f"{a.plugin}_{os.path.splitext(os.path.basename(a.target))[0]}" +
                        (f"_{a.filter}" if a.plugin == "nanovdbvolume" and a.filter != "trilinear"
                         else "") +
                        (f"_{a.integrator}" if a.integrator != "prbvolpath" else "") +
                        ("_frozen" if a.freeze else ""))
    with open(stem + ".json", "w") as f:
        json.dump(dict(summary=summary, rows=rows), f, indent=1)
    with open(stem + ".csv", "w") as f:
        f.write("iter,view,time_s,elapsed_s,loss,volume_rmse\n")
        for r in rows:
            f.write(f"{r['iter']},{r['view']},{r['time_s']:.4f},{r['elapsed_s']:.4f},"
                    f"{r['loss']:.6g},{r['volume_rmse']:.6g}\n")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
        ax[0].semilogy([r["iter"] for r in rows], [r["loss"] for r in rows], label="image loss")
        ax[0].semilogy([r["iter"] for r in rows], [r["volume_rmse"] for r in rows],
                       label="volume RMSE")
        ax[0].set_xlabel("iteration")
        ax[0].legend()
        ax[1].semilogy([r["elapsed_s"] for r in rows], [r["loss"] for r in rows])
        ax[1].set_xlabel("time [s]")
        ax[1].set_ylabel("image loss")
        fig.suptitle(f"{a.integrator}, {a.plugin}, {os.path.basename(a.target)}, {a.variant}" +
                     (", frozen" if a.freeze else ""))
        fig.tight_layout()
        fig.savefig(stem + ".png", dpi=100)
    except ImportError:
        pass
    print(f"wrote {stem}.json, .csv, .png")


def compare(out):
    """One figure per case of the runs in `out`: image loss against
    iteration and against time, every plugin and filter (OUT/compare_CASE.png)"""
    import glob
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = {}
    for path in sorted(glob.glob(os.path.join(out, "*.json"))):
        data = json.load(open(path))
        if "summary" not in data:
            continue
        s = data["summary"]
        case = (os.path.basename(path)[:-5].split("_", 1)[1].replace("_stochastic_trilinear", "")
                .replace("_prbvolpathlocal", "").replace("_frozen", ""))
        runs.setdefault(case, []).append(
            (f"{s.get('integrator', 'prbvolpath')}, {s['plugin']}, {s.get('filter', 'trilinear')}" +
             (", frozen" if s.get("frozen") else ""), data))
    for case, rs in runs.items():
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
        for label, data in rs:
            rows = data["rows"]
            ax[0].semilogy([r["iter"] for r in rows], [r["loss"] for r in rows], label=label)
            ax[1].semilogy([r["elapsed_s"] for r in rows], [r["loss"] for r in rows], label=label)
        ax[0].set_xlabel("iteration")
        ax[1].set_xlabel("time [s]")
        ax[0].set_ylabel("image loss (one view)")
        ax[0].legend(fontsize=8)
        fig.suptitle(f"{case}: Adam, {rs[0][1]['summary']['variant']}")
        fig.tight_layout()
        fig.savefig(os.path.join(out, f"compare_{case}.png"), dpi=100)
        print(f"wrote {os.path.join(out, f'compare_{case}.png')}")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--compare":
        compare(sys.argv[2])
    else:
        main()
