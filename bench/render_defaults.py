"""nanovdb-render's defaults against what they say (issue 33): for each file
in the shared data folder that the command renders, the density scale it
picks, the mean optical depth across the box that this scale really gives,
and how the camera frames the volume.

    nice -n 5 python3 bench/render_defaults.py --label after \\
        --json bench/results/render_defaults_after.json [--images DIR]
    python3 bench/render_defaults.py --report bench/results/render_defaults.md \\
        --before bench/results/render_defaults_before.json \\
        --after bench/results/render_defaults_after.json \\
        --mean8 bench/results/render_defaults_mean8.json

before: the package of d32da2e (--package, see --help); mean8: a run with
scene.default_scale made 8 / (the density's real mean x the box's mean
extent), the rule not taken (the report says why).

Each file is measured in a child process of its own (bench/harness.py).
What the command picks: render_file() itself runs (python/nanovdb_mitsuba/
render.py, no flags) up to its first mi.render() call, which stops it;
framed_scene's result (scale, camera, the loaded volume) and the mean
optical depth it prints are kept; nothing is rendered.

The mean optical depth across the box, along axis a: the mean, over the
lines parallel to axis a through the volume's world box (the medium's box),
of scale x the integral of the density along the line = scale x rho x L_a,
where rho is the density's mean over the box and L_a the box's extent. The
figure compared with the rule's claim is its average over the three axes,
scale x rho x (L_x + L_y + L_z) / 3. rho two ways, neither through the rule:
  - lookups: the exact mean of the trilinear density the renderer sees: the
    plugin's eval() at the midpoints of a lattice of 2 x dims cells per axis
    (each half-voxel cell lies inside one trilinear piece, so the midpoint
    rule is exact there); a coarser lattice where that exceeds --max-points,
    said in the row;
  - dense: numpy's mean of `vdb2nvdb --dense` (OpenVDB's reader, vdb2nvdb's
    level set -> fog conversion, the voxels of the active box), for .vdb
    files; it differs from the lookups by the half-voxel layer at the box's
    faces, where the trilinear density falls towards the outside.

The framing: an optical-depth image at --res x --res from the command's
camera: per pixel, scale x the density integrated along the ray through the
box (the plugin's lookups at the midpoints of --steps equal steps). A pixel
is covered where the volume takes at least 5 % of the light (optical depth
> 0.0513). Reported: the covered share of the pixels, and the share of the
image's width and height between the outermost covered columns (rows); and
for comparison the width share of the box's 8 projected corners.
"""
import argparse
import contextlib
import io
import json
import math
import os
import re
import struct
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

VISIBLE_DEPTH = -math.log(0.95)  # 5 % of the light taken


class _Captured(Exception):
    pass


def command_choice(path):
    """What `nanovdb-render path` picks: (info of framed_scene, its volume,
    seconds framed_scene took), or (None, the command's message). The
    command runs up to its first mi.render() call, which stops it."""
    import mitsuba as mi
    from nanovdb_mitsuba import render
    got = {}
    real, real_render = render.framed_scene, mi.render

    def keep(mi_, *args, **kw):
        t0 = time.perf_counter()
        scene, info = real(mi_, *args, **kw)
        got.update(info=dict(info), volume=kw.get("volume"), seconds=time.perf_counter() - t0)
        return scene, info

    def stop(*args, **kw):
        raise _Captured()

    render.framed_scene, mi.render = keep, stop
    printed = io.StringIO()
    try:
        with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(printed):
            render.render_file(path, os.path.join(tmp, "x.png"), res=8, spp=1)
    except _Captured:
        m = re.search(r"mean optical depth across the box ([0-9.e+-]+)", printed.getvalue())
        got["info"]["printed_depth"] = float(m.group(1)) if m else None
        return got["info"], got["volume"], got["seconds"]
    except SystemExit as e:
        return None, str(e)
    except RuntimeError as e:
        return None, str(e).strip().splitlines()[-1]
    finally:
        render.framed_scene, mi.render = real, real_render
    return None, "rendered without calling mi.render (?)"


def eval_points(mi, volume, pts):
    """The volume's eval() at world points (numpy (n, 3)), averaged over its
    channels, in chunks: numpy (n,)"""
    import numpy as np
    import drjit as dr
    out = np.empty(len(pts))
    chunk = 1 << 22
    for s in range(0, len(pts), chunk):
        p = pts[s:s + chunk]
        it = dr.zeros(mi.Interaction3f, len(p))
        it.p = mi.Point3f(p[:, 0].astype(np.float32), p[:, 1].astype(np.float32),
                          p[:, 2].astype(np.float32))
        v = volume.eval(it)
        acc = v[0]
        for c in range(1, len(v)):
            acc = acc + v[c]
        out[s:s + chunk] = np.array(acc / len(v), dtype=np.float64)
    return out


