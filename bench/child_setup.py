"""What a benchmark's child process does first (bench/filters.py,
bench/far_grid.py, bench/worker.py, bench/optimize.py): Mitsuba in the given variant, with the plugins of a
build folder searched before the installed package's.

The installed `nanovdb_mitsuba` package, if any, is imported before the
build folder is prepended: importing it afterwards would put its own plugin
folder first and silently render with the installed plugins. With a build
folder, the package is the clone's (python/, beside bench/), pointed at that
folder ($NVDB_BUILD_DIR), so that its Python integrators (prbvolpathlocal)
are the clone's too.
"""
import os
import sys


def mitsuba_for(variant, build=""):
    """Returns (drjit, mitsuba), the variant set and `build` (a folder
    holding plugins/; "" for the installed plugins) searched first."""
    import drjit as dr
    import mitsuba as mi
    mi.set_variant(variant)
    if build:
        os.environ["NVDB_BUILD_DIR"] = os.path.abspath(build)
        sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
    try:
        import nanovdb_mitsuba  # noqa: F401 (the installed plugins' folder)
    except (ImportError, RuntimeError):  # (not installed, or without its plugins)
        pass
    if build:
        mi.file_resolver().prepend(build)  # (searched first)
    return dr, mi
