#!/usr/bin/env python3
"""The plugin reference: docs/plugins/*.md, generated from the plugins' doc blocks.

Each plugin source opens with a `/**! ... */` block (a Python plugin: its
class's docstring, as Mitsuba's own Python integrators have it) in the form Mitsuba's
`docs/generate_plugin_doc.py` reads (RST: a `.. pluginparameters::` table,
`|int|`-style markers, `:math:`, `.. tabs::` examples). Mitsuba turns such
blocks into RST for Sphinx; here they become Markdown that a code host
renders: one page per plugin (its parameter table, its prose, its XML and
Python examples) and an index, docs/plugins/README.md. The block is the one
source of the parameters: edit it, never the pages, and run

    python3 docs/generate_plugin_doc.py           # writes the pages
    python3 docs/generate_plugin_doc.py --check   # exit 1 if a page is stale

Only the RST this project's blocks use is understood; anything else (an
unknown directive, role or marker) is an error, so that nothing is dropped
from a page without notice. Standard library only.
"""
import argparse
import re
import textwrap
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "plugins"

# (scene type, plugin kind, source), in the order of the index
PLUGINS = [
    ("nanovdbvolume", "volume", "src/volumes/grid_nanovdb.cpp"),
    ("volpathlocal", "integrator", "src/integrators/volpathlocal.cpp"),
    ("emissiveheterogeneous", "medium", "src/media/emissiveheterogeneous.cpp"),
    ("prbvolpathlocal", "integrator", "python/nanovdb_mitsuba/prbvolpathlocal.py"),
]

# Mitsuba's substitution markers (its docs/src/... `rst_prolog`), as Markdown
MARKERS = {
    "bool": "bool", "int": "int", "float": "float", "string": "string",
    "spectrum": "spectrum", "texture": "texture", "volume": "volume",
    "tensor": "tensor", "transform": "transform", "point": "point",
    "vector": "vector", "true": "`true`", "false": "`false`",
    "exposed": "exposed", "differentiable": "differentiable",
    "discontinuous": "discontinuous",
}

# Targets of :ref: outside this project: Mitsuba's reference (Sphinx keeps
# the label as the anchor)
MITSUBA_DOCS = "https://mitsuba.readthedocs.io/en/stable/src/generated/"
MITSUBA_PAGES = {"integrator": "plugins_integrators.html", "medium": "plugins_media.html",
                 "volume": "plugins_volumes.html", "phase": "plugins_phase.html",
                 "emitter": "plugins_emitters.html", "bsdf": "plugins_bsdfs.html"}

NOT_RUN = ("<!-- readme-test: skip: a fragment of a scene, as in Mitsuba's plugin "
           "reference; the guides hold complete examples -->")


class DocError(Exception):
    pass


@dataclass
class Row:
    names: str       # "values, coords"
    type: str        # "|tensor|"
    description: str
    flags: str = ""  # "|exposed|, |differentiable|"

    def properties(self):
        """The property names of the row ("(nested phase)" is not one)."""
        return [n.strip() for n in self.names.split(",")
                if n.strip() and not n.strip().startswith("(")]


@dataclass
class Block:
    source: str
    label: str = ""
    title: str = ""
    rows: list = field(default_factory=list)
    body: list = field(default_factory=list)  # the lines after the table


def extract_block(text, source):
    """The text between `/**!` and the `*/` that closes it; in a Python
    source (a Python plugin, as Mitsuba's own prbvolpath), the first
    docstring (r\"\"\") that opens with a `.. _label:`, dedented."""
    if source.endswith(".py"):
        m = re.search(r'r"""\n(\s*\.\. _[\w-]+:.*?)"""', text, re.S)
        if not m:
            raise DocError(f"{source}: no docstring that opens with a .. _label:")
        return textwrap.dedent(m.group(1))
    start = text.find("/**!")
    if start < 0:
        raise DocError(f"{source}: no /**! doc block")
    end = text.find("*/", start)
    if end < 0:
        raise DocError(f"{source}: the /**! doc block is not closed")
    return text[start + 4:end]


def _indent(line):
    return len(line) - len(line.lstrip(" "))


