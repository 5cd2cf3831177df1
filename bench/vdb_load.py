"""What a .vdb costs nanovdbvolume at load against the .nvdb that vdb2nvdb
writes of it: load time and peak memory, per grid (issue 22).

    python3 bench/vdb_load.py [--variant llvm_ad_rgb] [--repeat 3] [--out bench/results/vdb_load.md]
        [FILE.vdb ...]          (default: every .vdb of ../shared/data, and a
                                 generated cloud_512 for a grid of some size)

Each load runs in a fresh process (bench/harness.py; so that the peak
resident memory, ru_maxrss, is that load's): Python, Mitsuba and the variant set up, then
mi.load_dict of the volume, evaluated (the grid on the backend). The
baseline is the same process without the load; "peak over baseline" is the
difference. Times are the median of --repeat processes; the .vdb's own
read and conversion times come from the plugin (traverse:
vdb_convert_seconds).
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BUILD = Path(os.environ.get("NVDB_BUILD_DIR", ROOT / "build"))
VDB2NVDB = BUILD / "bin" / "vdb2nvdb"
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "python"))
import harness  # noqa: E402
from nanovdb_mitsuba import files  # noqa: E402

def load_child(spec):
    """In a fresh process (bench/harness.py): Python, Mitsuba and the variant
    set up, then, given a path, mi.load_dict of the volume, evaluated (the
    grid on the backend); the process's peak resident memory at the end."""
    import resource
    import time
    import mitsuba as mi
    mi.set_variant(spec["variant"])
    import nanovdb_mitsuba
    nanovdb_mitsuba.setup(mi)
    import drjit as dr
    out = {"baseline_kb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}
    if spec["path"]:
        t0 = time.perf_counter()
        vol = mi.load_dict({"type": "nanovdbvolume", "filename": spec["path"],
                            "grid": spec["grid"]})
        dr.eval()
        dr.sync_thread()
        out["seconds"] = time.perf_counter() - t0
        p = mi.traverse(vol)
        out["grid_bytes"] = float(p["grid_bytes"])
        out["convert_seconds"] = float(p["vdb_convert_seconds"]) if p["vdb_imported"] else 0.0
        # (since issue 32 the .vdb is read by nanovdb-vdb-reader, a process
        # of its own: its time, start to reply, and its peak)
        out["reader_seconds"] = float(p["vdb_reader_seconds"]) if "vdb_reader_seconds" in p else 0.0
        out["reader_peak_mb"] = float(p["vdb_reader_peak_mb"]) if "vdb_reader_peak_mb" in p else 0.0
    out["peak_kb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return out


def child(variant, path="", grid=""):
    try:
        return harness.run_child("vdb_load:load_child",
                                 {"variant": variant, "path": str(path), "grid": grid})
    except harness.ChildFailed as e:
        lines = e.stderr.strip().splitlines()
        raise RuntimeError(lines[-1] if lines else "failed") from None


def grids_of(vdb):
    """(name, type) of the file's float and vec3s grids, from the plugin's
    own listing (nanovdb_mitsuba.files: structured, not parsed from text)"""
    return [(n, t) for n, t in files.grid_rows(vdb) if t in ("float", "vec3s")]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="*")
    ap.add_argument("--variant", default="llvm_ad_rgb")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "vdb_load.md"))
    a = ap.parse_args()
    os.environ["NVDB_BUILD_DIR"] = str(BUILD)   # (the children's plugins)
    tmp = Path(tempfile.mkdtemp(prefix="vdb_load_"))
    files = [Path(f) for f in a.files]
    if not files:
        shared = ROOT.parent / "shared" / "data"
        files = sorted(shared.glob("*.vdb")) if shared.is_dir() else []
        big = tmp / "cloud_512.vdb"
        subprocess.run([str(VDB2NVDB), "generate", "cloud_512", str(big)], check=True,
                       capture_output=True)
        files.append(big)
    base = statistics.median(child(a.variant)["peak_kb"] for _ in range(a.repeat))
    rows = []
    for vdb in files:
        for grid, type_ in grids_of(vdb):
            nvdb = tmp / f"{vdb.stem}.{grid or 'unnamed'}.nvdb"
            subprocess.run([str(VDB2NVDB), str(vdb), str(nvdb), "--grid", grid, "--verify", "0"],
                           check=True, capture_output=True)
            result = {}
            for kind, path in (("vdb", vdb), ("nvdb", nvdb)):
                try:
                    runs = [child(a.variant, path, grid) for _ in range(a.repeat)]
                except RuntimeError as e:
                    result[kind] = {"error": str(e)}
                    continue
                result[kind] = {
                    "seconds": statistics.median(r["seconds"] for r in runs),
                    "convert_seconds": statistics.median(r["convert_seconds"] for r in runs),
                    "peak_mb": (statistics.median(r["peak_kb"] for r in runs) - base) / 1024,
                    "grid_mb": runs[0]["grid_bytes"] / 2**20,
                    "reader_seconds": statistics.median(r["reader_seconds"] for r in runs),
                    "reader_peak_mb": statistics.median(r["reader_peak_mb"] for r in runs),
                }
            rows.append({"file": vdb.name, "grid": grid, "type": type_,
                         "vdb_bytes": vdb.stat().st_size, **result})
            print(json.dumps(rows[-1]), flush=True)
    lines = [
        "# .vdb against .nvdb: nanovdbvolume's load (bench/vdb_load.py)", "",
        f"{a.variant}, median of {a.repeat} fresh processes each; peak: ru_maxrss over a "
        f"process that loads nothing ({base / 1024:.0f} MB). Machine: "
        f"{os.cpu_count()} cores. Command: `python3 bench/vdb_load.py`.", "",
        "| file | grid | grid MB | .nvdb load s | .vdb load s (convert) | time x | "
        ".nvdb peak MB | .vdb peak MB | peak x | reader process s | reader peak MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        v, n = r.get("vdb", {}), r.get("nvdb", {})
        if "error" in v or "error" in n:
            lines.append(f"| {r['file']} | \"{r['grid']}\" | | refused: {v.get('error') or n.get('error')} "
                         "| | | | | | | |")
            continue
        lines.append(
            f"| {r['file']} | \"{r['grid']}\" ({r['type']}) | {n['grid_mb']:.2f} | "
            f"{n['seconds']:.3f} | {v['seconds']:.3f} ({v['convert_seconds']:.3f}) | "
            f"{v['seconds'] / n['seconds']:.1f} | {n['peak_mb']:.1f} | {v['peak_mb']:.1f} | "
            f"{v['peak_mb'] / max(n['peak_mb'], 1e-9):.1f} | {v.get('reader_seconds', 0):.3f} | "
            f"{v.get('reader_peak_mb', 0):.1f} |")
    Path(a.out).write_text("\n".join(lines) + "\n")
    Path(a.out).with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
