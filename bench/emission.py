"""What emission costs: the emissiveheterogeneous medium rendered by
volpathlocal, against the same medium without emission (heterogeneous: same
density, albedo, scale and phase), in a scene with a floor that the fire
lights and a dim sky.

    python3 bench/emission.py                      # ~5 min on 2 cores (~3 with cached references)
                                                   #   -> bench/results/emission.md, .json, _error_time.png
    python3 bench/emission.py --quick              # harness check (~2-3 min: JIT compiles) -> /tmp/emission_quick/
    python3 bench/emission.py --report-only        # the report again from its .json
    python3 bench/emission.py --cases fireball --variants llvm_ad_rgb --out /tmp/e/emission.md

Cases:
  fireball   `vdb2nvdb generate fireball_<--n>` (default 128; the
             generator's case, tools/testdata/generate_cases.cpp): a
             turbulent ball of smoke, empty outside (those voxels are not in
             the sparse grids), with a temperature grid (kK) hot in the core
             (2800 K) that cools outwards to 0 before the rim (the outer
             soot shell does not glow); both grids through the file, placed
             by its transform (voxel size 1/n: the unit cube). Cached in
             --data.
  usd_heat   ../shared/data/usd_density_heat_fog.vdb (OpenUSD test data:
             `density` and `heat` fog grids, different active boxes),
             converted by BUILD/bin/vdb2nvdb (which keeps every float grid)
             into --data; both volumes with use_grid_transform, so that they
             line up, turned z-up -> y-up and scaled into the unit cube.
             Heat, in [0, 0.76], is a simulation's temperature-like field,
             not radiance and not kelvin: it goes through temperature mode
             (temperature_scale 3700: 0.76 -> 2810 K, about the fireball's
             core; heat below 0.027 -> below the 100 K cutoff), so the
             colour goes from dull red to yellow-white as a hot gas does,
             and the measurement includes the blackbody evaluation, the more
             expensive of the two modes. Skipped, with a message, when
             ../shared/data is absent.

Configurations, per case and variant, in one process (so their ratios are
back to back): `off` (heterogeneous + volpathlocal) and `on`
(emissiveheterogeneous + volpathlocal, temperature mode). The scene: the
medium in the unit cube standing on a diffuse floor, a dim constant sky, a
turntable of --sensors perspective sensors (the benchmark's bench/scene.py
style: independent sampler, Gaussian film), max_depth 64 as the benchmark
scene. Per configuration:

  - render time at equal spp: the first turntable (the child starts with an
    empty Dr.Jit kernel cache, so on llvm_ad_rgb it includes the JIT
    compilation, reported), then --runs turntables per configuration,
    interleaved off, on, on, off, ... so that load changes on the machine
    hit both; the ratio on / off of the medians, of wall time and of the
    process's CPU time (which other processes on the machine do not
    inflate);
  - error against time: an spp sweep (the minimum time of --sweep-repeats
    renders per point) against the configuration's own converged reference
    (llvm_ad_rgb, --ref-spp in --ref-passes passes, cached in --data/refs,
    keyed by the settings, the grids and the plugin binaries): RMSE with the
    reference's own noise subtracted (bench/metrics.py), that RMSE relative
    to the reference's mean pixel value (on and off are different images, so
    only relative errors compare), and SSIM;
  - whether volpathlocal tracked the medium through the walk
    (`tracked_media`) and the density volume's local_majorant_ratio: the
    emissive medium is always walked, a heterogeneous one only up to
    max_majorant_ratio (0.5); where `off` is not walked, its time is not the
    same tracking without emission, and the report says so.

A measurement, not a test: nothing is asserted.
"""
import argparse
import datetime
import hashlib
import inspect
import io
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import cases  # noqa: E402
import harness  # noqa: E402
import report_common  # noqa: E402

SHARED_USD = os.path.join(ROOT, "..", "shared", "data", "usd_density_heat_fog.vdb")
CASES = ["fireball", "usd_heat"]
CONFIGS = ["off", "on"]
# Warnings of the child processes, counted (bench/emission.py's report):
# - negative_sample: scalar variants' ImageBlock refuses samples with a
#   negative channel; the blackbody's linear sRGB colour has negative
#   components below ~1500 K (outside the gamut), which the fire's cool
#   parts emit;
# - emission_left_out: emissiveheterogeneous warns that an integrator
#   renders it without emission when its get_majorant() is called before
#   volpathlocal prepared it. Here it is the JIT trace of the `off` scene's
#   medium call, which records every Medium instance alive in the process,
#   the `on` scene's too (not yet rendered): a false alarm.
WARNINGS = {"negative_sample": "Invalid sample value",
            "emission_left_out": "renders the medium without its emission"}
PLUGINS = ["nanovdbvolume", "volpathlocal", "emissiveheterogeneous"]
# The region of each pixel (region_ids): 0 the sky, then the scene's shapes
REGION_IDS = {"floor": 1, "cube": 2}
REGIONS = ["fire", "floor", "smoke"]

