"""The integrator comparison in the report: volpathlocal against volpath.

Three configurations per case (bench/run.py's integrator axis): volpath +
gridvolume (the baseline of the targets), volpath + nanovdbvolume and
volpathlocal + nanovdbvolume, in the benchmark scene (albedo 0.9, sky + sun,
max_depth 64). From the workers' results and sweep points: render time at
equal spp, lookups and walk steps per camera path, error against time, the
issue's targets; CSV rows, PNG plots and the section of REPORT.md. The
hand-written account of missed targets (why, what was tried) is
bench/INTEGRATOR_LOG.md, copied verbatim into the section.
"""
import os

import numpy as np

import metrics
from report_common import (error_time_figure, find, fmt, integrator_of, mark, png_name,
                           save_figure, timing_fields)

HERE = os.path.dirname(os.path.abspath(__file__))
LOG = os.path.join(HERE, "INTEGRATOR_LOG.md")
LOG_HEADER = """# volpathlocal: missed targets

Why a target of the integrator comparison is missed and what was tried, one
entry per finding: date, commit, the command, the numbers (with the load).
`bench/run.py` copies this file verbatim into the section "Integrator" of
`bench/results/REPORT.md`; the measured values themselves are generated.
"""
# (tag, integrator, plugin, label, colour, line style); "grid" is the baseline
CONFIGS = [("grid", "volpath", "gridvolume", "volpath + gridvolume", "tab:orange", "--"),
           ("nano", "volpath", "nanovdbvolume", "volpath + nanovdbvolume", "tab:blue", "-"),
           ("local", "volpathlocal", "nanovdbvolume", "volpathlocal + nanovdbvolume",
            "tab:green", "-")]
LABEL = {c[0]: c[3] for c in CONFIGS}
TARGET_VARIANT = "llvm_ad_rgb"
# The targets: volpathlocal + nanovdbvolume over the baseline's warm
# median at equal spp. Dense constant cubes, where local majorants equal the
# global one, are held against volpath with the same plugin (the walk's
# overhead alone).
TARGET_SPARSE, TARGET_CLOUD, TARGET_DENSE = 0.2, 0.6, 1.10


def target_for(case):
    """(baseline tag, bound) of the issue's target for a case, or None."""
    if case.name.startswith("constant_"):
        return "nano", TARGET_DENSE
    if case.name == "cloud":
        return "grid", TARGET_CLOUD
    if case.name == "cloudfield_400" or case.source != "generated":  # the real smoke
        return "grid", TARGET_SPARSE
    return None


def _configs(results, case, variant, filt):
    return {tag: find(results, case=case, variant=variant, filter=filt, plugin=plugin,
                      integrator=integ) for tag, integ, plugin, *_ in CONFIGS}


def _keys(rows, case_names):
    """(case, variant, filter) of the comparison's cells, in report order."""
    keys = {(r["case"], r["variant"], r["filter"]) for r in rows
            if integrator_of(r) == "volpathlocal"}
    return sorted(keys, key=lambda k: (k[1], case_names.index(k[0]), k[2]))


def time_rows(results, case_names):
    """Per cell: the three configurations' render times at equal spp, their
    ratios, and lookups and walk steps per camera path."""
    rows = []
    for case, variant, filt in _keys(results, case_names):
        rs = _configs(results, case, variant, filt)
        local = rs["local"]
        row = {"case": case, "variant": variant, "filter": filt, "res": local["spec"]["res"],
               "spp": local["spec"]["spp"], "runs": local["spec"]["runs"]}
        for tag, r in rs.items():
            if r is None:
                continue
            row.update(timing_fields(tag, r))
            row[f"{tag}_max"] = r.get("max")
            if "counts" in r:  # lookup_count -> lookup_per_path, walk_step_count, ...
                row.update({f"{tag}_{k[:-len('_count')]}_per_path": v / r["count_paths"]
                            for k, v in r["counts"].items()})
                row[f"{tag}_counted_paths"] = r["count_paths"]
        for a, b in (("local", "grid"), ("local", "nano"), ("nano", "grid")):
            if rs[a] and rs[b]:
                row[f"{a}_over_{b}"] = rs[a]["warm_median_s"] / rs[b]["warm_median_s"]
        if row.get("local_lookup_per_path") and row.get("nano_lookup_per_path"):
            row["lookups_nano_over_local"] = (row["nano_lookup_per_path"]
                                              / row["local_lookup_per_path"])
        rows.append(row)
    return rows


