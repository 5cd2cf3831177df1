"""Every code block of README.md and of the guides in docs/ runs as written,
from the clone, and every relative link in them leads somewhere, so the
documentation cannot rot.

The files run in order: README.md first (its first block is the quickstart,
which installs the package and makes scenes/cloud.nvdb, which the guides
read), then docs/**/*.md by path. Within a file the blocks run in order, as
a user after the first command would type them: `sh` blocks with bash
(stopping at the first failing line), `python` blocks with the interpreter
(a block sees the blocks before it in the same section of the same file,
like cells of a notebook), `xml` blocks as a scene file that is loaded and
rendered. Each block is one test, named by file and line
(`docs/fire.md:22`). A block picked alone (`-k`) first runs the `sh` blocks
before it in its section, which make the files it reads. They run in the
clone's root, with no PYTHONPATH or NVDB_BUILD_DIR: the package is the one
`pip install .` installed. Files the blocks create there, and git ignores,
are removed afterwards.

Not run, each with its reason in the file (an HTML comment
`<!-- readme-test: skip: REASON -->`, on a line of its own before the
block), and reported as skipped with it: what needs root and the network,
the benchmarks, the GPU kit. Also not run: the test command itself (it runs
this test), and blocks that read ../shared/data when that folder is absent.
Blocks without a language are diagrams and sample output.

Not run at all (their links are still checked):
- docs/plugins/: generated from the plugins' doc blocks, whose examples
  tests/test_plugin_docs.py owns;
- docs/research/: dated research notes, quoting other projects' code and
  one-off outputs as they were found, not instructions to follow.
"""
import os
import re
import shutil
import subprocess
import sys
from collections import namedtuple
from pathlib import Path

import pytest

from conftest import ROOT, build_dir_lock

README = ROOT / "README.md"
DOCS = ROOT / "docs"
NOT_RUN_DIRS = ("docs/plugins", "docs/research")  # see the docstring
RUN_LANGS = {"sh", "python", "xml"}
NOT_RUN_LINES = {"bash scripts/test.sh": "the test command, which runs this test"}
FENCE = re.compile(r"^(\s*)```(\w*)\s*$")
SKIP = re.compile(r"^\s*<!--\s*readme-test:\s*skip:\s*(.+?)\s*-->\s*$")
ANNOTATION = re.compile(r"^\s*<!--\s*readme-test:")
SHARED = (ROOT.parent / "shared" / "data").is_dir()

Block = namedtuple("Block", "file line section lang text skip")


def _rel(path):
    return path.relative_to(ROOT).as_posix()


def markdown_files():
    """README.md, then every .md under docs/ by path: the files whose links
    are checked"""
    return [README] + sorted(DOCS.rglob("*.md"))


def doc_files():
    """The files whose blocks run: markdown_files() less NOT_RUN_DIRS"""
    return [p for p in markdown_files()
            if not any(_rel(p).startswith(d + "/") for d in NOT_RUN_DIRS)]


def doc_blocks(path):
    """[Block(file, first line number, section, language, text, skip reason or None)]"""
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
        assert j < len(lines), f"{_rel(path)}:{i + 1}: unterminated code block"
        text = "\n".join(l[len(indent):] if l.startswith(indent) else l for l in lines[start:j])
        prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        skip = SKIP.match(prev)
        blocks.append(Block(_rel(path), i + 1, section, lang, text, skip.group(1) if skip else None))
        i = j + 1
    return blocks


BLOCKS = [b for f in doc_files() for b in doc_blocks(f)]
RUN = [b for b in BLOCKS if b.lang in RUN_LANGS]


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


def _named_by_blocks(name):
    """Whether a block that ran names `name` as the first part of a path
    (`out/smoke.png` names `out`; `f"fit_{name}.png"` names fit_*.png; an
    image `-o smoke.png` also names the `smoke.exr` nanovdb-render writes
    beside it). A pattern needs 3 characters of its own: `{}` names nothing."""
    for b in RUN:
        if (b.file, b.line) not in _done:
            continue
        for token in re.findall(r"[\w{}$.\-]+(?=/|\b)", b.text):
            pattern = re.escape(token).replace(r"\{", "{").replace(r"\}", "}")
            pattern = re.sub(r"\{[^}]*\}|\\\$\w+", "\0", pattern)
            if len(pattern.replace("\0", "").replace("\\", "")) < 3:
                continue
            pattern = pattern.replace("\0", ".+")
            pattern = re.sub(r"\\\.png$", r"\\.(png|exr)", pattern)
            if re.fullmatch(pattern, name):
                return True
    return False


@pytest.fixture(scope="module")
def clone():
    """The clone's root; what the blocks wrote into it is removed at the end:
    new files git ignores, and new entries of the root that a block named
    (`out/`, `cloud_albedo.nvdb`). Other new files are someone's work in
    this tree, never removed."""
    before = _files(ROOT)
    top_before = set(os.listdir(ROOT))
    yield ROOT
    new = sorted(_files(ROOT) - before)
    if new:
        ignored = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--stdin"],
                                 input="\n".join(new), capture_output=True, text=True)
        for f in ignored.stdout.splitlines():
            if os.path.isfile(f):
                os.remove(f)
    for name in sorted(set(os.listdir(ROOT)) - top_before):
        if _named_by_blocks(name):
            path = ROOT / name
            shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()


def _why_not(b):
    if b.skip:
        return b.skip
    if "../shared/data" in b.text and not SHARED:
        return "no ../shared/data beside the clone"
    return None


_done = set()  # (file, line) of the blocks that ran in this session