# The media of both cases: an explosion's smoke is dark (pbrt-v4's explosion
# scene: sigma_a = sigma_s, albedo 0.5), optical depth up to ~10 across the
# unit cube
MEDIUM = dict(scale=10.0, albedo=0.5)
FIRE = {
    # fireball: kelvin = value x 1000 (the grid holds kK); usd_heat: heat x
    # 3700 (0.76 -> 2810 K). emission_scale 0.05 puts the core at a few
    # units on the film (a 2800 K blackbody's luminance is ~300)
    "fireball": dict(temperature_scale=1000.0, emission_scale=0.05),
    "usd_heat": dict(temperature_scale=3700.0, emission_scale=0.05),
}


def log(msg):
    print(msg, flush=True)


# ---------------------------------------------------------------------------
# The cases' files

def source_key(*objs):
    """A short hash of the code of functions and of values: cached grids and
    references are keyed by what made them."""
    h = hashlib.sha1()
    for o in objs:
        h.update((inspect.getsource(o) if callable(o) else json.dumps(o, sort_keys=True))
                 .encode())
    return h.hexdigest()[:8]


def fireball_file(data_dir, build, n):
    return cases.generate(f"fireball_{n}", os.path.join(data_dir, f"fireball_{n}"), build,
                          dense=False, log=io.StringIO())


def usd_file(data_dir, build):
    out = os.path.join(data_dir, "usd_density_heat_fog.nvdb")
    if not os.path.exists(out):
        os.makedirs(data_dir, exist_ok=True)
        cmd = [os.path.join(build, "bin", "vdb2nvdb"), SHARED_USD, out]
        r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{r.stdout}")
    return out


# ---------------------------------------------------------------------------
# The scene (built in the child, where Mitsuba is loaded)

def volumes(mi, case):
    """(sigma_t, temperature) volume dicts of a case, placed in the unit cube."""
    if case["name"] == "fireball":
        # the generator's placement: voxel size 1/n, the unit cube
        return tuple({"type": "nanovdbvolume", "filename": case["file"], "grid": g,
                      "use_grid_transform": True} for g in ("density", "temperature"))
    # usd_heat: the grids' own world space (they line up), z up -> y up, the
    # density's world box scaled into the unit cube (its long axis 1), centred
    T = mi.ScalarTransform4f
    probe = mi.load_dict({"type": "nanovdbvolume", "filename": case["file"], "grid": "density",
                          "use_grid_transform": True})
    bb = probe.bbox()
    lo, hi = [float(v) for v in bb.min], [float(v) for v in bb.max]
    centre = [0.5 * (lo[k] + hi[k]) for k in range(3)]
    s = 1.0 / max(hi[k] - lo[k] for k in range(3))
    to_world = (T().translate([0.5, 0.5, 0.5]) @ T().scale(s) @ T().rotate([1, 0, 0], -90)
                @ T().translate([-v for v in centre]))
    return tuple({"type": "nanovdbvolume", "filename": case["file"], "grid": g,
                  "use_grid_transform": True, "to_world": to_world}
                 for g in ("density", "heat"))


def sensor(mi, i, n, res, spp):
    phi = 2 * math.pi * (i + 0.125) / n
    el, radius, target = math.radians(14.0), 2.1, [0.5, 0.4, 0.5]
    o = [target[0] + radius * math.cos(el) * math.sin(phi), target[1] + radius * math.sin(el),
         target[2] + radius * math.cos(el) * math.cos(phi)]
    return {"type": "perspective", "fov": 40,
            "to_world": mi.ScalarTransform4f().look_at(origin=o, target=target, up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": res, "height": res,
                     "rfilter": {"type": "gaussian"}}}


def scene_dict(mi, case, config, res, spp, n_sensors):
    sigma_t, temperature = volumes(mi, case)
    T = mi.ScalarTransform4f
    medium = {"type": "heterogeneous", "sigma_t": sigma_t, "scale": MEDIUM["scale"],
              "albedo": {"type": "rgb", "value": [MEDIUM["albedo"]] * 3}}
    if config == "on":
        medium.update(type="emissiveheterogeneous", temperature=temperature,
                      **FIRE[case["name"]])
    desc = {
        "type": "scene",
        "integrator": {"type": "volpathlocal", "max_depth": 64},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.02, 0.025, 0.04]}},
        "floor": {"type": "rectangle",
                  "to_world": T().translate([0.5, -0.02, 0.5]).rotate([1, 0, 0], -90)
                  .scale(4.0),
                  "bsdf": {"type": "diffuse",
                           "reflectance": {"type": "rgb", "value": [0.5, 0.45, 0.4]}}},
        "cube": {"type": "cube", "to_world": T().translate([0.5, 0.5, 0.5]).scale(0.5),
                 "bsdf": {"type": "null"}, "interior": medium},
    }
    for i in range(n_sensors):
        desc[f"sensor_{i}"] = sensor(mi, i, n_sensors, res, spp)
    return desc


# ---------------------------------------------------------------------------
# The child process: one variant, every case and configuration

