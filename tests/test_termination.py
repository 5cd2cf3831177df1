"""
Every path of volpathlocal ends (issue 23).

The hang: a path whose ray starts outside its medium's box and meets no
surface (a ray spawned from a surface that cuts through the medium's
boundary, or a medium given to an open surface) was left active and
unchanged, for ever. Mitsuba's participating_media scene with
sphere_base.obj, tracked through the walk, hung at max_depth 2. Since the
fix, and as a second line, every loop of the integrator has a bound that a
valid ray cannot reach; a lane it stops is counted and shown as the
integrator's "loop_bound_trips" (traverse()), which these tests require to
be 0.

Renders run in a child process with a time limit, so that a hang coming
back fails the test instead of stopping the suite.

- test01: Mitsuba's scene (tests/mitsuba_media_scenes.py: the sigmat grid,
  an equivalent of the mesh) with tracking forced, at max_depth 2 and 6,
  many seeds, on scalar_rgb and llvm_ad_rgb; and at the default settings on
  the grid padded by one voxel, whose local_majorant_ratio is below the
  default max_majorant_ratio (so the walk is used without forcing it).
- test02: a fuzz test: random spheres straddling the faces of a tracked
  cube, a medium given to an open rectangle (every path that enters it
  leaves through nothing), random cameras, several seeds per variant.
- test03: the same scenes (closed media) agree with volpath (the per-pixel
  z-test of test_volpathlocal.py), so termination did not come from ending
  paths early.
- test04: a path that leaves an unenclosed medium's box and meets no surface
  sees what lies beyond (analytic: the sky), with tracking and with
  volpath's own sampling in volpathlocal. Different from volpath by design:
  volpath's weight for that flight is 0 / 0 (inf x 0 in
  transmittance_eval_pdf) and it loses the path.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import BUILD, ROOT

TIME_LIMIT = 240  # seconds per child process (measured: 10-30 s)

WORKER = r"""
import gc, json, sys
import numpy as np
import mitsuba as mi, drjit as dr
cfg = json.loads(sys.argv[1])
mi.set_variant(cfg["variant"])
mi.file_resolver().prepend(cfg["build"])
sys.path.insert(0, cfg["tests"])
import mitsuba_media_scenes as ms

def trips(scene):
    params = mi.traverse(scene.integrator())
    return int(params["loop_bound_trips"]) if "loop_bound_trips" in params else 0

def tracked(scene):
    return int(mi.traverse(scene.integrator())["tracked_media"])

