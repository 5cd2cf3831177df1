#!/usr/bin/env python3
"""Kernels that differ only by literals, from a NVDB_KERNEL_STATS directory
(tests/conftest.py): groups of compiled kernels whose IR is the same once
every numeric literal and every hash-derived name is blanked (and their
callables sorted), with the tests that compiled them and the compile
seconds a shared kernel would have saved.

    NVDB_KERNEL_STATS=/tmp/ks HOME=$(mktemp -d) python3 -m pytest tests ...
    python3 scripts/kernel_groups.py /tmp/ks [--top 25]

A group is a test (or a scene) whose values reach kernels as literals: a
Mitsuba plugin's scalar member (heterogeneous's scale, an emitter's
bounding sphere), or one of ours not yet an opaque variable. Make the
value data (the volume's values, an opaque member) and the group compiles
once (bench/PERF_LOG.md 30, 31). Only kernels that took over 0.5 s to
compile keep their IR, so only those are grouped.
"""
import argparse
import collections
import glob
import json
import os
import re

NAME = re.compile(r"_[0-9a-f]{32}")
LITERAL = re.compile(r"\b(float|double|half|i1|i8|i16|i32|i64) (-?[0-9][0-9a-fA-Fx.e+-]*)")


def shape(ir):
    """The IR with names and literals blanked, its functions in sorted order"""
    text = LITERAL.sub(r"\1 L", NAME.sub("", ir))
    return "\n".join(sorted(re.split(r"\n(?=define )", text)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("stats", help="the NVDB_KERNEL_STATS directory")
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args(argv)
    owner, seconds = {}, {}
    with open(os.path.join(args.stats, "kernels.jsonl")) as f:
        for line in f:
            row = json.loads(line)
            for k in row["kernels"]:
                if not k["hit"]:
                    owner.setdefault(k["hash"], row["test"])
                    seconds[k["hash"]] = k["backend_ms"] / 1000
    groups = collections.defaultdict(list)
    for path in glob.glob(os.path.join(args.stats, "*.ll")):
        h = os.path.basename(path)[:-3]
        with open(path) as f:
            groups[shape(f.read())].append(h)
    found = []
    for hashes in groups.values():
        if len(hashes) > 1:
            cost = [seconds.get(h, 0.0) for h in hashes]
            found.append((sum(cost) - max(cost), hashes))
    found.sort(key=lambda g: -g[0])
    for saved, hashes in found[:args.top]:
        tests = sorted({owner.get(h, "?") for h in hashes})
        print(f"{len(hashes)} kernels, {saved:.1f} s to save: " + "; ".join(tests[:4]) +
              (f" (+{len(tests) - 4} tests)" if len(tests) > 4 else ""))
    print(f"{len(found)} groups; compile seconds that literal-only differences cost: "
          f"{sum(g[0] for g in found):.0f}")


if __name__ == "__main__":
    main()
