"""One measurement in a fresh process: `measure(spec)`, run by bench/run.py
(and bench/cases.py's dense export) through bench/harness.py,

    harness.run_child("worker:measure", spec, home=..., timeout=...)

spec holds {"mode": "measure" | "reference" | "dense", ...} (see run.py).
A fresh process per (case, variant, integrator, plugin, filter) makes the
peak RSS meaningful and keeps Dr.Jit's allocator statistics to one volume.
The result is the returned dict (harness.py hands it back as JSON); images
are written to spec["out_npz"].
spec["integrator"] (volpath, volpathlocal) picks the scene's integrator;
spec["count_lookups"] adds lookups and walk steps per camera path, counted
on a render of their own after the timed ones.

Memory of the volume is measured across mi.load_dict() of the volume alone:
- jit_storage: Dr.Jit's own accounting of the bytes held by evaluated JIT
  variables ("Storage ... on device" of dr.whos()), after minus before. It
  counts memory the plugin hands to Dr.Jit (mapped/adopted buffers) as well as
  memory Dr.Jit allocated itself, at its exact size;
- alloc_held / alloc_peak: what Dr.Jit's allocator reserves
  (dr.detail.malloc_watermark, after malloc_clear_statistics): allocations are
  rounded up to powers of two, and memory merely adopted by Dr.Jit is not in it;
- rss_held: resident set size after minus before (the process's own view);
- peak_rss: the process's peak resident set size (ru_maxrss) after loading,
  and its increase over the RSS before loading;
- gpu_used (CUDA): device memory in use after minus before, as the driver
  reports it (NVML, i.e. nvidia-smi; bench/gpu.py).
"""
import os
import re
import resource
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def rss_bytes():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


def peak_rss_bytes():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


_UNITS = {"B": 1, "KiB": 1024, "MiB": 1024 ** 2, "GiB": 1024 ** 3, "TiB": 1024 ** 4}


def jit_storage_bytes(dr):
    """Bytes of evaluated JIT variables, as dr.whos() accounts them."""
    text = dr.whos(True)
    m = re.search(r"Storage\s*:\s*([0-9.]+)\s*(B|KiB|MiB|GiB|TiB) on device", text)
    return int(round(float(m.group(1)) * _UNITS[m.group(2)])) if m else None


def sync(dr):
    dr.sync_thread()


def load_volume(mi, dr, spec):
    """Loads the volume alone and measures what it holds."""
    from scene import volume_dict
    jit = dr.is_jit_v(mi.Float)
    backend = dr.backend_v(mi.Float) if jit else None
    mem = {}
    cuda = jit and backend == dr.JitBackend.CUDA
    if jit:
        sync(dr)
        dr.flush_malloc_cache()
        dr.detail.malloc_clear_statistics()
        u0 = dr.detail.malloc_watermark(backend)
        s0 = jit_storage_bytes(dr)
    if cuda:
        import gpu
        g0 = gpu.used_bytes()
    r0 = rss_bytes()
    t0 = time.perf_counter()
    vol = mi.load_dict(volume_dict(spec["plugin"], spec["volume"], spec["filter"],
                                   spec.get("grid", "")))
    if jit:
        dr.eval()
        sync(dr)
    mem["load_s"] = time.perf_counter() - t0
    mem["rss_before"] = r0
    mem["peak_rss"] = peak_rss_bytes()
    mem["peak_rss_increase"] = mem["peak_rss"] - r0
    if jit:
        mem["alloc_peak"] = dr.detail.malloc_watermark(backend) - u0
        dr.flush_malloc_cache()
        dr.detail.malloc_clear_statistics()
        mem["alloc_held"] = dr.detail.malloc_watermark(backend) - u0
        s1 = jit_storage_bytes(dr)
        mem["jit_storage"] = s1 - s0 if s0 is not None and s1 is not None else None
    mem["rss_held"] = rss_bytes() - r0
    if cuda and g0 is not None:
        # Device memory as the driver reports it (nvidia-smi's view): the
        # only measure that sees gridvolume's CUDA texture arrays, which
        # are not Dr.Jit variables. The driver maps memory in 2 MiB pages.
        mem["gpu_used"] = gpu.used_bytes() - g0
    return vol, mem