out = []
for job in cfg["jobs"]:
    if job["kind"] == "mitsuba":
        sig = ms.sigmat_values()
        if job.get("pad"):
            sig = np.pad(sig, 4)
        integ = {"type": job["integrator"], "max_depth": job["max_depth"], **job.get("args", {})}
        d = ms.hetero_scene("hetero_sigmat", cfg["tmp"], integ, plugin="nanovdbvolume",
                            res=job["res"], spp=job["spp"], sigmat=sig,
                            volume_args={"wrap_mode": "tree"} if job.get("pad") else {})
    else:
        rng = np.random.default_rng(job["scene_seed"])
        T = mi.ScalarTransform4f
        # The random density scale goes into the values: heterogeneous keeps
        # its scale as a kernel literal, the volume's values are data
        vol = ms.grid_volume(ms.sigmat_values() * rng.uniform(1, 8), "nanovdbvolume")
        med = {"type": "heterogeneous", "scale": 1.0, "albedo": 0.8, "sigma_t": vol}
        eye = rng.normal(size=3); eye = 3.5 * eye / np.linalg.norm(eye)
        d = {"type": "scene",
             "integrator": {"type": job["integrator"], "max_depth": job["max_depth"],
                            **job.get("args", {})},
             "sensor": {"type": "perspective", "fov": 50,
                        "to_world": T().look_at(origin=eye.tolist(), target=[0, 0, 0], up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": job["res"], "height": job["res"],
                                 "rfilter": {"type": "box"}},
                        "sampler": {"type": "independent", "sample_count": job["spp"]}},
             "sky": {"type": "constant", "radiance": 0.7},
             "sun": {"type": "directional", "direction": [-1, -2, -0.5], "irradiance": 2.0},
             "cube": ms.medium_cube(med)}
        for i in range(8):
            c = rng.uniform(-0.75, 0.75, 3)
            a = rng.integers(3)
            c[a] = rng.choice([-0.75, 0.75]) + rng.uniform(-0.15, 0.15)
            d[f"ball{i}"] = {"type": "sphere", "center": c.tolist(),
                             "radius": float(rng.uniform(0.05, 0.4)),
                             "bsdf": {"type": "diffuse"}}
        # A medium on an open surface: paths that cross it enter a medium
        # they never leave through a surface
        if job.get("open", True):
          d["open"] = {"type": "rectangle", "bsdf": {"type": "null"}, "interior": med,
                       "to_world": T().translate([0, float(rng.uniform(-1.3, -0.9)), 0])
                       .rotate([1, 0, 0], -90).scale(2.0)}
        # Two specks fix the scene's bounding sphere, which the sky and the
        # sun keep as kernel literals: then every fuzz scene of a max_depth
        # shares the integrator's kernel (one LLVM compile, not one a scene)
        for i, c in enumerate(([-2.5] * 3, [2.5] * 3)):
            d[f"speck{i}"] = {"type": "sphere", "center": c, "radius": 1e-4,
                              "bsdf": {"type": "diffuse"}}
    scene = mi.load_dict(d)
    means = []
    for seed in job["seeds"]:
        img = np.array(mi.render(scene, seed=seed), dtype=np.float64)
        assert np.all(np.isfinite(img)), "NaN or Inf in a pixel"
        means.append(img.tolist() if job.get("images") else img.mean(axis=(0, 1)).tolist())
    out.append({"trips": trips(scene), "tracked": tracked(scene) if "local" in job["integrator"] else None,
                "means": means})
    # (freed before the next scene loads: its objects' registry ids, kernel
    # literals too, are then the same as this one's)
    del scene
    gc.collect()