def lookup_mean(mi, volume, lo, hi, dims, max_points):
    """(mean of the trilinear density over the box, lattice shape)"""
    import numpy as np
    n = [2 * d for d in dims]
    total = float(np.prod([float(x) for x in n]))
    if total > max_points:
        f = (max_points / total) ** (1.0 / 3.0)
        n = [max(1, int(x * f)) for x in n]
    axes = [lo[k] + (np.arange(n[k]) + 0.5) / n[k] * (hi[k] - lo[k]) for k in range(3)]
    # one z slab at a time (the lattice may not fit at once)
    total, count = 0.0, 0
    xs, ys = np.meshgrid(axes[0], axes[1], indexing="ij")
    for z in axes[2]:
        pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)
        total += eval_points(mi, volume, pts).sum()
        count += len(pts)
    return total / count, n


def dense_mean(path, grid):
    """numpy's mean of vdb2nvdb --dense of `path`'s grid (.vdb only), and
    the dense box's dimensions"""
    import numpy as np
    from nanovdb_mitsuba import vdb2nvdb
    with tempfile.TemporaryDirectory() as tmp:
        args = [vdb2nvdb(), path, os.path.join(tmp, "g.nvdb"), "--dense",
                os.path.join(tmp, "g.vol"), "--verify", "0", "--quiet"]
        if grid:
            args += ["--grid", grid]
        p = subprocess.run(args, capture_output=True, text=True)
        if p.returncode != 0:
            return None, (p.stderr.strip().splitlines() or ["?"])[-1]
        with open(os.path.join(tmp, "g.vol"), "rb") as f:
            head = f.read(48)
            assert head[:4] == b"VOL\x03", head[:4]
            enc, nx, ny, nz, ch = struct.unpack("<5i", head[4:24])
            assert enc == 1, enc
            data = np.fromfile(f, dtype=np.float32)
    assert data.size == nx * ny * nz * ch, (data.size, nx, ny, nz, ch)
    return float(data.astype(np.float64).mean()), [nx, ny, nz]


