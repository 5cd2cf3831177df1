"""Which transmittance estimator for volpathlocal's shadow rays (issue 34):
a numpy model of the estimators on the real smoke's shadow rays, before any
of them is written in C++. Measures, per estimator, the variance of one
estimate of T on the same rays and its cost in density lookups, so that
they are chosen by efficiency (1 / (variance x lookups)), not by name.

    python3 bench/transmittance_estimators.py [--vol smoke.vol] [--scale 40]
        [--rays 400] [--samples 512] [--block 8] [--out bench/results/transmittance_estimators.md]

The model: the dense .vol of a volume (`vdb2nvdb FILE.vdb X.nvdb --dense
X.vol`; default: the shared smoke, converted into /tmp) in the unit cube's
box as the benchmark scene places it (bench/scene.py: the active box
scaled into the unit cube, its long axis 1), density = scale x the voxel's
value, read with the nearest filter (piecewise constant: each ray's exact
optical depth is a sum over the voxels it crosses). The walk's cells are
the blocks of block^3 voxels (8: the leaves), each with its majorant (the
block's largest value) and, for the control-variate estimators, its mean.
Shadow rays start at points drawn in proportion to the density (where
real paths scatter) and leave the box towards the benchmark's sun
(direction (0.3, 1, 0.2), normalized).

Estimators of T = exp(-tau) along one ray, each unbiased:
  ratio      ratio tracking (volpathlocal today): tentative collisions at
             rate mu_b in each block b, weight prod (1 - sigma / mu_b)
  residual   residual ratio tracking (Novak et al. 2014) with the block's
             mean as the control: exp(-sum sigma_c l) x ratio tracking of
             sigma - sigma_c against mu_r = max |sigma - sigma_c| per block
  residual_min  the same with the block's minimum as the control (a
             minorant: the residual is >= 0, weights in [0, 1])
  ratio_x2   two ratio-tracking estimates averaged (the cost reference)
Cost: the density lookups (tentative collisions) of one estimate.

And free flights (the path's distance to its next collision), from
density-weighted points in isotropic directions: delta tracking against
the block majorant (volpathlocal today) and decomposition tracking (Kutz
et al. 2017) with the block's minimum as the control, whose collisions
need no lookup. Both sample the same distances; the table compares their
lookups and checks that escape probability and mean distance agree.
"""
import argparse
import math
import os
import struct
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def read_vol(path):
    data = open(path, "rb").read()
    assert data[:3] == b"VOL" and data[3] == 3
    _, nx, ny, nz, ch = struct.unpack_from("<5i", data, 4)
    v = np.frombuffer(data, np.float32, nx * ny * nz * ch, 48).reshape(nz, ny, nx, ch)[..., 0]
    return np.ascontiguousarray(v.transpose(2, 1, 0)).astype(np.float64)  # (x, y, z)


def voxel_segments(density, origin, direction, h):
    """(voxel index (3,), length) of every voxel the ray from `origin` (in
    the box [0, dims * h]) crosses until it leaves: Amanatides-Woo."""
    dims = np.array(density.shape)
    p = np.array(origin, float) / h
    d = np.array(direction, float)
    ijk = np.minimum(np.floor(p).astype(int), dims - 1)
    step = np.where(d > 0, 1, -1)
    with np.errstate(divide="ignore"):
        t_delta = np.where(d != 0, np.abs(1.0 / d), np.inf)
        nxt = np.where(d > 0, ijk + 1 - p, p - ijk)
        t_max = np.where(d != 0, nxt * t_delta, np.inf)
    t = 0.0
    out = []
    while np.all(ijk >= 0) and np.all(ijk < dims):
        a = int(np.argmin(t_max))
        t_next = t_max[a]
        out.append((ijk.copy(), (t_next - t) * h))
        t = t_next
        ijk[a] += step[a]
        t_max[a] += t_delta[a]
    return out


