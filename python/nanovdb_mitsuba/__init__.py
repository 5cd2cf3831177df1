"""nanovdb-mitsuba: sparse NanoVDB volumes for Mitsuba 3.

    import mitsuba as mi
    import nanovdb_mitsuba          # Mitsuba now finds nanovdbvolume and volpathlocal
                                    # (and, in *_ad_* variants, prbvolpathlocal)
    mi.set_variant("llvm_ad_rgb")
    vol = mi.load_dict({"type": "nanovdbvolume", "filename": "scenes/cloud.nvdb"})

Importing the package puts the directory that holds plugins/nanovdbvolume.so
and plugins/volpathlocal.so first in Mitsuba's file resolver, which is where
Mitsuba looks plugins up (before or after mi.set_variant; threads started
later inherit it). That directory is:
- $NVDB_BUILD_DIR, when set (a build directory: plugins/, bin/);
- the installed package itself (pip install .: nanovdb_mitsuba/plugins/);
- otherwise, run from a clone (PYTHONPATH=python), the clone's build/.

A nanovdbvolume's values asked for from mi.traverse() where they are no
parameter (loaded without differentiable=true) raise a KeyError that says
so (params.py). Also here: volume_facts() and integrator_facts() (facts.py: what a loaded
plugin is, through mi.traverse), framed_scene() (scene.py: a volume framed
and lit, as a scene dict), nanovdb-render (render.py) and the vdb2nvdb
console script (tools.py).
`python3 -m nanovdb_mitsuba` prints the plugin directory, for
`mitsuba -a "$(python3 -m nanovdb_mitsuba)" scene.xml`.
"""
import os
import shutil

__version__ = "0.3.0"  # the package's version (pyproject.toml reads it here)

_HERE = os.path.dirname(os.path.abspath(__file__))
_PLUGINS = ("nanovdbvolume", "volpathlocal", "emissiveheterogeneous")


def plugin_root():
    """The directory holding plugins/ (and bin/vdb2nvdb): $NVDB_BUILD_DIR,
    else this package when installed, else the clone's build/."""
    if os.environ.get("NVDB_BUILD_DIR"):
        return os.path.abspath(os.environ["NVDB_BUILD_DIR"])
    if os.path.exists(os.path.join(_HERE, "plugins", "nanovdbvolume.so")):
        return _HERE
    return os.path.abspath(os.path.join(_HERE, "..", "..", "build"))


def setup(mi=None):
    """Puts plugin_root() first in Mitsuba's file resolver (once). Called on
    import; call it again after changing $NVDB_BUILD_DIR or the resolver."""
    if mi is None:
        import mitsuba as mi
    d = plugin_root()
    missing = [p for p in _PLUGINS if not os.path.exists(os.path.join(d, "plugins", p + ".so"))]
    if missing:
        raise RuntimeError(
            f"nanovdb_mitsuba: no plugins/{missing[0]}.so in {d}: install the package "
            "(pip install .) or build the clone (README), or set NVDB_BUILD_DIR")
    resolver = mi.file_resolver()
    if len(resolver) == 0 or str(resolver[0]) != d:
        resolver.prepend(d)
    _register_python_integrators(mi)
    from . import params
    params.install(mi)
    return d


_CALLBACK_ADDED = False


def _register_python_integrators(mi):
    """prbvolpathlocal (prbvolpathlocal.py), a Python integrator as
    Mitsuba's prbvolpath is: registered in the current variant when it is
    an *_ad_* one, and again after every mi.set_variant (its module
    reloaded, as Mitsuba reloads its own, so that its class derives from
    that variant's types)"""
    global _CALLBACK_ADDED

    def register(*_):
        variant = mi.variant()
        if not variant or "_ad_" not in variant or "polarized" in variant:
            return
        import importlib
        # Mitsuba reloads its AD integrators for the new variant, but maybe
        # after this callback: prbvolpathlocal's base class must be the new
        # variant's (else scenes load it as no integrator at all)
        import mitsuba.ad.integrators as ad_integrators
        if not issubclass(ad_integrators.common.RBIntegrator, mi.Integrator):
            importlib.reload(ad_integrators)
        from . import prbvolpathlocal
        importlib.reload(prbvolpathlocal).register()

    register()
    if not _CALLBACK_ADDED:
        mi.detail.add_variant_callback(register)
        _CALLBACK_ADDED = True


def vdb2nvdb():
    """The converter binary: $NVDB_VDB2NVDB, else bin/vdb2nvdb under
    plugin_root(), else a vdb2nvdb on PATH that is not our console script."""
    candidates = [os.environ.get("NVDB_VDB2NVDB"), os.path.join(plugin_root(), "bin", "vdb2nvdb")]
    for path in candidates:
        if path and os.path.isfile(path) and os.access(path, os.X_OK):
            return path
    found = shutil.which("vdb2nvdb")
    if found and not _is_console_script(found):
        return found
    raise RuntimeError(
        f"nanovdb_mitsuba: vdb2nvdb not found in {os.path.join(plugin_root(), 'bin')} (it needs "
        "OpenVDB 10 at build time: apt-get install libopenvdb-dev libboost-dev libtbb-dev "
        "libimath-dev, then reinstall), nor as $NVDB_VDB2NVDB")


def _is_console_script(path):
    """pip's wrapper around tools.vdb2nvdb_main (a Python script), which
    must not run itself"""
    try:
        with open(path, "rb") as f:
            return f.read(2) == b"#!" and b"nanovdb_mitsuba" in f.read(4096)
    except OSError:
        return False


try:
    setup()
except RuntimeError as e:
    # A clone before its build: importing still works (scene helpers), and
    # Mitsuba would only say "plugin not found" later, so say why now
    import warnings
    warnings.warn(str(e), RuntimeWarning, stacklevel=2)

from .facts import integrator_facts, volume_facts  # noqa: E402,F401
from .scene import default_scale, enclosing_cube, framed_scene  # noqa: E402,F401
