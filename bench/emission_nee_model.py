"""Which emission distribution to sample for next-event estimation toward
an emissive volume (issue 35): a numpy model on the fire's real values,
before the hierarchy is built.

    python3 bench/emission_nee_model.py --build BUILD   # ~2 min -> bench/results/emission_nee_model.md

It reads the density and temperature of bench/emission.py's fireball
(`vdb2nvdb generate fireball_128`, made by that benchmark into
bench/data/emission/) at every voxel centre of their active box (nearest
lookups through nanovdbvolume, llvm_ad_rgb), with bench/emission.py's
medium: sigma_a = scale x density x (1 - albedo), Le = a blackbody at
value x 1000 K (its luminance: Planck's law against a Gaussian stand-in
for CIE y; below the 100 K cutoff nothing), times emission_scale.

The integrand is the irradiance a receiver p gets from the fire,
    E(p) = sum over voxels of sigma_a Le T(p, x) cos / r^2 x voxel volume,
with x uniform in the voxel, T marched through the density (nearest, 1/2
voxel steps). Receivers: 64 points on bench/emission.py's floor under and
around the fire (cos = the floor's normal), and 64 points inside the smoke
drawn by density outside the hot core (cos = 1: a medium's vertex), where
1/r^2 is largest. Each candidate distribution q draws --samples points per
receiver; the model reports the mean relative variance of f / q (one
sample's variance / E^2, median over receivers) and the table's bytes per
leaf against the temperature grid's.

Candidates (all exact: each estimate is unbiased for its own q):
  voxel       sigma_a Le per voxel, float (the ideal the others approximate)
  block2      the same summed over 2^3 blocks, float; uniform in a block
  block2_q8   block2 quantized to 8 bits per block, relative to its leaf's
              largest block (rounded up, so no emitting block gets 0)
  block2_q4   the same, 4 bits
  block4      4^3 blocks, float
  leaf        one weight per 8^3 leaf, uniform in it
  le_only     block2 weighted by Le alone (no density): what a table that
              reads only the emission grid gives
A measurement, not a test.
"""
import argparse
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SCALE, ALBEDO, T_SCALE, E_SCALE, CUTOFF = 10.0, 0.5, 1000.0, 0.05, 100.0


def planck_luminance(t):
    """Luminance of a blackbody at t kelvin (arbitrary units): Planck's law
    against a Gaussian at 555 nm (sigma 45 nm) for CIE y"""
    lam = np.linspace(380e-9, 780e-9, 81)
    ybar = np.exp(-0.5 * ((lam - 555e-9) / 45e-9) ** 2)
    h, c, k = 6.626e-34, 2.998e8, 1.381e-23
    t = np.maximum(np.asarray(t, dtype=np.float64), 1.0)[..., None]
    b = 2 * h * c * c / lam ** 5 / np.expm1(np.minimum(h * c / (lam * k * t), 700.0))
    return (b * ybar).sum(-1) * (lam[1] - lam[0]) * 1e-6


def load(path, build):
    sys.path.insert(0, HERE)
    from child_setup import mitsuba_for
    _, mi = mitsuba_for("llvm_ad_rgb", build)
    try:
        from nanovdb_mitsuba import volume_facts
    except ImportError:
        sys.path.insert(0, os.path.join(ROOT, "python"))
        from nanovdb_mitsuba import volume_facts
    out = {}
    for g in ("density", "temperature"):
        v = mi.load_dict({"type": "nanovdbvolume", "filename": path, "grid": g,
                          "use_grid_transform": True, "filter_type": "nearest"})
        bb = v.bbox()
        lo, hi = np.array(bb.min, dtype=np.float64), np.array(bb.max, dtype=np.float64)
        f = volume_facts(v)
        dims = np.array(f["index_dims"])
        vs = (hi - lo) / dims
        idx = np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1)
        p = lo + (idx.reshape(-1, 3) + 0.5) * vs
        it = mi.Interaction3f()
        it.p = mi.Point3f(p[:, 0], p[:, 1], p[:, 2])
        val = np.asarray(v.eval_1(it)).reshape(*dims)
        out[g] = val
        out["lo"], out["vs"], out["bytes_" + g] = lo, vs, f["grid_bytes"]
    return out


