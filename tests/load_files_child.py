"""
Loads .vdb/.nvdb files through nanovdbvolume, one after another, in this
process, and prints one JSON line per file, then the peaks:

    python3 tests/load_files_child.py BUILD_DIR VARIANT FILE...

A test runs it as a child process (tests/test_vdb_damaged.py), so that if a
file did crash the process that loads it, the test would see the crash
instead of dying with it. Each line: {"file", "ok", "error", "seconds",
"reader_peak_mb"} where reader_peak_mb is the peak resident memory of the
.vdb reader process (nanovdb-vdb-reader reports it through
NVDB_VDB_READER_REPORT; 0 for a .nvdb, or a reader that died before its
reply); the last line: {"self_peak_mb"}.
"""

import json
import os
import sys
import tempfile
import time

import mitsuba as mi


def main(build, variant, files):
    mi.set_variant(variant)
    mi.file_resolver().prepend(build)
    mi.set_log_level(mi.LogLevel.Error)
    report = os.path.join(tempfile.mkdtemp(), "reader.jsonl")
    os.environ["NVDB_VDB_READER_REPORT"] = report
    seen = 0
    for f in files:
        t0 = time.perf_counter()
        row = {"file": f, "ok": False, "error": ""}
        try:
            mi.load_dict({"type": "nanovdbvolume", "filename": f})
            row["ok"] = True
        except Exception as e:  # the load's error, reported by the test
            row["error"] = str(e)
        row["seconds"] = time.perf_counter() - t0
        lines = open(report).read().splitlines() if os.path.exists(report) else []
        row["reader_peak_mb"] = max([json.loads(l)["peak_mb"] for l in lines[seen:]],
                                    default=0.0)
        seen = len(lines)
        print(json.dumps(row), flush=True)
    # VmHWM: this process's peak since exec (ru_maxrss would count the
    # parent's pages: subprocess starts children with vfork, and a parent
    # that ran half the test suite holds gigabytes)
    hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))
    print(json.dumps({"self_peak_mb": hwm / 1024}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3:])
