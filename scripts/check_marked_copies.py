#!/usr/bin/env python3
"""Lists the differences between our copies of Mitsuba's code and their
upstream files that carry no marker comment.

    python3 scripts/check_marked_copies.py UPSTREAM_DIR

UPSTREAM_DIR is a mitsuba3 checkout (or just its src/ files at their paths),
given by path and never copied into this repository; the copies were made
from v3.9.1, and a checkout of another version reports its changes too.

The copies, each with its upstream file and its marker:

  src/integrators/volpathlocal.cpp     src/integrators/volpath.cpp   volpathlocal
  src/media/emissiveheterogeneous.cpp  src/media/heterogeneous.cpp   emissiveheterogeneous
  python/nanovdb_mitsuba/prbvolpathlocal.py
                        src/python/python/ad/integrators/prbvolpath.py   prbvolpathlocal
                                       (a Python copy: its marker is ``# MARKER``)

The rule. Both files are compared line by line after four steps: the
``/**!`` documentation block is left out (each plugin documents itself),
so are ``#include`` lines (a copy includes what it needs, in sorted order)
and blank lines, and whitespace inside a line is ignored. A hunk
is a run of consecutive lines that differ (upstream lines removed, copy
lines added, or both). A hunk is marked when a comment ``// MARKER`` (also
``/* MARKER``) sits on one of its copy lines or on one of the LOOKBACK (3)
non-blank copy lines just above it: one marker covers the lines it
introduces, as in ``// volpathlocal: the loop bound`` above three new lines.
A hunk whose two sides are the same text once all whitespace is removed
(a line wrapped differently) is a reflow and needs no marker. Every other
hunk is listed, with the lines of both sides; the exit status is 1 when one
is listed, 0 otherwise, 2 on a usage error.

A partial copy (emissiveheterogeneous takes heterogeneous's members and
adds its own) is held to the same rule: code of its own is a difference,
and one marker at the top of each new block marks it.
"""

import difflib
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

LOOKBACK = 3

COPIES = [
    ("src/integrators/volpathlocal.cpp", "src/integrators/volpath.cpp", "volpathlocal"),
    ("src/media/emissiveheterogeneous.cpp", "src/media/heterogeneous.cpp",
     "emissiveheterogeneous"),
    ("python/nanovdb_mitsuba/prbvolpathlocal.py", "src/python/python/ad/integrators/prbvolpath.py",
     "prbvolpathlocal"),
]


@dataclass
class Hunk:
    """One run of differing lines; line numbers are 1-based, in each file."""
    upstream: list = field(default_factory=list)  # [(line number, text)] removed
    copy: list = field(default_factory=list)      # [(line number, text)] added
    copy_at: int = 0   # the copy's line number where the hunk starts (or would)

    def reflow(self):
        squash = lambda lines: re.sub(r"\s+", "", "".join(t for _, t in lines))
        return bool(self.upstream and self.copy) and squash(self.upstream) == squash(self.copy)


def strip_doc_block(lines):
    """The lines outside the plugin's documentation block, as (number,
    text): C++'s ``/**! ... */``; Python's class docstring ``r\"\"\" ...
    \"\"\"`` (the same block in Mitsuba's Python plugins). Each copy's block
    is its own page (docs/generate_plugin_doc.py), not code to diff."""
    out, inside, close = [], False, None
    for n, text in enumerate(lines, 1):
        if not inside and text.lstrip().startswith("/**!"):
            inside, close = True, "*/"
        elif not inside and text.strip() == 'r"""':
            inside, close = True, '"""'
            continue  # (the closing quotes are on a later line)
        if not inside:
            out.append((n, text))
        elif close in text:
            inside = False
    return out


def hunks(upstream_lines, copy_lines):
    """The hunks between two files given as lists of lines (the rule above)."""
    kept = lambda t: t.strip() and not t.lstrip().startswith("#include")
    a = [(n, t) for n, t in strip_doc_block(upstream_lines) if kept(t)]
    b = [(n, t) for n, t in strip_doc_block(copy_lines) if kept(t)]
    key = lambda t: " ".join(t.split())
    matcher = difflib.SequenceMatcher(None, [key(t) for _, t in a], [key(t) for _, t in b],
                                      autojunk=False)
    out = []
    for op, i1, i2, j1, j2 in matcher.get_opcodes():
        if op == "equal":
            continue
        if j1 < len(b):
            at = b[j1][0]
        else:
            at = (b[-1][0] + 1) if b else 1
        out.append(Hunk(upstream=a[i1:i2], copy=b[j1:j2], copy_at=at))
    return out


def is_marked(hunk, copy_lines, marker, lookback=LOOKBACK):
    """A marker comment on the hunk's copy lines or just above them."""
    pattern = re.compile(r"(//|/\*|#)\s*" + re.escape(marker) + r"\b")
    if any(pattern.search(t) for _, t in hunk.copy):
        return True
    above = [t for t in copy_lines[:hunk.copy_at - 1] if t.strip()][-lookback:] if lookback else []
    return any(pattern.search(t) for t in above)


def unmarked(upstream_lines, copy_lines, marker, lookback=LOOKBACK):
    """(all hunks, the hunks that are neither marked nor a reflow)."""
    hs = hunks(upstream_lines, copy_lines)
    return hs, [h for h in hs if not h.reflow() and not is_marked(h, copy_lines, marker, lookback)]


def describe(hunk):
    lines = []
    span = lambda side: (f"{side[0][0]}-{side[-1][0]}" if len(side) > 1 else str(side[0][0])) \
        if side else "-"
    lines.append(f"  copy {span(hunk.copy) if hunk.copy else 'before ' + str(hunk.copy_at)}, "
                 f"upstream {span(hunk.upstream)}:")
    lines += [f"    - {t}" for _, t in hunk.upstream]
    lines += [f"    + {t}" for _, t in hunk.copy]
    return "\n".join(lines)


def main(argv):
    if len(argv) != 2 or argv[1] in ("-h", "--help"):
        print(__doc__.strip().splitlines()[2].strip() if len(argv) != 2 else __doc__)
        return 2
    upstream_dir = Path(argv[1])
    root = Path(__file__).resolve().parent.parent
    status = 0
    for copy, upstream, marker in COPIES:
        up = upstream_dir / upstream
        if not up.is_file():
            print(f"{up}: not found (UPSTREAM_DIR must be a mitsuba3 checkout)", file=sys.stderr)
            return 2
        copy_lines = (root / copy).read_text().splitlines()
        hs, bad = unmarked(up.read_text().splitlines(), copy_lines, marker)
        reflows = sum(h.reflow() for h in hs)
        comment = "#" if copy.endswith(".py") else "//"
        print(f"{copy} against {upstream} (marker: {comment} {marker}): {len(hs)} hunks, "
              f"{len(hs) - reflows - len(bad)} marked, {reflows} reflowed, {len(bad)} unmarked")
        for h in bad:
            print(describe(h))
        status |= bool(bad)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv))