def lookup_throughput(mi, dr, vol, n, runs):
    """Random eval_1 calls per second at uniform points of the unit cube."""
    rng = np.random.default_rng(12345)
    pts = rng.random((3, n), dtype=np.float32)
    if dr.is_jit_v(mi.Float):
        it = dr.zeros(mi.Interaction3f, n)
        it.p = mi.Point3f(mi.Float(pts[0]), mi.Float(pts[1]), mi.Float(pts[2]))
        dr.eval(it.p)
        sync(dr)
        times = []
        checksum = 0.0
        for r in range(runs + 1):
            t0 = time.perf_counter()
            v = vol.eval_1(it)
            dr.eval(v)
            sync(dr)
            times.append(time.perf_counter() - t0)
            if r == 0:
                checksum = float(np.sum(np.asarray(v), dtype=np.float64))
        warm = times[1:]
        return {"lookup_n": n, "lookup_first_s": times[0],
                "lookup_median_s": statistics.median(warm), "lookup_min_s": min(warm),
                "lookups_per_s": n / statistics.median(warm), "lookup_checksum": checksum,
                "lookup_note": "vectorized: one eval_1 over all points"}
    # Scalar: one Python call per lookup, so the Python binding dominates.
    it = mi.Interaction3f()
    ps = [mi.Point3f(float(pts[0, i]), float(pts[1, i]), float(pts[2, i])) for i in range(n)]
    times = []
    checksum = 0.0
    for r in range(runs + 1):
        t0 = time.perf_counter()
        acc = 0.0
        for p in ps:
            it.p = p
            acc += vol.eval_1(it)
        times.append(time.perf_counter() - t0)
        checksum = acc
    warm = times[1:]
    return {"lookup_n": n, "lookup_first_s": times[0], "lookup_median_s": statistics.median(warm),
            "lookup_min_s": min(warm), "lookups_per_s": n / statistics.median(warm),
            "lookup_checksum": checksum,
            "lookup_note": "scalar: one Python call per lookup (binding overhead included)"}


def render_turntable(mi, dr, scene, spp, seed):
    """Renders all sensors; returns (seconds, images [S, H, W, 3] float32)."""
    imgs = []
    t0 = time.perf_counter()
    for i in range(len(scene.sensors())):
        img = mi.render(scene, sensor=i, spp=spp, seed=seed * 1009 + i)
        if dr.is_jit_v(mi.Float):
            dr.eval(img)
            sync(dr)
        imgs.append(img)
    t = time.perf_counter() - t0
    return t, np.stack([np.asarray(im, dtype=np.float32)[..., :3] for im in imgs])


def paths_and_counts(mi, dr, spec):
    """Lookups and majorant-walk steps, counted on a render of their own:
    count_lookups adds an atomic add per lookup and walk step, so the timed
    renders never count. A fresh volume with count_lookups, one turntable at
    the timing spp (seed 0). Returns the volume's counters (volume_facts:
    lookup_count, walk_step_count and the steps by cell) and the
    camera paths of that render (pixels x spp x sensors), to divide them by.
    nanovdbvolume only (gridvolume cannot count)."""
    from scene import turntable_scene, volume_dict
    vol = mi.load_dict(volume_dict(spec["plugin"], spec["volume"], spec["filter"],
                                   spec.get("grid", ""), count_lookups=True))
    scene = mi.load_dict(turntable_scene(vol, spec["res"], spec["spp"],
                                         spec.get("integrator", "volpath")))
    render_turntable(mi, dr, scene, spec["spp"], 0)
    from nanovdb_mitsuba import volume_facts
    facts = volume_facts(vol)
    counts = {k: v for k, v in facts.items() if k.endswith("_count")}
    for key in ("lookup_count", "walk_step_count"):
        if key not in counts:
            raise SystemExit(f"{spec['volume']}: no '{key}' in the volume's facts with "
                             f"count_lookups (a plugin build without counting?): {facts}")
    return {"counts": counts,
            "count_paths": spec["res"] ** 2 * spec["spp"] * len(scene.sensors())}


def jit_compile_ms(dr):
    hist = dr.kernel_history()
    codegen = backend = 0.0
    kernels = hits = 0
    for k in hist:
        if k.get("type") != dr.KernelType.JIT:
            continue
        kernels += 1
        hits += int(bool(k.get("cache_hit", 0)))
        codegen += float(k.get("codegen_time", 0.0))
        backend += float(k.get("backend_time", 0.0))
    return {"jit_codegen_ms": codegen, "jit_backend_ms": backend, "jit_kernels": kernels,
            "jit_cache_hits": hits}