def block_sums(w, b):
    """Sums over b^3 blocks (the array padded to a multiple of b)"""
    pad = [(0, (-n) % b) for n in w.shape]
    w = np.pad(w, pad)
    s = w.shape
    return w.reshape(s[0] // b, b, s[1] // b, b, s[2] // b, b).sum((1, 3, 5))


def candidates(weight, le_weight):
    """{name: (block size, block weights)}: a piecewise constant density
    over blocks, uniform inside each"""
    c = {"voxel": (1, weight), "block2": (2, block_sums(weight, 2)),
         "block4": (4, block_sums(weight, 4)), "leaf": (8, block_sums(weight, 8)),
         "le_only": (2, block_sums(le_weight, 2))}
    b2 = block_sums(weight, 2)
    leafmax = _spread(_leaf_max(b2), b2.shape)
    for bits in (8, 4):
        levels = (1 << bits) - 1
        q = np.where(b2 > 0, np.ceil(levels * b2 / np.maximum(leafmax, 1e-300)), 0.0)
        # the leaf's weight, spread over its blocks by q (as the table holds it)
        leafsum = _spread(block_sums(b2, 4), b2.shape)
        qsum = _spread(block_sums(q, 4), b2.shape)
        c[f"block2_q{bits}"] = (2, np.where(qsum > 0, leafsum * q / np.maximum(qsum, 1e-300), 0))
    return c


def _leaf_max(b2):
    pad = [(0, (-n) % 4) for n in b2.shape]
    w = np.pad(b2, pad)
    s = w.shape
    return w.reshape(s[0] // 4, 4, s[1] // 4, 4, s[2] // 4, 4).max((1, 3, 5))


def _spread(leafvals, shape):
    r = np.repeat(np.repeat(np.repeat(leafvals, 4, 0), 4, 1), 4, 2)
    return r[:shape[0], :shape[1], :shape[2]]


def transmittance(sig, lo, vs, p, x, steps_per_voxel=2):
    """exp(-int sigma_t) from p to x (arrays [N, 3]), marched at midpoints"""
    d = x - p
    length = np.linalg.norm(d, axis=1)
    n = int(np.ceil(length.max() / vs.min() * steps_per_voxel)) + 1
    tau = np.zeros(len(p))
    for k in range(n):
        q = p + d * ((k + 0.5) / n)
        i = np.floor((q - lo) / vs).astype(np.int64)
        inside = np.all((i >= 0) & (i < np.array(sig.shape)), axis=1)
        i = np.clip(i, 0, np.array(sig.shape) - 1)
        tau += np.where(inside, sig[i[:, 0], i[:, 1], i[:, 2]], 0.0) * length / n
    return np.exp(-tau)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--file", default=os.path.join(HERE, "data", "emission", "fireball_128.nvdb"))
    ap.add_argument("--samples", type=int, default=2048)
    ap.add_argument("--receivers", type=int, default=64)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "emission_nee_model.md"))
    a = ap.parse_args()
    if not os.path.exists(a.file):
        sys.exit(f"{a.file} not found: run bench/emission.py once (it generates the fireball)")
    g = load(a.file, a.build)
    rho, temp, lo, vs = g["density"], g["temperature"], g["lo"], g["vs"]
    sig_t = SCALE * rho
    le = np.where(temp * T_SCALE > CUTOFF, planck_luminance(temp * T_SCALE), 0.0) * E_SCALE
    emit = sig_t * (1 - ALBEDO) * le                 # sigma_a Le per voxel
    vol = float(np.prod(vs))
    rng = np.random.default_rng(1)
    # Receivers: the floor (y = -0.02, bench/emission.py) and the smoke
    floor = np.stack([rng.uniform(-0.25, 1.25, a.receivers), np.full(a.receivers, -0.02),
                      rng.uniform(-0.25, 1.25, a.receivers)], 1)
    cool = (rho > 0.05) & (le == 0)
    flat = np.flatnonzero(cool)
    pick = rng.choice(flat, a.receivers, p=rho.ravel()[flat] / rho.ravel()[flat].sum())
    smoke = lo + (np.stack(np.unravel_index(pick, rho.shape), 1) + rng.random((a.receivers, 3))) * vs
    receivers = {"floor": (floor, np.array([0.0, 1.0, 0.0])), "smoke": (smoke, None)}
    cands = candidates(emit * vol, le * vol)
    leaves = int((block_sums((rho > 0) | (temp > 0), 8) > 0).sum())
    rows = []
    for name, (b, w) in cands.items():
        flatw = w.ravel()
        prob = flatw / flatw.sum()
        cdf = np.cumsum(prob)
        res = {}
        for rname, (pts, normal) in receivers.items():
            rel = []
            for p in pts:
                u = rng.random(a.samples)
                k = np.minimum(np.searchsorted(cdf, u * cdf[-1], side="right"), len(prob) - 1)
                bi = np.stack(np.unravel_index(k, w.shape), 1)
                vox = bi * b + rng.integers(0, b, (a.samples, 3))
                inside = np.all(vox < np.array(emit.shape), 1)
                vox = np.minimum(vox, np.array(emit.shape) - 1)
                x = lo + (vox + rng.random((a.samples, 3))) * vs
                pdf = prob[k] / (vol * b ** 3)               # per unit volume
                d = x - p
                r2 = (d * d).sum(1)
                cos = (d @ normal) / np.sqrt(r2) if normal is not None else 1.0
                f = np.where(inside, emit[vox[:, 0], vox[:, 1], vox[:, 2]], 0.0) \
                    * np.maximum(cos, 0.0) / r2
                live = f > 0
                if live.any():
                    f[live] *= transmittance(sig_t, lo, vs, np.repeat(p[None], live.sum(), 0),
                                             x[live])
                est = f / pdf
                m = est.mean()
                if m > 0:
                    rel.append(est.var() / (m * m))
            res[rname] = (float(np.median(rel)), float(np.percentile(rel, 90)))
        nblocks = (512 // b ** 3) if b < 8 else 1
        bits = {"block2_q8": 8, "block2_q4": 4}.get(name, 32)
        per_leaf = nblocks * bits / 8 + 8     # + the leaf's weight and its CDF entry
        rows.append((name, b, res["floor"], res["smoke"], per_leaf,
                     100 * leaves * per_leaf / g["bytes_temperature"]))
        print(f"{name:10s} floor {res['floor'][0]:.3f} smoke {res['smoke'][0]:.3f} "
              f"{per_leaf:.0f} B/leaf", flush=True)
    ref = {r[0]: r for r in rows}["voxel"]
    L = ["# Which emission distribution to sample: a model (bench/emission_nee_model.py)", "",
         f"`python3 bench/emission_nee_model.py --samples {a.samples} --receivers "
         f"{a.receivers}`: bench/emission.py's fireball ({'x'.join(map(str, rho.shape))} "
         f"voxels, {leaves} leaves with density or temperature, the temperature grid "
         f"{g['bytes_temperature'] / 2**20:.2f} MiB). One sample's relative variance "
         "(median over receivers; lower is better) and its ratio to the per-voxel "
         "ideal; the table's bytes per leaf and their share of the temperature grid's "
         "bytes.", "",
         "| distribution | block | floor: rel. variance, median (/ voxel); 90th percentile | smoke: the same | bytes per leaf | % of the grid |",
         "|---|---:|---|---|---:|---:|"]
    for name, b, fl, sm, pl, pct in rows:
        L.append(f"| {name} | {b}³ | {fl[0]:.3f} ({fl[0] / ref[2][0]:.2f}); {fl[1]:.2f} | "
                 f"{sm[0]:.3f} ({sm[0] / ref[3][0]:.2f}); {sm[1]:.2f} | {pl:.0f} | {pct:.2f} |")
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        f.write("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
