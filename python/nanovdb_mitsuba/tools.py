"""Console scripts around the compiled tools (pyproject.toml [project.scripts])."""
import os
import sys


def vdb2nvdb_main():
    """`vdb2nvdb ...`: runs the converter binary installed in the package
    (nanovdb_mitsuba/bin/vdb2nvdb), with the same arguments and exit code."""
    from . import vdb2nvdb
    try:
        exe = vdb2nvdb()
    except RuntimeError as e:
        sys.exit(str(e))
    os.execv(exe, [exe] + sys.argv[1:])