def equal_time_rows(errors, case_names):
    """Per cell: volpathlocal's error at equal time against each volpath
    configuration, and at equal spp against volpath + nanovdbvolume (the
    same volume: a ratio far from 1 at equal spp is a difference of the
    estimators' variance, or a bias)."""
    rows = []
    for case, variant, filt in _keys(errors, case_names):
        by_spp = {tag: {e["spp"]: e for e in errors
                        if (e["case"], e["variant"], e["filter"], e["plugin"], integrator_of(e))
                        == (case, variant, filt, plugin, integ)}
                  for tag, integ, plugin, *_ in CONFIGS}
        pts = {tag: [(e["time_s"], e["rmse"]) for e in es.values()] for tag, es in by_spp.items()}
        row = {"case": case, "variant": variant, "filter": filt}
        for base in ("grid", "nano"):
            m = metrics.error_at_equal_time(pts["local"], pts[base])
            row.update({f"t_{base}_s": m["t"], f"rmse_local_at_t_{base}": m["ea"],
                        f"rmse_{base}": m["eb"], f"ratio_{base}": m["ratio"],
                        f"cost_ratio_{base}": m["cost_ratio"]})
        spp = max(by_spp["local"])
        row["top_spp"] = spp
        for tag in ("grid", "nano", "local"):
            e = by_spp[tag].get(spp)
            row[f"rmse_{tag}_top_spp"] = e["rmse"] if e else None
            row[f"ssim_{tag}_top_spp"] = e["ssim"] if e else None
        n, lo = row["rmse_nano_top_spp"], row["rmse_local_top_spp"]
        row["equal_spp_local_over_nano"] = lo / n if n and lo is not None else None
        rows.append(row)
    return rows


def measured_text(t):
    """What was measured in a cell, in one line (for the targets' misses)."""
    parts = [f"warm median volpathlocal {fmt(t.get('local_median_s'))} s, volpath + grid "
             f"{fmt(t.get('grid_median_s'))} s, volpath + nano {fmt(t.get('nano_median_s'))} s "
             f"({t['res']}² × 8 sensors, {t['spp']} spp)"]
    if t.get("local_lookup_per_path") is not None:
        parts.append(f"per camera path {fmt(t.get('nano_lookup_per_path'), '.1f')} lookups with "
                     f"volpath, {t['local_lookup_per_path']:.1f} with volpathlocal (÷ "
                     f"{fmt(t.get('lookups_nano_over_local'), '.1f')}) + "
                     f"{t['local_walk_step_per_path']:.1f} walk steps")
    parts.append(f"first turntable (JIT compile included) {fmt(t.get('local_first_s'))} s")
    return "; ".join(parts)


def target_rows(trows, case_by_name):
    """The issue's targets on TARGET_VARIANT, one row per cell (cases without
    a target get one, with ok None)."""
    rows = []
    for t in trows:
        if t["variant"] != TARGET_VARIANT:
            continue
        tgt = target_for(case_by_name[t["case"]])
        base = tgt[0] if tgt else "grid"
        value = t.get(f"local_over_{base}")
        ok = None if tgt is None or value is None else value <= tgt[1]
        rows.append({"case": t["case"], "filter": t["filter"],
                     "kind": f"render time volpathlocal / {LABEL[base]} (llvm, warm median, "
                             "equal spp)",
                     "baseline": base, "bound": tgt[1] if tgt else None,
                     "value": value, "target": f"≤ {tgt[1]:.2f}" if tgt else "— (none)",
                     "ok": ok, "measured": measured_text(t)})
    return rows