def render_turntable(mi, dr, scene, spp, seed, cpu=None):
    """Renders every sensor: (seconds, images [S, H, W, 3]). cpu: a list that
    gets the process's CPU time of the turntable (every thread's)."""
    imgs = []
    c0 = time.process_time()
    t0 = time.perf_counter()
    for i in range(len(scene.sensors())):
        img = mi.render(scene, sensor=i, spp=spp, seed=seed * 1009 + i)
        if dr.is_jit_v(mi.Float):
            dr.eval(img)
            dr.sync_thread()
        imgs.append(img)
    t = time.perf_counter() - t0
    if cpu is not None:
        cpu.append(time.process_time() - c0)
    return t, np.stack([np.asarray(im, dtype=np.float32)[..., :3] for im in imgs])


_COUNTER = []  # (the appender, kept alive)


def count_warnings(mi):
    """Mitsuba's log in this process through one appender: the WARNINGS
    counted, not printed (scalar variants warn for every negative sample),
    every other line printed. Returns the counts, live."""
    counts = {k: 0 for k in WARNINGS}

    class Counter(mi.Appender):
        def append(self, level, text):
            hit = [k for k, t in WARNINGS.items() if t in text]
            for k in hit:
                counts[k] += 1
            if not hit:
                print(text, flush=True)

        def log_progress(self, progress, name, formatted, eta, ptr=None):
            pass

    logger = mi.Thread.thread().logger()
    logger.clear_appenders()
    _COUNTER.append(Counter())
    logger.add_appender(_COUNTER[-1])
    return counts