print("RESULT " + json.dumps(out))
"""


def run_jobs(variant, jobs, tmp_path):
    cfg = {"variant": variant, "build": str(BUILD), "tests": str(ROOT / "tests"),
           "tmp": str(tmp_path), "jobs": jobs}
    try:
        r = subprocess.run([sys.executable, "-c", WORKER, json.dumps(cfg)],
                           capture_output=True, text=True, timeout=TIME_LIMIT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{variant}: the renders did not finish within {TIME_LIMIT} s (a hang?)")
    assert r.returncode == 0, r.stderr[-3000:]
    line = [l for l in r.stdout.splitlines() if l.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


FORCE = {"max_majorant_ratio": 1.0}


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test01_mitsuba_scene_with_a_surface_through_the_medium(variant, tmp_path):
    # scalar_rgb, seed 1 at 64 spp hung before the fix (one path in 147,456)
    seeds = list(range(8)) if variant == "scalar_rgb" else list(range(16))
    spp = 32 if variant == "scalar_rgb" else 64
    jobs = [
        {"kind": "mitsuba", "integrator": "volpathlocal", "max_depth": 2, "args": FORCE,
         "res": 48, "spp": spp, "seeds": seeds},
        {"kind": "mitsuba", "integrator": "volpathlocal", "max_depth": 6, "args": FORCE,
         "res": 48, "spp": spp // 2, "seeds": seeds[:4]},
        # Default settings: the grid padded by 4 voxels of 0 on every side
        # (its local_majorant_ratio: 0.44) is tracked without forcing it
        {"kind": "mitsuba", "integrator": "volpathlocal", "max_depth": 2, "pad": True,
         "res": 48, "spp": spp, "seeds": seeds},
    ]
    results = run_jobs(variant, jobs, tmp_path)
    for job, res in zip(jobs, results):
        assert res["trips"] == 0, (job, res)
        assert res["tracked"] == 1, (job, res)


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test02_fuzz_surfaces_in_and_around_tracked_media(variant, tmp_path):
    n_scenes = 6 if variant == "scalar_rgb" else 10
    jobs = [{"kind": "fuzz", "scene_seed": s, "integrator": "volpathlocal",
             "max_depth": [3, 8, 64][s % 3], "args": FORCE, "res": 24,
             "spp": 16 if variant == "scalar_rgb" else 64, "seeds": [s, s + 100]}
            for s in range(n_scenes)]
    for job, res in zip(jobs, run_jobs(variant, jobs, tmp_path)):
        assert res["trips"] == 0, (job, res)
        assert res["tracked"] == 1, (job, res)  # one medium: the cube's and the open surface's


def test03_fuzz_scenes_match_volpath(tmp_path):
    # Two seeds per side, the per-pixel z-test of test_volpathlocal.py
    # (z_scores; |z| < 5 per channel)
    from test_volpathlocal import Z_MAX, z_scores
    variant = "llvm_ad_rgb"
    jobs, ref = [], []
    for s in range(4):
        # (without the open surface: see test04)
        common = {"kind": "fuzz", "scene_seed": s, "max_depth": 64, "res": 24, "spp": 128,
                  "images": True, "open": False}
        jobs.append({**common, "integrator": "volpathlocal", "args": FORCE, "seeds": [1, 2]})
        ref.append({**common, "integrator": "volpath", "seeds": [3, 4]})
    a, b = run_jobs(variant, jobs, tmp_path), run_jobs(variant, ref, tmp_path)
    for s, (ra, rb) in enumerate(zip(a, b)):
        assert ra["trips"] == 0
        ia, ib = np.array(ra["means"]), np.array(rb["means"])
        z = z_scores(ia, ib)
        print(f"scene {s}: volpathlocal {ia.mean(axis=(0, 1, 2))}, volpath "
              f"{ib.mean(axis=(0, 1, 2))}, z {np.round(z, 2)}")
        assert np.all(np.abs(z) < Z_MAX), (s, z)


@pytest.mark.parametrize("plugin", ["nanovdbvolume", "gridvolume"])
def test04_unenclosed_medium_sees_the_sky(variants_rgb, tmp_path, plugin):
    # An orthographic camera looks down through an open rectangle that
    # carries a heterogeneous medium whose box lies elsewhere (above the
    # rectangle): every path crosses the rectangle into the medium, never
    # enters its box and meets nothing: each pixel is the sky, 0.7
    import mitsuba as mi
    import mitsuba_media_scenes as ms
    T = mi.ScalarTransform4f
    med = {"type": "heterogeneous", "scale": 3.0, "albedo": 0.8,
           "sigma_t": ms.grid_volume(ms.sigmat_values(), plugin)}
    for ratio, tracked in [(1.0, plugin == "nanovdbvolume"), (0.0, False)]:
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "volpathlocal", "max_majorant_ratio": ratio},
            "sensor": {"type": "orthographic",
                       "to_world": T().look_at(origin=[0, 3, 0], target=[0, 0, 0], up=[0, 0, 1]),
                       "film": {"type": "hdrfilm", "width": 8, "height": 8,
                                "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": 16}},
            "sky": {"type": "constant", "radiance": 0.7},
            "open": {"type": "rectangle", "bsdf": {"type": "null"}, "interior": med,
                     "to_world": T().translate([0, -1.1, 0]).rotate([1, 0, 0], -90).scale(2.0)},
        })
        img = np.array(mi.render(scene), dtype=np.float64)
        assert np.allclose(img, 0.7, rtol=1e-5), (ratio, img.min(), img.max())
        from test_volpathlocal import tracked_media
        assert tracked_media(scene) == int(tracked)