def parse_block(text, source):
    """Splits a doc block into its label, title, parameter rows and body."""
    lines = text.splitlines()
    block = Block(source)
    i = 0
    while i < len(lines):
        line = lines[i]
        m = re.match(r"^\.\. _([\w-]+):\s*$", line)
        if m:
            block.label = m.group(1)
        elif line.strip() and i + 1 < len(lines) and re.match(r"^-{3,}\s*$", lines[i + 1]):
            block.title = line.strip()
            i += 1
        elif line.strip() == ".. pluginparameters::":
            i = _parse_table(lines, i + 1, block)
            block.body = lines[i:]
            break
        elif line.strip():
            raise DocError(f"{source}: unexpected line before the parameter table: {line!r}")
        i += 1
    if not block.title or not block.rows:
        raise DocError(f"{source}: the block needs a title and a .. pluginparameters:: table")
    while block.body and not block.body[-1].strip():
        block.body.pop()
    return block


def _parse_table(lines, i, block):
    """Reads ` * - name` / `   - type` / `   - description` [/ `   - flags`]
    rows; returns the index of the first line after the table."""
    fields = None
    while i < len(lines):
        line = lines[i]
        if line.strip() and _indent(line) == 0:
            break
        m = re.match(r"^(\s*)(\* )?- (.*)$", line)
        if m and m.group(2):
            fields = [m.group(3)]
            block.rows.append(fields)
        elif m and fields is not None and len(m.group(1)) >= 2 and not _continues(fields, line):
            fields.append(m.group(3))
        elif line.strip():
            if fields is None:
                raise DocError(f"{block.source}: a table line outside a row: {line!r}")
            fields[-1] += " " + line.strip()
        i += 1
    rows = []
    for f in block.rows:
        if len(f) not in (3, 4):
            raise DocError(f"{block.source}: row {f[0]!r} has {len(f)} fields, not 3 or 4")
        rows.append(Row(*[x.strip() for x in f]))
    block.rows = rows
    return i


def _continues(fields, line):
    """A `- ` line inside a description that is a list item of its own (more
    indented than the fields) rather than the next field."""
    return _indent(line) > 3


_INLINE = re.compile(r"``(?P<code>[^`]+?)``"
                     r"|:(?P<role>[\w-]+):`(?P<arg>[^`]+)`"
                     r"|\|(?P<marker>[\w-]+)\|")


def inline(text, source):
    """RST inline markup as Markdown (markup that spans a line break is
    joined onto one line)."""
    def one(m):
        return re.sub(r"\s*\n\s*", " ", _one(m))

    def _one(m):
        if m.group("code") is not None:
            return f"`{m.group('code')}`"
        if m.group("marker") is not None:
            name = m.group("marker")
            if name not in MARKERS:
                raise DocError(f"{source}: unknown marker |{name}|")
            return MARKERS[name]
        role, arg = m.group("role"), m.group("arg")
        if role == "monosp":
            return f"`{arg}`"
        if role == "math":
            return f"${arg.strip()}$"
        if role == "ref":
            r = re.match(r"^(.*?)\s*<([\w-]+)>$", arg)
            label_text, label = (r.group(1), r.group(2)) if r else (arg, arg)
            return f"[{label_text}]({ref_target(label, source)})"
        raise DocError(f"{source}: unknown role :{role}:")
    out = _INLINE.sub(one, text)
    left = re.search(r":[\w-]+:`|``", out)
    if left:
        raise DocError(f"{source}: markup not understood near {out[left.start():][:40]!r}")
    return out


def ref_target(label, source):
    """A :ref: label as a link: our own plugins' pages, or Mitsuba's reference."""
    for name, kind, _ in PLUGINS:
        if label == f"{kind}-{name}":
            return f"{name}.md"
    kind = label.split("-", 1)[0]
    if kind not in MITSUBA_PAGES:
        raise DocError(f"{source}: :ref: to an unknown label {label!r}")
    return MITSUBA_DOCS + MITSUBA_PAGES[kind] + "#" + label


def _cell(text, source):
    return inline(text, source).replace("|", "\\|")


def _names(row, source):
    out = []
    for n in row.names.split(","):
        n = n.strip()
        out.append(_cell(n, source) if n.startswith("(") else f"`{n}`")
    return ", ".join(out)