def _run_block(b, tmp):
    where = f"{b.file}:{b.line} ({b.section})"
    if b.lang == "sh":
        script = [l for l in b.text.splitlines() if l.split("#")[0].strip() not in NOT_RUN_LINES]
        with build_dir_lock():  # (the quickstart's pip install . builds in build/)
            _run(["bash", "-e", "-o", "pipefail", "-c", "\n".join(script)], where)
    elif b.lang == "python":
        cells = [c for c in RUN if c.file == b.file and c.section == b.section
                 and c.lang == "python" and c.line <= b.line and not c.skip]
        prog = ["import sys"] + [f"exec(compile({c.text!r}, '{c.file}:{c.line}', 'exec'))"
                                 for c in cells]
        _run([sys.executable, "-c", "\n".join(prog)], where)
    elif b.lang == "xml":
        name = re.sub(r"\W", "_", f"{b.file}_{b.line}")
        scene, out = tmp / f"{name}.xml", tmp / f"{name}.exr"
        scene.write_text(b.text)
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
    _done.add((b.file, b.line))


def test_every_block_is_run_or_says_why_not():
    files = doc_files()
    assert README in files and len(files) >= 10, f"the guides in docs/ not found: {files}"
    assert len(BLOCKS) >= 20, "code blocks not found"
    for b in BLOCKS:
        if b.lang in RUN_LANGS:
            continue
        assert b.lang == "", f"{b.file}:{b.line}: a ```{b.lang} block: run it (sh, python, xml) " \
                             "or make it a plain ``` block (output, diagrams)"
    # a skip annotation needs a reason, and may only stand right before a block
    for f in files:
        annotated = sum(1 for l in f.read_text().splitlines() if ANNOTATION.match(l))
        skips = sum(1 for b in BLOCKS if b.file == _rel(f) and b.skip)
        assert annotated == skips, \
            f"{_rel(f)}: a readme-test annotation that is not right before a code block, " \
            "or without its reason (<!-- readme-test: skip: REASON -->)"
    runnable = [b for b in RUN if not b.skip]
    assert len(runnable) >= 15, f"only {len(runnable)} blocks would run"


@pytest.mark.parametrize("block", RUN, ids=[f"{b.file}:{b.line}" for b in RUN])
def test_block_runs(block, clone, tmp_path_factory):
    why = _why_not(block)
    if why:
        pytest.skip(f"{block.file}:{block.line}: {why}")
    tmp = tmp_path_factory.mktemp("blocks")
    # the sh blocks before it in its section make the files it reads
    for b in RUN:
        if (b.file, b.section, b.lang) == (block.file, block.section, "sh") \
                and b.line < block.line and (b.file, b.line) not in _done and not _why_not(b):
            _run_block(b, tmp)
    _run_block(block, tmp)


# Links: [text](target), ![alt](target), [id]: target, outside code
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REF_LINK = re.compile(r"^\s*\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)", re.M)


def _prose(text):
    """The text less fenced blocks, inline code and HTML comments"""
    out, fence = [], False
    for l in text.splitlines():
        if re.match(r"^\s*```", l):
            fence = not fence
            continue
        if not fence:
            out.append(l)
    prose = "\n".join(out)
    prose = re.sub(r"<!--.*?-->", "", prose, flags=re.S)
    return re.sub(r"`[^`]*`", "", prose)


def heading_anchors(path):
    """The #anchors a code host gives the headings of a Markdown file (GitHub's
    rule: the heading's text, lower case, without punctuation other than
    - and _, spaces made -, a repeat numbered -1, -2, ...)"""
    anchors, seen, fence = set(), {}, False
    for l in path.read_text().splitlines():
        if re.match(r"^\s*```", l):
            fence = not fence
        m = None if fence else re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", l)
        if not m:
            continue
        text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", m.group(1)).replace("`", "")
        slug = re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        anchors.add(slug if n == 0 else f"{slug}-{n}")
    return anchors


def dead_links(path):
    """[(target, why)] of the relative links in a Markdown file that lead nowhere"""
    prose = _prose(path.read_text())
    dead = []
    for target in LINK.findall(prose) + REF_LINK.findall(prose):
        if re.match(r"^[a-zA-Z][\w+.-]*:", target):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        if not dest.exists():
            dead.append((target, "no such file"))
        elif anchor and dest.suffix == ".md" and anchor not in heading_anchors(dest):
            dead.append((target, f"no heading #{anchor} in {_rel(dest)}"))
    return dead


LINKED = markdown_files() + [ROOT / "bench" / "README.md"]


@pytest.mark.parametrize("md", LINKED, ids=[_rel(p) for p in LINKED])
def test_links_lead_somewhere(md):
    """Every relative link and picture leads to a file of the clone (and a
    #section of a Markdown file to one of its headings)"""
    dead = dead_links(md)
    assert not dead, f"{_rel(md)}: dead links:\n" + "\n".join(f"  {t}: {w}" for t, w in dead)


def test_links_found():
    """The link pattern finds the README's table of links, and links in the guides"""
    assert len(LINK.findall(_prose(README.read_text()))) >= 20
    assert sum(len(LINK.findall(_prose(p.read_text()))) for p in doc_files()[1:]) >= 30


def test_pictures_exist():
    """README.md shows a picture, and so does the gallery docs/make_images.py
    writes (docs/images/README.md); test_links_lead_somewhere checks that
    they exist"""
    for md in (README, DOCS / "images" / "README.md"):
        links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md.read_text())
        assert links, f"{md}: no pictures found"
        missing = [l for l in links if not (md.parent / l).is_file()]
        assert not missing, f"{md}: missing pictures {missing}"