def summary_lines(trows, tgt):
    """The report's summary: the targets, and the ratios on other variants."""
    L = []
    for g in tgt:
        L.append(f"- volpathlocal, {g['case']} ({g['filter']}, {TARGET_VARIANT}): render time / "
                 f"{LABEL[g['baseline']]} at equal spp {fmt(g['value'], '.2f')} (target "
                 f"{g['target']}) {mark(g['ok'])}.")
    for v in sorted({t["variant"] for t in trows} - {TARGET_VARIANT}):
        rs = [t for t in trows if t["variant"] == v and "local_over_grid" in t]
        if rs:
            L.append(f"- volpathlocal, {v}: render time / volpath + gridvolume at equal spp "
                     + ", ".join(f"{t['case']} ({t['filter']}) {t['local_over_grid']:.2f}"
                                 for t in rs) + ".")
    return L


# ---------------------------------------------------------------------------
# Plots

def plots(out, errors, trows, tgt, case_names, dpi):
    """Error against time with the three curves per case and variant, the
    render time ratios, the lookups and walk steps per path."""
    import matplotlib.pyplot as plt
    files = []
    cells = _keys(errors, case_names)
    for case, variant in sorted({k[:2] for k in cells},
                                key=lambda k: (case_names.index(k[0]), k[1])):
        pts = [e for e in errors if (e["case"], e["variant"], e["filter"]) in cells
               and (e["case"], e["variant"]) == (case, variant)]
        curves = [(label, lambda e, i=integ, p=plugin: (integrator_of(e), e["plugin"]) == (i, p),
                   color, ls, tag == "grid") for tag, integ, plugin, label, color, ls in CONFIGS]
        files.append(error_time_figure(out, png_name("integrator_error_time", case, variant),
                                       pts, curves, f"{case}, {variant}: error against time "
                                       "(labels: spp)", dpi))
    if not trows:
        return files

    # Render time at equal spp, relative to volpath + gridvolume (the line at
    # 1), with the targets on the same scale
    variants = sorted({t["variant"] for t in trows})
    fig, axes = plt.subplots(1, len(variants), figsize=(max(3.0, 0.8 * len(trows) / len(variants)
                                                            + 2.0) * len(variants), 3.2),
                             squeeze=False)
    for j, v in enumerate(variants):
        rows = [t for t in trows if t["variant"] == v]
        x = np.arange(len(rows))
        ax = axes[0, j]
        for tag, marker in (("nano", "o"), ("local", "s")):
            ax.plot(x, [t.get(f"{tag}_over_grid", np.nan) for t in rows], marker, ms=5,
                    label=LABEL[tag], color=next(c[4] for c in CONFIGS if c[0] == tag))
        targets = []
        for t in rows:
            g = next((g for g in tgt if (g["case"], g["filter"], v)
                      == (t["case"], t["filter"], TARGET_VARIANT) and g["bound"]), None)
            scale = 1.0 if g is None or g["baseline"] == "grid" else t.get("nano_over_grid")
            targets.append(g["bound"] * scale if g is not None and scale else np.nan)
        if not np.all(np.isnan(targets)):
            ax.plot(x, targets, "k_", ms=14, mew=1.5, label="target")
        ax.axhline(1.0, color="tab:orange", lw=1, ls="--", label=LABEL["grid"])
        ax.set_yscale("log")
        ax.set_xlim(-0.6, len(rows) - 0.4)
        ax.set_xticks(x, [f"{t['case']}\n{t['filter']}" for t in rows], fontsize=6)
        ax.set_ylabel("render time / volpath + grid (equal spp)")
        ax.set_title(v, fontsize=8)
        ax.grid(True, which="both", axis="y", alpha=0.3)
    handles = {h.get_label(): h for ax in axes[0] for h in ax.get_legend_handles_labels()[0]}
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=4, fontsize=6)
    files.append(save_figure(fig, out, "integrator_render_time.png", dpi,
                             rect=(0, 0.08, 1, 1)))

    # Lookups and walk steps per camera path (the target variant, else the first)
    v = TARGET_VARIANT if any(t["variant"] == TARGET_VARIANT for t in trows) else variants[0]
    rows = [t for t in trows if t["variant"] == v]
    series = [("volpath: lookups", "nano_lookup_per_path", "tab:blue", ""),
              ("volpathlocal: lookups", "local_lookup_per_path", "tab:green", ""),
              ("volpathlocal: walk steps", "local_walk_step_per_path", "tab:olive", "//")]
    fig, ax = plt.subplots(figsize=(max(4.0, 0.9 * len(rows) + 2), 3.0))
    x = np.arange(len(rows))
    for k, (name, key, color, hatch) in enumerate(series):
        ax.bar(x + (k - 1) * 0.27, [t.get(key) or np.nan for t in rows], 0.27, label=name,
               color=color, hatch=hatch)
    ax.set_yscale("log")
    ax.set_xticks(x, [f"{t['case']}\n{t['filter']}" for t in rows], fontsize=6)
    ax.set_ylabel("per camera path")
    ax.set_title(f"{v}: lookups and walk steps per path", fontsize=8)
    ax.legend(fontsize=6)
    files.append(save_figure(fig, out, "integrator_lookups.png", dpi))
    return files