def depth_image(mi, volume, cam, lo, hi, scale, res, steps):
    """Optical depth per pixel (numpy (res, res), row 0 at the top)"""
    import numpy as np
    o = np.array(cam["origin"], dtype=np.float64)
    w = np.array(cam["target"], dtype=np.float64) - o
    w /= np.linalg.norm(w)
    u = np.cross(w, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(u, w)
    t = math.tan(math.radians(cam["fov"]) / 2)
    px = (np.arange(res) + 0.5) / res * 2 - 1
    X, Y = np.meshgrid(px, -px, indexing="xy")  # Y: +1 at the top row
    d = w[None, :] + (X.ravel()[:, None] * u[None, :] + Y.ravel()[:, None] * v[None, :]) * t
    d /= np.linalg.norm(d, axis=1)[:, None]
    # the ray's segment inside the box (slabs)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (np.array(lo)[None, :] - o[None, :]) * inv
        t1 = (np.array(hi)[None, :] - o[None, :]) * inv
    tn = np.nanmax(np.minimum(t0, t1), axis=1)
    tf = np.nanmin(np.maximum(t0, t1), axis=1)
    hit = tf > np.maximum(tn, 0.0)
    tn = np.maximum(tn, 0.0)
    depth = np.zeros(res * res)
    idx = np.nonzero(hit)[0]
    if len(idx):
        s = (np.arange(steps) + 0.5) / steps
        ts = tn[idx, None] + s[None, :] * (tf - tn)[idx, None]
        pts = o[None, None, :] + ts[:, :, None] * d[idx, None, :]
        vals = eval_points(mi, volume, pts.reshape(-1, 3)).reshape(len(idx), steps)
        depth[idx] = scale * vals.sum(axis=1) * (tf - tn)[idx] / steps
    return depth.reshape(res, res)


def box_width_share(cam, lo, hi):
    from nanovdb_mitsuba.scene import _project
    xs = []
    for i in range(8):
        q = _project([hi[k] if (i >> k) & 1 else lo[k] for k in range(3)], cam["origin"],
                     cam["target"], cam["fov"])
        xs.append(q[0] if q else float("nan"))
    return (max(xs) - min(xs)) / 2


def measure(mi, path, args):
    import numpy as np
    from nanovdb_mitsuba import volume_facts
    row = {"file": os.path.basename(path)}
    got = command_choice(path)
    if got[0] is None:
        row["not_rendered"] = got[1]
        return row
    info, volume, seconds = got
    facts = volume_facts(volume)
    lo, hi = info["bbox_min"], info["bbox_max"]
    L = [hi[k] - lo[k] for k in range(3)]
    scale = float(info["scale"])
    from nanovdb_mitsuba import files
    grid = files.volume_properties(volume, path).get("grid") or ""
    row.update(scale=scale, scene_seconds=seconds, grid=grid,
               printed_depth=info.get("printed_depth"),
               dims=facts["index_dims"], extent=L, max=facts["max"],
               majorant_ratio=facts["local_majorant_ratio"])
    if facts["max"] == 0:
        row["empty"] = True
        return row
    t0 = time.perf_counter()
    rho, lattice = lookup_mean(mi, volume, lo, hi, facts["index_dims"], args.max_points)
    row.update(rho_lookups=rho, lattice=lattice, lookup_seconds=time.perf_counter() - t0)
    row["depth_axes"] = [scale * rho * L[k] for k in range(3)]
    row["depth"] = scale * rho * sum(L) / 3
    if path.endswith(".vdb"):
        rho_d, dims_d = dense_mean(path, grid)
        if rho_d is None:
            row["dense_why"] = dims_d
        else:
            row.update(rho_dense=rho_d, dense_dims=dims_d, depth_dense=scale * rho_d * sum(L) / 3)
    img = depth_image(mi, volume, info["camera"], lo, hi, scale, args.res, args.steps)
    covered = img > VISIBLE_DEPTH
    row["covered"] = float(covered.mean())
    cols, rows = np.nonzero(covered.any(axis=0))[0], np.nonzero(covered.any(axis=1))[0]
    row["width"] = float((cols.max() - cols.min() + 1) / args.res) if len(cols) else 0.0
    row["height"] = float((rows.max() - rows.min() + 1) / args.res) if len(rows) else 0.0
    row["edge_touched"] = bool(covered[0].any() or covered[-1].any() or covered[:, 0].any()
                               or covered[:, -1].any())
    row["box_width"] = box_width_share(info["camera"], lo, hi)
    if args.images:
        os.makedirs(args.images, exist_ok=True)
        b = mi.Bitmap(np.exp(-img).astype(np.float32))
        b.convert(mi.Bitmap.PixelFormat.Y, mi.Struct.Type.UInt8, srgb_gamma=True).write(
            os.path.join(args.images, f"{os.path.splitext(row['file'])[0]}_{args.label}.png"))
    return row


def measure_child(spec):
    """One file in a child process of its own (bench/harness.py): the
    package measured (--package) first on the path, then Mitsuba and its
    plugins as that package sets them up."""
    sys.path.insert(0, spec["package"])
    import mitsuba as mi
    mi.set_variant(spec["variant"])
    import nanovdb_mitsuba
    nanovdb_mitsuba.setup(mi)
    t0 = time.perf_counter()
    row = measure(mi, spec["path"], argparse.Namespace(**spec["args"]))
    row["seconds"] = time.perf_counter() - t0
    return row


def run(args):
    import harness
    paths = sorted(os.path.join(args.data, f) for f in os.listdir(args.data)
                   if f.endswith((".vdb", ".nvdb")))
    rows = []
    keys = ("res", "steps", "max_points", "images", "label")
    for p in paths:
        row = harness.run_child("render_defaults:measure_child",
                                {"path": p, "variant": args.variant,
                                 "package": os.path.abspath(args.package),
                                 "args": {k: getattr(args, k) for k in keys}})
        print(json.dumps(row), flush=True)
        rows.append(row)
    with open(args.json, "w") as f:
        json.dump({"label": args.label, "variant": args.variant, "res": args.res,
                   "steps": args.steps, "rows": rows}, f, indent=1)


def pct(x):
    return f"{100 * x:.0f} %"


def report(args):
    """The report: --after (this code), --before (d32da2e's, whose scales
    must be the same) and --mean8 (a run of the rejected rule, an exact mean
    of 8 across the box)"""
    runs = {}
    for key in ("before", "after", "mean8"):
        with open(getattr(args, key)) as f:
            runs[key] = json.load(f)
    before, after, mean8 = ({r["file"]: r for r in runs[k]["rows"]}
                            for k in ("before", "after", "mean8"))
    same = all(before[f].get("scale") == after[f].get("scale") for f in after)
    lines = [
        "# nanovdb-render's default scale and framing, measured (issue 33)",
        "",
        f"Made by `bench/render_defaults.py` ({runs['after']['variant']}; depth images "
        f"{runs['after']['res']}², {runs['after']['steps']} steps per ray; definitions in its "
        "docstring) on every .vdb/.nvdb in `../shared/data` that `nanovdb-render` renders.",
        "",
        "- **scale**: the default, `8 / (mean per-node density bound × mean extent)` "
        "(`scene.default_scale`); " + ("the same before (d32da2e) and after." if same else
                                       "**differs** from d32da2e's!"),
        "- **real depth**: the mean optical depth across the box that this scale gives: "
        "scale × the density's mean over the box × the box's mean extent (the mean over "
        "lines parallel to an axis, averaged over the three axes), the mean from the "
        "plugin's lookups (exact trilinear mean) and from numpy on `vdb2nvdb --dense` (.vdb "
        "files). Before, the command printed \"mean optical depth ~8\" for every file; "
        "after, it prints this number (**printed**).",
        "- **x, y, z**: the real depth along each axis.",
        "- **framing** (the camera is unchanged): **covered**, the pixels where the volume "
        "takes ≥ 5 % of the light; **width**/**height**, the span of the covered "
        "columns/rows; **box**, the width of the box's 8 projected corners (the camera "
        "puts them within 85 % of the frame's half-width and half-height).",
        "",
        "| file | scale | real depth (dense) | printed | x, y, z | covered | width | height "
        "| box width |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for name in sorted(after):
        a = after[name]
        if "not_rendered" in a:
            notes.append(f"- {name}: not rendered: {a['not_rendered']}")
            continue
        if a.get("empty"):
            notes.append(f"- {name}: an empty grid; scale {a['scale']:g}, printed depth "
                         f"{a['printed_depth']:g}")
            continue
        dense = f" ({a['depth_dense']:.3f})" if "depth_dense" in a else ""
        axes = ", ".join(f"{d:.2f}" for d in a["depth_axes"])
        lines.append(
            f"| {name} | {a['scale']:.4g} | {a['depth']:.3f}{dense} | {a['printed_depth']:g} | "
            f"{axes} | {pct(a['covered'])} | {pct(a['width'])} | {pct(a['height'])} | "
            f"{pct(a['box_width'])} |")
        if a["lattice"] != [2 * d for d in a["dims"]]:
            notes.append(f"- {name}: the reference lattice is {a['lattice']} (index box "
                         f"{a['dims']}): a midpoint estimate, not exact")
    lines += ["", *notes, "",
              "## The rule not taken: a scale for a real mean of 8",
              "",
              "Making the old words true (scale = 8 / (the density's real mean × mean "
              "extent)) gives these scales and framings. It makes sparse volumes dense "
              "where they have density: the fire in usd_density_heat_fog is buried in its "
              "smoke (tests/test_render_fire.py test04 and test07 fail with it), and the "
              "zeno particles become opaque blots. So the rule stays and the command "
              "prints the depth it really gives.",
              "",
              "| file | scale now → for a mean of 8 | covered now → then | time of the "
              "mean (whole lattice) |",
              "|---|---|---|---|"]
    for name in sorted(mean8):
        m, a = mean8[name], after[name]
        if "depth" not in m:
            continue
        lines.append(f"| {name} | {a['scale']:.4g} → {m['scale']:.4g} | {pct(a['covered'])} → "
                     f"{pct(m['covered'])} | {m['scene_seconds']:.2f} s |")
    lines.append("")
    with open(args.report_out, "w") as f:
        f.write("\n".join(lines))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=os.path.join(os.path.dirname(ROOT), "shared", "data"))
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--steps", type=int, default=256)
    ap.add_argument("--max-points", type=float, default=float(1 << 26))
    ap.add_argument("--package", default=os.path.join(ROOT, "python"),
                    help="the folder holding the nanovdb_mitsuba to measure (before: "
                         "`git archive d32da2e python | tar -x -C DIR`, then DIR/python, "
                         "with NVDB_BUILD_DIR=build)")
    ap.add_argument("--label", default="after")
    ap.add_argument("--json", default=None)
    ap.add_argument("--images", default=None, help="write exp(-depth) images here")
    ap.add_argument("--report", dest="report_out", default=None)
    ap.add_argument("--before", default=None)
    ap.add_argument("--after", default=None)
    ap.add_argument("--mean8", default=None)
    args = ap.parse_args()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # (bench/: harness)
    if args.report_out:
        report(args)
    else:
        args.json = args.json or os.path.join(ROOT, "bench", "results",
                                              f"render_defaults_{args.label}.json")
        run(args)


if __name__ == "__main__":
    main()
