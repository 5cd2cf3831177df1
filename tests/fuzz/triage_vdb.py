"""
Triage of fuzz_vdb's findings (issue 32): every crash is either in our code
(a bug to fix: this script fails) or inside the third-party reading code
(OpenVDB and the codecs it calls), which the plugin never runs in its own
process: then the finding, loaded through nanovdbvolume, must come back as
an error that names the file, with the Mitsuba process alive
(tests/load_files_child.py).

    python3 tests/fuzz/triage_vdb.py FUZZ_VDB_BINARY BUILD_DIR FINDING...

For each finding: fuzz_vdb replays it alone; the innermost stack frame that
is neither the C/C++ runtime nor a sanitizer interceptor names where it
crashed. Prints one line per finding and exits 1 if any crash is ours or
is not contained.
"""
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
CHILD = HERE.parent / "load_files_child.py"
# (blosc's codecs included: a campaign's finding crashed in liblz4's
# LZ4_decompress_safe, called by blosc_decompress_ctx from OpenVDB)
# Their headers too: UBSan stops in OpenVDB's and TBB's header templates,
# compiled into the fuzzer (RootNode::readTopology loading a stream byte
# into a bool; a CI run's 20 s found 7 such files)
THIRD_PARTY = ("libopenvdb", "libblosc", "libz.", "liblz4", "libzstd", "libsnappy", "libtbb",
               "libImath", "libboost", "/usr/include/openvdb/", "/usr/include/tbb/",
               "/usr/include/oneapi/", "/usr/include/boost/", "/usr/include/Imath/",
               "/usr/include/blosc")
# A UBSan report's first line: "FILE:LINE:COL: runtime error: ..."
UB_SITE = re.compile(r"^(\S+?):\d+:\d+: runtime error")
RUNTIME = ("libc.so", "libstdc++", "libgcc_s", "libm.so", "__interceptor_", "__asan", "__sanitizer",
           "__ubsan", "libclang_rt")
# ASan's interceptors, linked into the fuzzer: clang 14 symbolizes them by
# the C function's own name ("memmove (.../fuzz_vdb+0x17ba3c)"), and the
# caller is the frame below
INTERCEPTOR = re.compile(r"^(memmove|memcpy|memset|memcmp|memchr|strlen|strnlen|strcpy|strncpy|"
                         r"strcmp|malloc|calloc|realloc|free|posix_memalign) \(")
FRAME = re.compile(r"^\s+#(\d+) 0x[0-9a-f]+ in (.*)$")


def crash_site(fuzzer, finding):
    """(where, first line of the report) of a replay; where is None if the
    replay does not crash"""
    # (UBSan prints no stack unless asked)
    env = dict(os.environ, UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:" +
               os.environ.get("UBSAN_OPTIONS", ""))
    r = subprocess.run([fuzzer, str(finding)], capture_output=True, text=True, timeout=300,
                       errors="replace", env=env)
    if r.returncode == 0:
        return None, "no crash on replay"
    report = r.stderr.splitlines()
    head = next((l for l in report if "ERROR:" in l or "runtime error" in l), "crash")
    for line in report:
        m = FRAME.match(line)
        if not m:
            continue
        text = m.group(2)
        if any(k in text for k in RUNTIME) or INTERCEPTOR.match(text):
            continue
        func = re.sub(r"\(.*", "", text).strip()[:90]
        return ("third-party: " + func if any(k in text for k in THIRD_PARTY)
                else "ours: " + text), head
    ub = UB_SITE.match(head.strip())
    if ub:  # no frames: the report's own source location
        return ("third-party: " if any(k in ub.group(1) for k in THIRD_PARTY)
                else "ours: ") + ub.group(1), head
    return "unknown", head


def main(fuzzer, build, findings):
    bad = reader_crashes = 0
    with tempfile.TemporaryDirectory() as tmp:
        for f in findings:
            where, head = crash_site(fuzzer, f)
            # the plugin's view of the same bytes
            copy = Path(tmp) / (Path(f).name + ".vdb")
            copy.write_bytes(Path(f).read_bytes())
            r = subprocess.run([sys.executable, str(CHILD), build, "scalar_rgb", str(copy)],
                               capture_output=True, text=True, timeout=600)
            rows = [json.loads(l) for l in r.stdout.splitlines() if l.startswith('{"file"')]
            contained = (r.returncode == 0 and rows and
                         (rows[0]["ok"] or copy.name in rows[0]["error"]))
            verdict = ("ok" if contained and (where is None or where.startswith("third-party"))
                       else "FAIL")
            bad += verdict == "FAIL"
            plugin = ("loaded" if rows and rows[0]["ok"] else
                      (rows[0]["error"].split("nanovdbvolume: ")[-1][:160] if rows else
                       f"the Mitsuba process died ({r.returncode})"))
            # The reader's process, uninstrumented, crashed: contained, but a
            # check the reader lacks (ASan does not see inside libblosc: a
            # wild read there faults only without it)
            reader_crashes += "reader crashed" in plugin
            print(f"{verdict}: {Path(f).name}: crash {where or 'none'} ({head.strip()[:120]}); "
                  f"plugin: {plugin}")
    print(f"{len(findings)} findings, {bad} not contained or in our code; "
          f"{reader_crashes} crashed the reader's process (contained)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2], sys.argv[3:]))