# ---------------------------------------------------------------------------
# REPORT.md

def section(trows, erows, tgt, pngs):
    L = ["## Integrator: volpathlocal against volpath\n"]
    w = L.append
    w("Three configurations in the benchmark scene (scattering medium: albedo 0.9, scale 40; "
      "constant sky + directional sun; `max_depth` 64; the 8-sensor turntable): **volpath + "
      "gridvolume** (the baseline), **volpath + nanovdbvolume** and **volpathlocal + "
      "nanovdbvolume** (`src/integrators/volpathlocal.cpp`: delta and ratio tracking against "
      "per-node majorants, walking the NanoVDB tree). Same scene, seeds and settings as above, a "
      "fresh worker each. **Lookups per path**: `count_lookups` on a render of its own (one "
      "turntable at the timing spp, after the timed ones: counting adds an atomic add per "
      "lookup), `lookup_count` (eval calls, per lane) and `walk_step_count` divided by the "
      "camera paths of that render (pixels × spp × 8 sensors). `gridvolume` cannot count; volpath "
      "tracks against the global majorant `scale × max()` with either plugin, so volpath + "
      "gridvolume makes the lookups of volpath + nanovdbvolume wherever the two `max()` agree "
      "(rows marked † where they do not). volpathlocal's error is measured against volpath's "
      "reference of the same plugin (its expectation is volpath's).\n")
    if not trows:
        w("Not measured in this run (no volpathlocal workers: `--integrators` without it, or no "
          "case of the comparison).\n")
    else:
        L += _targets_lines(tgt)
        L += _time_lines(trows, pngs)
        L += _error_lines(erows, pngs)
    w("### Missed targets: why, and what was tried\n")
    w("The contents of `bench/INTEGRATOR_LOG.md`, verbatim:\n")
    if not os.path.exists(LOG):
        with open(LOG, "w") as f:
            f.write(LOG_HEADER)
    w(open(LOG).read().rstrip("\n"))
    w("")
    return L


def _targets_lines(tgt):
    L = [f"### Targets ({TARGET_VARIANT})\n",
         f"Warm medians at equal spp: volpathlocal + nanovdbvolume ≤ {TARGET_SPARSE} × volpath + "
         f"gridvolume on the real smoke (user files) and `cloudfield_400`, ≤ {TARGET_CLOUD} × on "
         f"the `cloud`; on the dense constant cubes, where local majorants cannot help, ≤ "
         f"{TARGET_DENSE:.2f} × volpath + nanovdbvolume (the walk's overhead).\n"]
    if not tgt:
        return L + [f"No {TARGET_VARIANT} measurements in this run.\n"]
    L += ["| case | filter | volpathlocal over | measured | target | |",
          "|---|---|---|---:|---|:-:|"]
    for g in tgt:
        L.append(f"| {g['case']} | {g['filter']} | {LABEL[g['baseline']]} | "
                 f"{fmt(g['value'])} | {g['target']} | {mark(g['ok'])} |")
    missed = [g for g in tgt if g["ok"] is False]
    if missed:
        L.append("\nMissed, what was measured:\n")
        L += [f"- **{g['case']}** ({g['filter']}): {fmt(g['value'])} × {LABEL[g['baseline']]} "
              f"(target {g['target']}); {g['measured']}." for g in missed]
    L.append("")
    return L


