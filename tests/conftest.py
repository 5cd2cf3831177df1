"""
Shared fixtures for the nanovdbvolume pytest suite.

The suite loads build/plugins/nanovdbvolume.so through Mitsuba's file resolver
(NVDB_BUILD_DIR overrides the build directory) and generates its volumes with
build/bin/nvdb_make_test_grid, which writes them through NanoVDB's own writer
(tests/grids.cpp), together with dense Mitsuba .vol exports of the same
active box for gridvolume.
"""

import contextlib
import os
import subprocess
import struct
from pathlib import Path

import pytest
import drjit as dr
import mitsuba as mi

ROOT = Path(__file__).resolve().parent.parent
BUILD = Path(os.environ.get("NVDB_BUILD_DIR", ROOT / "build")).resolve()
MAKE_GRID = BUILD / "bin" / "nvdb_make_test_grid"
MAKE_STABILITY_GRID = BUILD / "bin" / "nvdb_make_stability_grid"
# Real volumes from other tools, read in place: $NVDB_SHARED_DATA, by default
# ../shared/data beside the repository. Tests that need them skip without it.
SHARED_DATA = Path(os.environ.get("NVDB_SHARED_DATA") or ROOT.parent / "shared" / "data").resolve()
# NVDB_TEST_VARIANTS=cuda_ad_rgb,cuda_ad_mono,...: the variants that the
# variant-parametrized tests run on (the GPU kit sets it), instead of
# scalar_rgb + llvm_ad_rgb (+ cuda_ad_rgb on a GPU) and every variant.
TEST_VARIANTS = [v for v in os.environ.get("NVDB_TEST_VARIANTS", "").split(",") if v]


