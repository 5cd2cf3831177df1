"""`pip install .` into a fresh virtual environment, as a user installs it.

The environment sees the system's site-packages (mitsuba, drjit, numpy and
the build requirements: no download), and the build reuses the clone's
build directory (--config-settings build-dir, as scripts/install.sh builds), so that only
the configure step, the packaging and the installation run here, not the
compilation. Then, from a directory outside the clone and with no
PYTHONPATH or NVDB_BUILD_DIR:
- `import nanovdb_mitsuba` is the venv's copy and makes Mitsuba find both
  plugins (nothing else set up);
- the console scripts vdb2nvdb and nanovdb-render run (a .vdb generated,
  converted and rendered);
- `pip uninstall` removes the package, its plugins and its scripts.
"""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import BUILD, ROOT, build_dir_lock


def _run(cmd, cwd, env, timeout=900):
    p = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True, timeout=timeout)
    assert p.returncode == 0, f"{' '.join(map(str, cmd))} failed ({p.returncode}):\n{p.stdout[-6000:]}"
    return p.stdout


def _clean_env(venv):
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "NVDB_BUILD_DIR", "NVDB_VDB2NVDB", "VIRTUAL_ENV",
                        "PYTHONHOME")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return env


@pytest.fixture(scope="module")
def venv(tmp_path_factory):
    for mod in ("scikit_build_core", "nanobind", "venv"):
        try:
            __import__(mod)
        except ImportError:
            pytest.skip(f"{mod} is not installed (scripts/install.sh installs it)")
    if not (BUILD / "CMakeCache.txt").exists():
        pytest.skip(f"no build directory at {BUILD} (run scripts/install.sh first)")
    d = tmp_path_factory.mktemp("pip") / "venv"
    _run([sys.executable, "-m", "venv", "--system-site-packages", d], cwd=d.parent,
         env=_clean_env(d))
    return d


def _site_packages(venv):
    out = _run([venv / "bin" / "python", "-c", "import sysconfig; print(sysconfig.get_path('platlib'))"],
               cwd=venv, env=_clean_env(venv))
    return Path(out.strip())


def test_pip_install_fresh_venv(venv, tmp_path):
    env = _clean_env(venv)
    py = venv / "bin" / "python"
    # pip install . (the build requirements come from the system's site-packages)
    with build_dir_lock():
        try:
            _run([py, "-m", "pip", "install", "--disable-pip-version-check",
                  "--no-build-isolation", "--no-deps", "--config-settings", f"build-dir={BUILD}",
                  "--config-settings", "cmake.define.NVDB_BUILD_TESTS=ON", "."],
                 cwd=ROOT, env=env)
        finally:
            # The build directory's cache now names this venv's Python, which
            # goes with the test: name the suite's own again (the in-tree
            # check, tests/cmake_intree/check.sh, runs the cache's Python)
            _run(["cmake", BUILD, f"-DPython_EXECUTABLE={sys.executable}"], cwd=ROOT,
                 env=_clean_env(venv))
    site = _site_packages(venv)
    pkg = site / "nanovdb_mitsuba"
    installed = [pkg / "plugins" / "nanovdbvolume.so", pkg / "plugins" / "volpathlocal.so",
                 pkg / "plugins" / "emissiveheterogeneous.so", pkg / "bin" / "vdb2nvdb", venv / "bin" / "vdb2nvdb", venv / "bin" / "nanovdb-render"]
    for f in installed:
        assert f.exists(), f"pip install . did not install {f}"
    assert os.access(pkg / "bin" / "vdb2nvdb", os.X_OK)

    work = tmp_path / "user"
    work.mkdir()
    # The console script vdb2nvdb (the package's binary)
    _run(["vdb2nvdb", "generate", "cloud_32", "c.vdb", "c.nvdb"], cwd=work, env=env)
    assert (work / "c.nvdb").stat().st_size > 0
    # One import, no path set-up: the venv's package, both plugins found
    out = _run([py, "-c", f"""
import mitsuba as mi
import nanovdb_mitsuba
print("package", nanovdb_mitsuba.__file__)
mi.set_variant("scalar_rgb")
vol = mi.load_dict({{"type": "nanovdbvolume", "filename": "c.nvdb"}})
print("resolution", list(vol.resolution()))
# A .vdb straight in (the installed plugin links OpenVDB), and the emissive medium
vdb = mi.load_dict({{"type": "nanovdbvolume", "filename": "c.vdb"}})
print("vdb resolution", list(vdb.resolution()), mi.traverse(vdb)["vdb_imported"])
print("medium", type(mi.load_dict({{"type": "emissiveheterogeneous", "emission": 1.0}})).__name__)
print("integrator", type(mi.load_dict({{"type": "volpathlocal"}})).__name__)
"""], cwd=work, env=env)
    assert f"package {pkg / '__init__.py'}" in out, out
    assert re.search(r"resolution \[\d+, \d+, \d+\]", out), out
    assert re.search(r"vdb resolution \[\d+, \d+, \d+\] True", out), out
    assert "integrator" in out and "medium" in out
    # The render command: a .vdb in, PNG + EXR out
    out = _run(["nanovdb-render", "c.vdb", "-o", "c.png", "--res", "24", "--spp", "4"],
               cwd=work, env=env)
    assert "density scale" in out and "wrote c.png" in out, out
    assert (work / "c.png").stat().st_size > 0 and (work / "c.exr").stat().st_size > 0

    # pip uninstall takes everything back
    _run([py, "-m", "pip", "uninstall", "-y", "--disable-pip-version-check", "nanovdb-mitsuba"],
         cwd=work, env=env)
    left = [str(f) for f in installed if f.exists()]
    assert not left, f"left after pip uninstall: {left}"
    assert not pkg.exists() or not any(pkg.rglob("*.so")), f"{pkg} still holds plugins"