def render_body(lines, source):
    """The prose and the examples: paragraphs and lists as they are (inline
    markup converted), `.. tabs::` / `.. code-tab::` and `.. code-block::`
    as fenced blocks."""
    out, prose, i = [], [], 0

    def flush():
        if prose:
            out.extend(inline("\n".join(prose), source).split("\n"))
            prose.clear()

    while i < len(lines):
        line = lines[i]
        d = re.match(r"^(\s*)\.\. ([\w-]+)::\s*(\S*)\s*$", line)
        if not d:
            if line.lstrip().startswith(".. "):
                raise DocError(f"{source}: not understood: {line.strip()!r}")
            prose.append(line.rstrip())
            i += 1
            continue
        flush()
        name, arg = d.group(2), d.group(3)
        if name == "tabs":
            i += 1
            continue
        if name not in ("code-tab", "code-block"):
            raise DocError(f"{source}: unknown directive .. {name}::")
        lang = {"xml": "xml", "python": "python", "py": "python"}.get(arg)
        if lang is None:
            raise DocError(f"{source}: code block in an unknown language {arg!r}")
        base, j, code = _indent(line), i + 1, []
        while j < len(lines) and (not lines[j].strip() or _indent(lines[j]) > base):
            code.append(lines[j])
            j += 1
        while code and not code[-1].strip():
            code.pop()
        while code and not code[0].strip():
            code.pop(0)
        strip = min(_indent(c) for c in code if c.strip())
        if out and out[-1].strip():
            out.append("")
        out += [NOT_RUN, f"```{lang}"] + [c[strip:].rstrip() for c in code] + ["```", ""]
        i = j
    flush()
    while out and not out[-1].strip():
        out.pop()
    # no runs of blank lines
    return "\n".join(out).replace("\n\n\n", "\n\n").strip("\n")


def header(source):
    return (f"<!-- Generated by docs/generate_plugin_doc.py from the /**! block of {source}. "
            f"Do not edit: edit the block, then run python3 docs/generate_plugin_doc.py -->")


def render_page(name, kind, source):
    block = parse_block(extract_block((ROOT / source).read_text(), source), source)
    rows = ["| Parameter | Type | Description | Flags |", "|---|---|---|---|"]
    for r in block.rows:
        rows.append(f"| {_names(r, source)} | {_cell(r.type, source)} | "
                    f"{_cell(r.description, source)} | {_cell(r.flags, source)} |")
    parts = [
        header(source), "",
        f"# {inline(block.title, source)}", "",
        f"A Mitsuba 3 `{kind}` plugin (`\"type\": \"{name}\"`), "
        f"from [`{source}`](../../{source}). [All plugins](README.md)", "",
        "## Parameters", "",
        *rows, "",
        "*exposed*: `mi.traverse()` lists it; *differentiable*: it can carry gradients. "
        "Types as in Mitsuba's reference.", "",
        "## Description", "",
        render_body(block.body, source), "",
    ]
    return "\n".join(parts)


def render_index():
    lines = [header("each plugin source below").replace("the /**! block of", "the /**! blocks of"),
             "", "# Plugin reference", "",
             "The parameters of this project's Mitsuba plugins, generated from the "
             "documentation block at the top of each plugin's source, as Mitsuba "
             "generates its own reference. This is the one parameter reference: "
             "edit the block, then run `python3 docs/generate_plugin_doc.py`; "
             "`tests/test_plugin_docs.py` fails when a page is stale or a block misses "
             "a property that its plugin reads.", "",
             "| Plugin | Kind | What | Source |", "|---|---|---|---|"]
    for name, kind, source in PLUGINS:
        block = parse_block(extract_block((ROOT / source).read_text(), source), source)
        title = re.sub(r"\s*\(:monosp:`[^`]*`\)\s*$", "", block.title)
        lines.append(f"| [`{name}`]({name}.md) | {kind} | {_cell(title, source)} | "
                     f"[`{source}`](../../{source}) |")
    return "\n".join(lines) + "\n"


def generate():
    """{path: text} for every page."""
    pages = {OUT / f"{name}.md": render_page(name, kind, source)
             for name, kind, source in PLUGINS}
    pages[OUT / "README.md"] = render_index()
    return pages


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 if a page differs from what it would be")
    args = parser.parse_args(argv)
    try:
        pages = generate()
    except DocError as e:
        print(f"generate_plugin_doc: {e}", file=sys.stderr)
        return 2
    stale = []
    for path, text in pages.items():
        rel = path.relative_to(ROOT)
        current = path.read_text() if path.exists() else None
        if current == text:
            continue
        if args.check:
            stale.append(rel)
            print(f"{rel} is {'missing' if current is None else 'stale'}: "
                  f"run python3 docs/generate_plugin_doc.py", file=sys.stderr)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            print(f"wrote {rel}")
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