@contextlib.contextmanager
def build_dir_lock():
    """Held while a test runs `pip install .` into the build directory
    (test_pip_install; test_readme's sh blocks, whose quickstart runs
    scripts/install.sh): pytest's workers run two files at once, and two
    builds in one directory would race"""
    import fcntl
    BUILD.mkdir(parents=True, exist_ok=True)
    with open(BUILD / ".pip-install.lock", "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def need_shared_data(*names):
    """Skips the test unless the shared data folder (and the files) exist."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"no shared data folder at {SHARED_DATA} (set NVDB_SHARED_DATA)")
    for n in names:
        if not (SHARED_DATA / n).exists():
            pytest.skip(f"{SHARED_DATA / n} is missing")
    return SHARED_DATA


def shared_data_files(pattern):
    """Parameters for a test over every shared file matching `pattern`, with
    the file names as ids. Without the folder: one parameter None (id
    "no_shared_data"), so that the test runs and its need_shared_data() call
    skips with the reason, where an empty list would skip with pytest's
    "got empty parameter set"."""
    if not SHARED_DATA.is_dir():
        return [pytest.param(None, id="no_shared_data")]
    return [pytest.param(p, id=p.name) for p in sorted(SHARED_DATA.glob(pattern))]


def has_cuda():
    try:
        return dr.has_backend(dr.JitBackend.CUDA)
    except Exception:
        return False


def has_llvm():
    try:
        return dr.has_backend(dr.JitBackend.LLVM)
    except Exception:
        return False


def _setup_variant(name):
    if name not in mi.variants():
        pytest.skip(f"variant {name} is not part of this Mitsuba build")
    if TEST_VARIANTS and name not in TEST_VARIANTS:
        pytest.skip(f"{name}: not in NVDB_TEST_VARIANTS (a build of some variants)")
    if name.startswith("cuda") and not has_cuda():
        pytest.skip(f"{name}: no CUDA device on this machine")
    if name.startswith("llvm") and not has_llvm():
        pytest.skip(f"{name}: Dr.Jit's LLVM backend is not available (libLLVM missing)")
    mi.set_variant(name)
    # Our plugin directory goes first: mitsuba looks up plugins/<name>.so
    mi.file_resolver().prepend(str(BUILD))


# Markers (registered here, so that --strict-markers accepts them):
#   slow: takes more than ~3 s on a 2-core CPU machine (the >4 GiB grid of
#         test_stability.py). The default run includes them;
#         `python3 -m pytest -q tests -p no:cacheprovider -m "not slow"` is the
#         quick subset.
def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes more than ~3 s on a 2-core CPU machine; "
                            'deselect with -m "not slow"')


# The files in order of their run time, longest first: scripts/test.sh runs
# them on one worker per core (pytest-xdist, --dist loadfile, with
# --no-loadscope-reorder so that this order holds), and longest first keeps
# both cores busy to the end (xdist's own order, by test count, left one
# core idle for about 4 minutes: bench/PERF_LOG.md 34). Seconds of test
# time on the 2-core CI machine (`--durations=0`, summed per file); a file
# not listed runs after these, and its place is refreshed from the same
# measurement when it grows.
FILE_SECONDS = {
    "test_upstream_renders.py": 405, "test_volpathlocal.py": 280,
    "test_differentiable.py": 269, "test_readme.py": 202, "test_value_types.py": 123,
    "test_termination.py": 95, "test_render.py": 90, "test_stochastic_filters.py": 90,
    "test_emission.py": 88, "test_sequence.py": 88, "test_stability.py": 77,
    "test_render_fire.py": 49, "test_upstream_volumes.py": 41, "test_vdb_import.py": 37,
    "test_nanovdbvolume.py": 31, "test_vdb2nvdb.py": 30, "test_vdb_damaged.py": 23,
    "test_pip_install.py": 20,
}


def pytest_runtest_logreport(report):
    """NVDB_FAILURE_LOG=FILE: each failure's report appended to FILE as it
    happens, in the process that prints the results (with pytest-xdist, the
    controller). A run stopped at a time limit (the GPU kit's device calls)
    prints no failure section, so without this only the failures' names
    would be known."""
    path = os.environ.get("NVDB_FAILURE_LOG")
    if not path or not report.failed or os.environ.get("PYTEST_XDIST_WORKER"):
        return
    with open(path, "a") as f:
        f.write(f"==== {report.nodeid} ({report.when})\n{report.longreprtext}\n\n")


def pytest_collection_modifyitems(session, config, items):
    # (stable: each file's tests stay together and in their order)
    items.sort(key=lambda item: (-FILE_SECONDS.get(item.path.name, 0), item.path.name))


def pytest_generate_tests(metafunc):
    # "variants_all": every non-CUDA variant, plus the CUDA ones when a GPU exists
    if "variants_all" in metafunc.fixturenames:
        names = [v for v in mi.variants() if not v.startswith("cuda") or has_cuda()]
        if TEST_VARIANTS:
            names = [v for v in names if v in TEST_VARIANTS]
        metafunc.parametrize("variants_all", names, indirect=True)
    # "variants_rgb": scalar_rgb and llvm_ad_rgb, plus cuda_ad_rgb on a GPU
    # (or NVDB_TEST_VARIANTS, less its spectral variants: these tests expect
    # a colour without wavelength sampling -- a constant radiance read back
    # as exactly 1, binomial noise alone, Vec3f index grids as colours --
    # and fail on llvm_ad_spectral and cuda_ad_spectral alike; mono passes.
    # The spectral variants run the variants_all tests.)
    if "variants_rgb" in metafunc.fixturenames:
        names = ([v for v in TEST_VARIANTS if "spectral" not in v] if TEST_VARIANTS else
                 ["scalar_rgb", "llvm_ad_rgb"] + (["cuda_ad_rgb"] if has_cuda() else []))
        metafunc.parametrize("variants_rgb", names, indirect=True)


@pytest.fixture
def variants_all(request):
    _setup_variant(request.param)
    return request.param


@pytest.fixture
def variants_rgb(request):
    _setup_variant(request.param)
    return request.param


@pytest.fixture
def variant_scalar_rgb():
    _setup_variant("scalar_rgb")


@pytest.fixture
def variant_llvm_ad_rgb():
    _setup_variant("llvm_ad_rgb")


class GridFactory:
    """Writes named test grids once per session (nvdb + dense vol)."""

    def __init__(self, directory):
        self.dir = Path(directory)
        self.cache = {}

    def __call__(self, name, codec="none", dense=True, value_type="float"):
        """value_type: float, fp4, fp8, fp16, fpn or half (tests/typed_grids.h);
        the dense export then holds the decoded values."""
        key = (name, codec, dense, value_type)
        if key not in self.cache:
            if not MAKE_GRID.exists():
                pytest.fail(f"{MAKE_GRID} is missing: build the project first")
            suffix = "" if value_type == "float" else f"_{value_type}"
            nvdb = self.dir / f"{name}_{codec}{suffix}.nvdb"
            vol = self.dir / f"{name}{suffix}.vol"
            cmd = [str(MAKE_GRID), name, str(nvdb), "--codec", codec, "--type", value_type]
            if dense:
                cmd += ["--dense", str(vol)]
            subprocess.run(cmd, check=True, capture_output=True, text=True)
            self.cache[key] = (str(nvdb), str(vol) if dense else None)
        return self.cache[key]


@pytest.fixture(scope="session")
def make_grid(tmp_path_factory):
    return GridFactory(tmp_path_factory.mktemp("grids"))


def make_stability_grid(directory, name, *args, dense=True):
    """Writes directory/name.nvdb (+ .vol) with build/bin/nvdb_make_stability_grid
    (OpenVDB -> NanoVDB's own converter and writer, tests/make_stability_grid.cpp);
    `args` are its options. Returns (nvdb, vol or None, summary)."""
    if not MAKE_STABILITY_GRID.exists():
        pytest.fail(f"{MAKE_STABILITY_GRID} is missing: build the project first")
    directory = Path(directory)
    nvdb, vol = directory / f"{name}.nvdb", directory / f"{name}.vol"
    cmd = [str(MAKE_STABILITY_GRID), str(nvdb), *map(str, args)]
    if dense:
        cmd += ["--dense", str(vol)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.split()
    # "bbox x0 y0 z0 x1 y1 z1 bytes N leaves N lowers N uppers N"
    summary = {out[i]: int(out[i + 1]) for i in range(7, len(out) - 1, 2)}
    summary["bbox"] = [int(v) for v in out[1:7]]
    return str(nvdb), (str(vol) if dense else None), summary


def _bench_module(name):
    """A module of bench/ (the measurement helpers the tests share with it)."""
    import importlib
    import sys
    if str(ROOT / "bench") not in sys.path:
        sys.path.insert(0, str(ROOT / "bench"))
    return importlib.import_module(name)


def gpu_used_bytes():
    """Device memory in use on GPU 0 (bench/gpu.py: NVML or nvidia-smi)."""
    return _bench_module("gpu").used_bytes()


def rss_bytes():
    """This process's resident memory (bench/worker.py)."""
    return _bench_module("worker").rss_bytes()


def trim_heap():
    """Returns the heap's free pages to the system (glibc's malloc_trim), so
    that RSS measures what is held, not what earlier tests or a load's own
    temporaries freed and the allocator kept"""
    import ctypes
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def settle_gpu():
    """Waits for pending kernels and returns Dr.Jit's cached blocks, so that
    gpu_used_bytes() sees what live objects hold."""
    import gc
    gc.collect()
    dr.sync_thread()
    dr.flush_malloc_cache()


def load_nvdb(filename, **kwargs):
    return mi.load_dict({"type": "nanovdbvolume", "filename": filename, **kwargs})


def load_dense(filename, **kwargs):
    # On CUDA, gridvolume samples through hardware textures by default, whose
    # interpolation weights have 8 fractional bits (measured: trilinear off
    # by up to 0.5 %, and 1 in 10^5 nearest lookups at a voxel face in the
    # neighbouring voxel). The exact comparisons need its float arithmetic.
    if mi.variant().startswith("cuda"):
        kwargs.setdefault("accel", False)
    return mi.load_dict({"type": "gridvolume", "filename": filename, **kwargs})


def eval_points(volume, points):
    """eval_1 at an (N, 3) array of local points; returns a numpy array."""
    import numpy as np
    points = np.asarray(points, dtype=np.float32)
    if dr.is_jit_v(mi.Float):
        it = dr.zeros(mi.Interaction3f, len(points))
        it.p = mi.Point3f(points[:, 0], points[:, 1], points[:, 2])
        return np.array(volume.eval_1(it))
    out = np.empty(len(points), dtype=np.float32)
    it = dr.zeros(mi.Interaction3f)
    for i, p in enumerate(points):
        it.p = mi.ScalarPoint3f(*map(float, p))
        out[i] = volume.eval_1(it)
    return out


def assert_renders_match(a, b, filter_type):
    """nanovdbvolume (a) vs gridvolume (b) renders of the same scene and seed.

    nearest: the same voxels and values, so the same image up to float
    summation order. trilinear: the same 8 voxels and weights up to rounding,
    but where values reach max() gridvolume's result overshoots its own
    majorant by up to 3 ulps (weights rounded to a sum above 1) while
    nanovdbvolume clamps to max(); the overshoot makes the null density
    slightly negative, which changes a few free-flight decisions and sends
    those paths elsewhere (and in the outer half voxel a VDB blends towards
    the background where gridvolume clamps). So trilinear is compared
    statistically. Measured at 24x24, 4 spp: 95 % (fog sphere, a plateau of
    1.0) and 99.5 % (cloud) of the pixel channels identical, means within 0.1 %.
    """
    import numpy as np
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    if filter_type == "nearest":
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4)
    else:
        close = np.isclose(a, b, rtol=1e-4, atol=1e-4)
        assert close.mean() > 0.85, f"{(~close).sum()} pixel channels differ"
        assert abs(a.mean() - b.mean()) < 0.01 * b.mean()


def read_vol(path):
    """Reads a Mitsuba .vol (version 3, float32, 1 or 3 channels): (res, bbox,
    list of every channel's values, interleaved)."""
    data = Path(path).read_bytes()
    assert data[:3] == b"VOL" and data[3] == 3
    enc, xres, yres, zres, ch = struct.unpack_from("<5i", data, 4)
    assert enc == 1 and ch in (1, 3)
    bbox = struct.unpack_from("<6f", data, 24)
    n = xres * yres * zres * ch
    values = struct.unpack_from(f"<{n}f", data, 48)
    return (xres, yres, zres), bbox, values


# NVDB_KERNEL_STATS=DIR: every test's Dr.Jit kernels (their count, cache
# hits, code generation and LLVM/CUDA compile times) appended to
# DIR/kernels.jsonl, and the IR of each kernel that took over 0.5 s to
# compile kept as DIR/<hash>.ll: with a cold kernel cache, compilation is
# where most of the suite's time goes (bench/PERF_LOG.md 29-30)
KERNEL_STATS = os.environ.get("NVDB_KERNEL_STATS")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    if not KERNEL_STATS:
        yield
        return
    import json
    import time
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # (drops what came before this test)
    t0 = time.perf_counter()
    yield
    wall = time.perf_counter() - t0
    history = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    out = Path(KERNEL_STATS)
    out.mkdir(parents=True, exist_ok=True)
    kernels = []
    for k in history:
        if k.get("type") != dr.KernelType.JIT:
            continue
        kernels.append(dict(hash=k["hash"], hit=int(k["cache_hit"]), disk=int(k["cache_disk"]),
                            ops=k["operation_count"], size=k["size"],
                            codegen_ms=k["codegen_time"], backend_ms=k["backend_time"],
                            exec_ms=k["execution_time"]))
        if k["backend_time"] > 500 and "ir" in k:
            ll = out / f"{k['hash']}.ll"
            if not ll.exists():
                ll.write_text(k["ir"].getvalue())
    with open(out / "kernels.jsonl", "a") as f:
        f.write(json.dumps(dict(test=item.nodeid, wall_s=wall, kernels=kernels)) + "\n")