def measure(spec):
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    from scene import turntable_scene
    out = {"spec": {k: v for k, v in spec.items() if k != "out_npz"},
           "loadavg_start": os.getloadavg()}
    jit = dr.is_jit_v(mi.Float)

    if spec["mode"] == "dense":
        dense_export(mi, dr, spec, out)
        return out

    vol, mem = load_volume(mi, dr, spec)
    out.update(mem)
    out["resolution"] = [int(x) for x in vol.resolution()]
    out["max"] = float(vol.max())

    if spec["mode"] == "measure" and spec.get("lookups", 0) > 0:
        out.update(lookup_throughput(mi, dr, vol, spec["lookups"], spec.get("lookup_runs", 5)))

    out["integrator"] = spec.get("integrator", "volpath")
    scene = mi.load_dict(turntable_scene(vol, spec["res"], spec["spp"], out["integrator"]))
    images = {}
    if spec["mode"] == "reference":
        # Passes with independent seeds: their mean is the reference, and their
        # spread estimates the reference's own noise (subtracted from the MSE).
        passes = []
        t_total = 0.0
        for k in range(spec["ref_passes"]):
            t, im = render_turntable(mi, dr, scene, spec["ref_spp"] // spec["ref_passes"],
                                     1_000_000 + k)
            passes.append(im.astype(np.float64))
            t_total += t
        p = np.stack(passes)
        images["mean"] = p.mean(axis=0).astype(np.float32)
        k = len(passes)
        images["var_of_mean"] = (p.var(axis=0, ddof=1) / k).astype(np.float32) if k > 1 \
            else np.zeros_like(images["mean"])
        out["ref_time_s"] = t_total
    else:
        # Render time at equal spp: one cold turntable (JIT compile included;
        # the worker runs with an empty kernel cache), then >= 5 warm ones.
        if jit:
            dr.set_flag(dr.JitFlag.KernelHistory, True)
            dr.kernel_history()  # clears
        t_first, _ = render_turntable(mi, dr, scene, spec["spp"], 0)
        out["first_s"] = t_first
        if jit:
            out.update(jit_compile_ms(dr))
            dr.set_flag(dr.JitFlag.KernelHistory, False)
        times = []
        for r in range(spec["runs"]):
            t, im = render_turntable(mi, dr, scene, spec["spp"], 1 + r)
            times.append(t)
        out["warm_s"] = times
        out["warm_median_s"] = statistics.median(times)
        out["warm_min_s"] = min(times)
        images["timing_last"] = im
        # spp sweep for error against time. Same seeds for both plugins.
        sweep = []
        for j, s in enumerate(spec["sweep"]):
            ts = []
            for rep in range(spec.get("sweep_repeats", 1)):
                t, im = render_turntable(mi, dr, scene, s, 100 + 17 * j + rep)
                ts.append(t)
            images[f"sweep_{s}"] = im
            sweep.append({"spp": s, "time_s": min(ts), "times_s": ts})
        out["sweep"] = sweep
        if spec.get("count_lookups"):
            out.update(paths_and_counts(mi, dr, spec))
    out["peak_rss_end"] = peak_rss_bytes()
    out["loadavg_end"] = os.getloadavg()
    if images:
        np.savez(spec["out_npz"], **images)
    return out


def dense_export(mi, dr, spec, out):
    """Writes the dense .vol of a .nvdb's active box by reading every voxel
    centre with nanovdbvolume's `nearest` filter (which reads voxel
    floor(m + u d) at u = (i + 0.5) / d: exactly voxel i), slab by slab."""
    import struct
    from scene import volume_dict
    vol = mi.load_dict(volume_dict("nanovdbvolume", spec["volume"], "nearest",
                                   spec.get("grid", "")))
    X, Y, Z = [int(v) for v in vol.resolution()]
    total = X * Y * Z * 4
    if total > spec["max_dense_bytes"]:
        raise SystemExit(f"dense export of {spec['volume']} would need {total} B "
                         f"(> {spec['max_dense_bytes']} B); skipped")
    tmp = spec["dense_out"] + ".tmp"
    ys, xs = np.meshgrid(np.arange(Y, dtype=np.float64), np.arange(X, dtype=np.float64),
                         indexing="ij")
    px = ((xs.ravel() + 0.5) / X).astype(np.float32)
    py = ((ys.ravel() + 0.5) / Y).astype(np.float32)
    with open(tmp, "wb") as f:
        f.write(b"VOL" + bytes([3]))
        f.write(struct.pack("<iiiii", 1, X, Y, Z, 1))
        f.write(struct.pack("<6f", 0, 0, 0, 1, 1, 1))
        it = dr.zeros(mi.Interaction3f, X * Y) if dr.is_jit_v(mi.Float) else None
        for z in range(Z):
            pz = np.full(X * Y, (z + 0.5) / Z, dtype=np.float32)
            it.p = mi.Point3f(mi.Float(px), mi.Float(py), mi.Float(pz))
            v = np.asarray(vol.eval_1(it), dtype=np.float32)
            f.write(v.tobytes())
    os.replace(tmp, spec["dense_out"])
    out["dense_resolution"] = [X, Y, Z]

