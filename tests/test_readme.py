"""Every code block of README.md runs as written, from the clone, so the README
cannot rot.

The blocks run in the README's order, as a user after the first command
would type them: `sh` blocks with bash (stopping at the first failing
line), `python` blocks with the interpreter (a block sees the blocks before
it in the same section, like cells of a notebook), `xml` blocks as a scene
file that is loaded and rendered. They run in the clone's root, with no
PYTHONPATH or NVDB_BUILD_DIR: the package is the one `pip install .`
installed. Files a block creates there are removed afterwards.

Not run, each with its reason in the README (an HTML comment
`<!-- readme-test: skip: REASON -->` on the line before the block): what
needs root and the network, the benchmarks, the GPU kit. Also not run: the
test command itself (it runs this test), and blocks that read
../shared/data when that folder is absent. Blocks without a language are
diagrams and sample output.
"""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT

README = ROOT / "README.md"
RUN_LANGS = {"sh", "python", "xml"}
NOT_RUN_LINES = {"bash scripts/test.sh": "the test command, which runs this test"}
FENCE = re.compile(r"^(\s*)```(\w*)\s*$")
SKIP = re.compile(r"<!--\s*readme-test:\s*skip:\s*(.+?)\s*-->")


def readme_blocks(path=README):
    """[(first line number, section, language, text, skip reason or None)]"""
    lines = path.read_text().splitlines()
    blocks, section, i = [], "", 0
    while i < len(lines):
        if lines[i].startswith("#"):
            section = lines[i].lstrip("#").strip()
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, lang, start = m.group(1), m.group(2), i + 1
        j = start
        while j < len(lines) and not re.match(r"^\s*```\s*$", lines[j]):
            j += 1
        assert j < len(lines), f"README.md:{i + 1}: unterminated code block"
        text = "\n".join(l[len(indent):] if l.startswith(indent) else l for l in lines[start:j])
        prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        skip = SKIP.search(prev)
        blocks.append((i + 1, section, lang, text, skip.group(1) if skip else None))
        i = j + 1
    return blocks


def _files(root):
    out = set()
    for d, dirs, files in os.walk(root):
        rel = os.path.relpath(d, root)
        dirs[:] = [x for x in dirs if not (rel == "." and (x.startswith("build") or x == ".git"))
                   and x != "__pycache__"]
        out.update(os.path.join(d, f) for f in files)
    return out


def _env():
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "NVDB_BUILD_DIR", "NVDB_VDB2NVDB")}
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _run(cmd, what, timeout=900, **kw):
    p = subprocess.run(cmd, cwd=ROOT, env=_env(), stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True, timeout=timeout, **kw)
    assert p.returncode == 0, f"{what} failed (exit {p.returncode}):\n{p.stdout[-8000:]}"
    return p.stdout


def test_every_block_is_run_or_says_why_not():
    blocks = readme_blocks()
    assert len(blocks) >= 10, "README.md: code blocks not found"
    for line, _, lang, text, skip in blocks:
        if lang in RUN_LANGS:
            continue
        assert lang == "", f"README.md:{line}: a ```{lang} block: run it (sh, python, xml) or " \
                           "make it a plain ``` block (output, diagrams)"
    # a skip annotation needs a reason, and may only stand before a block
    text = README.read_text()
    annotated = len(re.findall(r"readme-test:", text))
    assert annotated == sum(1 for b in blocks if b[4]), \
        "README.md: a readme-test annotation that is not right before a code block"


def test_readme_blocks_run(tmp_path):
    shared = (ROOT.parent / "shared" / "data").is_dir()
    before = _files(ROOT)
    ran, not_run = [], []
    python_cells = {}  # section -> earlier python blocks
    try:
        for line, section, lang, text, skip in readme_blocks():
            where = f"README.md:{line} ({section})"
            if lang not in RUN_LANGS:
                continue
            if skip:
                not_run.append(f"{where}: {skip}")
                continue
            if "../shared/data" in text and not shared:
                not_run.append(f"{where}: no ../shared/data beside the clone")
                continue
            if lang == "sh":
                script = []
                for l in text.splitlines():
                    cmd = l.split("#")[0].strip()
                    if cmd in NOT_RUN_LINES:
                        not_run.append(f"{where}: `{cmd}`: {NOT_RUN_LINES[cmd]}")
                        continue
                    script.append(l)
                _run(["bash", "-e", "-o", "pipefail", "-c", "\n".join(script)], where)
            elif lang == "python":
                cells = python_cells.setdefault(section, [])
                cells.append((line, text))
                prog = ["import sys"]
                for n, (cl, ct) in enumerate(cells):
                    prog.append(f"exec(compile({ct!r}, 'README.md:{cl}', 'exec'))")
                _run([sys.executable, "-c", "\n".join(prog)], where)
            elif lang == "xml":
                scene = tmp_path / f"readme_{line}.xml"
                scene.write_text(text)
                out = tmp_path / f"readme_{line}.exr"
                _run([sys.executable, "-c", f"""
import mitsuba as mi
import nanovdb_mitsuba
mi.set_variant("llvm_ad_rgb")
scene = mi.load_file({str(scene)!r})
image = mi.render(scene, spp=4)
import numpy as np
a = np.array(image)
assert np.isfinite(a).all() and a.std() > 0, "a constant or non-finite image"
mi.util.write_bitmap({str(out)!r}, image)
"""], where)
            ran.append(where)
    finally:
        # What the blocks wrote into the clone: outputs git ignores. A new
        # file git would track is someone's work in this tree, never removed.
        new = sorted(_files(ROOT) - before)
        if new:
            ignored = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--stdin"],
                                     input="\n".join(new), capture_output=True, text=True)
            for f in ignored.stdout.splitlines():
                if os.path.isfile(f):
                    os.remove(f)
    print("ran:\n  " + "\n  ".join(ran))
    print("not run:\n  " + "\n  ".join(not_run))
    assert len(ran) >= 8


def test_pictures_exist():
    """Every picture README.md and docs/images/README.md show is in the
    repository (docs/make_images.py makes them)"""
    for md in (README, ROOT / "docs" / "images" / "README.md"):
        links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md.read_text())
        assert links, f"{md}: no pictures found"
        missing = [l for l in links if not (md.parent / l).is_file()]
        assert not missing, f"{md}: missing pictures {missing}"
