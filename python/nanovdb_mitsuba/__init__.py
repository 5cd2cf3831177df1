"""Python helpers of nanovdb-mitsuba: find the plugins, frame a NanoVDB
volume in a scene, render a user's file (see render.py).

From a clone, after the build: `PYTHONPATH=python python3 -m nanovdb_mitsuba.render ...`
"""
import os
import shutil

_HERE = os.path.dirname(os.path.abspath(__file__))


def build_dir():
    """The build directory holding plugins/ and bin/: $NVDB_BUILD_DIR, else
    the clone's build/ (this package lives in <clone>/python/)."""
    return os.path.abspath(os.environ.get("NVDB_BUILD_DIR") or
                           os.path.join(_HERE, "..", "..", "build"))


def setup(mi):
    """Lets Mitsuba find nanovdbvolume and volpathlocal: prepends the build
    directory to its file resolver (call after mi.set_variant)."""
    d = build_dir()
    if not os.path.exists(os.path.join(d, "plugins", "nanovdbvolume.so")):
        raise RuntimeError(f"nanovdb_mitsuba: no plugins/nanovdbvolume.so in {d}: build the "
                           "project first (README), or set NVDB_BUILD_DIR")
    mi.file_resolver().prepend(d)


def vdb2nvdb():
    """The converter: $NVDB_VDB2NVDB, the build's bin/vdb2nvdb, or the one on PATH."""
    for path in (os.environ.get("NVDB_VDB2NVDB"), os.path.join(build_dir(), "bin", "vdb2nvdb"),
                 shutil.which("vdb2nvdb")):
        if path and os.path.exists(path):
            return path
    raise RuntimeError("nanovdb_mitsuba: vdb2nvdb not found (build the project, or set "
                       "NVDB_VDB2NVDB)")


from .scene import framed_scene  # noqa: E402,F401