def _time_lines(trows, pngs):
    L = ["### Render time at equal spp, lookups per path\n",
         "Warm medians of the turntable; first: the first turntable of the process (JIT compile "
         "included); lookups and walk steps per camera path as counted (see above; empty: "
         "steps through cells whose bound is 0; the CSV splits the steps by cell size too). "
         "load: the highest 1-min load average at the three workers' starts.\n",
         "| variant | case | filter | grid warm [s] | nano warm [s] | local warm [s] | "
         "**local / grid** | local / nano | nano / grid | local first [s] | local JIT [ms] | "
         "lookups/path volpath | lookups/path local | walk steps/path local (empty) | load |",
         "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for t in trows:
        maxima = (t.get("grid_max"), t.get("nano_max"))
        dagger = " †" if None not in maxima and maxima[0] != maxima[1] else ""
        load = max(t.get(f"{k}_load1") or 0 for k in ("grid", "nano", "local"))
        L.append(f"| {t['variant']} | {t['case']} | {t['filter']} | "
                 f"{fmt(t.get('grid_median_s'))} | {fmt(t.get('nano_median_s'))} | "
                 f"{fmt(t.get('local_median_s'))} | **{fmt(t.get('local_over_grid'))}** | "
                 f"{fmt(t.get('local_over_nano'))} | {fmt(t.get('nano_over_grid'))} | "
                 f"{fmt(t.get('local_first_s'))} | {fmt(t.get('local_jit_ms'), '.0f')} | "
                 f"{fmt(t.get('nano_lookup_per_path'), '.2f')}{dagger} | "
                 f"{fmt(t.get('local_lookup_per_path'), '.2f')} | "
                 f"{fmt(t.get('local_walk_step_per_path'), '.2f')} "
                 f"({fmt(t.get('local_walk_empty_step_per_path'), '.2f')}) | {load:.2f} |")
    for p in ("integrator_render_time.png", "integrator_lookups.png"):
        if p in pngs:
            L.append(f"\n![{p[:-4]}]({p})")
    L.append("")
    return L


def _error_lines(erows, pngs):
    L = ["### Error against run time\n",
         "The spp sweep of each configuration against volpath's converged reference (RMSE minus "
         "the reference's noise; see above). At equal time: interpolated in log-log at the "
         "longest time both sweeps reach, ratio < 1: volpathlocal has the lower error. Cost "
         "ratio: (RMSE² × time) volpathlocal over the other, how many times longer volpathlocal "
         "needs for the same error. At equal spp: RMSE volpathlocal / volpath + nanovdbvolume at "
         "the sweep's highest spp (the estimators' variance; ≫ 1 would also show a bias).\n",
         "| variant | case | filter | at t [s] | RMSE local | RMSE grid | **local / grid** | "
         "cost local / grid | local / nano at equal time | cost local / nano | "
         "local / nano at equal spp (spp) |",
         "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for e in erows:
        L.append(f"| {e['variant']} | {e['case']} | {e['filter']} | {fmt(e['t_grid_s'])} | "
                 f"{fmt(e['rmse_local_at_t_grid'], '.4g')} | {fmt(e['rmse_grid'], '.4g')} | "
                 f"**{fmt(e['ratio_grid'])}** | {fmt(e['cost_ratio_grid'])} | "
                 f"{fmt(e['ratio_nano'])} | {fmt(e['cost_ratio_nano'])} | "
                 f"{fmt(e['equal_spp_local_over_nano'])} ({e['top_spp']}) |")
    L.append("")
    L += [f"![{p[:-4]}]({p})" for p in pngs if p.startswith("integrator_error_time_")]
    L.append("")
    return L
