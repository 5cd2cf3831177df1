"""scripts/check_marked_copies.py's rule on small synthetic pairs of files
(no upstream checkout needed): which hunks it finds, which it calls
marked, and which it lists. Expectations are derived by hand from the rule
in the script's docstring."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "scripts" / "check_marked_copies.py"

spec = importlib.util.spec_from_file_location("check_marked_copies", SCRIPT)
mc = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mc)

UPSTREAM = """\
#include <a.h>
#include <b.h>

/**!
Upstream's documentation.
*/
int f(int a) {
    int b = a + 1;
    return b;
}

int g(int x,
      int y) {
    return x * y;
}

int h() {
    return 2;
}
""".splitlines()


def copy_of(*replacements):
    text = "\n".join(UPSTREAM)
    for old, new in replacements:
        assert old in text
        text = text.replace(old, new)
    return text.splitlines()


def test01_identical_copy_has_no_hunk():
    assert mc.hunks(UPSTREAM, list(UPSTREAM)) == []


def test02_one_marked_and_one_unmarked_difference():
    copy = copy_of(("    int b = a + 1;\n", "    // mine: one more\n    int b = a + 2;\n"),
                   ("    return 2;\n", "    return 3;\n"))
    hs, bad = mc.unmarked(UPSTREAM, copy, "mine")
    assert len(hs) == 2
    # The marked one: a comment line and the changed line, copy lines 8-9
    assert [n for n, _ in hs[0].copy] == [8, 9]
    assert [t for _, t in hs[0].upstream] == ["    int b = a + 1;"]
    # The unmarked one: "return 2" became "return 3" on copy line 19
    assert len(bad) == 1
    assert bad[0].copy == [(19, "    return 3;")]
    assert bad[0].upstream == [(18, "    return 2;")]
    assert "    - " + "    return 2;" in mc.describe(bad[0])


@pytest.mark.parametrize("gap, marked", [(0, True), (1, True), (2, False)])
def test03_marker_counts_within_three_lines_above(gap, marked):
    # A marker, then `gap` unchanged lines, then the changed line: marked
    # when the marker is among the 3 non-blank lines just above it
    up = ["int k() {"] + [f"    int u{i} = {i};" for i in range(gap)] + ["    return 2;", "}"]
    cp = ["// mine: k returns 3", "int k() {"] + [f"    int u{i} = {i};" for i in range(gap)] + \
         ["    return 3;", "}"]
    hs, bad = mc.unmarked(up, cp, "mine")
    assert len(hs) == 2  # the added marker line, the changed return
    assert [t for _, t in hs[1].copy] == ["    return 3;"]
    # above "return 3": the gap lines, "int k() {", then the marker: the
    # (gap + 2)-th non-blank line above, within 3 for gap <= 1
    assert (hs[1] not in bad) == marked


def test04_reflow_blank_lines_and_whitespace_need_no_marker():
    copy = copy_of(("int g(int x,\n      int y) {", "int g(int x, int y) {"),
                   ("    return x * y;", "    return   x * y;\n\n"))
    hs, bad = mc.unmarked(UPSTREAM, copy, "mine")
    assert len(hs) == 1 and hs[0].reflow()
    assert bad == []


def test05_doc_block_and_includes_are_left_out():
    copy = copy_of(("Upstream's documentation.", "Our own documentation,\nlonger."),
                   ("#include <a.h>\n#include <b.h>", "#include <b.h>\n#include <c.h>\n#include <a.h>"))
    assert mc.hunks(UPSTREAM, copy) == []


def test06_removed_lines_are_a_difference_too():
    removed = copy_of(("    int b = a + 1;\n    return b;", "    return a + 1;"))
    hs, bad = mc.unmarked(UPSTREAM, removed, "mine")
    assert len(bad) == 1 and len(bad[0].upstream) == 2
    deleted = copy_of(("\nint h() {\n    return 2;\n}", ""))
    hs, bad = mc.unmarked(UPSTREAM, deleted, "mine")
    assert len(bad) == 1 and [t for _, t in bad[0].upstream] == ["int h() {", "    return 2;", "}"]
    assert bad[0].copy == []
    marked = copy_of(("int h() {\n    return 2;\n}", "// mine: no h"))
    assert mc.unmarked(UPSTREAM, marked, "mine")[1] == []


def test07_marker_must_be_a_comment():
    copy = copy_of(("    return 2;", '    throw "mine: not a marker";'))
    assert len(mc.unmarked(UPSTREAM, copy, "mine")[1]) == 1
    copy = copy_of(("    return 2;", "    return 3; /* mine: a marker */"))
    assert mc.unmarked(UPSTREAM, copy, "mine")[1] == []
    # the marker is a whole word: "minefield" is not "mine"
    copy = copy_of(("    return 2;", "    return 3; // minefield"))
    assert len(mc.unmarked(UPSTREAM, copy, "mine")[1]) == 1


def test08_command_line_refuses_a_directory_without_upstream(tmp_path):
    r = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert "not found" in r.stderr
    r = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True)
    assert r.returncode == 2


def test09_python_docstring_block_is_left_out():
    """A Python plugin's class docstring is its doc block (Mitsuba's Python
    integrators): left out as /**! is; code after it still counts"""
    up = ['class A:', '    r"""', '    .. _integrator-a:', '    A (:monosp:`a`)',
          '    """', '    def f(self):', '        return 1']
    ours = ['class A:', '    r"""', '    .. _integrator-b:', '    B, documented', '    at length',
            '    """', '    def f(self):', '        return 1']
    assert mc.hunks(up, ours) == []
    changed = ours[:-1] + ['        return 2']
    assert len(mc.hunks(up, changed)) == 1
