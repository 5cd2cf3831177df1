"""Helpers shared by the report's modules (bench/report.py and the
comparisons' bench/report_plugins.py, bench/report_integrator.py,
bench/report_cuda.py): number formatting, finding a worker's result, the
integrator of a result, a worker's timing columns, and the error-against-time
figure with its file name and saving.
"""
import os
import textwrap

PLOT_DPI = 80  # small PNGs: they are committed


def mib(b):
    return "—" if b is None else f"{b / 2 ** 20:,.1f}"


def fmt(x, spec=".3f"):
    return "—" if x is None else format(x, spec)


def mark(ok):
    return "—" if ok is None else ("✓" if ok else "✗")


def find(results, **kw):
    for r in results:
        if all(r.get(k) == v for k, v in kw.items()):
            return r
    return None


def integrator_of(r):
    """A result's or sweep point's integrator (results saved before the
    integrator axis existed are all volpath's)."""
    return r.get("integrator", "volpath")


def timing_fields(tag, r):
    """A worker's render times at equal spp, as columns `tag`_... of a row."""
    return {f"{tag}_median_s": r["warm_median_s"], f"{tag}_min_s": r["warm_min_s"],
            f"{tag}_first_s": r["first_s"],
            f"{tag}_jit_ms": (r["jit_codegen_ms"] + r["jit_backend_ms"])
            if "jit_codegen_ms" in r else None,
            f"{tag}_jit_kernels": r.get("jit_kernels"),
            f"{tag}_load1": r["loadavg_start"][0],
            f"{tag}_warm_s": " ".join(f"{t:.4f}" for t in r["warm_s"])}


# ---------------------------------------------------------------------------
# Plots

def png_name(prefix, case, variant):
    return f"{prefix}_{case}_{variant}.png".replace(":", "_").replace("/", "_")


def error_time_figure(out, name, errors, curves, title, dpi):
    """Writes OUT/name, an error-against-time figure of one case and variant:
    a column per filter found in `errors` (that case's and variant's sweep
    points), RMSE on top, 1 − SSIM below, and a curve per (label, match,
    color, line style, spp labels) in `curves`, match(e) picking its points.
    Returns `name`."""
    import matplotlib.pyplot as plt
    filters = [f for f in ("trilinear", "nearest") if any(e["filter"] == f for e in errors)]
    fig, axes = plt.subplots(2, len(filters), figsize=(3.4 * len(filters), 4.8), squeeze=False)
    for j, filt in enumerate(filters):
        for label, match, color, ls, spp_labels in curves:
            pts = sorted((e for e in errors if e["filter"] == filt and match(e)),
                         key=lambda e: e["spp"])
            if not pts:
                continue
            t = [e["time_s"] for e in pts]
            axes[0, j].loglog(t, [e["rmse"] for e in pts], "o" + ls, ms=3, color=color,
                              label=label)
            axes[1, j].loglog(t, [max(1 - e["ssim"], 1e-6) for e in pts], "o" + ls, ms=3,
                              color=color, label=label)
            if spp_labels:
                for e in pts:
                    axes[0, j].annotate(str(e["spp"]), (e["time_s"], e["rmse"]), fontsize=6,
                                        textcoords="offset points", xytext=(3, 3))
        axes[0, j].set_title(f"{filt}")
        axes[0, j].set_ylabel("RMSE vs reference")
        axes[1, j].set_ylabel("1 − SSIM")
        axes[1, j].set_xlabel("render time, 8 sensors [s]")
        axes[0, j].grid(True, which="both", alpha=0.3)
        axes[1, j].grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(textwrap.fill(title, 45 * len(filters)), fontsize=9)  # long case names
    return save_figure(fig, out, name, dpi)


def save_figure(fig, out, name, dpi, rect=None):
    """Lays out, writes and closes a figure as OUT/name; returns `name`."""
    import matplotlib.pyplot as plt
    fig.tight_layout(rect=rect)
    fig.savefig(os.path.join(out, name), dpi=dpi)
    plt.close(fig)
    return name


def write_markdown(path, lines, notes=()):
    """Writes a report's lines to `path`, with its notes (if any) as a list
    at the end."""
    lines = list(lines)
    if notes:
        lines += ["", "Notes:", ""] + [f"- {n}" for n in notes]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
