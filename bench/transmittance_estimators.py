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


def block_segments(density, segs, block, blocks_max, blocks_mean, blocks_min, scale,
                   lookup=None):
    """The ray's walk: per block crossed, (block, length, majorant, mean,
    minimum, [(start, length, sigma) of its voxels], sigma(x) at offsets x
    into the block). lookup(t) (t: distances along the ray): the filter's
    density there; None: nearest (the voxel's)"""
    out = []
    t0 = 0.0
    for ijk, length in segs:
        b = tuple(ijk // block)
        sigma = scale * density[tuple(ijk)]
        if out and out[-1][0] == b:
            out[-1][5].append((out[-1][1], length, sigma))
            out[-1][1] += length
        else:
            out.append([b, length, scale * blocks_max[b], scale * blocks_mean[b],
                        scale * blocks_min[b], [(0.0, length, sigma)], t0])
        t0 += length
    for e in out:
        voxels, start = e[5], e[6]
        e[6] = ((lambda x, v=voxels: sigma_at(v, x)) if lookup is None else
                (lambda x, s0=start: scale * lookup(s0 + x)))
    return out


def stochastic_trilinear(density, origin, direction, h, rng):
    """lookup(t) of the stochastic trilinear filter along a ray: one voxel
    per lookup, picked with the trilinear weights (each axis: the upper
    neighbour with the fractional part's probability); 0 outside"""
    dims = np.array(density.shape)

    def lookup(t):
        q = (np.asarray(origin)[None, :] + np.asarray(t)[:, None] * direction[None, :]) / h - 0.5
        base = np.floor(q)
        ijk = (base + (rng.random(q.shape) < q - base)).astype(int)
        inside = np.all((ijk >= 0) & (ijk < dims), axis=1)
        v = np.zeros(len(ijk))
        v[inside] = density[tuple(ijk[inside].T)]
        return v
    return lookup


def trilinear_depth(density, origin, direction, h, length, scale, steps_per_voxel=8):
    """The optical depth the stochastic trilinear filter has in expectation:
    the trilinear density (0 outside) integrated by the midpoint rule"""
    dims = np.array(density.shape)
    n = max(1, int(math.ceil(length / h * steps_per_voxel)))
    t = (np.arange(n) + 0.5) * (length / n)
    q = (np.asarray(origin)[None, :] + t[:, None] * direction[None, :]) / h - 0.5
    base = np.floor(q).astype(int)
    f = q - base
    acc = np.zeros(n)
    for c in range(8):
        o = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1])
        ijk = base + o
        wgt = np.prod(np.where(o == 1, f, 1 - f), axis=1)
        inside = np.all((ijk >= 0) & (ijk < dims), axis=1)
        v = np.zeros(n)
        v[inside] = density[tuple(ijk[inside].T)]
        acc += wgt * v
    return scale * acc.sum() * (length / n)


def block_bounds(density, block, reach):
    """Per block: (max, mean, min) over the values a lookup in it can
    return: its voxels, and `reach` voxels around them (0 beyond the
    volume), as the walk's majorants take the filter's footprint"""
    dims = np.array(density.shape)
    nb = -(-dims // block)
    pad = np.zeros(nb * block + 2 * reach)
    pad[reach:reach + dims[0], reach:reach + dims[1], reach:reach + dims[2]] = density
    w = np.lib.stride_tricks.sliding_window_view(pad, (block + 2 * reach,) * 3)
    w = w[::block, ::block, ::block][:nb[0], :nb[1], :nb[2]]
    inner = pad[reach:reach + nb[0] * block, reach:reach + nb[1] * block,
                reach:reach + nb[2] * block]
    inner = inner.reshape(nb[0], block, nb[1], block, nb[2], block).mean(axis=(1, 3, 5))
    return w.max(axis=(3, 4, 5)), inner, w.min(axis=(3, 4, 5))


def sigma_at(voxels, x):
    """sigma at offsets x (array) inside a block's segment (nearest)"""
    starts = np.array([v[0] for v in voxels])
    sig = np.array([v[2] for v in voxels])
    return sig[np.searchsorted(starts, x, side="right") - 1]


def tracking(rng, segs, n, control):
    """n ratio-tracking estimates of the residual sigma - control against
    max |sigma - control| per block; control None: plain ratio tracking
    against the block majorant. Returns (estimates, lookups per estimate)."""
    w = np.ones(n)
    lookups = 0
    for _, length, mu, mean, mn, _voxels, sigma_of in segs:
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
            r = sigma_of(x) - c
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
    for _, length, mu, mean, mn, _voxels, sigma_of in segs:
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
                sig = sigma_of(x[live])
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
    ap.add_argument("--filter", choices=["nearest", "stochastic_trilinear"], default="nearest",
                    help="the lookups (stochastic_trilinear: one voxel per lookup, the bounds "
                    "over each block and its 1-voxel rim)")
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
    stochastic = a.filter == "stochastic_trilinear"
    bmax, bmean, bmin = block_bounds(density, B, 1 if stochastic else 0)
    rng = np.random.default_rng(a.seed)

    def walk(origin, d):
        lookup = stochastic_trilinear(density, origin, d, h, rng) if stochastic else None
        return block_segments(density, voxel_segments(density, origin, d, h), B,
                              bmax, bmean, bmin, a.scale, lookup)
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
        segs = walk(origin, sun)
        tau = sum(v[1] * v[2] for s in segs for v in s[5])
        if stochastic:
            tau = trilinear_depth(density, origin, sun, h, sum(s[1] for s in segs), a.scale)
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
        segs = walk(origin, d)
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
        f"--rays {a.rays} --samples {a.samples} --block {B} --filter {a.filter}` ({seconds:.0f} s). "
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