def child(spec):
    """One variant's measurements, in a process of its own (bench/harness.py;
    the parent's run_child): returns them, and writes the images to
    spec["out_npz"]"""
    from child_setup import mitsuba_for
    dr, mi = mitsuba_for(spec["variant"], spec["build"])
    warnings = count_warnings(mi)
    try:
        from nanovdb_mitsuba import volume_facts
    except ImportError:
        sys.path.insert(0, os.path.join(ROOT, "python"))
        from nanovdb_mitsuba import volume_facts
    out = {"variant": spec["variant"], "loadavg_start": os.getloadavg(), "cases": {}}
    images = {}
    for case in spec["cases"]:
        cres = out["cases"][case["name"]] = {}
        scenes = {}
        for config in spec["configs"]:
            t0 = time.perf_counter()
            scenes[config] = mi.load_dict(scene_dict(mi, case, config, spec["res"], spec["spp"],
                                                     spec["sensors"]))
            cres.setdefault("load_s", {})[config] = time.perf_counter() - t0
        facts = volume_facts(mi.load_dict(volumes(mi, case)[0]))
        cres["density"] = {k: facts[k] for k in ("index_dims", "local_majorant_ratio",
                                                 "grid_bytes", "max")}
        if spec["mode"] == "reference":
            images[f"{case['name']}__regions"] = region_ids(mi, case, spec)
            for config in spec["configs"]:
                passes, t_total = [], 0.0
                for k in range(spec["ref_passes"]):
                    t, im = render_turntable(mi, dr, scenes[config],
                                             spec["ref_spp"] // spec["ref_passes"], 1_000_000 + k)
                    passes.append(im.astype(np.float64))
                    t_total += t
                p = np.stack(passes)
                images[f"{case['name']}__{config}__mean"] = p.mean(axis=0).astype(np.float32)
                images[f"{case['name']}__{config}__var_of_mean"] = \
                    (p.var(axis=0, ddof=1) / len(passes)).astype(np.float32)
                cres.setdefault("ref_time_s", {})[config] = t_total
                log(f"    reference {case['name']} {config}: {t_total:.1f} s")
            continue
        # Render time at equal spp: the first turntable (compiles the
        # kernels: the process starts with an empty kernel cache), then
        # interleaved timed turntables
        first = {}
        jit = dr.is_jit_v(mi.Float)
        for config in spec["configs"]:
            if jit:
                dr.set_flag(dr.JitFlag.KernelHistory, True)
                dr.kernel_history()  # (clears it)
            t, _ = render_turntable(mi, dr, scenes[config], spec["spp"], 0)
            first[config] = t
            if jit:
                cres.setdefault("jit_compile_ms", {})[config] = sum(
                    float(k.get("codegen_time", 0.0)) + float(k.get("backend_time", 0.0))
                    for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT)
                dr.set_flag(dr.JitFlag.KernelHistory, False)
            p = mi.traverse(scenes[config].integrator())
            cres.setdefault("tracked_media", {})[config] = int(p["tracked_media"])
        cres["first_s"] = first
        times = {c: [] for c in spec["configs"]}
        cpu_times = {c: [] for c in spec["configs"]}
        for r in range(spec["runs"]):
            order = spec["configs"] if r % 2 == 0 else spec["configs"][::-1]
            for config in order:
                t, _ = render_turntable(mi, dr, scenes[config], spec["spp"], 1 + r,
                                        cpu_times[config])
                times[config].append(t)
        cres["warm_s"] = times
        cres["warm_cpu_s"] = cpu_times
        cres["warm_median_s"] = {c: statistics.median(v) for c, v in times.items()}
        # spp sweep (error against time), interleaved too. A render at a new
        # spp may compile new kernels (llvm_ad_rgb: 1 or 2 spp after 16, 10-20
        # s in a trial): one untimed render of one sensor at that spp first
        sweep = {c: [] for c in spec["configs"]}
        for j, s in enumerate(spec["sweep"]):
            for config in spec["configs"]:
                img = mi.render(scenes[config], sensor=0, spp=s, seed=99)
                if jit:
                    dr.eval(img)
                    dr.sync_thread()
                ts = []
                for rep in range(spec["sweep_repeats"]):
                    t, im = render_turntable(mi, dr, scenes[config], s, 100 + 17 * j + rep)
                    ts.append(t)
                images[f"{case['name']}__{config}__sweep_{s}"] = im
                sweep[config].append({"spp": s, "time_s": min(ts), "times_s": ts})
        cres["sweep"] = sweep
        med = cres["warm_median_s"]
        log(f"    {spec['variant']} {case['name']}: " + ", ".join(
            f"{c} {med[c]:.3f} s (first {first[c]:.2f} s, walked {cres['tracked_media'][c]})"
            for c in spec["configs"])
            + (f", on/off {med['on'] / med['off']:.3f}" if "on" in med and "off" in med else ""))
    out["loadavg_end"] = os.getloadavg()
    out["warnings"] = dict(warnings)
    np.savez(spec["out_npz"], **images)
    return out


def region_ids(mi, case, spec):
    """What each pixel's camera ray meets first, per sensor [S, H, W]: 0 the
    sky, else REGION_IDS of the shape. From the depth of each shape alone
    (Mitsuba's `aov` integrator, 0 where the ray misses), one sample at the
    pixel centre (a box filter)"""
    depths = {}
    for name in REGION_IDS:
        desc = scene_dict(mi, case, "off", spec["res"], 1, spec["sensors"])
        desc["integrator"] = {"type": "aov", "aovs": "dd:depth"}
        for k in list(desc):
            if k in REGION_IDS and k != name:
                del desc[k]
            elif k.startswith("sensor_"):
                desc[k]["film"]["rfilter"] = {"type": "box"}
        scene = mi.load_dict(desc)
        d = np.stack([np.asarray(mi.render(scene, sensor=i, spp=1, seed=0))[..., 0]
                      for i in range(spec["sensors"])]).astype(np.float64)
        depths[name] = np.where(d > 0, d, np.inf)
    ids = np.zeros(next(iter(depths.values())).shape, dtype=np.int8)
    nearest = np.full(ids.shape, np.inf)
    for name, d in depths.items():
        closer = d < nearest
        ids[closer], nearest[closer] = REGION_IDS[name], d[closer]
    return ids


def region_masks(ids, ref_on, fire_share=0.03):
    """The issue's regions: the fire seen directly (the brightest
    `fire_share` of each sensor's pixels in the `on` reference, by
    luminance), the floor and the cube (the medium's box: the smoke, and
    what is seen through it) outside those; [S, H, W, 3] masks"""
    import metrics
    luma = ref_on.astype(np.float64) @ metrics.LUMA
    fire = np.zeros(ids.shape, dtype=bool)
    for s in range(ids.shape[0]):
        cut = np.quantile(luma[s], 1.0 - fire_share)
        fire[s] = luma[s] >= cut
    masks = {"fire": fire, "floor": (ids == REGION_IDS["floor"]) & ~fire,
             "smoke": (ids == REGION_IDS["cube"]) & ~fire}
    return {k: np.repeat(m[..., None], ref_on.shape[-1], axis=-1) for k, m in masks.items()}


def run_child(spec, work, tag):
    """One variant's child (child()): its measurements and images"""
    spec = dict(spec, out_npz=os.path.join(work, tag + ".npz"))
    # An empty Dr.Jit kernel cache (a HOME of its own, as bench/run.py's
    # workers): the first turntable's time includes the compilation
    home = tempfile.mkdtemp(prefix="jit_home_", dir=work)
    t0 = time.perf_counter()
    try:
        out = harness.run_child("emission:child", spec, home=home, echo=True)
    finally:
        shutil.rmtree(home, ignore_errors=True)
    out["wall_s"] = time.perf_counter() - t0
    counts = out["warnings"]
    if any(counts.values()):
        log(f"    {tag}: warnings " + ", ".join(f"{k} x{v}" for k, v in counts.items() if v))
    with np.load(spec["out_npz"]) as z:
        imgs = {k: z[k] for k in z.files}
    return out, imgs


def file_key(paths):
    h = hashlib.sha1()
    for p in paths:
        st = os.stat(p)
        h.update(f"{os.path.abspath(p)}|{st.st_size}|{st.st_mtime_ns}".encode())
    return h.hexdigest()[:12]


def references(a, case_list, work):
    """{case: {config: (mean, var_of_mean, seconds)}}, cached in --data/refs."""
    refs, missing = {}, []
    sos = [os.path.join(a.build, "plugins", p + ".so") for p in PLUGINS]
    for case in case_list:
        # (the scene's code and parameters, the grids' files and the plugins)
        key = (f"{case['name']}__r{a.res}x{a.sensors}__s{a.ref_spp}x{a.ref_passes}__"
               f"{a.ref_variant}__{source_key(volumes, sensor, scene_dict, region_ids, MEDIUM, FIRE)}__"
               f"{file_key([case['file']] + sos)}")
        path = os.path.join(a.data, "refs", key + ".npz")
        case["ref_path"] = path
        if os.path.exists(path) and not a.no_cache:
            with np.load(path) as z:
                refs[case["name"]] = {c: (z[f"{c}__mean"], z[f"{c}__var_of_mean"],
                                          float(z[f"{c}__time_s"]), True) for c in CONFIGS}
                case["regions"] = z["regions"]
        else:
            missing.append(case)
    if missing:
        log(f"== references ({a.ref_variant}, {a.ref_spp} spp in {a.ref_passes} passes): "
            + ", ".join(c["name"] for c in missing))
        spec = {"mode": "reference", "variant": a.ref_variant, "build": a.build,
                "cases": missing, "configs": CONFIGS, "res": a.res, "spp": a.ref_spp,
                "sensors": a.sensors, "ref_spp": a.ref_spp, "ref_passes": a.ref_passes}
        out, imgs = run_child(spec, work, "reference")
        for case in missing:
            n = case["name"]
            d = {"regions": imgs[f"{n}__regions"]}
            case["regions"] = d["regions"]
            for c in CONFIGS:
                d[f"{c}__mean"] = imgs[f"{n}__{c}__mean"]
                d[f"{c}__var_of_mean"] = imgs[f"{n}__{c}__var_of_mean"]
                d[f"{c}__time_s"] = out["cases"][n]["ref_time_s"][c]
            os.makedirs(os.path.dirname(case["ref_path"]), exist_ok=True)
            np.savez(case["ref_path"], **d)
            refs[n] = {c: (d[f"{c}__mean"], d[f"{c}__var_of_mean"], d[f"{c}__time_s"], False)
                       for c in CONFIGS}
    return refs


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="harness check: 64^3 fireball, 24^2 images, few spp, "
                    "out /tmp/emission_quick/")
    ap.add_argument("--cases", nargs="+", choices=CASES, default=CASES)
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--n", type=int, default=128, help="fireball voxels per axis")
    ap.add_argument("--res", type=int, default=48, help="image width = height")
    ap.add_argument("--sensors", type=int, default=4, help="turntable sensors")
    # (64 spp: at 16, llvm_ad_rgb's fixed cost per render, one thread's
    # launch and film work, dilutes the ratio: 1.13 at 16 spp, 1.27 at 64 in
    # a trial)
    ap.add_argument("--spp", type=int, default=64, help="spp of the timed renders (JIT)")
    ap.add_argument("--scalar-spp", type=int, default=32,
                    help="spp of the timed renders (scalar)")
    ap.add_argument("--runs", type=int, default=5, help="timed turntables per configuration")
    # (llvm_ad_rgb compiles a second kernel, ~15 s here, for 1 or 2 spp: the
    # JIT sweep starts at 4)
    ap.add_argument("--sweep", type=int, nargs="+", default=[4, 8, 16, 32])
    ap.add_argument("--scalar-sweep", type=int, nargs="+", default=[2, 4, 8, 16])
    ap.add_argument("--sweep-repeats", type=int, default=1)
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--ref-passes", type=int, default=4)
    ap.add_argument("--ref-variant", default="llvm_ad_rgb")
    ap.add_argument("--data", default=os.path.join(HERE, "data", "emission"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", help="the report (default bench/results/emission.md; "
                    "its .json and .png beside it)")
    ap.add_argument("--no-cache", action="store_true", help="re-render the references")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite the report (.md, .png) from its .json, without measuring")
    a = ap.parse_args()
    if a.report_only:
        return report_only(a)
    if a.quick:
        a.n, a.res, a.sensors, a.spp, a.scalar_spp, a.runs = 64, 24, 2, 4, 4, 3
        a.sweep, a.scalar_sweep, a.ref_spp, a.ref_passes = [1, 4], [1, 4], 64, 2
    a.out = os.path.abspath(a.out or (os.path.join("/tmp", "emission_quick", "emission.md")
                                      if a.quick else os.path.join(HERE, "results",
                                                                   "emission.md")))
    a.build, a.data = os.path.abspath(a.build), os.path.abspath(a.data)
    for p in PLUGINS:
        if not os.path.exists(os.path.join(a.build, "plugins", p + ".so")):
            sys.exit(f"{a.build}/plugins/{p}.so not found: build the project first")
    started = datetime.datetime.now().astimezone()
    t_start = time.perf_counter()
    notes = []
    case_list = []
    for name in a.cases:
        if name == "fireball":
            case_list.append({"name": name, "file": fireball_file(a.data, a.build, a.n)})
        elif not os.path.exists(SHARED_USD):
            msg = f"usd_heat skipped: {os.path.normpath(SHARED_USD)} not found (../shared/data)"
            log("== " + msg)
            notes.append(msg)
        else:
            case_list.append({"name": name, "file": usd_file(a.data, a.build)})
    if not case_list:
        sys.exit("no case to measure")
    work = os.path.join(a.data, "runs")
    os.makedirs(work, exist_ok=True)
    so_stats = {p: os.stat(os.path.join(a.build, "plugins", p + ".so")).st_mtime_ns
                for p in PLUGINS}

    refs = references(a, case_list, work)
    t_refs = time.perf_counter() - t_start
    import metrics
    measured = {}
    rows, errors = [], []
    for variant in a.variants:
        scalar = variant.startswith("scalar")
        spec = {"mode": "measure", "variant": variant, "build": a.build,
                "cases": [{k: v for k, v in c.items() if k != "regions"} for c in case_list],
                "configs": CONFIGS, "res": a.res, "sensors": a.sensors,
                "spp": a.scalar_spp if scalar else a.spp, "runs": a.runs,
                "sweep": a.scalar_sweep if scalar else a.sweep,
                "sweep_repeats": a.sweep_repeats}
        log(f"== {variant}: {a.res}^2 x {a.sensors} sensors, {spec['spp']} spp x {a.runs} runs, "
            f"sweep {spec['sweep']} (load {os.getloadavg()[0]:.2f})")
        out, imgs = run_child(spec, work, variant)
        measured[variant] = out
        if any(out["warnings"].values()):
            notes.append(f"{variant}: Mitsuba's warnings, counted: " + ", ".join(
                f"`{k}` x{v}" for k, v in out["warnings"].items() if v)
                + " (see WARNINGS in bench/emission.py for what each means)")
        for case in case_list:
            n = case["name"]
            cres = out["cases"][n]
            med = cres["warm_median_s"]
            per_round = [on / off for on, off in zip(cres["warm_s"]["on"], cres["warm_s"]["off"])]
            cpu = cres["warm_cpu_s"]
            cpu_round = [on / off for on, off in zip(cpu["on"], cpu["off"])]
            eff = {}
            masks = region_masks(case["regions"], refs[n]["on"][0])
            for config in CONFIGS:
                mean, var, _, _ = refs[n][config]
                level = float(np.mean(mean))
                pts = []
                for pt in cres["sweep"][config]:
                    img = imgs[f"{n}__{config}__sweep_{pt['spp']}"]
                    raw, corr = metrics.rmse(img, mean, var)
                    e = {"case": n, "variant": variant, "config": config, "spp": pt["spp"],
                         "time_s": pt["time_s"], "rmse": corr, "rmse_raw": raw,
                         "rel_rmse": corr / level, "ssim": metrics.ssim(img, mean),
                         "regions": metrics.region_errors(img, mean, var, masks)}
                    errors.append(e)
                    pts.append(e)
                # Monte Carlo efficiency: relative error^2 x time (median over
                # the sweep; lower is better)
                eff[config] = statistics.median(e["rel_rmse"] ** 2 * e["time_s"] for e in pts)
            rows.append({"case": n, "variant": variant, "spp": spec["spp"],
                         "off_median_s": med["off"], "on_median_s": med["on"],
                         "ratio": med["on"] / med["off"],
                         "ratio_rounds_median": statistics.median(per_round),
                         "off_cpu_s": statistics.median(cpu["off"]),
                         "on_cpu_s": statistics.median(cpu["on"]),
                         "cpu_ratio": statistics.median(cpu["on"]) / statistics.median(cpu["off"]),
                         "cpu_rounds_min": min(cpu_round), "cpu_rounds_max": max(cpu_round),
                         "ratio_rounds_min": min(per_round), "ratio_rounds_max": max(per_round),
                         "off_first_s": cres["first_s"]["off"],
                         "on_first_s": cres["first_s"]["on"],
                         "off_jit_ms": cres.get("jit_compile_ms", {}).get("off"),
                         "on_jit_ms": cres.get("jit_compile_ms", {}).get("on"),
                         "walked_off": cres["tracked_media"]["off"],
                         "walked_on": cres["tracked_media"]["on"],
                         "local_majorant_ratio": cres["density"]["local_majorant_ratio"],
                         "eff_off": eff["off"], "eff_on": eff["on"],
                         "eff_ratio": eff["on"] / eff["off"],
                         "load1": [out["loadavg_start"][0], out["loadavg_end"][0]],
                         "child_wall_s": out["wall_s"]})
            r = rows[-1]
            log(f"   {n}: on/off {r['ratio']:.3f} at {spec['spp']} spp (rounds "
                f"{r['ratio_rounds_min']:.3f}..{r['ratio_rounds_max']:.3f}), CPU time "
                f"{r['cpu_ratio']:.3f} ({r['cpu_rounds_min']:.3f}..{r['cpu_rounds_max']:.3f}), "
                f"relative error^2 x time on/off {r['eff_ratio']:.2f}")
    for p, m in so_stats.items():
        if os.stat(os.path.join(a.build, "plugins", p + ".so")).st_mtime_ns != m:
            notes.append(f"**build/plugins/{p}.so was rebuilt during this run**")
    elapsed = time.perf_counter() - t_start
    write_report(a, case_list, refs, measured, rows, errors, notes, started, elapsed, t_refs)
    log(f"== done in {elapsed:.0f} s (references {t_refs:.0f} s); {a.out}")


def report_only(a):
    """The report again from --out's .json (its rows recomputed where they
    derive from the raw times)."""
    path = os.path.splitext(os.path.abspath(a.out or os.path.join(HERE, "results",
                                                                  "emission.md")))[0]
    saved = json.load(open(path + ".json"))
    s = argparse.Namespace(**saved["settings"])
    s.out = path + ".md"
    for r in saved["rows"]:
        w = saved["measured"][r["variant"]]["cases"][r["case"]]["warm_s"]
        r["ratio_rounds_median"] = statistics.median(
            on / off for on, off in zip(w["on"], w["off"]))
    refs = {n: {c: (None, None, t) for c, t in d.items()}
            for n, d in saved["reference_times_s"].items()}
    write_report(s, saved["cases"], refs, saved["measured"], saved["rows"], saved["errors"],
                 saved["notes"], datetime.datetime.fromisoformat(saved["started"]),
                 saved["elapsed_s"], saved["references_s"], command=saved["command"],
                 refs_cached=saved.get("references_cached", False))
    log(f"== report rewritten from {path}.json")


def command_line(a):
    argv = [x for x in sys.argv[1:]]
    return "python3 bench/emission.py" + (" " + " ".join(argv) if argv else "")


def write_report(a, case_list, refs, measured, rows, errors, notes, started, elapsed, t_refs,
                 command=None, refs_cached=None):
    """refs: {case: {config: (mean, var_of_mean, seconds[, cached])}}; command: the
    measuring run's (default: this one's)."""
    command = command or command_line(a)
    if refs_cached is None:
        refs_cached = all(r[3] for d in refs.values() for r in d.values())
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    base = os.path.splitext(a.out)[0]
    png = os.path.basename(base) + "_error_time.png"
    plot_error_time(errors, os.path.join(os.path.dirname(a.out), png))
    settings = {k: v for k, v in vars(a).items() if k != "child"}
    with open(base + ".json", "w") as f:
        json.dump({"command": command, "settings": settings,
                   "started": started.isoformat(), "elapsed_s": elapsed,
                   "references_s": t_refs, "references_cached": refs_cached, "notes": notes,
                   "cases": [{k: v for k, v in c.items() if k not in ("ref_path", "regions")}
                             for c in case_list],
                   "reference_times_s": {n: {c: r[2] for c, r in d.items()}
                                         for n, d in refs.items()},
                   "medium": MEDIUM, "fire": FIRE, "rows": rows, "errors": errors,
                   "measured": measured}, f, indent=1, default=str)
    L = [
        "# What emission costs: emissiveheterogeneous vs heterogeneous (bench/emission.py)", "",
        f"`{command}`", "",
        f"Run {started:%Y-%m-%d %H:%M %Z}, {elapsed:.0f} s in all (references "
        f"{t_refs:.0f} s{', cached' if refs_cached else ''}), "
        f"{os.cpu_count()} cores. Ratios are from one process per variant "
        "(timed turntables interleaved off, on, on, off, …); absolute times from different "
        "runs do not compare.", "",
        f"Scene: the medium in the unit cube on a diffuse floor, dim sky, `volpathlocal` "
        f"(max_depth 64), {a.sensors} turntable sensors at {a.res}², scale "
        f"{MEDIUM['scale']:g}, albedo {MEDIUM['albedo']:g}. **off**: `heterogeneous`; **on**: "
        "`emissiveheterogeneous` in temperature mode (blackbody), same density, albedo, "
        "scale and phase. Each configuration's error is against its own reference "
        f"({a.ref_variant}, {a.ref_spp} spp); relative RMSE = RMSE / the reference's mean "
        "pixel value.", "",
        "| case | density grid | local majorant ratio | fire |",
        "|---|---|---|---|",
    ]
    for c in case_list:
        n = c["name"]
        d = next(iter(measured.values()))["cases"][n]["density"]
        fire = FIRE[n]
        desc = (f"`vdb2nvdb generate fireball_{a.n}`, core 2800 K"
                if n == "fireball" else "usd_density_heat_fog.vdb, `heat` as temperature")
        L.append(f"| {n} | {desc}; {'×'.join(map(str, d['index_dims']))} active box, "
                 f"{d['grid_bytes'] / 2**20:.2f} MiB | {d['local_majorant_ratio']:.3f} | "
                 f"temperature_scale {fire['temperature_scale']:g}, emission_scale "
                 f"{fire['emission_scale']:g} |")
    L += ["", "## Render time at equal spp", "",
          "| case | variant | spp | off [s] | on [s] | on / off | per round: median, range | CPU off / on [s] | **CPU on / off** | per round: range | first turntable off / on [s] (JIT compile) | walked off / on | load |",
          "|---|---|---:|---:|---:|---:|---|---|---:|---|---|---|---|"]
    for r in rows:
        L.append(f"| {r['case']} | {r['variant']} | {r['spp']} | {r['off_median_s']:.3f} | "
                 f"{r['on_median_s']:.3f} | {r['ratio']:.3f} | "
                 f"{r['ratio_rounds_median']:.3f}, {r['ratio_rounds_min']:.3f}–"
                 f"{r['ratio_rounds_max']:.3f} | {r['off_cpu_s']:.3f} / {r['on_cpu_s']:.3f} | "
                 f"**{r['cpu_ratio']:.3f}** | {r['cpu_rounds_min']:.3f}–{r['cpu_rounds_max']:.3f} | "
                 f"{r['off_first_s']:.2f} / {r['on_first_s']:.2f}"
                 + (f" ({r['off_jit_ms'] / 1000:.2f} / {r['on_jit_ms'] / 1000:.2f})"
                    if r["off_jit_ms"] is not None else "") + " | "
                 f"{'yes' if r['walked_off'] else 'no'} / {'yes' if r['walked_on'] else 'no'} | "
                 f"{r['load1'][0]:.2f}–{r['load1'][1]:.2f} |")
    L += ["", "Medians of the warm turntables (each renders every sensor): wall time, and "
          "the process's CPU time (every thread's; `time.process_time()`), which time "
          "taken by other processes on this shared 2-core machine does not inflate: the "
          "CPU ratio is the steadier measure of the work emission adds; *per round*: the "
          "median and range of on / off within a round of the interleaved runs (the "
          "rounds alternate off, on and on, off); *first turntable*: the "
          "process's first (an empty kernel cache), with the JIT's codegen + backend time of "
          "its kernels (llvm); *walked*: whether volpathlocal tracked the medium through its "
          "majorant walk (`tracked_media`); *load*: the 1-minute load average at the child's "
          "start and end (2 cores: above ~2 the times are inflated).", "",
          "## Error against time", "", f"![error against time]({png})", "",
          "| case | variant | config | spp | time [s] | RMSE | relative RMSE | SSIM |",
          "|---|---|---|---:|---:|---:|---:|---:|"]
    for e in errors:
        L.append(f"| {e['case']} | {e['variant']} | {e['config']} | {e['spp']} | "
                 f"{e['time_s']:.3f} | {e['rmse']:.4f} | {e['rel_rmse']:.4f} | "
                 f"{e['ssim']:.4f} |")
    if any(e.get("regions") for e in errors):
        L += ["", "### The error by region", "",
              "Where the error is: *fire*, the brightest 3 % of each sensor's pixels in the "
              "`on` reference (the fire seen directly); *floor* and *smoke* (the medium's "
              "box: the smoke, and what is seen through it), the pixels whose camera ray "
              "first meets the floor or the box, outside the fire (Mitsuba's `aov` "
              "integrator, shape_index). Per region: the relative RMSE (noise-corrected "
              "RMSE / the reference's mean there) and its share of the image's squared "
              "error. The masks are the same for `off` and `on`.", "",
              "| case | variant | config | spp | " + " | ".join(
                  f"{r}: rel. RMSE, share" for r in REGIONS) + " |",
              "|---|---|---|---:|" + "---|" * len(REGIONS)]
        for e in errors:
            if not e.get("regions"):
                continue
            cells = []
            for r in REGIONS:
                g = e["regions"].get(r, {})
                cells.append("–" if g.get("rel_rmse") is None else
                             f"{g['rel_rmse']:.3f}, {100 * g['share']:.0f} %")
            L.append(f"| {e['case']} | {e['variant']} | {e['config']} | {e['spp']} | "
                     + " | ".join(cells) + " |")
    L += ["", "Efficiency, relative RMSE² × time (median over the sweep; lower is better), "
          "and how much longer `on` needs than `off` to reach the same relative error. The "
          "two are different images: `off` is the dark smoke against a dim sky on a floor "
          "lit by the sky, which the sky's emitter sampling converges quickly; `on` adds the "
          "fire, and the floor and the smoke lit by it, which a path finds only by hitting "
          "the fire (there is no emitter sampling of a medium's emission), so most of this "
          "ratio is the variance of that lighting, not the time of the emission's lookups "
          "(those are the render-time ratio above).", "",
          "| case | variant | off | on | on / off |", "|---|---|---:|---:|---:|"]
    for r in rows:
        L.append(f"| {r['case']} | {r['variant']} | {r['eff_off']:.3g} | {r['eff_on']:.3g} | "
                 f"{r['eff_ratio']:.2f} |")
    L += ["", "| case | reference | off [s] | on [s] |", "|---|---|---:|---:|"]
    for n, d in refs.items():
        L.append(f"| {n} | {a.ref_spp} spp, {a.ref_variant} | {d['off'][2]:.1f} | "
                 f"{d['on'][2]:.1f} |")
    report_common.write_markdown(a.out, L, notes)


def plot_error_time(errors, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cases = sorted({e["case"] for e in errors}, key=CASES.index)
    variants = list(dict.fromkeys(e["variant"] for e in errors))
    fig, axes = plt.subplots(1, len(cases), figsize=(3.6 * len(cases), 3.2), squeeze=False)
    colors = {"off": "tab:blue", "on": "tab:red"}
    styles = ["-", "--", ":"]
    for j, n in enumerate(cases):
        ax = axes[0, j]
        for k, v in enumerate(variants):
            for config in CONFIGS:
                pts = sorted((e for e in errors if e["case"] == n and e["variant"] == v
                              and e["config"] == config), key=lambda e: e["spp"])
                if pts:
                    ax.loglog([e["time_s"] for e in pts], [e["rel_rmse"] for e in pts],
                              "o" + styles[k % 3], ms=3, color=colors[config],
                              label=f"{config}, {v}")
        ax.set_title(n, fontsize=9)
        ax.set_xlabel("render time, all sensors [s]")
        ax.set_ylabel("relative RMSE vs reference")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    report_common.save_figure(fig, *os.path.split(path), 80)


if __name__ == "__main__":
    main()