def block_segments(density, segs, block, blocks_max, blocks_mean, blocks_min, scale):
    """The ray's walk: per block crossed, (length, majorant, mean, minimum,
    [(start, length, sigma) of its voxels])"""
    out = []
    for ijk, length in segs:
        b = tuple(ijk // block)
        sigma = scale * density[tuple(ijk)]
        if out and out[-1][0] == b:
            out[-1][5].append((out[-1][1], length, sigma))
            out[-1][1] += length
        else:
            out.append([b, length, scale * blocks_max[b], scale * blocks_mean[b],
                        scale * blocks_min[b], [(0.0, length, sigma)]])
    return out


def sigma_at(voxels, x):
    """sigma at offsets x (array) inside a block's segment"""
    starts = np.array([v[0] for v in voxels])
    sig = np.array([v[2] for v in voxels])
    return sig[np.searchsorted(starts, x, side="right") - 1]


def tracking(rng, segs, n, control):
    """n ratio-tracking estimates of the residual sigma - control against
    max |sigma - control| per block; control None: plain ratio tracking
    against the block majorant. Returns (estimates, lookups per estimate)."""
    w = np.ones(n)
    lookups = 0
    for _, length, mu, mean, mn, voxels in segs:
        c = 0.0 if control is None else (mean if control == "mean" else mn)
        # the residual's majorant per block (the node's, as a table would
        # hold it, not the ray's): the block's largest |sigma - c|
        mu_r = mu if control is None else max(mu - c, c - mn)
        if control is not None:
            w *= math.exp(-c * length)
        if mu_r <= 0:
            continue
        k = rng.poisson(mu_r * length, n)
        lookups += int(k.sum())
        for m in range(1, int(k.max(initial=0)) + 1):
            has = k >= m
            x = rng.random(int(has.sum())) * length
            r = sigma_at(voxels, x) - c
            w[has] *= 1.0 - r / mu_r
    return w, lookups / n


def flights(rng, segs, n, decomposed):
    """n free flights along a ray's blocks: delta tracking against the block
    majorant, or decomposition tracking (Kutz et al. 2017) with the block's
    minimum as the control: its collisions sampled analytically, only the
    residual (sigma - min, bounded by max - min) tracked with lookups. The
    two sample the same distance distribution; they differ in lookups.
    Returns (distance, or inf where the flight leaves; lookups per flight)."""
    dist = np.full(n, np.inf)
    lookups = np.zeros(n)
    alive = np.ones(n, bool)
    t0 = 0.0
    for _, length, mu, mean, mn, voxels in segs:
        if not alive.any():
            break
        idx = np.nonzero(alive)[0]
        c = mn if decomposed else 0.0
        rate = (mu - mn) if decomposed else mu
        # the control's collision in this block (memoryless: drawn afresh)
        xc = rng.exponential(1.0, idx.size) / c if c > 0 else np.full(idx.size, np.inf)
        k = rng.poisson(rate * length, idx.size) if rate > 0 else np.zeros(idx.size, int)
        kmax = int(k.max(initial=0))
        xr = np.full(idx.size, np.inf)
        used = np.zeros(idx.size)
        if kmax:
            pts = rng.random((idx.size, kmax)) * length
            pts[np.arange(kmax)[None, :] >= k[:, None]] = np.inf
            pts.sort(axis=1)
            for m in range(kmax):
                x = pts[:, m]
                live = np.isfinite(x) & (x < xc) & ~np.isfinite(xr)
                if not live.any():
                    continue
                used[live] += 1
                sig = sigma_at(voxels, x[live])
                accept = rng.random(int(live.sum())) < (sig - c) / rate
                sel = np.nonzero(live)[0][accept]
                xr[sel] = x[sel]
        hit = np.minimum(xc, xr)
        inside = hit < length
        lookups[idx] += used
        dist[idx[inside]] = t0 + hit[inside]
        alive[idx[inside]] = False
        t0 += length
    return dist, lookups


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vol", default="")
    ap.add_argument("--scale", type=float, default=40.0)
    ap.add_argument("--rays", type=int, default=400)
    ap.add_argument("--samples", type=int, default=512)
    ap.add_argument("--block", type=int, default=8)
    ap.add_argument("--seed", type=int, default=34)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "transmittance_estimators.md"))
    a = ap.parse_args()
    if not a.vol:
        a.vol = "/tmp/nvdb_smoke_dense.vol"
        if not os.path.exists(a.vol):
            smoke = os.path.join(ROOT, "..", "shared", "data", "openvdb_smoke1_fog.vdb")
            subprocess.run([os.path.join(ROOT, "build", "bin", "vdb2nvdb"), smoke,
                            "/tmp/nvdb_smoke_dense.nvdb", "--dense", a.vol], check=True,
                           capture_output=True)
    density = read_vol(a.vol)
    dims = np.array(density.shape)
    h = 1.0 / dims.max()                       # the long axis is 1
    B = a.block
    nb = -(-dims // B)
    pad = np.zeros(nb * B)
    pad[:dims[0], :dims[1], :dims[2]] = density
    blocks = pad.reshape(nb[0], B, nb[1], B, nb[2], B).transpose(0, 2, 4, 1, 3, 5)
    blocks = blocks.reshape(*nb, -1)
    bmax, bmean, bmin = blocks.max(-1), blocks.mean(-1), blocks.min(-1)
    rng = np.random.default_rng(a.seed)
    sun = np.array([0.3, 1.0, 0.2])
    sun /= np.linalg.norm(sun)
    flat = density.ravel() / density.sum()
    estimators = {"ratio": None, "residual": "mean", "residual_min": "min"}
    var = {k: [] for k in list(estimators) + ["ratio_x2"]}
    means = {k: [] for k in estimators}   # per ray, the estimates' mean
    cost = {k: [] for k in var}
    taus = []
    t0 = time.perf_counter()
    for _ in range(a.rays):
        i = rng.choice(flat.size, p=flat)
        ijk = np.array(np.unravel_index(i, density.shape))
        origin = (ijk + rng.random(3)) * h
        segs = block_segments(density, voxel_segments(density, origin, sun, h), B,
                              bmax, bmean, bmin, a.scale)
        tau = sum(v[1] * v[2] for s in segs for v in s[5])
        taus.append(tau)
        for name, control in estimators.items():
            w, lk = tracking(rng, segs, a.samples, control)
            var[name].append(w.var())
            means[name].append(w.mean())
            cost[name].append(lk)
        var["ratio_x2"].append(var["ratio"][-1] / 2)
        cost["ratio_x2"].append(2 * cost["ratio"][-1])
    # Free flights: from density-weighted points in isotropic directions
    # (where paths scatter), delta against decomposition tracking
    ff = {"delta": [], "decomposition": []}
    escape = {"delta": [], "decomposition": []}
    mean_dist = {"delta": [], "decomposition": []}
    for _ in range(a.rays):
        i = rng.choice(flat.size, p=flat)
        ijk = np.array(np.unravel_index(i, density.shape))
        origin = (ijk + rng.random(3)) * h
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        segs = block_segments(density, voxel_segments(density, origin, d, h), B,
                              bmax, bmean, bmin, a.scale)
        for name in ff:
            dist, lk = flights(rng, segs, a.samples, name == "decomposition")
            ff[name].append(lk.mean())
            escape[name].append(np.mean(~np.isfinite(dist)))
            mean_dist[name].append(np.mean(np.where(np.isfinite(dist), dist, 0.0)))
    seconds = time.perf_counter() - t0
    # The image averages over rays: what matters is the mean per-ray
    # variance (E[Var(T | ray)]) and the mean lookups
    V = {k: float(np.mean(v)) for k, v in var.items()}
    C = {k: float(np.mean(c)) for k, c in cost.items()}
    taus = np.array(taus)
    lines = [
        "# Transmittance estimators on the shadow rays of a real volume (bench/transmittance_estimators.py)",
        "",
        f"`python3 bench/transmittance_estimators.py --vol {os.path.basename(a.vol)} --scale {a.scale:g} "
        f"--rays {a.rays} --samples {a.samples} --block {B}` ({seconds:.0f} s). "
        f"Volume {dims[0]}×{dims[1]}×{dims[2]} voxels, blocks of {B}³ (the leaves); "
        f"{a.rays} shadow rays from density-weighted points towards the sun; their optical "
        f"depth: median {np.median(taus):.2f}, 90th percentile {np.percentile(taus, 90):.2f}, "
        f"max {taus.max():.2f}. Per estimator: the mean over the rays of the variance of one "
        "estimate of T, its lookups, and the efficiency against ratio tracking, "
        "(V_ratio × C_ratio) / (V × C): above 1, the estimator reaches equal error in less work.",
        "",
        "Unbiasedness: the estimates' mean over every ray and sample against the mean of "
        "exp(-tau) over the rays (1 if unbiased), with its standard error (from the "
        "per-ray variances).",
        "",
        "| estimator | variance of one estimate | lookups per estimate | variance / ratio's | efficiency vs ratio | mean / exact mean |",
        "|---|---:|---:|---:|---:|---|"]
    for k in var:
        eff = V["ratio"] * C["ratio"] / (V[k] * C[k]) if V[k] > 0 and C[k] > 0 else float("inf")
        exact = float(np.mean(np.exp(-taus)))
        z = (f"{np.mean(means[k]) / exact:.4f} ± "
             f"{math.sqrt(np.sum(var[k]) / a.samples) / len(taus) / exact:.4f}"
             if k in means else "")
        lines.append(f"| {k} | {V[k]:.3g} | {C[k]:.2f} | {V[k] / V['ratio']:.3f} | {eff:.2f} | {z} |")
    lines += [
        "",
        f"Free flights: {a.rays} rays from density-weighted points in isotropic directions, "
        f"{a.samples} flights each; decomposition tracking (control = the block's minimum, "
        "sampled analytically) against delta tracking (volpathlocal today). Both sample the "
        "same distances (the escape probability and the mean distance to a collision must "
        "agree); they differ in lookups.",
        "",
        "| tracking | lookups per flight | lookups / delta's | escape probability | mean distance of a collision (0 where it escapes) |",
        "|---|---:|---:|---:|---:|"]
    for k in ff:
        lines.append(f"| {k} | {np.mean(ff[k]):.2f} | {np.mean(ff[k]) / np.mean(ff['delta']):.3f} | "
                     f"{np.mean(escape[k]):.4f} | {np.mean(mean_dist[k]):.5f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        os.makedirs(os.path.dirname(a.out), exist_ok=True)
        with open(a.out, "w") as f:
            f.write(text)


if __name__ == "__main__":
    sys.exit(main())
